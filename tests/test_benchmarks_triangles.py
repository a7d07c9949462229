"""Smoke test: the caustic triangles benchmark runs in its quick mode and writes its
table and plot. Slow (about a minute on 2 cores, mostly compilation)."""

import importlib.util
from pathlib import Path

import pytest

BENCH = Path(__file__).parent.parent / "benchmarks" / "bench_triangles.py"


@pytest.mark.slow
def test_bench_triangles_quick(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_triangles", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--quick", "--out", str(tmp_path)])
    text = (tmp_path / "triangles.md").read_text()
    for heading in ("exact triangles", "Gouraud triangles", "Gaussian splats", "reference"):
        assert heading in text
    assert "| 129^2 |" in text
    png = tmp_path / "triangles_error_vs_time.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size < 100_000
