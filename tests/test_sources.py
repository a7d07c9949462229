"""Extended light sources (`jc.SunLight`, `jc.AreaLight`): their sampling, the
reference's integration over them, the blur kernel a design uses against that
integration, and designs made for them."""

import json
import warnings

import equinox as eqx
import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.inverse import source_blur
from jaxcaustics.inverse.problem import problem_from_dict, problem_to_dict


def _error(a, b):
    a, b = a / a.mean(), b / b.mean()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ------------------------------------------------------------------ the lights


def test_the_sun_is_a_directional_light_with_its_disc():
    sun = jc.SunLight.from_angles(30.0, 90.0)
    assert isinstance(sun, jc.DirectionalLight)
    np.testing.assert_allclose(
        np.asarray(sun.direction), np.asarray(jc.DirectionalLight.from_angles(30.0, 90.0).direction)
    )
    assert sun.angular_radius_deg == pytest.approx(0.2665)
    directions, weights = sun.directions(257)
    centre = np.asarray(sun.unit_direction, float)
    angles = np.degrees(np.arccos(np.clip(directions @ centre, -1, 1)))
    assert angles.max() <= 0.2665 and angles.max() > 0.26  # the disc, to its rim
    assert weights.sum() == pytest.approx(1.0) and np.ptp(weights) == 0.0
    # the stratified cover is centred: the mean direction is the centre's
    mean = (weights[:, None] * directions).sum(axis=0)
    assert np.degrees(np.arccos(mean @ centre / np.linalg.norm(mean))) < 0.01


def test_limb_darkening_weights_the_rim_less():
    directions, weights = jc.SunLight(limb_darkening=0.6).directions(400)
    rho = np.linalg.norm(directions[:, :2], axis=1)
    assert weights[np.argmin(rho)] > 2.0 * weights[np.argmax(rho)]  # 1 against 0.4 + a bit


