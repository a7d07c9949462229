"""Caustic maps: Shah et al.'s caustics mapping and Wyman & Nichols' adaptive maps.

Scenes: a glass ball (icosphere, radius 0.5 m, centre 1 m above the screen) over a
screen four times its width, so it fills about 5% of the light's view, as an object
does in the papers' scene-wide light frustum.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.methods.caustic_map.gbuffer import (
    geometry_buffers,
    intersection_errors,
    raster_window,
)


def ball_scene(zenith=10.0, *, shape=(32, 32), subdivisions=2, dtype=np.float64, **kwargs):
    ball = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.5)
    ball.apply_translation([0.0, 0.0, 1.0])
    light = jc.DirectionalLight.from_angles(zenith)
    return jc.MeshScene(
        jc.Mesh(np.asarray(ball.vertices, dtype), ball.faces),
        jc.DirectionalLight(np.asarray(light.direction, dtype)),
        jc.PlaneReceiver(np.asarray((-2.0, 2.0, -2.0, 2.0), dtype), shape),
        ior=kwargs.pop("ior", 1.5),
        interfaces=kwargs.pop("interfaces", 4),
        **kwargs,
    )


def blur(image, sigma=1.0):
    from skimage.filters import gaussian

    return gaussian(np.asarray(image, np.float64), sigma=sigma, mode="constant")


@pytest.fixture(scope="module")
def ball():
    return ball_scene()


@pytest.fixture(scope="module")
def ball_reference(ball):
    # 768^2 photons over the ball's projection: ~460k photons, ~450 per lit pixel
    return reference.trace_mesh(ball, 768)


@pytest.mark.slow
def test_splatted_maps_converge_to_the_reference(ball, ball_reference):
    """More photons with a proportionally smaller splat radius (``sigma='auto'``: one
    photon spacing in map texels) approach the reference. Both images are blurred by a
    1-pixel Gaussian before the relative L1 error (the map's bilinear lookup and the
    reference's binning are different filters at the pixel scale; the reference's own
    error, 768^2 against 1536^2 photons, is 6e-4). Measured with the exact intersection:
    0.19, 0.090, 0.034 for 64, 128, 256 photons per side of the light's view."""
    errors = [
        jc.image_error(
            jc.internal.caustics_mapping(
                ball, photons=n, map_resolution=128, intersection="exact"
            ).image,
            ball_reference,
        )
        for n in (64, 128, 256)
    ]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.05


@pytest.mark.slow  # on request (slow), for the default run's 10-minute budget: the image-space
# estimate is also checked against the reference in this file
def test_image_space_estimate_converges_with_iterations(ball):
    """Shah et al.'s rayGeo update against the exact hits: the median distance to the
    exact exit point and the exact hit on the screen falls with each iteration (the
    update is a fixed-point iteration; on a plane it contracts by ``sin^2`` of the ray's
    angle to the light). Measured on this ball (metres, median): 0.17 / 0.065 with no
    iteration, 0.025 / 0.014 after one (the paper's choice), about 1e-3 after four."""
    view = jc.internal.light_view(ball)
    window = raster_window(ball, view, 128)
    buffers = eqx.filter_jit(geometry_buffers)(ball, view, 128, window)
    errors = intersection_errors(ball, buffers, 48, iterations=(0, 1, 4))
    back = [errors[k][0] for k in (0, 1, 4)]
    screen = [errors[k][2] for k in (0, 1, 4)]
    assert back == sorted(back, reverse=True) and screen == sorted(screen, reverse=True)
    assert back[0] > 0.05 and screen[0] > 0.02  # no iteration: far off
    assert back[-1] < 3e-3 and screen[-1] < 3e-3


@pytest.mark.slow
def test_image_space_caustic_against_the_reference(ball, ball_reference):
    """The paper's pipeline (geometry buffers, two interfaces, rayGeo with 4 iterations)
    against the reference, 1-pixel blur: measured 0.085 at 256 photons per side and
    0.088 at 512 (the exact intersection: 0.034): the estimate's own error dominates,
    from photons near the ball's rim, where the rayGeo update contracts slowly (their
    landing points are off by 0.18 m median after 4 iterations, 0.004 m after 32)."""
    image = jc.internal.caustics_mapping(ball, photons=256, map_resolution=128, iterations=4).image
    assert jc.image_error(image, ball_reference) < 0.11


