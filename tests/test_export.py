"""Exporting lenses for fabrication: the solid, the height maps, the report."""

import json
import math

import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics.inverse.export import (
    ManufacturabilityReport,
    export_lens,
    lens_height_map,
    lens_solid,
    manufacturability,
)


def _cap(radius_m, size_m, n, *, kind="sphere", sign=1.0, boundary="clamp"):
    """A bowl (``sign=1``, concave seen from above) or dome (``sign=-1``) over a square
    aperture of side `size_m`, ``n x n`` samples, apex at the centre."""
    c = (np.arange(n) + 0.5) / n * size_m - size_m / 2
    x, y = np.meshgrid(c, c)
    r2 = x * x + y * y
    if kind == "sphere":
        h = radius_m - np.sqrt(radius_m**2 - r2)
    else:
        h = r2 / (2 * radius_m)
    return jc.HeightField(sign * h, (0.0, size_m, 0.0, size_m), boundary)


def _lens_scene(surface, thickness):
    return jc.LensScene(
        surface,
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver(np.asarray(surface.extent), (8, 8)),
        thickness=thickness,
        screen_distance=0.3,
    )


# --------------------------------------------------------------------------- the solid


def test_flat_slab_is_a_box_in_millimetres():
    # a 30 x 20 mm aperture away from the origin, 5 mm thick
    surface = jc.HeightField(np.zeros((4, 6)), (0.1, 0.13, -0.05, -0.03), "clamp")
    for mesh in (lens_solid(surface, 0.005), lens_solid(_lens_scene(surface, 0.005))):
        assert isinstance(mesh, trimesh.Trimesh)
        assert mesh.is_watertight and mesh.is_volume
        np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [30, 20, 5]], atol=1e-9)
        assert mesh.volume == pytest.approx(30 * 20 * 5, rel=1e-9)
        assert mesh.units == "mm"
        # bottom at z = 0 facing down, top at z = 5 facing up, walls outwards
        normals, centres = mesh.face_normals, mesh.triangles_center
        bottom = centres[:, 2] < 1e-9
        np.testing.assert_allclose(normals[bottom], [[0, 0, -1]] * bottom.sum(), atol=1e-12)
        top = centres[:, 2] > 5 - 1e-9
        np.testing.assert_allclose(normals[top], [[0, 0, 1]] * top.sum(), atol=1e-12)


def test_solid_top_is_the_rendered_surface():
    rng = np.random.default_rng(0)
    heights = 1e-3 * rng.standard_normal((5, 7))
    surface = jc.HeightField(heights, (0.0, 0.07, 0.0, 0.05), "clamp")
    z = lens_height_map(surface, 0.004)
    assert z.shape == (11, 15)  # default: twice the grid plus one
    # vertices at pixel centres hold the samples; at the pixel corners between the
    # centres 0..3 (rows and columns), the Catmull-Rom weights at t = 1/2
    np.testing.assert_allclose(z[1::2, 1::2], (0.004 + heights) * 1000, atol=1e-12)
    w = np.array([-1.0, 9.0, 9.0, -1.0]) / 16
    assert z[4, 4] == pytest.approx((0.004 + w @ heights[:4, :4] @ w) * 1000, abs=1e-12)

    mesh = lens_solid(surface, 0.004, samples=(9, 12))
    assert mesh.is_watertight and mesh.is_volume
    z9 = lens_height_map(surface, 0.004, samples=(9, 12))
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [70, 50, z9.max()]], atol=1e-9)

    # a rotated field is exported in its own frame: the same solid
    rotated = jc.HeightField(heights, (0.0, 0.07, 0.0, 0.05), "clamp", rotation=0.7)
    np.testing.assert_allclose(lens_height_map(rotated, 0.004), z, atol=1e-12)


# --------------------------------------------------------------------------- the report


def test_paraboloid_radius_and_slope():
    # z = r^2 / (2 R), R = 20 mm: the Catmull-Rom bicubic reproduces quadratics exactly
    # away from the clamped edge, so the smallest radius is R (at the apex) to rounding
    # and the steepest slope is atan(r / R) at the corners of the checked region.
    surface = _cap(0.02, 0.02, 20, kind="paraboloid")
    report = manufacturability(surface, thickness=0.005, margin_mm=2.0, samples=(41, 41))
    assert report.min_concave_radius_mm == pytest.approx(20.0, rel=1e-9)
    assert report.min_radius_mm == pytest.approx(20.0, rel=1e-9)
    np.testing.assert_allclose(report.min_concave_radius_at_mm, (10.0, 10.0), atol=1e-9)
    corner = math.hypot(8.0, 8.0)
    assert report.max_slope_deg == pytest.approx(math.degrees(math.atan(corner / 20)), 1e-9)
    assert report.min_thickness_mm == pytest.approx(5.0, abs=1e-9)
    assert report.max_thickness_mm == pytest.approx(5.0 + corner**2 / 40, rel=1e-9)
    assert report.ok and report.warnings == ()


