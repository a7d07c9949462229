"""The caustic spot light figure scripts (Liu et al. 2008) run in their quick modes and
give sane numbers."""

import importlib.util
import math
from pathlib import Path

import pytest

FIGURES = Path(__file__).parent.parent / "paper_figures"


def load(name):
    spec = importlib.util.spec_from_file_location(name, FIGURES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def check_files(result, tmp_path):
    for path in result["files"]:
        assert Path(path).parent == tmp_path
        assert Path(path).stat().st_size > 0
    assert (tmp_path / Path(result["files"][0]).name).read_text() == result["markdown"]


@pytest.mark.slow
def test_fig2_sphere_rays_quick(tmp_path):
    module = load("fig2_sphere_rays")
    result = module.main(["--quick", "--output", str(tmp_path)])
    check_files(result, tmp_path)
    rows = result["rows"]
    assert [r["n"] for r in rows] == [1.1, 1.2, 1.3]
    for r in rows:
        assert r["valid"] > 0
        assert r["paraxial"] == pytest.approx(r["n"] / (2 * (r["n"] - 1)))
        # the ray nearest the axis focuses at the paraxial focus ...
        assert r["near_axis"] == pytest.approx(r["paraxial"], rel=2e-3)
        # ... the marginal rays much nearer (spherical aberration), where optics says
        assert r["grazing"] < r["marginal"] < 0.6 * r["paraxial"]
        assert r["marginal"] == pytest.approx(r["marginal_exact"], rel=1e-3)
        assert r["marginal"] > 1.0  # outside the ball
    # a stronger lens focuses nearer
    assert rows[0]["paraxial"] > rows[1]["paraxial"] > rows[2]["paraxial"]
    assert rows[0]["marginal"] > rows[1]["marginal"] > rows[2]["marginal"]


@pytest.mark.slow
def test_fig6_intensity_correction_quick(tmp_path):
    module = load("fig6_intensity_correction")
    result = module.main(["--quick", "--output", str(tmp_path)])
    check_files(result, tmp_path)
    for key in ("error_corrected", "error_uncorrected", "error_reference_half"):
        assert math.isfinite(result[key]) and result[key] >= 0, key
    # Eq. 4 matters: the corrected image is far nearer the reference
    assert result["error_corrected"] < 0.5 * result["error_uncorrected"]
    assert result["error_corrected"] < 0.3
    assert 0.8 < result["flux_corrected"] < 1.2
    assert result["error_reference_half"] < 0.05
    assert result["lights"] >= 1


@pytest.mark.slow
def test_csl_moving_light_quick(tmp_path):
    module = load("csl_moving_light")
    result = module.main(["--quick", "--output", str(tmp_path)])
    check_files(result, tmp_path)
    assert (tmp_path / "csl_moving_light_table.npz").exists()
    assert result["directions"] == 42 and result["precompute_seconds"] > 0
    assert result["vertex"]["zenith"] <= module.MAX_ZENITH
    assert result["face_centre"]["zenith"] <= module.MAX_ZENITH
    assert result["face_centre"]["to_nearest_vertex_deg"] > 5.0  # between the directions
    errors = {(r["direction"], r["method"]): r["rel_l1"] for r in result["rows"]}
    assert len(errors) == 5 and all(math.isfinite(e) for e in errors.values())
    # at a vertex the table gives the vertex's own fit (resampled into a canonical frame)
    assert abs(errors[("vertex", "table")] - errors[("vertex", "direct fit")]) < 0.05
    # between the vertices, interpolating beats the nearest precomputed set
    interpolated = errors[("face centre", "table")]
    assert interpolated < errors[("face centre", "nearest precomputed set")]
    assert interpolated < 0.5 and errors[("face centre", "direct fit")] < 0.5
    # the reloaded table gives the same numbers
    again = module.main(["--quick", "--reuse-table", "--output", str(tmp_path)])
    assert again["precompute_seconds"] is None
    assert again["rows"][0]["rel_l1"] == pytest.approx(result["rows"][0]["rel_l1"], rel=1e-6)