def test_adaptive_traversal_equals_the_dense_map(ball):
    """Maximal traversal at level L splats exactly the photons of the dense grid that go
    through the ball (the footprint test discards no cluster the object touches): same
    image to rounding."""
    knobs = dict(photons=256, map_resolution=64, gbuffer_resolution=64)
    dense = jc.internal.caustics_mapping(ball, **knobs)
    adaptive = jc.internal.adaptive_caustic_map(ball, metric="traversal", **knobs)
    assert adaptive.stats["splatted"] == dense.stats["splatted"]
    # all levels counted, the tree generates a fraction of the dense grid's photons
    assert adaptive.stats["generated"] <= dense.stats["generated"] / 4
    np.testing.assert_allclose(adaptive.image, dense.image, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_paper_discard_test_loses_the_rim(ball):
    """The paper's test (``discard='samples'``: a cluster whose four photons all miss)
    loses the ball's rim between coarse photons (1.8% relative L1 measured at 512^2 on
    a larger map; here 256^2), against the dense grid."""
    knobs = dict(photons=256, map_resolution=64, gbuffer_resolution=64)
    dense = jc.internal.caustics_mapping(ball, **knobs)
    samples = jc.internal.adaptive_caustic_map(ball, discard="samples", **knobs)
    lost = float(jnp.abs(samples.image - dense.image).sum() / dense.image.sum())
    assert 0 < lost < 0.05
    assert samples.stats["splatted"] < dense.stats["splatted"]


@pytest.mark.slow
def test_adaptive_counts_at_2048_equivalent(ball):
    """At a 2048^2-equivalent photon buffer the traversal metric generates at most a
    fifth of the dense grid's photons (all levels counted), and the caustic-map error
    metric fewer still."""
    knobs = dict(photons=2048, map_resolution=256, gbuffer_resolution=256)
    traversal = jc.internal.adaptive_caustic_map(ball, metric="traversal", **knobs)
    error = jc.internal.adaptive_caustic_map(ball, metric="error", **knobs)
    dense = 2048 * 2048
    assert traversal.stats["generated"] <= dense / 5
    assert error.stats["generated"] < traversal.stats["generated"]
    assert error.stats["splatted"] < traversal.stats["splatted"]
    assert sum(traversal.stats["splatted_per_level"][:-1]) == 0  # all at the last level
    np.testing.assert_allclose(error.image.sum(), traversal.image.sum(), rtol=1e-2)


# on request (slow), for the default run's budget: batching is tested by default in
# test_memory.py, and the traversal against the dense map above
@pytest.mark.slow
@pytest.mark.parametrize("metric", ["traversal", "error"])
def test_batches_under_a_memory_limit(ball, metric):
    """A memory limit of a few clusters' photons: many batches, the same image to float
    rounding, and no batch's photon buffer over the limit."""
    knobs = dict(photons=256, map_resolution=64, gbuffer_resolution=64, metric=metric)
    whole = jc.internal.adaptive_caustic_map(ball, **knobs)
    limit = 300 * jc.internal.photon_bytes(1, 2 * 3 + 1, np.float64)  # sigma 1 texel: 7 x 7 splats
    batched = jc.internal.adaptive_caustic_map(ball, memory_limit=limit, **knobs)
    assert batched.stats["batches"] > 3 * whole.stats["batches"]
    assert batched.stats["peak_buffer_bytes"] <= limit
    assert whole.stats["peak_buffer_bytes"] > limit
    np.testing.assert_allclose(batched.image, whole.image, rtol=1e-10, atol=1e-12)
    dense = jc.internal.caustics_mapping(ball, photons=256, map_resolution=64, memory_limit=limit)
    assert dense.stats["batches"] > 1 and dense.stats["peak_buffer_bytes"] <= limit


def _tilted_cube(dtype):
    """A glass cube turned 45 degrees about y: light from above enters its upper faces
    and meets the lower ones at 45 degrees inside, past the critical angle of glass."""
    box = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    box.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, [0, 1, 0]))
    box.apply_translation([0.0, 0.0, 1.0])
    return jc.Mesh(np.asarray(box.vertices, dtype), box.faces)


