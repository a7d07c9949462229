"""Smoke test: the scaling benchmark runs in its quick mode (1 and 2 simulated devices)
and writes its table and plot. Slow (a few minutes on 2 cores, mostly compilation)."""

import importlib.util
import json
from pathlib import Path

import pytest

BENCH = Path(__file__).parent.parent / "benchmarks" / "bench_scaling.py"


@pytest.mark.slow
def test_bench_scaling_quick(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_scaling", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--quick", "--out", str(tmp_path)])
    text = (tmp_path / "scaling.md").read_text()
    for name in bench.WORKLOADS:
        assert f"| {name} | 1 |" in text and f"| {name} | 2 |" in text
    raw = json.loads((tmp_path / "scaling.json").read_text())["rows"]
    assert set(raw) == {"1", "2"} and all(name in raw["1"] for name in bench.WORKLOADS)
    png = tmp_path / "scaling.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size < 100_000
