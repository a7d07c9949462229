"""Error estimates from two settings of a method's accuracy knob, and
``render(scene, tolerance=t, refine=True)`` refining until the estimate meets t."""

import numpy as np
import pytest
import trimesh

import jaxcaustics as jc

APERTURE = (-0.05, 0.05, -0.05, 0.05)


def lens(pixels=24):
    bump = jc.internal.gaussian_bump(
        (32, 32), APERTURE, center=(0.01, -0.01), sigma=0.02, amplitude=0.002
    )
    return jc.LensScene(
        jc.HeightField(bump, APERTURE, "clamp"),
        jc.DirectionalLight.from_angles(15.0, 30.0),
        jc.PlaneReceiver((-0.07, 0.07, -0.07, 0.07), (pixels, pixels)),
        thickness=0.01,
        screen_distance=0.3,
    )


@pytest.fixture(scope="module")
def reference():
    return jc.reference_image(lens(), photons_per_axis=800)


def test_refined_and_coarsened_are_inverse_steps_of_the_accuracy_knob():
    finer = jc.TwoPass(supersample=2, hit_iterations=3).refined()
    assert (finer.supersample, finer.hit_iterations) == (4, 4)
    assert finer.coarsened() == jc.TwoPass(supersample=2, hit_iterations=3)
    assert jc.TwoPass(supersample=1).coarsened() is None
    assert jc.TwoPass(supersample=2, hit_iterations=0).coarsened() is None
    assert jc.CausticTriangles(photons=33).refined().photons == (65, 65)
    assert jc.CausticTriangles(photons=(65, 33)).coarsened().photons == (33, 17)
    assert jc.CausticsMapping(photons=512).coarsened().photons == 256
    assert jc.AdaptiveCausticMap(photons=64, base=64).coarsened() is None
    assert jc.SpotLightMethod(rays_per_axis=64).refined().rays_per_axis == 128


def test_the_estimate_is_the_difference_of_two_settings_and_not_optimistic(reference):
    scene = lens()
    result, estimate = jc.internal.estimate_error(scene, jc.CausticTriangles(photons=33))
    assert estimate.coarse.photons == (17, 17) and estimate.fine.photons == 33
    coarse = jc.render(scene, estimate.coarse)
    assert estimate.difference == pytest.approx(jc.image_error(coarse, result.image), rel=1e-9)
    assert estimate.missed == 0.0 and estimate.error == estimate.difference
    true = jc.image_error(np.asarray(result.image), reference)
    # measured: 0.036 estimated for a true 0.017 (caustic triangles converge at second
    # order, so the difference over-states the finer image's error); never below 1/1.5
    assert estimate.error >= true / 1.5


@pytest.mark.parametrize("tolerance", [0.02, 0.005])
def test_refining_meets_the_tolerance_against_the_reference(reference, tolerance):
    image, stats = jc.render(lens(), tolerance=tolerance, refine=True, return_stats=True)
    assert stats["error_estimate"] <= tolerance
    assert jc.image_error(np.asarray(image), reference) <= tolerance
    assert stats["levels"][-1].error == stats["error_estimate"]


def test_a_spent_budget_warns_with_the_error_reached():
    with pytest.warns(UserWarning, match="tolerance 1e-07 not met: the estimated error is"):
        jc.render(lens(), tolerance=1e-7, refine=True, budget_s=1e-3)


def test_refine_options_are_checked():
    with pytest.raises(ValueError, match="`refine`"):
        jc.render(lens(), refine="yes", tolerance=0.1)
    with pytest.raises(ValueError, match="`refine` applies only with `tolerance`"):
        jc.render(lens(), refine=True)
    with pytest.raises(ValueError, match="`budget_s` applies only when refining"):
        jc.render(lens(), tolerance=0.1, refine=False, budget_s=10.0)
    with pytest.raises(ValueError, match="budget_s"):
        jc.render(lens(), tolerance=0.1, refine=True, budget_s=-1.0)
    with pytest.raises(ValueError, match="`method` must be a Method"):
        jc.internal.estimate_error(lens(), "triangles")
    with pytest.raises(ValueError, match="`subdivisions` is for an EllipsoidScene"):
        jc.internal.estimate_error(lens(), jc.CausticTriangles(photons=9), subdivisions=2)
    with pytest.raises(ValueError, match="`subdivisions`"):
        jc.internal.estimate_error(lens(), jc.CausticTriangles(photons=9), subdivisions=-1)