@jax.jit
def _hard_value_and_grad(scene):
    """The squared caustics map's sum and its gradient in the vertices: jitted once per
    scene structure (grazing and misses share it; run eagerly, op by op, each case took
    8-13 s)."""

    def loss(vertices):
        s = jc.MeshScene(
            jc.Mesh(vertices, scene.generator.faces),
            scene.light,
            scene.receiver,
            ior=1.5,
            normals=scene.normals,
        )
        knobs = dict(photons=128, map_resolution=32, gbuffer_resolution=64)
        return jnp.sum(jc.internal.caustics_mapping(s, **knobs).image ** 2)

    return jax.value_and_grad(loss)(scene.generator.vertices)


# the float64 twin runs on request (slow), for the default run's 10-minute budget
# (float32, the default, stays)
@pytest.mark.parametrize("dtype", [pytest.param(np.float64, marks=pytest.mark.slow), np.float32])
@pytest.mark.parametrize("case", ["grazing", "tir", "misses"])
def test_hard_cases_stay_finite(case, dtype):
    """Values and gradients (with respect to the vertices) stay finite for grazing light
    (85 degrees), total internal reflection (tilted cube, image-space refraction drops
    those photons) and a ball whose light lands mostly off the screen."""
    if case == "grazing":
        scene = ball_scene(85.0, shape=(16, 16), subdivisions=1, dtype=dtype)
    elif case == "misses":
        scene = ball_scene(60.0, shape=(16, 16), subdivisions=1, dtype=dtype)
    else:
        scene = ball_scene(0.0, shape=(16, 16), dtype=dtype)
        scene = jc.MeshScene(
            _tilted_cube(dtype),
            scene.light,
            scene.receiver,
            ior=1.5,
            normals="flat",
            interfaces=6,
        )

    value, grad = _hard_value_and_grad(scene)
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))
    assert grad.dtype == dtype


@pytest.mark.slow
def test_adaptive_gradient_stays_finite_in_float32():
    """The host-driven adaptive traversal under `jax.grad`, grazing light, float32."""
    scene = ball_scene(85.0, shape=(16, 16), subdivisions=1, dtype=np.float32)

    def loss(vertices):
        s = jc.MeshScene(
            jc.Mesh(vertices, scene.generator.faces), scene.light, scene.receiver, ior=1.5
        )
        knobs = dict(photons=128, map_resolution=32, gbuffer_resolution=64)
        return jnp.sum(jc.internal.adaptive_caustic_map(s, **knobs).image ** 2)

    grad = jax.grad(loss)(scene.generator.vertices)
    assert grad.dtype == np.float32 and np.all(np.isfinite(np.asarray(grad)))
    assert np.any(np.asarray(grad) != 0)


@pytest.mark.slow
def test_image_space_refraction_drops_totally_reflected_photons():
    """Image-space refraction has two interfaces: the photons that the exact tracer
    follows through total internal reflection in the tilted cube (up to 6 interfaces)
    are dropped, not sent somewhere wrong."""
    base = ball_scene(0.0, shape=(16, 16))
    scene = jc.MeshScene(
        _tilted_cube(np.float64),
        base.light,
        base.receiver,
        ior=1.5,
        normals="flat",
        interfaces=6,
    )
    r = jc.internal.caustics_mapping(scene, photons=128, map_resolution=32)
    exact = jc.internal.caustics_mapping(
        scene, photons=128, map_resolution=32, intersection="exact"
    )
    assert r.stats["splatted"] < exact.stats["splatted"]


