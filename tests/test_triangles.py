"""Caustic triangles on lens and mesh scenes: physics checks, folds, foci, gradients.

Comparisons with the NumPy reference are in `test_triangles_reference.py`.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc

APERTURE = (0.0, 0.1, 0.0, 0.1)  # a 10 cm square lens
SCREEN = (-0.01, 0.11, -0.01, 0.11)


def lens_scene(
    heights,
    *,
    light=None,
    screen_distance=0.2,
    thickness=0.01,
    shape=(48, 48),
    dtype=None,
    screen=SCREEN,
    **kw,
):
    dtype = dtype or np.float64
    light = light or jc.DirectionalLight.from_angles(0.0)
    if isinstance(light, jc.DirectionalLight):
        light = jc.DirectionalLight(np.asarray(light.direction, dtype))
    return jc.LensScene(
        jc.HeightField(np.asarray(heights, dtype), np.asarray(APERTURE, dtype), "clamp"),
        light,
        jc.PlaneReceiver(np.asarray(screen, dtype), shape),
        np.asarray(thickness, dtype),
        np.asarray(screen_distance, dtype),
        **kw,
    )


def plano_convex(n_samples, focal, ior=1.5, dtype=np.float64, cylindrical=False):
    """Paraxial plano-convex top surface of focal length `focal` (curved side up);
    `cylindrical`: curved along x only (a line focus)."""
    radius = focal * (ior - 1.0)
    x = (np.arange(n_samples) + 0.5) / n_samples * 0.1 - 0.05
    xx, yy = np.meshgrid(x, x)
    r2 = xx**2 if cylindrical else xx**2 + yy**2
    return (-r2 / (2.0 * radius)).astype(dtype)


def pixel_area(scene):
    e = np.asarray(scene.receiver.extent)
    rows, cols = scene.receiver.shape
    return (e[1] - e[0]) / cols * (e[3] - e[2]) / rows


def total_flux(result):
    """Flux of the valid triangles (half a cell each, mean corner density)."""
    ph = result.photons
    d = np.where(np.asarray(ph.valid), np.asarray(ph.density), np.nan)
    corners = [d[:, :-1, :-1], d[:, :-1, 1:], d[:, 1:, :-1], d[:, 1:, 1:]]
    first = (corners[0] + corners[1] + corners[3]) / 3
    second = (corners[0] + corners[3] + corners[2]) / 3
    cell = float(ph.cell_area)
    return 0.5 * cell * (np.nansum(first, axis=(1, 2)) + np.nansum(second, axis=(1, 2)))


@pytest.mark.parametrize("reconstruction", ["exact", "gouraud"])
def test_flat_slab_gives_the_light_it_receives(reconstruction):
    scene = lens_scene(np.zeros((8, 8)))
    result = jc.internal.caustic_triangles(scene, photons=33, reconstruction=reconstruction)
    image = np.asarray(result.image)
    inner = image[8:-8, 8:-8]  # the aperture covers pixels 4..43
    np.testing.assert_allclose(inner, 1.0, atol=1e-12)
    assert image[:3].max() == 0.0 and image[:, -3:].max() == 0.0  # nothing outside
    if reconstruction == "exact":  # exactly the aperture's 0.01 m^2
        assert image.sum() * pixel_area(scene) == pytest.approx(0.01, rel=1e-12)


def test_flat_slab_fresnel_is_the_product_of_both_faces():
    scene = lens_scene(np.zeros((8, 8)), fresnel=True, ior=1.5)
    image = np.asarray(jc.internal.caustic_triangles(scene, photons=17).image)
    t = 1.0 - ((1.5 - 1.0) / (1.5 + 1.0)) ** 2  # normal incidence, each face
    np.testing.assert_allclose(image[8:-8, 8:-8], t * t, rtol=1e-12)


def test_oblique_flat_slab_shifts_the_aperture_by_snell():
    zenith, ior, thickness, screen_distance = 25.0, 1.5, 0.02, 0.05
    light = jc.DirectionalLight.from_angles(zenith, 0.0)
    scene = lens_scene(
        np.zeros((8, 8)),
        light=light,
        thickness=thickness,
        screen_distance=screen_distance,
        screen=(-0.01, 0.15, -0.03, 0.13),
        shape=(80, 80),
    )
    result = jc.internal.caustic_triangles(scene, photons=33)
    image = np.asarray(result.image)
    e = np.asarray(scene.receiver.extent)
    xs = e[0] + (np.arange(80) + 0.5) * (e[1] - e[0]) / 80
    ys = e[2] + (np.arange(80) + 0.5) * (e[3] - e[2]) / 80
    centroid_x = (image.sum(0) * xs).sum() / image.sum()
    centroid_y = (image.sum(1) * ys).sum() / image.sum()
    sin_t = math.sin(math.radians(zenith)) / ior
    shift = thickness * sin_t / math.sqrt(1 - sin_t**2) + screen_distance * math.tan(
        math.radians(zenith)
    )
    assert centroid_x == pytest.approx(0.05 + shift, abs=1e-9)
    assert centroid_y == pytest.approx(0.05, abs=1e-9)
    assert float(result.missed_flux_fraction[0]) < 1e-12


# the float64 twin runs on request (slow), for the default run's 10-minute budget
# (float32, the default, stays)
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=pytest.mark.slow)])
@pytest.mark.parametrize("reconstruction", ["exact", "gouraud"])
def test_sharp_focus_is_finite_in_value_and_gradient(dtype, reconstruction):
    focal = 0.2
    heights = plano_convex(24, focal, dtype=dtype)
    # back focal distance of a plano-convex lens: f - thickness / n
    scene = lens_scene(heights, thickness=0.04, screen_distance=focal - 0.04 / 1.5, dtype=dtype)

    def peak(h):
        s = eqx_replace_heights(scene, h)
        return jc.internal.caustic_triangles(
            s, photons=33, window=48, reconstruction=reconstruction
        ).image

    # jitted (the value with its gradient): run eagerly, op by op, 10.8 s (exact)
    @jax.jit
    def image_and_grad(h):
        (_, image), grad = jax.value_and_grad(
            lambda h: (jnp.sum(peak(h) ** 2), peak(h)), has_aux=True
        )(h)
        return image, grad

    image, grad = image_and_grad(jnp.asarray(heights))
    image = np.asarray(image)
    assert np.all(np.isfinite(image))
    assert image.max() > 100.0  # the aperture's light squeezed onto a few pixels
    assert grad.dtype == dtype and np.all(np.isfinite(np.asarray(grad)))


def eqx_replace_heights(scene, heights):
    import equinox as eqx

    return eqx.tree_at(lambda s: s.surface.heights, scene, heights)


@pytest.mark.parametrize("reconstruction", ["exact", "gouraud"])
# float64 on request (slow), for the default run's budget: the hard case runs in float32
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=pytest.mark.slow)])
def test_fold_overs_keep_their_flux(dtype, reconstruction):
    # a cylindrical lens (back focal distance 0.3 - 0.02 / 1.5) with the screen well past
    # its line focus: the image is mirrored along x, so every triangle is folded over
    heights = plano_convex(24, 0.3, cylindrical=True, dtype=dtype)
    scene = lens_scene(
        heights, thickness=0.02, screen_distance=0.5, screen=(-0.05, 0.15, -0.05, 0.15), dtype=dtype
    )

    def render(h):
        s = eqx_replace_heights(scene, h)
        return jc.internal.caustic_triangles(
            s, photons=33, window=32, reconstruction=reconstruction
        )

    result = render(jnp.asarray(heights))
    # all but those of the outer ring, where the clamped bicubic turns flat beyond the
    # outermost samples
    from jaxcaustics.methods.triangles.method import grid_triangles
    from jaxcaustics.reconstruct.raster import signed_area

    area = np.asarray(signed_area(grid_triangles(result.photons.position[..., :2])))
    assert np.all(area.reshape(32, 32, 2)[2:-2, 2:-2] < 0)
    image = np.asarray(result.image)
    assert np.all(np.isfinite(image)) and image.min() >= 0.0
    grad = jax.grad(lambda h: jnp.sum(render(h).image ** 2))(jnp.asarray(heights))
    assert grad.dtype == dtype and np.all(np.isfinite(np.asarray(grad)))
    if reconstruction == "exact":  # flux kept to rounding
        landed = image.sum() * pixel_area(scene)
        rel = 1e-10 if dtype == np.float64 else 1e-4
        assert landed == pytest.approx(total_flux(result)[0], rel=rel)
        assert float(result.missed_flux_fraction[0]) < rel


def test_gradients_match_finite_differences_away_from_folds(rng):
    x = (np.arange(12) + 0.5) / 12 * 2 - 1
    xx, yy = np.meshgrid(x, x)
    heights = 4e-4 * np.exp(-((xx - 0.1) ** 2 + yy**2) / 0.3)
    scene = lens_scene(
        heights, light=jc.DirectionalLight.from_angles(10.0, 40.0), screen_distance=0.1
    )
    weights = jnp.asarray(rng.uniform(0.5, 1.5, scene.receiver.shape))

    def loss(h):
        s = eqx_replace_heights(scene, h)
        return jnp.sum(weights * jc.internal.caustic_triangles(s, photons=21, window=6).image)

    # jitted, one program for the value and the gradient (the differences use its value):
    # run eagerly, op by op, the grad and six losses took 13.9 s; same check
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    h0 = jnp.asarray(heights)
    grad = value_and_grad(h0)[1]
    loss = lambda h: value_and_grad(h)[0]  # noqa: E731
    for _ in range(3):
        direction = jnp.asarray(rng.normal(size=heights.shape)) * 1e-4
        eps = 1e-4
        fd = (loss(h0 + eps * direction) - loss(h0 - eps * direction)) / (2 * eps)
        assert float(jnp.vdot(grad, direction)) == pytest.approx(float(fd), rel=1e-5)


def test_point_light_over_a_flat_slab_matches_the_inverse_square_law():
    light = jc.PointLight([0.05, 0.05, 2.0], intensity=3.0)
    scene = lens_scene(
        np.zeros((8, 8)), light=light, ior=1.0 + 1e-12, thickness=0.01, screen_distance=0.2
    )
    image = np.asarray(jc.internal.caustic_triangles(scene, photons=65).image)
    # index ~1: the slab does nothing; the centre pixel gets I cos(theta) / r^2
    e = np.asarray(scene.receiver.extent)
    centre = e[0] + (24 + 0.5) * (e[1] - e[0]) / 48
    r = math.dist((centre, centre, 0.0), (0.05, 0.05, 2.0))
    assert image[24, 24] == pytest.approx(3.0 * 2.0 / r**3, rel=1e-4)


def sphere_scene(radius=0.5, subdivisions=2, *, ior=1.5, shape=(48, 48), **kw):
    mesh = trimesh.creation.icosphere(subdivisions, radius=radius)
    mesh.apply_translation([0.0, 0.0, 1.0])
    return jc.MeshScene(
        jc.Mesh.from_trimesh(mesh),
        kw.pop("light", jc.DirectionalLight.from_angles(0.0)),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), shape),
        ior=ior,
        **kw,
    )


def test_sphere_of_index_one_casts_its_shadow_disc_of_light():
    scene = sphere_scene(ior=1.0)
    result = jc.internal.caustic_triangles(scene, photons=49)
    image = np.asarray(result.image)
    xs = -1 + (np.arange(48) + 0.5) * 2 / 48
    r = np.hypot(*np.meshgrid(xs, xs))
    np.testing.assert_allclose(image[r < 0.4], 1.0, atol=1e-9)  # light passes unchanged
    assert image[r > 0.55].max() == 0.0


def test_refractor_with_one_interface_renders_nothing():
    result = jc.internal.caustic_triangles(sphere_scene(interfaces=1), photons=17)
    assert float(np.abs(np.asarray(result.image)).max()) == 0.0
    assert not np.asarray(result.photons.valid).any()


# the float64 twin runs on request (slow), for the default run's 10-minute budget
# (float32, the default, stays)
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=pytest.mark.slow)])
def test_total_internal_reflection_in_the_sphere_is_finite(dtype):
    scene = sphere_scene(interfaces=4, fresnel=True, light=jc.DirectionalLight.from_angles(35.0))
    vertices = jnp.asarray(scene.generator.vertices, dtype)
    import equinox as eqx

    scene = eqx.tree_at(lambda s: s.generator.vertices, scene, vertices)

    def brightness(v):
        s = eqx.tree_at(lambda s: s.generator.vertices, scene, v)
        return jnp.sum(jc.internal.caustic_triangles(s, photons=25, window=24).image ** 2)

    # jitted: run eagerly, op by op, 11.9 s
    value, grad = jax.jit(jax.value_and_grad(brightness))(vertices)
    assert np.isfinite(float(value)) and float(value) > 0
    assert grad.dtype == dtype and np.all(np.isfinite(np.asarray(grad)))


def test_mesh_flux_is_accounted_for():
    result = jc.internal.caustic_triangles(sphere_scene(), photons=33)
    landed = np.asarray(result.image).sum() * (2 / 48) ** 2
    missed = float(result.missed_flux_fraction[0])
    assert landed == pytest.approx(total_flux(result)[0] * (1 - missed), rel=1e-10)


@pytest.mark.parametrize(
    "reconstruction", ["exact", pytest.param("gouraud", marks=pytest.mark.slow)]
)
def test_auto_window_draws_in_tiers_the_one_window_image(reconstruction):
    """window='auto' draws the narrow triangles in narrower windows (and skips the
    invalid ones): the image of the widest window for all, to rounding."""
    scene = sphere_scene(light=jc.DirectionalLight.from_angles(20.0))
    tiered = jc.internal.caustic_triangles(scene, photons=33, reconstruction=reconstruction)
    tiers = tiered.stats["tiers"]
    windows = [w for w, _, _ in tiers]
    assert len(tiers) > 1 and windows == sorted(windows, reverse=True)
    assert sum(n for _, n, _ in tiers) < 2 * 32 * 32  # photons missing the ball: skipped
    one = jc.internal.caustic_triangles(
        scene, photons=33, reconstruction=reconstruction, window=windows[0]
    )
    assert one.stats["tiers"] == ((windows[0], 2 * 32 * 32, 2 * 32 * 32),)
    scale = float(np.asarray(one.image).max())
    np.testing.assert_allclose(tiered.image, one.image, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(tiered.missed_flux_fraction, one.missed_flux_fraction, atol=1e-12)


def test_tiers_are_the_cheapest_that_hold_every_triangle(rng):
    """`_size_tiers` (dynamic programming) against every chain of windows (the widest,
    then powers of two): the same cost, and every tier's capacity holds what comes to it
    in every band and channel."""
    import itertools

    from jaxcaustics.methods.triangles.sizing import MAX_TIERS, _power_of_two, _size_tiers

    window, triangles, penalty = 12, 5000, 300.0
    spans = np.arange(window + 3)

    def cost(w):
        return 10 + w * w

    def held(counts, w, v, top):  # the most in a band of spans in (v, w] (top: above w too)
        inside = (spans > v) | ((v == 0) & (spans == 0))
        return np.where(inside & ((spans <= w) | top), counts, 0).sum(axis=1).max()

    def total(counts, chain):
        ends = [*chain[1:], 0]
        return sum(
            min(triangles, _power_of_two(max(1, held(counts, w, v, k == 0)))) * cost(w) + penalty
            for k, (w, v) in enumerate(zip(chain, ends, strict=True))
        )

    for _ in range(20):
        counts = rng.integers(0, 400, (2, window + 3)) * (rng.uniform(size=(2, window + 3)) < 0.7)
        tiers = _size_tiers(counts, window, triangles, cost, lambda w, n: n, penalty)
        windows = [w for w, _, _ in tiers] + [0]
        assert windows[0] == window and all(w in (1, 2, 4, 8) for w in windows[1:-1])
        for k, (w, capacity, _) in enumerate(tiers):
            assert capacity >= held(counts, w, windows[k + 1], k == 0)
        best = min(
            total(counts, (window, *rest))
            for k in range(MAX_TIERS)
            for rest in itertools.combinations((8, 4, 2, 1), k)
        )
        assert sum(n * cost(w) + penalty for w, n, _ in tiers) == pytest.approx(best)


@pytest.mark.parametrize(
    "knobs, match",
    [
        ({"photons": 1}, "photons"),
        ({"photons": "many"}, "photons"),
        ({"reconstruction": "splat"}, "reconstruction"),
        ({"window": 0}, "window"),
        ({"supersample": 0}, "supersample"),
        ({"hit_iterations": -1}, "hit_iterations"),
    ],
)
def test_bad_knobs_name_the_argument(knobs, match):
    with pytest.raises(ValueError, match=match):
        jc.internal.caustic_triangles(lens_scene(np.zeros((4, 4))), **knobs)


def test_render_dispatches_by_scene_type():
    scene = lens_scene(np.zeros((4, 4)))
    image, stats = jc.render(scene, photons=9, return_stats=True)
    assert image.shape == scene.receiver.shape and "missed_flux_fraction" in stats
    with pytest.raises(ValueError, match="scene"):
        jc.internal.caustic_triangles(object())


def test_dispersion_gives_one_channel_per_index():
    scene = lens_scene(plano_convex(16, 0.3), thickness=0.02, ior=(1.49, 1.51, 1.53))
    image = np.asarray(jc.internal.caustic_triangles(scene, photons=17).image)
    assert image.shape == (48, 48, 3)
    assert not np.allclose(image[..., 0], image[..., 2])


def test_mesh_gradients_match_finite_differences(rng):
    import equinox as eqx

    scene = sphere_scene(subdivisions=1, light=jc.DirectionalLight.from_angles(15.0, 30.0))
    weights = jnp.asarray(rng.uniform(0.5, 1.5, scene.receiver.shape))

    def loss(v):
        s = eqx.tree_at(lambda s: s.generator.vertices, scene, v)
        return jnp.sum(weights * jc.internal.caustic_triangles(s, photons=17, window=16).image)

    # jitted, one program for the value and the gradient (the differences use its value):
    # run eagerly, op by op, the grad and six losses took 15.5 s; same check
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    v0 = jnp.asarray(scene.generator.vertices)
    grad = value_and_grad(v0)[1]
    loss = lambda v: value_and_grad(v)[0]  # noqa: E731
    for _ in range(3):
        direction = jnp.asarray(rng.normal(size=v0.shape)) * 1e-3
        eps = 1e-5  # small enough that no photon changes triangle or validity
        fd = (loss(v0 + eps * direction) - loss(v0 - eps * direction)) / (2 * eps)
        assert float(jnp.vdot(grad, direction)) == pytest.approx(float(fd), rel=1e-5)


# float64 on request (slow), for the default run's budget: the hard case runs in float32
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=pytest.mark.slow)])
def test_degenerate_triangles_keep_their_flux_and_stay_finite(dtype):
    """Photons that land on one point (a collapsed cell) or on a line."""
    from jaxcaustics.methods.triangles.method import triangles_image

    n = 6
    xs = np.linspace(0.2, 0.8, n)
    position = np.stack([*np.meshgrid(xs, xs), np.zeros((n, n))], axis=-1)
    position[2:4, 2:4, :2] = 0.5  # a cell collapsed to a point
    position[4, :, 1] = 0.7  # row 4 pushed onto row 5's neighbour line: slivers
    position[5, :, 1] = 0.7
    ph = jc.internal.Photons(
        jnp.asarray(position[None], dtype),
        jnp.zeros((1, n, n, 3), dtype),
        jnp.ones((1, n, n), dtype),
        jnp.ones((1, n, n), bool),
        jnp.asarray(0.01, dtype),
    )
    receiver = jc.PlaneReceiver(np.asarray((0.0, 1.0, 0.0, 1.0), dtype), (16, 16))

    for reconstruction in ("exact", "gouraud"):

        def total(pos, reconstruction=reconstruction):
            p = eqx_replace_position(ph, pos)
            images, _ = triangles_image(p, receiver, reconstruction=reconstruction, window=8)
            return jnp.sum(images**2), images

        # jitted: run eagerly, op by op, both reconstructions took 11 s
        (value, images), grad = jax.jit(jax.value_and_grad(total, has_aux=True))(ph.position)
        assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))
        if reconstruction == "exact":
            flux = float(images.sum()) / 16**2
            assert flux == pytest.approx(0.01 * (n - 1) ** 2, rel=1e-5)


def eqx_replace_position(photons, position):
    import equinox as eqx

    return eqx.tree_at(lambda p: p.position, photons, position)


def occluded_sphere_scene():
    """A ball lens over the screen, with a thin opaque slab below it covering the +x half
    of its caustic."""
    slab = trimesh.creation.box((0.8, 2.0, 0.05))
    slab.apply_translation([0.55, 0.0, 0.12])
    return sphere_scene(
        shape=(64, 64),
        occluders=[jc.Mesh.from_trimesh(slab)],
        light=jc.DirectionalLight.from_angles(10.0, 0.0),
    )


def deep_shadow():
    """Screen pixels that no ray from the sphere (x in [-0.5, 0.5], z in [0.5, 1.5]) can
    reach past the slab (x in [0.15, 0.95], z in [0.095, 0.145])."""
    xs = -1 + (np.arange(64) + 0.5) * 2 / 64
    x, y = np.meshgrid(xs, xs)
    return (x > 0.4) & (x < 0.85) & (np.abs(y) < 0.7)


@pytest.mark.slow  # about 20 s; keeps the default run under 10 minutes
def test_distance_map_projection_does_not_leak_behind_occluders():
    from jaxcaustics.methods.triangles.method import CubeMapOptions

    scene = occluded_sphere_scene()
    shadow = deep_shadow()
    exact = np.asarray(jc.internal.caustic_triangles(scene, photons=33).image)
    tested = jc.internal.caustic_triangles(
        scene, photons=33, visibility="distance_map", cube_map=CubeMapOptions(resolution=64)
    )
    naive = jc.internal.caustic_triangles(
        scene,
        photons=33,
        visibility="distance_map",
        cube_map=CubeMapOptions(resolution=64, shadow_test=False),
    )
    on_slab = np.asarray(tested.photons.position[0, ..., 2] > 0.05) & np.asarray(
        tested.photons.valid[0]
    )
    assert on_slab.sum() > 100  # much of the caustic lands on the slab
    assert exact[shadow].max() == 0.0
    assert np.asarray(tested.image)[shadow].max() == 0.0  # no leak
    leak = np.asarray(naive.image)[shadow].sum() / np.asarray(naive.image).sum()
    assert leak > 0.05  # naive projection draws the slab's caustic on the screen behind it


@pytest.mark.slow  # on request (slow), for the default run's 10-minute budget: the distance maps
# have their own tests (test_distance_map.py)
def test_distance_map_pipeline_agrees_with_exact_visibility():
    """Without occluders the paper's pipeline (distance-map tracing, Gouraud triangles on
    the light cube map, projection) approximates the screen-space triangles; measured
    blurred relative L1 0.058 (64^2 texels per face) and 0.086 (128^2), flux 98%. Its
    errors are those of point-sampled Gouraud triangles on the cube faces and of the
    nearest-texel projection."""
    from jaxcaustics.methods.triangles.method import CubeMapOptions

    scene = sphere_scene(shape=(64, 64), light=jc.DirectionalLight.from_angles(10.0, 0.0))
    exact = np.asarray(jc.internal.caustic_triangles(scene, photons=33).image)
    cube = np.asarray(
        jc.internal.caustic_triangles(
            scene, photons=33, visibility="distance_map", cube_map=CubeMapOptions(resolution=64)
        ).image
    )
    assert jc.image_error(cube, exact) < 0.1
    assert cube.sum() == pytest.approx(exact.sum(), rel=0.05)


def test_distance_map_visibility_needs_a_mesh_scene():
    with pytest.raises(ValueError, match="visibility"):
        jc.internal.caustic_triangles(lens_scene(np.zeros((4, 4))), visibility="distance_map")
    with pytest.raises(ValueError, match="visibility"):
        jc.internal.caustic_triangles(lens_scene(np.zeros((4, 4))), visibility="cube")


def test_the_auto_window_fits_the_receiver():
    """Photons a few pixels apart on a 4 x 4 screen: the window that holds their
    triangles would be wider than the screen, and is capped one past its side (an 8 x 8
    design under 85-degree light asked for 16 and failed after its whole design)."""
    from jaxcaustics.methods.triangles.method import trace_photons, triangle_window, triangles_image

    scene = jc.LensScene(
        jc.HeightField(np.zeros((8, 8)), (-0.05, 0.05, -0.05, 0.05), "clamp"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver((-0.005, 0.005, -0.005, 0.005), (4, 4)),
    )
    photons = trace_photons(scene, (9, 9))
    window = triangle_window(photons, scene.receiver)
    assert window == 5
    triangles_image(photons, scene.receiver, window=window)  # taken as it is
