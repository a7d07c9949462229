"""Screens anywhere (`ScreenPose`) and caustic mirrors (`MirrorScene`): the library's
photon tracing against the NumPy reference, the gradient against finite differences,
mirror designs judged by the reference, and bad problems refused by name."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics.inverse.problem import problem_from_dict, problem_to_dict
from jaxcaustics.reference import trace_lens, trace_mirror

EXT = (-0.05, 0.05, -0.05, 0.05)


def bump(n=24, amplitude=0.002):
    yy, xx = np.mgrid[-1 : 1 : n * 1j, -1 : 1 : n * 1j]
    return amplitude * np.exp(-2.0 * (xx**2 + (yy - 0.2) ** 2)) - amplitude


def dip(n=24, amplitude=0.002):
    """A dip whose rim lies on the rest plane (to 4e-5 m): no light leans out past it."""
    yy, xx = np.mgrid[-1 : 1 : n * 1j, -1 : 1 : n * 1j]
    return -amplitude * np.exp(-2.0 * (xx**2 + (yy - 0.2) ** 2))


def tilted_mirror(heights, light, distance=1.0, shape=(32, 32), half=0.06):
    d = np.asarray(light.unit_direction) if isinstance(light, jc.DirectionalLight) else None
    if d is None:  # the central ray of a point light
        d = -np.asarray(light.position) / np.linalg.norm(np.asarray(light.position))
    reflected = d * np.array([1.0, 1.0, -1.0])
    pose = jc.ScreenPose.facing((0.0, 0.0, 0.0), reflected, distance)
    receiver = jc.PlaneReceiver((-half, half, -half, half), shape)
    return jc.MirrorScene(jc.HeightField(heights, EXT, "clamp"), light, receiver, pose)


def blocks(image, k=4):
    rows, cols = image.shape
    return image.reshape(rows // k, k, cols // k, k).mean(axis=(1, 3))


def relative_l2(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_a_pose_gives_the_screens_own_frame():
    pose = jc.ScreenPose((1.0, 2.0, 3.0), (0.0, 0.0, 2.0), up=(0.0, 1.0, 0.5))
    np.testing.assert_allclose(pose.normal, [0, 0, 1])
    np.testing.assert_allclose(pose.up, [0, 1, 0], atol=1e-7)
    np.testing.assert_allclose(pose.right, [1, 0, 0], atol=1e-7)
    s, t, ok = pose.land((jnp.array(1.5), jnp.array(1.0), jnp.array(5.0)), (0.0, 0.0, -1.0))
    assert bool(ok) and float(s) == pytest.approx(0.5) and float(t) == pytest.approx(-1.0)
    # a ray going away from the lit face does not reach it
    assert not bool(pose.land((jnp.array(0.0), jnp.array(0.0), jnp.array(5.0)), (0, 0, 1.0))[2])
    with pytest.raises(ValueError, match="`up`"):
        jc.ScreenPose((0, 0, 0), (0, 0, 1), up=(0, 0, 3))
    with pytest.raises(ValueError, match="`normal`"):
        jc.ScreenPose((0, 0, 0), (0, 0, 0))


@pytest.mark.parametrize(
    ("light", "reference_photons"),
    [
        # collimated: 1024^2 reference photons (measured 0.0028 of the peak apart, 0.00055
        # at 2048^2; 0.8 s of tracing instead of 3.1 s)
        (jc.DirectionalLight.from_angles(30.0, 20.0), 1024),
        (jc.PointLight(np.array([-0.4, 0.1, 0.8])), 2048),
    ],
    ids=["collimated", "point"],
)
def test_a_mirrors_caustic_matches_the_reference(light, reference_photons):
    """Caustic triangles (257^2 photons) against the reference (2048^2 under the point
    light, 1024^2 under the collimated one; cell centres), both averaged over 4 x 4 pixel
    blocks (the reference's binning aliases against the pixels: under the point light,
    2.8% of the peak at 1024^2 photons, 0.9% at 3072^2): within 2% of the peak."""
    scene = tilted_mirror(dip(), light)
    ref = blocks(trace_mirror(scene, reference_photons))
    image = blocks(np.asarray(jc.render(scene, photons=257)))
    assert (ref > 0).mean() > 0.5  # the light is on the screen
    assert np.abs(image - ref).max() <= 0.02 * ref.max()
    assert image.sum() == pytest.approx(ref.sum(), rel=2e-3)


def test_a_lens_screen_facing_the_refracted_beam_matches_the_reference():
    light = jc.DirectionalLight.from_angles(30.0, 0.0)
    pose = jc.ScreenPose.facing((0.0, 0.0, 0.5), light.unit_direction, 0.5)
    scene = jc.LensScene(
        jc.HeightField(bump(), EXT, "clamp"),
        light,
        jc.PlaneReceiver((-0.06, 0.06, -0.06, 0.06), (32, 32)),
        0.01,
        0.5,
        screen_pose=pose,
    )
    ref = trace_lens(scene, 1024)
    image = np.asarray(jc.render(scene, photons=257))
    assert np.abs(image - ref).max() <= 0.03 * ref.max()
    # all the aperture's light lands on the screen (irradiance relative to a horizontal
    # plane's: the flux is the aperture's area), in a beam cos 30 of the lens wide
    assert ref.sum() * (0.12 / 32) ** 2 == pytest.approx(0.1 * 0.1, rel=1e-9)
    lit = np.flatnonzero(ref.sum(axis=0) > 0)
    assert (lit[-1] - lit[0] + 1) * 0.12 / 32 == pytest.approx(
        0.1 * np.cos(np.radians(30)), abs=0.12 / 16
    )


def test_the_gradient_of_a_mirrors_caustic_matches_finite_differences():
    light = jc.DirectionalLight.from_angles(30.0, 0.0)
    base = tilted_mirror(bump(8), light, shape=(8, 8))
    weight = jnp.asarray(np.random.default_rng(0).random((8, 8)))
    direction = jnp.asarray(np.random.default_rng(1).standard_normal((8, 8)) * 1e-4)

    def loss(h):
        scene = jc.MirrorScene(
            jc.HeightField(h, EXT, "clamp"), light, base.receiver, base.screen_pose
        )
        return jnp.sum(weight * jc.render(scene, photons=33, window=8))

    # jitted, one program for the value and the gradient (the differences use its value):
    # run eagerly, op by op, 8 s; same check
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    h0 = jnp.asarray(bump(8))
    grad = value_and_grad(h0)[1]
    eps = 1e-4
    plus, minus = value_and_grad(h0 + eps * direction)[0], value_and_grad(h0 - eps * direction)[0]
    fd = (plus - minus) / (2 * eps)
    assert float(jnp.sum(grad * direction)) == pytest.approx(float(fd), rel=1e-4)


def test_bad_mirror_scenes_are_refused_by_name():
    light = jc.DirectionalLight.from_angles(30.0, 0.0)
    receiver = jc.PlaneReceiver((-0.06, 0.06, -0.06, 0.06), (8, 8))
    surface = jc.HeightField(np.zeros((4, 4)), EXT, "clamp")
    behind = jc.ScreenPose((0.5, 0.0, -0.5), (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="`screen_pose`.*in front"):
        jc.MirrorScene(surface, light, receiver, behind)
    away = jc.ScreenPose((0.5, 0.0, 0.9), (0.5, 0.0, 0.9))
    with pytest.raises(ValueError, match="`screen_pose`.*face the mirror"):
        jc.MirrorScene(surface, light, receiver, away)
    good = jc.ScreenPose.facing((0, 0, 0), (0.5, 0.0, 0.9), 1.0)
    with pytest.raises(ValueError, match="`reflectance`"):
        jc.MirrorScene(surface, light, receiver, good, reflectance=1.5)
    raised = jc.HeightField(np.full((4, 4), 0.01), EXT, "clamp")
    with pytest.raises(ValueError, match="`light`.*above the mirror"):
        jc.MirrorScene(raised, jc.PointLight(np.array([0.0, 0.0, 0.005])), receiver, good)
    # a lens's screen above its bottom face
    with pytest.raises(ValueError, match="`screen_pose`"):
        jc.LensScene(surface, light, receiver, 0.01, 0.5, screen_pose=good)


@pytest.mark.parametrize(
    "problem, match",
    [
        # vertical light: the reflected beam comes back through the light's own
        (
            lambda: jc.DesignProblem(jc.Mirror(0.02), jc.Rectangle(0.1, 0.1), jc.Screen(1.0)),
            "`screen` stands in the light",
        ),
        # a screen normal that looks away from the beam
        (
            lambda: jc.DesignProblem(
                jc.Mirror(0.02),
                jc.Rectangle(0.1, 0.1),
                jc.Screen(1.0, normal=(0.5, 0, 0.866)),
                jc.DirectionalLight.from_angles(30.0),
            ),
            "`screen`.*does not face",
        ),
        # a screen turned a quarter turn against the blank
        (
            lambda: jc.DesignProblem(
                jc.Mirror(0.02),
                jc.Rectangle(0.1, 0.1),
                jc.Screen(1.0, up=(0.866, 0, -0.5)),
                jc.DirectionalLight.from_angles(30.0),
            ),
            "`screen`.*turned",
        ),
    ],
    ids=["in-the-beam", "facing-away", "turned"],
)
def test_bad_mirror_problems_are_refused_by_name_before_anything_runs(problem, match):
    with pytest.raises(ValueError, match=match):
        jc.design(problem(), np.ones((8, 8)))


def test_a_mirror_problem_refuses_a_poisson_start_and_other_elements():
    problem = jc.DesignProblem(
        jc.Mirror(0.02), jc.Rectangle(0.1, 0.1), jc.Screen(1.0), jc.DirectionalLight.from_angles(30)
    )
    with pytest.raises(ValueError, match="`start`.*TransportStart"):
        jc.design(problem, np.ones((8, 8)), start=jc.PoissonLevels())
    with pytest.raises(ValueError, match="`element`"):
        jc.DesignProblem("mirror", jc.Rectangle(0.1, 0.1), jc.Screen(1.0))


def test_a_mirror_problem_survives_its_json():
    problem = jc.DesignProblem(
        jc.Mirror(0.015),
        jc.Circle(0.08),
        jc.Screen(1.0, normal="beam", up=(0, 1, 0)),
        jc.DirectionalLight.from_angles(30.0),
    )
    again = problem_from_dict(problem_to_dict(problem))
    assert isinstance(again.element, jc.Mirror) and again.element.thickness == 0.015
    assert again.screen.normal == "beam" and again.screen.up == (0.0, 1.0, 0.0)
    assert again.posed


def blob_mirror():
    """A 24^2 blob, and a 100 mm mirror under light 30 degrees from its normal, the
    screen 1 m away facing the reflected beam."""
    yy, xx = np.mgrid[-1:1:24j, -1:1:24j]
    target = 0.3 + np.exp(-4 * ((xx - 0.3) ** 2 + yy**2)) + 0.6 * np.exp(-8 * (xx + 0.4) ** 2)
    problem = jc.DesignProblem(
        jc.Mirror(0.02), jc.Rectangle(0.1, 0.1), jc.Screen(1.0), jc.DirectionalLight.from_angles(30)
    )
    return target, problem


# 25-40 s (a design and a 512^2 reference trace): on request, for the default run's time
# budget; benchmarks/results/mirror.md judges mirror designs at 128^2 by the reference
@pytest.mark.slow
def test_a_mirror_design_matches_its_target_by_the_reference():
    """A 24^2 blob under light 30 degrees from the mirror's normal, the screen 1 m away
    facing the reflected beam, judged by the reference (512^2 photons). Measured: 0.012
    (0.013 without the image refinement, which runs under leaning light whatever the
    target; the design's own prediction 0.0006, 0.006 without it)."""
    target, problem = blob_mirror()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        design = jc.design(problem, target)
    assert isinstance(design.scene, jc.MirrorScene)
    assert design.levels[-1]["stage"] == "image refinement"  # no dark pixels, yet it runs
    ref = trace_mirror(design.scene, 512)
    error = relative_l2(ref / ref.mean(), target / target.mean())
    assert error < 0.025
    # widened from 0.012: the refinement fits the prediction's own model, whose 24^2
    # image differs from the reference's by about 0.011 here (measured), so the gap is
    # that model error, not the design's
    assert abs(error - design.predicted_error) < 0.016


def test_the_transport_is_stretched_by_the_cosine_of_the_mirrors_angle():
    """Off a mirror under 30-degree light, with the screen across the reflected beam, a
    slope along x moves the light cos 30 as far (in the screen's width) as one along y
    moves it in its height: the transport's cells are cos 30 as wide as high."""
    from jaxcaustics.inverse.lens_model import level_model, vertex_sampling
    from jaxcaustics.inverse.lens_setup import prepare
    from jaxcaustics.inverse.transport_start import _landing_gain, transport_stretch

    problem = jc.DesignProblem(
        jc.Mirror(0.02), jc.Rectangle(0.1, 0.1), jc.Screen(1.0), jc.DirectionalLight.from_angles(30)
    )
    setup = prepare(problem, np.ones((16, 16)), jc.TransportStart(), None)
    shape = setup.shapes[-1]
    model = level_model(setup, shape)
    sampling = vertex_sampling(shape, setup.aperture, model.grid, setup.boundary)
    pixel = jnp.asarray([(setup.screen[1] - setup.screen[0]) / 16, 0.1 / 16])
    gain = _landing_gain(model, sampling, shape, 0.1 / shape[1], 0.1 / shape[0], pixel)
    assert setup.flips == (True, False)  # the mirror reverses the screen's s axis
    assert transport_stretch(gain, setup, shape) == pytest.approx(np.cos(np.radians(30)), 1e-3)


def test_a_target_correction_brings_a_mirror_design_closer():
    """The default under leaning light (one correction) against none: the predicted
    caustic's error falls (measured on this 24^2 blob: 0.0087 to 0.0061)."""
    target, problem = blob_mirror()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # without the finish, which now runs under leaning light: the correction alone
        none = jc.design(problem, target, start=jc.TransportStart(corrections=0), finish=None)
        one = jc.design(problem, target, finish=None)
    stages = [r["stage"] for r in one.levels]
    assert stages.count("target correction") == 1 and stages.count("landing fit") == 2
    # no dark regions: the smooth Legendre transforms (`TransportStart.smooth`)
    assert [r["smooth"] for r in one.levels if r["stage"] == "transport"] == [True, True]
    assert one.predicted_error < none.predicted_error