def test_gradient_matches_finite_differences():
    """d/ds of a loss on the caustics map, the ball stretched vertically by ``1 + s``
    about its centre (float64, central differences with step 1e-5; the faces the
    rasteriser picks and the photons' validity do not change over that step)."""
    scene = ball_scene(10.0, shape=(16, 16), subdivisions=2)
    verts = scene.generator.vertices
    target = np.linspace(0.0, 1.0, 256).reshape(16, 16)

    def loss(s):
        stretched = verts.at[:, 2].set(1.0 + (verts[:, 2] - 1.0) * (1.0 + s))
        moved = jc.MeshScene(
            jc.Mesh(stretched, scene.generator.faces), scene.light, scene.receiver, ior=1.5
        )
        image = jc.internal.caustics_mapping(
            moved, photons=96, map_resolution=64, iterations=2
        ).image
        return jnp.sum((image - target) ** 2)

    # jitted, one program for the value and the derivative (the differences use its
    # value): run eagerly, op by op, 13.9 s; same check
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    grad = float(value_and_grad(0.0)[1])
    h = 1e-5
    fd = (float(value_and_grad(h)[0]) - float(value_and_grad(-h)[0])) / (2 * h)
    assert abs(grad) > 1e-3
    np.testing.assert_allclose(grad, fd, rtol=1e-4)


# on request (slow), for the default run's 10-minute budget: the adaptive maps' jit
# tests below stay
@pytest.mark.slow
def test_caustics_mapping_is_jit_compatible(ball):
    image = jax.jit(lambda s: jc.internal.caustics_mapping(s, photons=32, map_resolution=32).image)(
        ball
    )
    eager = jc.internal.caustics_mapping(ball, photons=32, map_resolution=32).image
    np.testing.assert_allclose(image, eager, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="outside jax.jit"):
        jax.jit(lambda s: jc.internal.adaptive_caustic_map(s, photons=128).image)(ball)
    with pytest.raises(ValueError, match="capacity"):
        jc.internal.adaptive_caustic_map(ball, photons=128, capacity=100)


def test_render_dispatches_to_the_caustic_maps(ball):
    knobs = dict(photons=256, map_resolution=64, gbuffer_resolution=64)  # compiled above
    image, stats = jc.render(ball, "adaptive", return_stats=True, **knobs)
    assert image.shape == (32, 32) and stats["generated"] > 0
    assert jc.render(ball, "caustics_mapping", **knobs).shape == (32, 32)