def test_spherical_cap_radius_and_rim_slope():
    # z = R - sqrt(R^2 - r^2), R = 40 mm, 1 mm samples: radius R within 2 % (the
    # bicubic's error where the cap is steepest), rim slope asin(r / R) within 0.01 deg.
    surface = _cap(0.04, 0.02, 20)
    report = manufacturability(surface, thickness=0.005, margin_mm=2.0, samples=(41, 41))
    assert report.min_concave_radius_mm == pytest.approx(40.0, rel=0.02)
    assert report.min_radius_mm == pytest.approx(report.min_concave_radius_mm)
    rim = math.hypot(8.0, 8.0)
    assert report.max_slope_deg == pytest.approx(math.degrees(math.asin(rim / 40)), abs=0.01)
    x, y = report.max_slope_at_mm
    assert min(x, 20 - x) == pytest.approx(2.0) and min(y, 20 - y) == pytest.approx(2.0)


def test_tool_radius_warning_only_in_concave_regions_smaller_than_the_tool():
    bowl = _cap(0.02, 0.02, 20, kind="paraboloid")
    kw = {"thickness": 0.005, "margin_mm": 2.0, "samples": (41, 41)}
    big = manufacturability(bowl, tool_radius_mm=25.0, **kw)
    assert len(big.warnings) == 1 and "concave radius" in big.warnings[0]
    assert "tool radius 25 mm" in big.warnings[0] and not big.ok
    small = manufacturability(bowl, tool_radius_mm=15.0, **kw)
    assert small.ok

    dome = _cap(0.02, 0.02, 20, kind="paraboloid", sign=-1.0)
    convex = manufacturability(dome, tool_radius_mm=100.0, **kw)
    assert convex.ok
    assert math.isinf(convex.min_concave_radius_mm) and convex.min_concave_radius_at_mm is None
    assert convex.min_radius_mm == pytest.approx(20.0, rel=1e-9)


def test_clamped_edge_is_checked_without_margin():
    # the clamped edge levels the bowl off within 1.5 samples: a sharp bend that is part
    # of the exported surface, reported unless a margin leaves it out
    bowl = _cap(0.02, 0.02, 20, kind="paraboloid")
    report = manufacturability(bowl, thickness=0.005, tool_radius_mm=15.0, samples=(41, 41))
    assert report.min_concave_radius_mm < 15.0 and not report.ok


def test_thickness_and_slope_warnings_and_text():
    flat = jc.HeightField(np.zeros((20, 20)), (0.0, 0.01, 0.0, 0.01), "clamp")
    kw = {"samples": (41, 41)}
    thin = manufacturability(flat, thickness=0.0005, min_thickness_mm=1.0, **kw)
    assert thin.min_thickness_mm == pytest.approx(0.5)
    assert math.isinf(thin.min_radius_mm) and math.isinf(thin.min_concave_radius_mm)
    assert len(thin.warnings) == 1 and thin.warnings[0].startswith("too thin: 0.5 mm")

    steep = manufacturability(
        _cap(0.02, 0.02, 20), thickness=0.005, max_slope_deg=20.0, samples=(41, 41)
    )
    assert any(w.startswith("too steep") for w in steep.warnings)
    text = str(steep)
    for part in ("20.00 x 20.00 mm", "thickness:", "max slope:", "min concave radius:"):
        assert part in text
    assert "problem(s)" in text and "OK" not in text
    assert "OK: within all limits." in str(manufacturability(flat, thickness=0.005, **kw))
    assert isinstance(steep, ManufacturabilityReport)
    with pytest.raises(AttributeError):
        steep.max_slope_deg = 0.0  # frozen
    assert json.loads(json.dumps(thin.to_dict()))["min_radius_mm"] is None


# --------------------------------------------------------------------------- files


