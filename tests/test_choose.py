"""Choosing a method for an accuracy budget: `choose_method` and `render(tolerance=)`.

The rules are tested here on small synthetic tables; `test_tolerance.py` checks the stored
table against the reference on held-out scenes.
"""

import logging

import numpy as np
import pytest
import trimesh

import jaxcaustics as jc

APERTURE = (0.0, 0.1, 0.0, 0.1)


def water(shape=(8, 8)):
    heights = 0.002 * np.sin(np.linspace(0, 2 * np.pi, shape[1], endpoint=False))[None, :]
    surface = jc.HeightField(np.repeat(heights, shape[0], axis=0), (0, 1, 0, 1))
    return jc.WaterScene(
        surface, jc.DirectionalLight.from_angles(20.0), jc.PlaneReceiver((0, 1, 0, 1), shape)
    )


def lens(shape=(8, 8)):
    return jc.LensScene(
        jc.HeightField(np.zeros((8, 8)), APERTURE, "clamp"),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(APERTURE, shape),
        thickness=0.01,
        screen_distance=0.3,
    )


def mesh_scene(mesh, **kw):
    return jc.MeshScene(
        jc.Mesh.from_trimesh(mesh),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
        **kw,
    )


def ball(z=1.0, radius=0.3):
    mesh = trimesh.creation.icosphere(2, radius=radius)
    mesh.apply_translation([0.0, 0.0, z])
    return mesh


def cylinder():
    mesh = trimesh.creation.cylinder(radius=0.3, height=0.6, sections=32)
    mesh.apply_translation([0.0, 0.0, 1.0])
    return mesh


def ellipsoid_scene(radii=(0.3, 0.3, 0.3), occluders=()):
    return jc.EllipsoidScene(
        jc.Ellipsoid((0.0, 0.0, 1.0), radii),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
        occluders=occluders,
    )


def row(method, error, time_s, knobs=None, **extra):
    return dict(method=method, knobs=knobs or {}, error=error, time_s=time_s, **extra)


TABLE = {
    "schema": 1,
    "kinds": {
        "water": {
            "pixels": [8, 8],
            "rows": [
                row("twopass", 0.05, 0.001, {"supersample": 1}),
                row("twopass", 0.01, 0.004, {"supersample": 2}),
                row("twopass", 0.004, 0.02, {"supersample": 4}),
            ],
        },
        "lens": {
            "pixels": [16, 16],
            "rows": [
                row("triangles", 0.02, 0.01, {"photons": {"per_pixel": 2.0}}),
                row("triangles", 0.005, 0.05, {"photons": {"per_pixel": 8.0}}),
            ],
        },
        "mesh": {
            "pixels": [8, 8],
            "rows": [
                row("caustics_mapping", 0.03, 0.002, {"photons": 64}),
                row("spot_lights", 0.03, 0.001, {"rays_per_axis": 64}),
                row("triangles", 0.03, 0.01, {"photons": 65}),
                row("triangles", 0.01, 0.1, {"photons": 257}),
            ],
        },
        "moving_light": {
            "pixels": [8, 8],
            "rows": [
                row("spot_lights", 0.06, 0.01, {"rays_per_axis": 64}),
                row("triangles", 0.03, 0.2, {"photons": 65}, as_mesh={"subdivisions": 2}),
                row("spot_lights", 0.01, 0.001, {}, choosable=False),
            ],
        },
    },
}


def test_picks_the_fastest_setting_within_the_tolerance_with_margin():
    choice = jc.internal.choose_method(water(), 0.11, table=TABLE)
    assert (choice.method, choice.knobs) == ("twopass", {"supersample": 1})
    # 0.05 * 2 (the default margin) > 0.06: the next setting
    choice = jc.internal.choose_method(water(), 0.06, table=TABLE)
    assert choice.knobs == {"supersample": 2} and choice.expected_error == 0.01
    choice = jc.internal.choose_method(water(), 0.06, table=TABLE, margin=1.0)
    assert choice.knobs == {"supersample": 1}
    assert choice.candidates == 3 and choice.meeting == 3
    assert "twopass" in str(choice) and "0.05" in str(choice)


def test_tolerance_below_every_setting_names_the_best_error():
    with pytest.raises(ValueError, match=r"smallest error is 0\.004"):
        jc.internal.choose_method(water(), 0.005, table=TABLE)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "small"])
def test_bad_tolerance_is_named(bad):
    with pytest.raises(ValueError, match="tolerance"):
        jc.internal.choose_method(water(), bad, table=TABLE)


def test_margin_below_one_is_refused():
    with pytest.raises(ValueError, match="margin"):
        jc.internal.choose_method(water(), 0.1, margin=0.5, table=TABLE)


def test_knobs_that_follow_the_resolution_and_the_expected_time_scale():
    choice = jc.internal.choose_method(lens((32, 24)), 0.05, table=TABLE)
    assert choice.knobs == {"photons": 64}  # 2 per pixel of the longer side
    assert choice.expected_time_s == pytest.approx(0.01 * 32 * 24 / 256)
    assert choice.table_time_s == 0.01 and choice.table_pixels == (16, 16)


def test_method_restricts_the_choice_to_its_knobs():
    choice = jc.internal.choose_method(mesh_scene(ball()), 0.1, method="triangles", table=TABLE)
    assert choice.knobs == {"photons": 65}
    with pytest.raises(ValueError, match="`method`"):
        jc.internal.choose_method(water(), 0.1, method="triangles", table=TABLE)


