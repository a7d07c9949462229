"""Smoke test: the caustic maps benchmark runs in its quick mode and writes its table and
plot, with a row for every method and errors that behave. Slow (about three minutes on
2 cores, mostly compilation and exact ray tracing)."""

import importlib.util
import json
import math
from pathlib import Path

import pytest

BENCH = Path(__file__).parent.parent / "benchmarks" / "bench_caustic_maps.py"


def _load():
    spec = importlib.util.spec_from_file_location("bench_caustic_maps", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def _errors(rows, method):
    """``{photons: error}`` of one method's rows."""
    return {r["photons"]: r["error"] for r in rows if r["method"] == method}


@pytest.mark.slow
def test_bench_caustic_maps_quick(tmp_path):
    bench = _load()
    bench.main(["--quick", "--out", str(tmp_path)])
    md = tmp_path / bench.MD_NAME
    text = md.read_text()
    data = json.loads((tmp_path / "caustic_maps.json").read_text())
    meta, results = data["meta"], data["rows"]
    assert data["environment"]["jax"]
    assert meta["quick"] and meta["uptime_before"] and meta["uptime_after"]
    assert [r["name"] for r in results] == ["sphere", "torus"]
    config = bench.CONFIGS["quick"]
    for result in results:
        rows = result["rows"]
        assert f"## {result['name']}" in text
        # a row for every method and photon count asked for, with finite errors
        expected = {
            bench.DENSE: config["dense"],
            bench.DENSE_EXACT: config["dense_exact"],
            bench.ADAPTIVE["traversal"]: config["traversal"],
            bench.ADAPTIVE["error"]: config["error"],
            bench.TRIANGLES: config["triangles"],
            bench.REFERENCE: config["ref_checks"],
        }
        for method, grids in expected.items():
            assert sorted(_errors(rows, method)) == sorted(grids), method
            assert f"| {method}" in text
        for r in rows:
            assert math.isfinite(r["error"]) and 0 < r["error"] < 1.5, r
            assert r["ms"] > 0 and r["runs"] >= 1, r
            assert 0 < r["splatted"] <= r["generated"], r
        # more photons, less error: dense splats at their best radius and triangles
        for method in (bench.DENSE, bench.TRIANGLES):
            errors = _errors(rows, method)
            counts = sorted(errors)
            assert all(errors[a] > errors[b] for a, b in zip(counts, counts[1:], strict=False)), (
                result["name"],
                method,
                errors,
            )
        # the adaptive traversal ends on the same photons as the dense grid (at the same
        # splat radius), shading fewer of them
        dense = {r["photons"]: r for r in rows if r["method"] == bench.DENSE}
        for r in rows:
            if r["method"] == bench.ADAPTIVE["traversal"] and r["photons"] in dense:
                d = dense[r["photons"]]
                assert r["error"] == pytest.approx(d["error"], rel=0.1), (r, d)
                assert r["generated"] < d["generated"]
        # the truth's own error is estimated from a run with half its photons per axis
        assert result["truth_checks"] and result["truth"]["error"] is None
    png = tmp_path / bench.PNG_NAME
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size < 150_000
    # the report can be redone from the rows stored in the JSON beside it
    before = md.read_text()
    bench.main(["--report-only", "--out", str(tmp_path)])
    assert md.read_text() == before