@pytest.mark.parametrize(
    ("build", "name"),
    [
        (lambda: jc.SunLight(angular_radius_deg=0.0), "angular_radius_deg"),
        (lambda: jc.SunLight(angular_radius_deg=20.0), "angular_radius_deg"),
        (lambda: jc.SunLight(angular_radius_deg=float("nan")), "angular_radius_deg"),
        (lambda: jc.SunLight(limb_darkening=1.5), "limb_darkening"),
        (lambda: jc.SunLight([0.0, 0.0, 1.0]), "direction"),
        (lambda: jc.AreaLight([0, 0, 1.0], -0.003), "size"),
        (lambda: jc.AreaLight([0, 0, 1.0], (0.003, 0.002, 0.001)), "size"),
        (lambda: jc.AreaLight([0, 0, 1.0], (0.003, 0.002), shape="disc"), "size"),
        (lambda: jc.AreaLight([0, 0, 1.0], 0.003, shape="hexagon"), "shape"),
        (lambda: jc.AreaLight([0, 0, -1.0], 0.003), "position"),
    ],
)
def test_bad_sources_are_refused_by_name(build, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        build()


@pytest.mark.parametrize("shape", ["rectangle", "disc"])
def test_an_area_light_is_a_point_light_whose_points_cover_it(shape):
    die = jc.AreaLight([0.01, -0.02, 0.5], (0.004, 0.002) if shape == "rectangle" else 0.004,
                       shape=shape)  # fmt: skip
    assert isinstance(die, jc.PointLight) and die.lambertian
    points, weights = die.points(400)
    offset = points - np.asarray(die.position, float)
    assert np.all(offset[:, 2] == 0.0) and weights.sum() == pytest.approx(1.0)
    if shape == "rectangle":
        assert np.abs(offset[:, 0]).max() == pytest.approx(0.002 * 19 / 20)  # 20 x 20 cells
        assert np.abs(offset[:, 1]).max() == pytest.approx(0.001 * 19 / 20)
    else:
        assert np.linalg.norm(offset[:, :2], axis=1).max() <= 0.002
    np.testing.assert_allclose(offset[:, :2].mean(axis=0), 0.0, atol=2e-5)


def test_sources_survive_design_json():
    for light in (jc.SunLight.from_angles(10.0, limb_darkening=0.5),
                  jc.AreaLight([0, 0, 0.7], (0.003, 0.002), intensity=2.0),
                  jc.AreaLight([0, 0, 0.7], 0.003, shape="disc", lambertian=False)):  # fmt: skip
        problem = jc.DesignProblem(jc.Lens(0.01), jc.Rectangle(0.05, 0.05), jc.Screen(0.3), light)
        back = problem_from_dict(json.loads(json.dumps(problem_to_dict(problem)))).light
        assert type(back) is type(light)
        for field in ("angular_radius", "limb_darkening", "size", "shape", "lambertian"):
            assert getattr(back, field, None) == getattr(light, field, None), field


# ------------------------------------------------------- rendering under them


def _bump_lens(amplitude, light, n=48):
    x = np.linspace(-1.0, 1.0, 64)
    xx, yy = np.meshgrid(x, x)
    bumps = np.exp(-((xx - 0.3) ** 2 + yy**2) / 0.05)
    bumps += 0.6 * np.exp(-((xx + 0.4) ** 2 + (yy - 0.3) ** 2) / 0.02)
    extent = np.array([-0.05, 0.05, -0.05, 0.05])
    surface = jc.HeightField(-amplitude * bumps, extent, "clamp")
    return jc.LensScene(surface, light, jc.PlaneReceiver(extent, (n, n)), 0.01, 0.5)


def test_the_reference_under_the_sun_is_its_directions_averaged():
    """`trace_lens` under a `SunLight` is the weighted mean of collimated traces along
    the disc's directions, each with the photons shared out."""
    sun = jc.SunLight()
    scene = _bump_lens(3e-4, sun, n=16)
    image = reference.trace_lens(scene, 256, source_samples=16)
    directions, weights = sun.directions(16)
    by_hand = sum(
        w * reference.trace_lens(eqx.tree_at(lambda s: s.light, scene, jc.DirectionalLight(d)), 64)
        for d, w in zip(directions, weights, strict=True)
    )
    np.testing.assert_allclose(image, by_hand, rtol=1e-12)


def test_the_designs_blur_kernel_against_the_reference_sampling_the_sun():
    """The design models the Sun as the collimated caustic convolved with the Sun's image
    on the screen (`source_blur.source_kernel`). Against the reference sampling the disc
    densely (256 directions at 4096^2 photons; its noise 0.003) on a lens with two bumps,
    500 mm above a 48^2 screen (the blur: 1.1 pixels in radius): measured 0.0048 at a
    peak of 1.24 x the mean, 0.021 at 2.45 x (this test's lens, at 64 directions) and
    0.054 at 5.8 x (the collimated image is 0.071, 0.103 and 0.209 off): the kernel
    leaves out how the lens's own focusing changes the disc."""
    scene = _bump_lens(3e-4, jc.DirectionalLight([0.0, 0.0, -1.0]))
    sun = jc.SunLight()
    sampled = reference.trace_lens(eqx.tree_at(lambda s: s.light, scene, sun), 2048,
                                   source_samples=64)  # fmt: skip
    collimated = reference.trace_lens(scene, 2048)
    problem = jc.DesignProblem(jc.Lens(0.01), jc.Rectangle(0.1, 0.1), jc.Screen(0.5), sun)
    kernel = source_blur.source_kernel(problem, None, np.asarray(scene.receiver.extent), (48, 48))
    assert source_blur.blur_radius(kernel) == pytest.approx(1.39, abs=0.02)  # 1.13 + splat
    modelled = source_blur.blur(collimated, kernel)
    assert _error(modelled, sampled) < 0.03 < _error(collimated, sampled) / 3


def test_a_lambertian_die_sends_less_to_the_rim_than_a_point_light():
    """Under a tiny Lambertian die the flat lens's caustic falls off as a point light's
    times ``cos`` of the emission angle, in the reference and in the library alike."""
    above = 0.3 + 0.01 + 0.05
    die = jc.AreaLight([0.0, 0.0, above], 1e-6)
    point = jc.PointLight([0.0, 0.0, above])
    extent = np.array([-0.1, 0.1, -0.1, 0.1])
    flat = jc.HeightField(np.zeros((8, 8)), np.array([-0.025, 0.025, -0.025, 0.025]), "clamp")

    def scene(light):
        return jc.LensScene(flat, light, jc.PlaneReceiver(extent, (8, 8)), 0.01, 0.3)

    ratio_ref = reference.trace_lens(scene(die), 64, source_samples=1) / reference.trace_lens(
        scene(point), 64
    )
    # one sample of the die (it is 1 um wide; the default 64 took ten times as long)
    ratio_lib = np.asarray(jc.render(scene(die), "triangles", source_samples=1)) / np.asarray(
        jc.render(scene(point), "triangles")
    )
    lit = ratio_ref > 0
    assert ratio_ref[lit].max() == pytest.approx(1.0, abs=0.01)
    # the rim's pixels gather light leaving the die up to 35 mm aside of 50 mm (cos 0.82)
    assert 0.8 < ratio_ref[lit].min() < 0.97
    np.testing.assert_allclose(ratio_lib[lit], ratio_ref[lit], atol=0.02)


# --------------------------------------------------------------- designs


@pytest.fixture(scope="module")
def sun_design():
    """A 32^2 camera under the Sun at 2 m, the blur about 1.2 pixels."""
    from skimage import data

    from jaxcaustics.inverse.numerics import area_average

    target = area_average(data.camera().astype(float), (32, 32))
    problem = jc.DesignProblem(jc.Lens(0.01), jc.Rectangle(0.1, 0.1), jc.Screen(2.0),
                               jc.SunLight())  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        design = jc.design(problem, target)
    return design, target, [str(w.message) for w in caught]


@pytest.mark.slow  # with its design, 40 s in all: the time budget of the default run;
# the designs for the Sun are judged in benchmarks/results/sources.md
def test_a_design_for_the_sun_reports_its_blur_and_predicts_what_is_seen(sun_design):
    design, target, _ = sun_design
    # 2 m x tan(0.2665 deg) over 100 mm / 32 pixels: 3.0 pixels (splat included)
    assert design.source_blur_px == pytest.approx(3.0, abs=0.3)
    # the prediction is the blurred caustic: no sharper than the kernel allows
    centre = jc.DirectionalLight(np.asarray(design.scene.light.direction))
    raw = jc.render(eqx.tree_at(lambda s: s.light, design.scene, centre), "triangles")
    kernel = source_blur.source_kernel(design.problem, None, np.asarray(
        design.scene.receiver.extent), target.shape)  # fmt: skip
    assert _error(np.asarray(design.predicted), source_blur.blur(np.asarray(raw), kernel)) < 0.05


@pytest.mark.slow  # with its design, 40 s in all: the time budget of the default run;
# the designs for the Sun are judged in benchmarks/results/sources.md
def test_a_target_finer_than_the_sun_allows_is_warned_with_the_number(sun_design):
    _, _, caught = sun_design
    said = [m for m in caught if "blurs each point of the caustic" in m]
    assert len(said) == 1 and "`screen_distance`" in said[0], caught
    assert "pixels in radius" in said[0] and "relative L2" in said[0]


@pytest.mark.slow  # with its design, 40 s in all: the time budget of the default run;
# the designs for the Sun are judged in benchmarks/results/sources.md
def test_the_design_for_the_sun_beats_the_collimated_one_under_the_sun(sun_design):
    """Judged by the reference sampling the Sun (its noise: below 0.003 here)."""
    design, target, _ = sun_design
    collimated = jc.design(
        jc.DesignProblem(jc.Lens(0.01), jc.Rectangle(0.1, 0.1), jc.Screen(2.0)), target
    )
    sun = design.problem.light
    judged = [
        _error(
            reference.trace_lens(
                eqx.tree_at(lambda s: s.light, d.scene, sun), 512, source_samples=64
            ),
            target,
        )  # fmt: skip
        for d in (design, collimated)
    ]
    assert judged[0] < 0.8 * judged[1], judged


def test_the_cli_places_an_led_die_against_the_light_above_the_top():
    import argparse

    from jaxcaustics.cli.design import _light, _light_kind

    problem = jc.DesignProblem(jc.Lens(0.01), jc.Rectangle(0.05, 0.05), jc.Screen(0.3))
    args = argparse.Namespace(light=_light_kind("led:3mm@100mm"), zenith=0.0, azimuth=0.0)
    die = _light(args, problem)
    assert isinstance(die, jc.AreaLight) and die.size == pytest.approx((0.003, 0.003))
    np.testing.assert_allclose(np.asarray(die.position), [0.0, 0.0, 0.31 + 0.1], atol=1e-9)
    args = argparse.Namespace(light="sun", zenith=20.0, azimuth=45.0)
    assert isinstance(_light(args, problem), jc.SunLight)


def test_render_under_a_die_is_its_points_rendered_and_averaged():
    """`jc.render` under an `AreaLight` renders each of `source_samples` points as a
    tiny Lambertian die and averages them with the points' weights."""
    die = jc.AreaLight([0.0, 0.0, 0.9], 0.02)  # its image on the screen: 4 pixels
    scene = _bump_lens(3e-4, die, n=16)
    image = np.asarray(jc.render(scene, "triangles", photons=65, source_samples=4))
    points, weights = die.points(4)
    by_hand = sum(
        w * np.asarray(jc.render(eqx.tree_at(lambda s: s.light, scene,
                                             jc.AreaLight(p, 1e-9)), "triangles", photons=65))
        for p, w in zip(points, weights, strict=True)
    )  # fmt: skip
    np.testing.assert_allclose(image, by_hand, rtol=1e-5, atol=1e-6)
    centre = np.asarray(jc.render(eqx.tree_at(lambda s: s.light, scene, jc.AreaLight(
        die.position, 1e-9)), "triangles", photons=65))  # fmt: skip
    assert _error(image, centre) > 0.01  # the die's points do cast it aside


@pytest.mark.slow  # 13 s; its sampling is checked exactly in the test above
def test_render_under_the_sun_samples_its_disc_as_the_reference_does():
    """`jc.render` under a `SunLight` renders each of `source_samples` directions and
    averages them: against the reference sampling the Sun on the bump lens, as near as
    the collimated render is to the collimated reference (measured against 256
    directions at 4096^2 photons: 0.0083 at 16 samples, 0.0040 at 64; collimated render
    against collimated reference 0.012), and far from the collimated render, which the
    Sun's centre alone would give (0.100)."""
    scene = _bump_lens(3e-4, jc.SunLight())
    image, stats = jc.render(scene, "triangles", source_samples=64, return_stats=True)
    assert stats["source_samples"] == 64
    sampled = reference.trace_lens(scene, 2048, source_samples=64)
    centre = eqx.tree_at(lambda s: s.light, scene, jc.DirectionalLight([0.0, 0.0, -1.0]))
    collimated = np.asarray(jc.render(centre, "triangles"))
    floor = _error(collimated, reference.trace_lens(centre, 2048))
    assert _error(np.asarray(image), sampled) < max(1.5 * floor, 0.01)
    assert _error(collimated, sampled) > 5 * _error(np.asarray(image), sampled)


def test_render_refuses_source_samples_without_an_extended_light():
    scene = _bump_lens(3e-4, jc.DirectionalLight([0.0, 0.0, -1.0]), n=8)
    with pytest.raises(ValueError, match="`source_samples`"):
        jc.render(scene, "triangles", source_samples=4)
    with pytest.raises(ValueError, match="`tolerance`"):
        jc.render(_bump_lens(3e-4, jc.SunLight(), n=8), tolerance=0.05)


def test_an_extended_light_under_jit_says_what_to_do():
    import jax

    scene = _bump_lens(3e-4, jc.SunLight(), n=8)
    with pytest.raises(ValueError, match="`scene.light`: a SunLight's samples"):
        jax.jit(lambda s: jc.render(s, "triangles", photons=17, window=4))(scene)


def test_a_verification_under_a_source_takes_four_times_the_photons_per_side():
    from jaxcaustics.inverse.verify import default_photons

    assert default_photons(jc.DirectionalLight([0, 0, -1.0]), (32, 48)) == 8 * 48
    assert default_photons(jc.SunLight(), (32, 48)) == 32 * 48
    assert default_photons(jc.AreaLight([0, 0, 1.0], 0.003), (32, 48)) == 32 * 48