def test_occlusion_is_never_given_to_a_method_that_cannot_do_it():
    occluded = mesh_scene(ball(), occluders=[jc.Mesh.from_trimesh(ball(z=1.8, radius=0.1))])
    choice = jc.internal.choose_method(occluded, 0.1, table=TABLE)
    assert choice.method == "triangles"
    assert "occlu" in choice.excluded["caustics_mapping"]
    assert "occlu" in choice.excluded["spot_lights"]
    assert jc.internal.method_support("twopass", occluded) is not None
    assert jc.internal.method_support("triangles", occluded) is None


def test_a_cylinder_is_never_given_to_caustic_spot_lights():
    """Liu et al. Sect. 6: a cylinder focuses light on a moving line, not a point."""
    assert jc.internal.method_support("spot_lights", mesh_scene(ball())) is None
    reason = jc.internal.method_support("spot_lights", mesh_scene(cylinder()))
    assert reason is not None and "sphere-like" in reason
    choice = jc.internal.choose_method(mesh_scene(cylinder()), 0.1, table=TABLE)
    assert choice.method == "caustics_mapping" and "spot_lights" in choice.excluded
    # the ball gets the (faster) spot lights
    assert jc.internal.choose_method(mesh_scene(ball()), 0.1, table=TABLE).method == "spot_lights"


def test_elongated_ellipsoids_and_point_lights_are_not_given_to_spot_lights():
    assert jc.internal.method_support("spot_lights", ellipsoid_scene()) is None
    assert "elongated" in jc.internal.method_support(
        "spot_lights", ellipsoid_scene((0.1, 0.1, 0.5))
    )
    point = mesh_scene(ball())
    point = jc.MeshScene(
        point.generator, jc.PointLight([0.0, 0.0, 3.0]), point.receiver, ior=point.ior
    )
    assert "parallel" in jc.internal.method_support("spot_lights", point)


def test_two_pass_takes_water_only():
    assert jc.internal.method_support("twopass", water()) is None
    for scene in (lens(), mesh_scene(ball()), ellipsoid_scene()):
        assert jc.internal.method_support("twopass", scene) is not None


def test_moving_light_rows_render_through_the_mesh_and_skip_report_only_rows():
    choice = jc.internal.choose_method(ellipsoid_scene(), 0.07, table=TABLE)
    # the report-only spot-lights row (error 0.01, fastest) is not choosable
    assert choice.method == "triangles" and choice.as_mesh == {"subdivisions": 2}
    mesh = jc.methods.choose.as_mesh_scene(ellipsoid_scene(), 2)
    assert isinstance(mesh, jc.MeshScene) and mesh.generator.faces.shape == (320, 3)
    assert jc.internal.choose_method(ellipsoid_scene(), 0.13, table=TABLE).method == "spot_lights"


def test_mirrors_have_no_table():
    mirror = mesh_scene(ball(), material="mirror")
    with pytest.raises(ValueError, match="mirror"):
        jc.internal.choose_method(mirror, 0.1, table=TABLE)


def test_render_with_tolerance_runs_the_choice_and_reports_it(monkeypatch, caplog):
    monkeypatch.setattr(jc.methods.choose, "_packaged_table", lambda: TABLE)
    scene = water()
    with caplog.at_level(logging.INFO, logger="jaxcaustics"):
        # refine=False: the table's choice (water is refined by default)
        image, stats = jc.render(scene, tolerance=0.06, refine=False, return_stats=True)
    assert stats["choice"].knobs == {"supersample": 2}
    assert "twopass" in caplog.text and "expected error" in caplog.text
    np.testing.assert_array_equal(np.asarray(image), np.asarray(jc.render(scene, supersample=2)))
    with pytest.raises(ValueError, match="tolerance"):
        jc.render(scene, tolerance=0.06, supersample=4)


def test_stored_table_has_every_kind_and_runnable_methods():
    table = jc.internal.accuracy_table()
    assert set(table["kinds"]) == {"water", "lens", "mesh", "moving_light"}
    for kind, entry in table["kinds"].items():
        assert len(entry["pixels"]) == 2
        rows = [r for r in entry["rows"] if r.get("choosable", True)]
        assert rows, kind
        for r in rows:
            assert r["method"] in jc.methods.registry.METHODS
            assert np.isfinite(r["error"]) and r["error"] > 0 and r["time_s"] > 0
        for ref in entry["reference"]:
            assert np.isfinite(ref["error"]) and ref["time_s"] > 0


def test_image_error_blurs_across_the_border_of_a_periodic_image():
    """One bright pixel at the left edge against the same light one pixel away across
    the border (the right edge): with ``boundary="periodic"`` the two are neighbours and
    their blurred images nearly agree; with the default (zero outside) they are far
    apart. Unblurred, the boundary does not matter, and equal images have no error."""
    image, reference = np.zeros((16, 16)), np.zeros((16, 16))
    image[8, 0] = reference[8, 15] = 1.0
    periodic = jc.image_error(image, reference, boundary="periodic")
    constant = jc.image_error(image, reference)
    assert periodic < 0.9 and constant > 1.9  # measured 0.80 and 2.0
    assert jc.image_error(image, reference, blur=0.0, boundary="periodic") == 2.0
    assert jc.image_error(image, image, boundary="periodic") == 0.0
    with pytest.raises(ValueError, match="`boundary`"):
        jc.image_error(image, reference, boundary="wrap")