def test_export_files_round_trip(tmp_path):
    surface = _cap(0.02, 0.02, 20)
    scene = _lens_scene(surface, 0.004)
    paths = export_lens(scene, tmp_path / "out", name="cap", margin_mm=2.0, formats=("stl", "obj"))
    assert set(paths) == {
        "stl",
        "obj",
        "height_png",
        "height_json",
        "height_exr",
        "report_json",
        "report_txt",
    }
    assert all(p.is_file() and p.parent == tmp_path / "out" for p in paths.values())
    solid = lens_solid(scene)
    for fmt in ("stl", "obj"):
        loaded = trimesh.load(paths[fmt], force="mesh")
        assert loaded.is_watertight and loaded.is_volume
        np.testing.assert_allclose(loaded.bounds, solid.bounds, atol=1e-5)
        assert loaded.volume == pytest.approx(solid.volume, rel=1e-6)

    z = lens_height_map(scene)
    exr = jc.io.read_exr(paths["height_exr"])
    assert exr.dtype == np.float32 and exr.shape == z.shape
    np.testing.assert_allclose(exr, z, rtol=1e-7)
    meta = json.loads(paths["height_json"].read_text())
    lo, hi = meta["min_mm"], meta["max_mm"]
    assert meta["unit"] == "mm" and meta["shape"] == list(z.shape)
    assert meta["boundary"] == "clamp"  # the interpolant's, to read the samples back with
    assert lo == pytest.approx(z.min()) and hi == pytest.approx(z.max())
    png = jc.read_image(paths["height_png"]).astype(float)
    assert png.min() == 0.0 and png.max() == 1.0  # the full 16-bit range
    step = (hi - lo) / 65535
    np.testing.assert_allclose(lo + png * (hi - lo), z, atol=0.5 * step + 1e-6 * hi)

    report = manufacturability(scene, margin_mm=2.0)
    assert paths["report_txt"].read_text() == str(report) + "\n"
    assert json.loads(paths["report_json"].read_text()) == json.loads(json.dumps(report.to_dict()))


# --------------------------------------------------------------------------- bad input


def test_bad_inputs_raise_value_error_naming_the_argument(tmp_path):
    surface = jc.HeightField(np.zeros((3, 3)), (0.0, 0.01, 0.0, 0.01), "clamp")
    scene = _lens_scene(surface, 0.004)
    for bad in (-0.001, 0.0, float("nan"), "thick"):
        with pytest.raises(ValueError, match="`thickness`"):
            lens_solid(surface, bad)
    with pytest.raises(ValueError, match="`thickness`"):
        lens_solid(surface)  # required with a HeightField
    with pytest.raises(ValueError, match="`thickness`"):
        lens_solid(scene, 0.004)  # the scene has its own
    with pytest.raises(ValueError, match="`scene_or_surface`"):
        lens_solid(np.zeros((3, 3)), 0.004)
    with pytest.raises(ValueError, match="`samples`"):
        lens_solid(scene, samples=(1, 5))
    dips = np.full((4, 6), -0.002)
    dips[1, 1] = 0.0
    dips = jc.HeightField(dips, (0, 0.01, 0, 0.01), "clamp")
    with pytest.raises(ValueError, match="bottom face"):
        lens_solid(dips, 0.001)

    for bad in (0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match="`tool_radius_mm`"):
            manufacturability(scene, tool_radius_mm=bad)
        with pytest.raises(ValueError, match="`tool_radius_mm`"):
            export_lens(scene, tmp_path / "never", tool_radius_mm=bad)
    assert not (tmp_path / "never").exists()  # nothing written
    with pytest.raises(ValueError, match="`min_thickness_mm`"):
        manufacturability(scene, min_thickness_mm=-1.0)
    with pytest.raises(ValueError, match="`max_slope_deg`"):
        manufacturability(scene, max_slope_deg=91.0)
    with pytest.raises(ValueError, match="`margin_mm`"):
        manufacturability(scene, margin_mm=5.0)

    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory")
    with pytest.raises(ValueError, match="`directory`"):
        export_lens(scene, a_file)
    with pytest.raises(ValueError, match="`directory`"):
        export_lens(scene, a_file / "sub")
    with pytest.raises(ValueError, match="`formats`"):
        export_lens(scene, tmp_path, formats=("stl", "step"))
    with pytest.raises(ValueError, match="`name`"):
        export_lens(scene, tmp_path, name="../lens")


def test_an_export_that_fails_leaves_no_file_behind(tmp_path, monkeypatch):
    """Every file is staged and renamed into place at the end: a failure on the fourth
    file (the EXR) leaves neither the first three nor a half-written one, and the
    files of an earlier export stay as they were."""
    import jaxcaustics.inverse.export as export

    scene = _lens_scene(_cap(0.02, 0.02, 20), 0.004)
    out = tmp_path / "out"
    first = export_lens(scene, out, name="cap")
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(export, "write_exr", full_disk)
    with pytest.raises(OSError, match="No space"):
        export_lens(_lens_scene(_cap(0.03, 0.02, 20), 0.004), out, name="cap")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    with pytest.raises(OSError):
        export_lens(scene, tmp_path / "fresh", name="cap")
    assert list((tmp_path / "fresh").iterdir()) == []
    assert set(first) >= {"stl", "height_exr"}
