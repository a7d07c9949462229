"""The accuracy-time benchmark in its quick mode: its table has the schema that
`render(scene, tolerance=...)` reads, every choosable row runs through `jc.render` as
stored, and the package's own table is left alone. Slow (a few minutes on 2 cores,
mostly compilation)."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

import jaxcaustics as jc

ROOT = Path(__file__).parent.parent
BENCH = ROOT / "benchmarks" / "bench_accuracy.py"
PACKAGE_TABLE = ROOT / "jaxcaustics" / "data" / "accuracy.json"
KINDS = ("water", "lens", "mesh", "moving_light")
ROW_KEYS = {"method", "knobs", "as_mesh", "error", "time_s", "compile_s", "choosable"}


def load_bench():
    spec = importlib.util.spec_from_file_location("bench_accuracy", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_knobs_per_pixel_round_trip():
    """Cheap: photon grids are stored per pixel and resolved back exactly."""
    bench = load_bench()
    stored = bench.table_knobs("triangles", {"photons": 33, "reconstruction": "exact"}, 64)
    assert stored == {"photons": {"per_pixel": 0.515625}, "reconstruction": "exact"}
    resolve = jc.methods.choose.resolve_knobs
    assert resolve("triangles", stored, (64, 48), (64, 64)) == {
        "photons": 33,
        "reconstruction": "exact",
    }
    assert resolve("triangles", stored, (32, 128), (64, 64))["photons"] == 66
    # never fewer photons than measured
    assert resolve("triangles", stored, (16, 16), (64, 64))["photons"] == 33
    assert resolve("adaptive", {"photons": {"per_pixel": 4.0}}, (100, 90), (64, 64)) == {
        "photons": 512
    }
    assert bench.table_knobs("twopass", {"samples_x": 3, "channels_y": 2}, 64) == {
        "samples_x": 3,
        "channels_y": 2,
    }


@pytest.mark.slow
def test_bench_accuracy_quick(tmp_path):
    before = PACKAGE_TABLE.read_bytes() if PACKAGE_TABLE.exists() else None
    bench = load_bench()
    table_path = tmp_path / "accuracy.json"
    bench.main(["--quick", "--output", str(tmp_path), "--table", str(table_path)])
    if before is not None:
        assert PACKAGE_TABLE.read_bytes() == before

    table = json.loads(table_path.read_text())
    for key in ("schema", "generated", "commit", "device", "dtype", "metric", "kinds"):
        assert key in table, key
    assert table["schema"] == 1
    assert table["dtype"] == "float32"
    assert set(table["kinds"]) == set(KINDS)
    for kind, result in table["kinds"].items():
        assert result["failed"] == [], (kind, result["failed"])
        scene = bench.KIND_SCENES[kind][0](result["pixels"][0])
        assert list(scene.receiver.shape) == result["pixels"]
        assert result["rows"], kind
        for row in result["rows"]:
            assert ROW_KEYS <= set(row), (kind, row)
            assert row["method"] in jc.methods.registry.METHODS, row
            assert 0.0 <= row["error"] < 1.0 and row["time_s"] > 0.0, row
            assert row["as_mesh"] is None or set(row["as_mesh"]) == {"subdivisions"}
            if not row["choosable"]:
                continue
            # the row's knobs as stored, resolved for this receiver, run through render
            knobs = jc.methods.choose.resolve_knobs(
                row["method"], row["knobs"], scene.receiver.shape, result["pixels"]
            )
            image = np.asarray(jc.render(bench.scene_for_row(scene, row), row["method"], **knobs))
            assert image.shape == tuple(result["pixels"])
            assert np.all(np.isfinite(image)) and image.sum() > 0
        refs = result["reference"]
        assert refs and all(set(r) >= {"function", "knobs", "error", "time_s"} for r in refs)
        assert refs[-1]["error_estimated"] is True
        assert refs[-1]["knobs"]["photons_per_axis"] > refs[0]["knobs"]["photons_per_axis"]
        # the reference converges: its coarsest run is the worst
        assert refs[0]["error"] >= max(r["error"] for r in refs[1:])

    text = (tmp_path / "accuracy.md").read_text()
    for kind in KINDS:
        assert f"## {kind}" in text
    png = tmp_path / "accuracy.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size < 150_000


def test_package_table_schema():
    """Cheap: the stored table (when present) names methods and knobs `render` takes."""
    if not PACKAGE_TABLE.exists():
        pytest.skip("no stored table yet")
    table = json.loads(PACKAGE_TABLE.read_text())
    assert table["schema"] == 1
    for result in table["kinds"].values():
        for row in result["rows"]:
            assert ROW_KEYS <= set(row)
            assert row["method"] in jc.methods.registry.METHODS
            for value in row["knobs"].values():
                assert not isinstance(value, dict) or set(value) == {"per_pixel"}
