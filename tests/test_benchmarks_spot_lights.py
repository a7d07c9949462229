"""Smoke test: the caustic spot lights benchmark runs in its quick mode and writes its
tables (fitting, evaluation, error, precomputation) with finite numbers, and its plot.
Slow (one to a few minutes on 2 cores, mostly jit compilation of the fit)."""

import importlib.util
import json
import math
import re
from pathlib import Path

import pytest

BENCH = Path(__file__).parent.parent / "benchmarks" / "bench_spot_lights.py"


def _load():
    spec = importlib.util.spec_from_file_location("bench_spot_lights", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def _table(text, header_start):
    """The rows of the first markdown table whose header starts with `header_start`, as
    dicts from column name to cell text."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    names = [c.strip() for c in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert len(cells) == len(names), line
        rows.append(dict(zip(names, cells, strict=True)))
    assert rows, header_start
    return rows


def _number(cell):
    """The first number in a cell (``1,234.5``, ``0.0123``, ``32^2``...)."""
    match = re.search(r"-?\d[\d,]*(?:\.\d+)?(?:e-?\d+)?|-?\.\d+", cell)
    assert match, cell
    return float(match.group().replace(",", ""))


def _finite(cell):
    return math.isfinite(_number(cell))


@pytest.mark.slow
def test_bench_spot_lights_quick(tmp_path):
    bench = _load()
    bench.main(["--quick", "--output", str(tmp_path)])
    md = tmp_path / bench.MD_NAME
    text = md.read_text()
    config = bench.CONFIGS["quick"]
    assert "float32" in text and "load average" in text
    for title in ("## 1. Fitting", "## 2. Evaluating", "## 3. Error", "## 4. Precomputation"):
        assert title in text, title

    # 1. fitting time per direction, one row per ray count
    fit = _table(text, "| traced rays |")
    assert [r["traced rays"] for r in fit] == [f"{n}^2" for n in config["fit_rays"]]
    for r in fit:
        assert 1 <= _number(r["lights"]) <= 16, r
        assert 0.9 <= _number(r["energy held"]) <= 1.0, r
        assert _number(r["trace + fit ms"]) > 0 and _number(r["first call s"]) > 0, r

    # 2. evaluation: all slots and active only, as called and jitted
    ev = _table(text, "| lights rendered |")
    assert len(ev) == 4 and {r["call"] for r in ev} == {"as called", "jax.jit"}
    assert all(_number(r["time ms"]) > 0 for r in ev)

    # 3. error against the reference, over max_lights and energy_fraction
    by_lights = _table(text, "| max_lights |")
    by_energy = _table(text, "| energy_fraction |")
    assert [_number(r["max_lights"]) for r in by_lights] == config["max_lights"]
    assert [_number(r["energy_fraction"]) for r in by_energy] == config["energy_fractions"]
    for r in by_lights + by_energy:
        assert 0 < _number(r["energy held"]) <= 1 and 0 <= _number(r["discarded"]) < 1, r
        assert _finite(r["error (1 px blur)"]) and 0 < _number(r["error (1 px blur)"]) < 1, r
        assert _finite(r["error (no blur)"]) and 0 < _number(r["error (no blur)"]) < 1.5, r
        assert _number(r["fit ms"]) > 0 and _number(r["render ms"]) > 0, r
    # one light carries less of the energy than sixteen, and has more error
    one, sixteen = by_lights[0], by_lights[-1]
    assert _number(one["energy held"]) < _number(sixteen["energy held"])
    assert _number(one["error (1 px blur)"]) > _number(sixteen["error (1 px blur)"])
    assert re.search(r"photons took \d", text)  # the reference's own time

    # 4. precomputation: the measured run and the extrapolation, labelled as such
    pre = _table(text, "| subdivisions |")
    assert pre[0]["kind"] == "measured" and "estimate" in pre[1]["kind"]
    for r in pre:
        assert _finite(r["total"]) and _number(r["total"]) > 0, r
        assert _finite(r["CSL sets s"]) and _finite(r["tracking s"]), r

    # raw rows stored, plot written and small, report reproducible from the rows
    data = json.loads((tmp_path / f"{bench.NAME}.json").read_text())
    assert data["meta"]["quick"] and set(data["rows"]) == set(bench.PARTS)
    png = tmp_path / bench.PNG_NAME
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size < 100_000
    bench.main(["--report-only", "--output", str(tmp_path)])
    assert md.read_text() == text