def test_bad_arguments_raise_clear_errors(ball):
    with pytest.raises(ValueError, match="`scene` must be a MeshScene"):
        jc.internal.caustics_mapping("not a scene")
    lens = jc.LensScene(
        jc.HeightField(np.zeros((4, 4)), (0.0, 1.0, 0.0, 1.0), boundary="clamp"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver((0.0, 1.0, 0.0, 1.0), (4, 4)),
        thickness=0.1,
        screen_distance=0.5,
    )
    with pytest.raises(ValueError, match="caustic_triangles"):
        jc.internal.adaptive_caustic_map(lens)
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    box.apply_translation([1.0, 1.0, 0.3])
    blocker = jc.Mesh.from_trimesh(box)
    with pytest.raises(ValueError, match="occluders"):
        jc.internal.caustics_mapping(
            jc.MeshScene(ball.generator, ball.light, ball.receiver, occluders=[blocker])
        )
    for kwargs, name in [
        (dict(photons=1), "photons"),
        (dict(photons=100), "power of two"),
        (dict(base=63), "base"),
        (dict(metric="fast"), "metric"),
        (dict(sigma=-1.0), "sigma"),
        (dict(sigma="big"), "sigma"),
        (dict(memory_limit=0), "memory_limit"),
        (dict(map_resolution=1), "map_resolution"),
        (dict(intersection="guess"), "intersection"),
        (dict(iterations=-1), "iterations"),
        (dict(discard="never"), "discard"),
    ]:
        with pytest.raises(ValueError, match=name):
            jc.internal.adaptive_caustic_map(ball, **kwargs)


def test_camera_image_shades_the_receiver(ball):
    """Seen from a camera straight above, the lit receiver far from the ball has the
    Lambertian radiance ``albedo / pi`` of unit irradiance; the ball's shadow is darker
    except where its caustic lands; off the receiver the image is black."""
    result = jc.internal.caustics_mapping(
        ball, photons=256, map_resolution=64, gbuffer_resolution=64
    )
    camera = jc.PinholeCamera([0.0, 0.0, 8.0], [0.0, 0.0, 0.0], fov=40.0, shape=(60, 60))
    image = np.asarray(jc.camera_image(ball, result, camera, albedo=0.5))
    assert image[0, 0] == 0.0  # the corner ray misses the 4 m screen
    lit = image[30, 12]  # 1.7 m from the axis: no shadow, no caustic
    np.testing.assert_allclose(lit, 0.5 / np.pi, rtol=1e-6)
    assert image.max() > 3 * lit  # the caustic
    assert np.sum(image < 0.5 * lit) > 20  # the shadow ring around it
    with pytest.raises(ValueError, match="look_at"):
        jc.PinholeCamera([0.0, 0.0, 1.0], [0.0, 0.0, 1.0])


@pytest.mark.slow
def test_adaptive_capacity_runs_under_jit(ball):
    """The all-jit traversal (`capacity`) inside an outer `jax.jit`: the host-driven
    traversal's image."""
    knobs = dict(photons=128, map_resolution=32, gbuffer_resolution=64)
    host = jc.internal.adaptive_caustic_map(ball, **knobs)
    outer = jax.jit(lambda s: jc.internal.adaptive_caustic_map(s, capacity=2048, **knobs).image)
    np.testing.assert_allclose(outer(ball), host.image, rtol=1e-10, atol=1e-12)


@pytest.mark.slow
def test_adaptive_traversal_all_under_jit(ball):
    """With `capacity` the whole traversal runs under one jit (fixed-size level buffers,
    `jnp.nonzero` compaction, batches in a scan): the same counts and image as the
    host-driven traversal, under a memory limit (batches of at most the limit)."""
    knobs = dict(photons=256, map_resolution=64, gbuffer_resolution=64)
    host = jc.internal.adaptive_caustic_map(ball, **knobs)
    limit = 300 * jc.internal.photon_bytes(1, 7, np.float64)
    in_jit = jc.internal.adaptive_caustic_map(ball, capacity=4096, memory_limit=limit, **knobs)
    for key in ("generated_per_level", "splatted_per_level", "refined_per_level"):
        assert in_jit.stats[key] == host.stats[key]
    assert in_jit.stats["peak_buffer_bytes"] <= limit
    np.testing.assert_allclose(in_jit.image, host.image, rtol=1e-10, atol=1e-12)


@pytest.mark.slow
def test_adaptive_capacity_overflow_raises(ball):
    """At 512^2 equivalent the last level holds about 2500 clusters: a capacity of 1024
    (the first level's 32^2) overflows, and the error says so."""
    with pytest.raises(ValueError, match="`capacity` 1024 is too small"):
        jc.internal.adaptive_caustic_map(
            ball, photons=512, map_resolution=64, gbuffer_resolution=128, capacity=1024
        )


@pytest.mark.slow  # on request, for the default run's budget (the position gradients stay)
def test_gradient_with_respect_to_the_light_direction():
    """The light's direction reaches the photons (the view's window stays fixed): d/d
    zenith of a loss on the caustics map against central differences (float64, step
    1e-5 degrees)."""
    scene = ball_scene(10.0, shape=(16, 16), subdivisions=2)
    target = np.linspace(0.0, 1.0, 256).reshape(16, 16)

    def loss(zenith_deg):
        t = jnp.radians(zenith_deg)
        light = jc.DirectionalLight(jnp.stack([jnp.sin(t), 0.0 * t, -jnp.cos(t)]))
        moved = jc.MeshScene(scene.generator, light, scene.receiver, ior=1.5)
        image = jc.internal.caustics_mapping(
            moved, photons=64, map_resolution=32, iterations=2
        ).image
        return jnp.sum((image - target) ** 2)

    grad = float(jax.grad(loss)(10.0))
    h = 1e-5
    fd = (float(loss(10.0 + h)) - float(loss(10.0 - h))) / (2 * h)
    assert abs(grad) > 1e-4
    np.testing.assert_allclose(grad, fd, rtol=1e-4)