def sea(zenith, pixels=24):
    extent = (0.0, 1.0, 0.0, 1.0)
    waves = jc.sine_sum((pixels, pixels), extent, terms=((2, 3, 0.004, 0.3), (4, -1, 0.002, 1.1)))
    return jc.WaterScene(
        jc.HeightField(waves, extent),
        jc.DirectionalLight.from_angles(zenith, 40.0),
        jc.PlaneReceiver(extent, (pixels, pixels)),
        0.7,
    )


@pytest.mark.parametrize("zenith, tolerance", [(0.0, 0.005), (70.0, 0.01)])
def test_water_is_refined_by_default_and_meets_the_tolerance(zenith, tolerance):
    """The two-pass estimate compares S and 2S sub-samples (and one Newton step more):
    with sub-samples covering their own part of the pixel it converges to the reference
    and the difference does not under-state the error (bench_estimate.py)."""
    scene = sea(zenith)
    ref = jc.reference_image(scene, photons_per_axis=32)
    image, stats = jc.render(scene, tolerance=tolerance, return_stats=True)
    assert stats["error_estimate"] <= tolerance
    assert isinstance(stats["levels"][-1].fine, jc.TwoPass)
    assert jc.image_error(np.asarray(image), ref) <= tolerance


def test_only_methods_with_a_reliable_estimate_are_refined():
    """The caustic maps' estimate misses their splats' error (measured up to 95 times
    under the true error): refining them would miss the tolerance unsaid."""
    reliable = [c.name for c in jc.methods.registry.METHODS.values() if c.estimate_is_reliable]
    assert reliable == ["twopass", "triangles"]
    blob = jc.MeshScene(
        jc.Mesh.from_trimesh(
            trimesh.creation.icosphere(1, radius=0.3).apply_translation((0, 0, 1))
        ),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
        ior=1.5,
    )
    with pytest.raises(ValueError, match="estimate of method 'caustics_mapping' was measured"):
        jc.render(blob, "caustics_mapping", tolerance=0.05, refine=True)


@pytest.mark.slow  # 21 s (the default run's 8-minute budget); the mesh and lens
# refinements above keep the level bookkeeping in the default run
def test_an_ellipsoid_refines_its_tessellation_with_the_photons():
    """With a fixed tessellation its error is common to every photon grid (the estimate
    under-stated the error 1.7 times on a held-out ball, bench_estimate.py): each level
    is one subdivision finer."""
    ball = jc.EllipsoidScene(
        jc.Ellipsoid((0.0, 0.05, 0.8), (0.3, 0.26, 0.28)),
        jc.DirectionalLight.from_angles(30.0, 60.0),
        jc.PlaneReceiver((-1.2, 1.2, -1.2, 1.2), (16, 16)),
        ior=1.5,
    )
    image, stats = jc.render(ball, tolerance=0.02, return_stats=True)
    first, last = stats["levels"][0], stats["levels"][-1]
    assert first.fine_subdivisions == first.coarse_subdivisions + 1
    assert last.fine_subdivisions == first.fine_subdivisions + len(stats["levels"]) - 1
    assert stats["error_estimate"] <= 0.02
    ref = jc.reference_image(ball, photons_per_axis=512)
    assert jc.image_error(np.asarray(image), ref) <= 0.02


def test_a_configured_method_is_not_silently_replaced_by_the_tolerance_choice():
    with pytest.raises(ValueError, match="`tolerance` picks the knobs: pass the method's name"):
        jc.render(lens(), jc.CausticTriangles(photons=9), tolerance=0.05)
    # a default instance says only which method
    image = jc.render(lens(), jc.CausticTriangles(), tolerance=0.05, refine=True)
    assert image.shape == (24, 24)
