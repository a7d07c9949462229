"""The rayGeo iteration table script runs and shows the estimate converging."""

import importlib.util
from pathlib import Path

import pytest


@pytest.mark.slow
def test_raygeo_iterations_quick(tmp_path):
    path = Path(__file__).parent.parent / "paper_figures" / "raygeo_iterations.py"
    spec = importlib.util.spec_from_file_location("raygeo_iterations", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    text = module.main(["--quick", "--output", str(tmp_path)])
    assert (tmp_path / "raygeo_iterations.md").read_text() == text
    rows = [line.split("|") for line in text.splitlines() if line.startswith("| sun 10")]
    medians = [float(row[3].split("/")[0]) for row in rows]  # back surface, mm
    assert len(medians) == 4 and medians == sorted(medians, reverse=True)
    assert medians[-1] < 0.05 * medians[0]
