"""Two-pass caustics (Yuksel & Keyser) against the NumPy reference, gradients, hard cases.

Error measure throughout: relative L1 error ``sum |blur(a) - blur(b)| / sum |blur(b)|``
after a Gaussian blur of sigma = 1 caustic-map pixel (periodic). The blur is there
because the two methods reconstruct differently at the pixel scale: the two-pass method
spreads one sample per pixel as a pixel-sized square, the reference bins 16 x 16 exact
photons per pixel (so it is quantised to 1/256); both converge to the same irradiance
once each pixel's neighbourhood is averaged.
"""

import functools
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import make_scene

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.methods import twopass
from jaxcaustics.methods.render import MISSED_FLUX_WARNING

# the error of the library's tables, on a periodic sea's caustic (the image wraps)
periodic_error = functools.partial(jc.image_error, boundary="periodic")

EXT = (0.0, 1.0, 0.0, 0.75)  # 48 x 64 pixels of 1/64 m


def bump(shape=(48, 64), extent=EXT, amplitude=0.01, sigma=0.08):
    return np.asarray(jc.internal.gaussian_bump(shape, extent, sigma=sigma, amplitude=amplitude))


def sines(shape=(48, 64), extent=EXT, scale=1.0):
    terms = ((2, 1, 0.004 * scale, 0.0), (1, 3, 0.003 * scale, 1.0))
    return np.asarray(jc.sine_sum(shape, extent, terms=terms))


# ---------------------------------------------------------------- exactness on flat water


@pytest.mark.parametrize("zenith", [0.0, 30.0, 60.0, 80.0])
@pytest.mark.parametrize("boundary", ["periodic", "clamp"])
def test_flat_water_is_exactly_one(zenith, boundary):
    scene = make_scene(np.zeros((12, 16)), EXT, zenith=zenith, azimuth=35.0, boundary=boundary)
    image, stats = jc.render(scene, return_stats=True)
    np.testing.assert_allclose(np.asarray(image), 1.0, atol=1e-12)
    assert float(stats["missed_flux_fraction"][0]) < 1e-12


def test_flat_water_with_fresnel_gives_the_transmittance():
    n, zenith = 1.333, 50.0
    scene = make_scene(np.zeros((8, 8)), zenith=zenith, ior=n, fresnel=True)
    ci = np.cos(np.radians(zenith))
    ct = np.sqrt(1 - (np.sin(np.radians(zenith)) / n) ** 2)
    rs = ((ci - n * ct) / (ci + n * ct)) ** 2
    rp = ((n * ci - ct) / (n * ci + ct)) ** 2
    np.testing.assert_allclose(np.asarray(jc.render(scene)), 1 - (rs + rp) / 2, rtol=1e-12)


# ---------------------------------------------------------------- against the reference


# Measured at 48 x 64 pixels, N = 7, M = 6, 3 Newton steps: bump 0.0020 (0 deg) and 0.0024
# (30 deg); sines 0.0145 and 0.0153. The sum of sines has caustic lines about one pixel
# wide, where one sample per pixel and 1/256-quantised photon counts differ most. The
# tolerances leave a margin of about 2x over those numbers.
@pytest.mark.parametrize(
    "surface, tolerance", [(bump, 0.005), (sines, 0.03)], ids=["bump", "sines"]
)
@pytest.mark.parametrize("zenith", [0.0, 30.0])
def test_agrees_with_reference_on_smooth_surfaces(surface, tolerance, zenith):
    scene = make_scene(surface(), EXT, zenith=zenith, azimuth=20.0)
    ref = reference.trace_water(scene, photons_per_axis=16)
    assert periodic_error(jc.render(scene), ref) < tolerance


@pytest.mark.slow  # 8 s (the default run's 8-minute budget); the defaults' accuracy, S = 2
# included, stays checked in the default run
def test_supersampling_tightens_the_error():
    """S x S samples per pixel, each spread over its own 1/S of the pixel's side,
    remove the one-sample-per-pixel ripple and converge to the binned irradiance.

    Measured on the sum of sines at 30 degrees: 0.0153 (S = 1), 0.0044 (S = 2),
    0.0027 (S = 3), 0.0023 (S = 4); without blur 0.050, 0.034, 0.023, 0.016.
    """
    scene = make_scene(sines(), EXT, zenith=30.0, azimuth=20.0)
    ref = reference.trace_water(scene, photons_per_axis=16)
    errors = [periodic_error(jc.render(scene, supersample=s), ref) for s in (1, 2, 3)]
    assert errors[0] > 2 * errors[1] > 2 * 0.9 * errors[2] and errors[2] < 0.006, errors
    flat = make_scene(np.zeros((12, 16)), EXT, zenith=45.0)
    np.testing.assert_allclose(np.asarray(jc.render(flat, supersample=3)), 1.0, atol=1e-12)


def test_heightfield_resolution_need_not_match_the_caustic_map():
    """A 24 x 40 height field on a 48 x 64 caustic map (both sample the same interpolant)."""
    heights = sines((24, 40))
    scene = make_scene(heights, EXT, zenith=30.0, azimuth=20.0, shape=(48, 64))
    ref = reference.trace_water(scene, photons_per_axis=16)
    assert periodic_error(jc.render(scene), ref) < 0.03


# on request (slow), for the default run's 10-minute budget: dispersion is also
# checked in test_effects and test_triangles
@pytest.mark.slow
def test_dispersion_gives_one_channel_per_index():
    heights = sines()
    single = [jc.render(make_scene(heights, EXT, zenith=30.0, ior=n)) for n in (1.33, 1.34)]
    scene = make_scene(heights, EXT, zenith=30.0, ior=(1.33, 1.34))
    image = jc.render(scene)
    assert single[0].shape == (48, 64) and image.shape == (48, 64, 2)
    for c in range(2):
        np.testing.assert_allclose(np.asarray(image[..., c]), np.asarray(single[c]), atol=1e-12)
    ref = reference.trace_water(scene, photons_per_axis=16)
    assert ref.shape == (48, 64, 2)
    assert all(periodic_error(image[..., c], ref[..., c]) < 0.03 for c in range(2))


def _rotated(scene, rotation):
    import equinox as eqx

    value = jnp.asarray(rotation, scene.surface.heights.dtype)
    return eqx.tree_at(lambda s: s.surface.rotation, scene, value)


def off_centre_bump():
    return np.asarray(
        jc.internal.gaussian_bump((48, 64), EXT, center=(0.3, 0.45), sigma=0.08, amplitude=0.01)
    )


# Measured at rotation 0.5 rad, 30 degrees, 48 x 64, N = 7, M = 6: off-centre bump 0.0026
# (periodic) and 0.0024 (clamp), sums of sines 0.0146 and 0.0136: the same as unrotated
# (0.0025, 0.0024, 0.0153, 0.0161), so the same tolerances as above. The reference cannot
# wrap a rotated periodic field onto the receiver and pads its emission window instead.
# Against the *unrotated* reference the errors are 0.025 (bump) and 0.23-0.25 (sines):
# the rotation is seen, the right way round.
@pytest.mark.parametrize(
    "surface, tolerance", [(off_centre_bump, 0.005), (sines, 0.03)], ids=["bump", "sines"]
)
@pytest.mark.parametrize("boundary", ["periodic", "clamp"])
def test_rotated_heightfield_agrees_with_reference(surface, tolerance, boundary):
    scene = make_scene(surface(), EXT, zenith=30.0, azimuth=20.0, boundary=boundary)
    rotated = _rotated(scene, 0.5)
    ref = reference.trace_water(rotated, photons_per_axis=16)
    image = jc.render(rotated)
    assert periodic_error(image, ref) < tolerance
    assert periodic_error(jc.render(scene), ref) > 3 * tolerance  # the rotation matters


# ---------------------------------------------------------------- the gather window

STRONG = dict(extent=(0.0, 1.0, 0.0, 1.0), sigma=0.1, shape=(64, 64))


@pytest.mark.slow  # 16 s: compiles seven window sizes
def test_error_falls_as_the_window_grows():
    """A bump focusing 1.1 m below a 3 m deep surface displaces rays by up to ~9 pixels.

    Measured relative L1 errors for N = 3, 7, 11, 15, auto (19): 0.196, 0.127, 0.081,
    0.031, 0.006; the missed-flux fraction accounts for nearly all of it.
    """
    heights = bump(STRONG["shape"], STRONG["extent"], amplitude=0.03, sigma=STRONG["sigma"])
    scene = make_scene(heights, STRONG["extent"], depth=3.0)
    ref = reference.trace_water(scene, photons_per_axis=16)
    errors, missed = [], []
    for n in (3, 7, 11, 15, "auto"):
        image, stats = jc.render(
            scene, samples_x=n, channels_y="auto" if n == "auto" else n - 1, return_stats=True
        )
        errors.append(periodic_error(image, ref))
        missed.append(float(stats["missed_flux_fraction"][0]))
    assert all(a > b for a, b in zip(errors, errors[1:], strict=False)), errors
    assert all(a > b for a, b in zip(missed, missed[1:], strict=False)), missed
    assert errors[-1] < 0.02 and missed[-1] < 1e-9
    # the reported missed flux explains the error of the small windows
    assert all(abs(e - m) < 0.01 for e, m in zip(errors[:-1], missed[:-1], strict=False))


@pytest.mark.slow  # 13 s: a large window compiles slowly
def test_auto_window_catches_light_displaced_16_pixels():
    """Focus about 1 m above the ground of a 4 m pool: rays move ~16 pixels.

    Measured: N = 7 misses 17% of the flux (relative L1 error 0.175); the automatic
    window (N = 33, M = 32) has error 0.008.
    """
    heights = bump(STRONG["shape"], STRONG["extent"], amplitude=0.04, sigma=STRONG["sigma"])
    scene = make_scene(heights, STRONG["extent"], depth=4.0)
    assert jc.internal.auto_window(scene) == (33, 32)
    ref = reference.trace_water(scene, photons_per_axis=16)
    small, small_stats = jc.render(scene, samples_x=7, channels_y=6, return_stats=True)
    auto, auto_stats = jc.render(scene, samples_x="auto", return_stats=True)
    assert periodic_error(small, ref) > 0.1 and float(small_stats["missed_flux_fraction"][0]) > 0.1
    assert periodic_error(auto, ref) < 0.02 and float(auto_stats["missed_flux_fraction"][0]) < 1e-9


def test_newton_steps_find_the_moving_surface_under_oblique_light():
    """At 60 degrees the rest-plane point is far from the actual hit (0 steps)."""
    scene = make_scene(sines(scale=1.5), EXT, zenith=60.0, azimuth=10.0)
    ref = reference.trace_water(scene, photons_per_axis=16)
    errors = [periodic_error(jc.render(scene, hit_iterations=k), ref) for k in (0, 1, 3)]
    assert errors[0] > 2 * errors[2] and errors[2] < 0.04, errors


# ---------------------------------------------------------------- gradients


def _loss_fn(scene, weights, **knobs):
    def loss(heights, depth, direction):
        s = jax.tree_util.tree_map(lambda x: x, scene)
        s = eqx_set(s, heights, depth, direction)
        return jnp.sum(weights * jc.render(s, **knobs))

    return loss


def eqx_set(scene, heights, depth, direction):
    import equinox as eqx

    return eqx.tree_at(
        lambda s: (s.surface.heights, s.rest_depth, s.light.direction),
        scene,
        (heights, depth, direction),
    )


@pytest.mark.parametrize(
    "knobs",
    [
        {"supersample": 1},
        # on request (slow, 17 s), for the default run's budget: S = 1 keeps the
        # gradient check in the default run
        pytest.param({"supersample": 2}, marks=pytest.mark.slow),
        # on request (slow), for the default run's budget: by default the splatted sums
        # are checked against the gathered ones (test_splatting_takes_the_gathers_sums)
        pytest.param({"supersample": 2, "samples_x": 11, "channels_y": 10}, marks=pytest.mark.slow),
    ],
    ids=["S1", "S2", "S2-splat"],
)
def test_gradients_match_central_differences(rng, knobs):
    """Reverse and forward mode against central differences in float64, with the
    paper's pixel-sized footprint (S = 1), half-pixel sub-sample footprints (S = 2), and
    a window wide enough to be summed by splatting (`SPLAT_FROM_WINDOW`).

    Both derivatives are of the exact hit (implicit function theorem at convergence),
    so the Newton iteration count is high enough for the hit to converge.
    """
    heights = sines((16, 20), EXT)
    scene = make_scene(heights, EXT, zenith=30.0, azimuth=20.0, shape=(16, 20), fresnel=True)
    weights = jnp.asarray(rng.normal(size=(16, 20)))
    # jitted: run eagerly, the op-by-op dispatch of the six loss evaluations, the grad and
    # the three jvps took 16 s; the checks and tolerances are the same
    method = jc.method_for(scene, hit_iterations=6, **knobs)  # the window fixed, for jit
    loss = jax.jit(_loss_fn(scene, weights, method=method))
    args = (scene.surface.heights, scene.rest_depth, scene.light.direction)
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(*args)
    jvp = jax.jit(lambda a, t: jax.jvp(loss, a, t))
    for _ in range(3):
        tangents = (
            jnp.asarray(rng.normal(size=heights.shape)) * 1e-3,
            jnp.asarray(rng.normal()),
            jnp.asarray(rng.normal(size=3)) * 0.1,
        )
        eps = 1e-6
        plus = loss(*(a + eps * t for a, t in zip(args, tangents, strict=True)))
        minus = loss(*(a - eps * t for a, t in zip(args, tangents, strict=True)))
        fd = (plus - minus) / (2 * eps)
        rev = sum(jnp.sum(g * t) for g, t in zip(grads, tangents, strict=True))
        _, fwd = jvp(args, tangents)
        np.testing.assert_allclose(float(rev), float(fd), rtol=1e-5, atol=1e-8)
        np.testing.assert_allclose(float(fwd), float(fd), rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize(
    "half_x, half_y, supersample, dtype",
    [(2, 1, 1, np.float64), (1, 2, 2, np.float64), (0, 0, 1, np.float64), (2, 1, 4, np.float32)],
)
def test_splatting_takes_the_gathers_sums(half_x, half_y, supersample, dtype):
    """`splat_window` (each sample adds its square to the pixels it overlaps) gives
    `gather_window`'s image, forward derivative and gradient, also where samples sit on
    the tents' kinks (multiples of half a sub-pixel) and land beyond the window or off
    the image. Float64 to rounding; float32 within 1e-5 of the largest value (the sums
    are added in another order)."""
    rng = np.random.default_rng(half_x)
    shape = (12 + 2 * half_y, 15 + 2 * half_x)
    sx = rng.normal(size=shape) * (half_x + 1)
    sy = rng.normal(size=shape) * (half_y + 1)
    sx[::3] = np.round(sx[::3] * 2 * supersample) / (2 * supersample)  # on the kinks
    sy[1::3] = np.round(sy[1::3] * 2 * supersample) / (2 * supersample)
    flux = rng.uniform(size=shape)
    samples = tuple(jnp.asarray(a, dtype) for a in (sx, sy, flux))
    tangents = tuple(jnp.asarray(rng.normal(size=shape), dtype) for _ in range(3))
    weights = jnp.asarray(rng.normal(size=(12, 15)), dtype)
    width = 1.0 / supersample
    results = []
    for sums in (twopass.gather_window, twopass.splat_window):

        def image(*a, sums=sums):
            return sums(*a, half_x, half_y, width)

        value, jvp = jax.jit(lambda s, t, f=image: jax.jvp(f, s, t))(samples, tangents)
        loss = lambda *a, f=image: jnp.sum(weights * jnp.sin(f(*a)))  # noqa: E731
        grad = jax.jit(jax.grad(loss, (0, 1, 2)))(*samples)
        results.append((value, jvp, *grad))
    atol = 1e-12 if dtype == np.float64 else 1e-5
    for gathered, splatted in zip(*results, strict=True):
        scale = max(1.0, float(jnp.max(jnp.abs(gathered))))
        np.testing.assert_allclose(np.asarray(splatted), np.asarray(gathered), atol=atol * scale)


@pytest.mark.slow  # on request, for the default run's budget (the height gradients stay)
def test_gradients_with_respect_to_rotation_and_extent(rng):
    """d/d(rotation) and d/d(surface extent), reverse and forward mode, against central
    differences in float64, at rotation 0 and 0.5 rad (periodic only: the rotation is
    the same code for both boundaries, and each boundary costs a compilation). Measured:
    agree to 1e-9 relative; the tolerances are those of the test above."""
    import equinox as eqx

    heights = sines((16, 20), EXT)
    scene = make_scene(heights, EXT, zenith=30.0, azimuth=20.0, shape=(16, 20))
    scene = eqx.tree_at(lambda s: s.receiver.extent, scene, jnp.asarray([0.1, 0.9, 0.05, 0.7]))
    weights = jnp.asarray(rng.normal(size=(16, 20)))

    def loss(rotation, extent):
        s = eqx.tree_at(lambda s: (s.surface.rotation, s.surface.extent), scene, (rotation, extent))
        return jnp.sum(weights * jc.render(s, hit_iterations=6))

    for rotation in (0.0, 0.5):
        args = (jnp.asarray(rotation), scene.surface.extent)
        grads = jax.grad(loss, argnums=(0, 1))(*args)
        tangents = (jnp.asarray(1.0), jnp.asarray(rng.normal(size=4)) * 0.3)
        for k in range(2):  # rotation alone, then the extent alone
            t = tuple(v if i == k else jnp.zeros_like(v) for i, v in enumerate(tangents))
            eps = 1e-6
            plus = loss(*(a + eps * v for a, v in zip(args, t, strict=True)))
            minus = loss(*(a - eps * v for a, v in zip(args, t, strict=True)))
            fd = float((plus - minus) / (2 * eps))
            rev = float(jnp.sum(grads[k] * t[k]))
            _, fwd = jax.jvp(loss, args, t)
            assert abs(fd) > 1e-3  # a real dependence
            np.testing.assert_allclose(rev, fd, rtol=1e-5, atol=1e-8)
            np.testing.assert_allclose(float(fwd), fd, rtol=1e-5, atol=1e-8)


# ---------------------------------------------------------------- hard cases

HARD = {
    "grazing-80deg": dict(heights=lambda: sines(), zenith=80.0),
    "folding-waves": dict(heights=lambda: sines(scale=8.0), zenith=20.0),
    "total-internal-reflection": dict(heights=lambda: sines(scale=12.0), zenith=40.0, ior=0.75),
    "flat": dict(heights=lambda: np.zeros((48, 64)), zenith=30.0),
}


@jax.jit
def _hard_value_and_grads(scene):
    """The squared image's sum and its gradient in the heights and depth, with the paper's
    window: jitted once per scene structure (the cases share it; run eagerly each case
    took 5-7 s of op-by-op dispatch, jitted 3.7 s per compile)."""

    def loss(h, depth):
        s = eqx_set(scene, h, depth, scene.light.direction)
        return jnp.sum(jc.render(s, jc.TwoPass.paper()) ** 2)

    return jax.value_and_grad(loss, argnums=(0, 1))(scene.surface.heights, scene.rest_depth)


# the float64 twin runs on request (slow), for the default run's 10-minute budget
# (float32, the default, stays)
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=pytest.mark.slow)])
@pytest.mark.parametrize("case", sorted(HARD))
def test_hard_cases_stay_finite(case, dtype):
    spec = dict(HARD[case])
    heights = spec.pop("heights")()
    scene = make_scene(heights, EXT, dtype=dtype, fresnel=True, **spec)
    # the paper's window misses light in the strong cases: render says so
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        image, stats = jc.render(scene, jc.TwoPass.paper(), return_stats=True)
    missed = float(jnp.max(stats["missed_flux_fraction"]))
    said = [w for w in caught if "of the light" in str(w.message)]
    assert len(said) == (missed > MISSED_FLUX_WARNING), (missed, said)
    value, grads = _hard_value_and_grads(scene)
    assert image.dtype == dtype and grads[0].dtype == dtype
    assert bool(jnp.all(jnp.isfinite(image))) and bool(jnp.isfinite(value))
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)
    if case == "total-internal-reflection":
        assert float(jnp.mean(image)) < 0.99  # some light is lost to TIR
    if case == "folding-waves":
        assert float(jnp.max(image)) > 3.0  # folds make bright caustic lines


# ---------------------------------------------------------------- JAX transformations


def test_no_retracing_when_only_values_change(monkeypatch):
    traces = []
    original = twopass.prepass

    def counting(*args, **kwargs):
        traces.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(twopass, "prepass", counting)
    for seed in range(3):
        heights = np.random.default_rng(seed).normal(size=(13, 17)) * 1e-3
        # a fixed window (the default "auto" one is sized from the values)
        jc.render(make_scene(heights, zenith=10.0 * seed, depth=0.5 + seed), jc.TwoPass.paper())
    assert len(traces) == 1


def test_vmap_over_a_batch_of_surfaces():
    scene = make_scene(sines(), EXT, zenith=30.0)
    batch = jnp.stack([sines(scale=s) for s in (0.5, 1.0, 1.5)])

    def render_heights(h):
        # under vmap the window is fixed (the default "auto" one needs values)
        changed = eqx_set(scene, h, scene.rest_depth, scene.light.direction)
        return jc.render(changed, jc.TwoPass.paper())

    images = jax.jit(jax.vmap(render_heights))(batch)
    for i in range(3):
        np.testing.assert_allclose(
            np.asarray(images[i]), np.asarray(render_heights(batch[i])), atol=1e-12
        )


def test_blocks_of_rows_change_nothing(monkeypatch, supersample=2):
    """The pre-pass in blocks of rows (`SAMPLES_PER_BLOCK`; here 5 rows a block, the last
    one ragged) gives the samples and the gradient of one block, in float64."""
    scene = make_scene(sines((13, 17)), EXT, zenith=40.0, azimuth=20.0, shape=(13, 17))

    def loss(heights):  # (the block size is read when traced: a new jit each time)
        changed = eqx_set(scene, heights, scene.rest_depth, scene.light.direction)
        pre = twopass.prepass(changed, 3, 3, 3, supersample)
        return sum(jnp.sum(jnp.sin(3.0 * a)) for a in (pre.shift_x, pre.shift_y, pre.flux))

    heights = scene.surface.heights
    blocks = []
    original = jax.lax.map

    def spy(f, xs, **kwargs):
        blocks.append(xs.shape[0])
        return original(f, xs, **kwargs)

    monkeypatch.setattr(jax.lax, "map", spy)
    whole = jax.jit(jax.value_and_grad(loss))(heights)
    assert blocks == []
    padded_cols = 17 + 6  # the paper's window pads 3 columns on each side
    monkeypatch.setattr(twopass, "SAMPLES_PER_BLOCK", 5 * supersample**2 * padded_cols)
    blocked = jax.jit(jax.value_and_grad(loss))(heights)
    assert blocks == [4]  # 19 padded rows
    np.testing.assert_allclose(float(blocked[0]), float(whole[0]), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(blocked[1]), np.asarray(whole[1]), atol=1e-12)


def test_effects_a_scene_does_not_call_for_are_not_traced(monkeypatch):
    """A Fresnel-off scene never traces the Fresnel equations, and its jaxpr is smaller."""
    calls = []
    original = twopass.fresnel_transmittance

    def spy(*args):
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(twopass, "fresnel_transmittance", spy)
    heights = sines((9, 11))
    off = make_scene(heights, shape=(9, 11), zenith=20.0)
    on = make_scene(heights, shape=(9, 11), zenith=20.0, fresnel=True)
    jaxpr_off = jax.make_jaxpr(lambda s: twopass.prepass(s, 1, 1, 2, 1))(off)
    assert calls == []
    jaxpr_on = jax.make_jaxpr(lambda s: twopass.prepass(s, 1, 1, 2, 1))(on)
    assert calls == [1]
    assert len(jaxpr_on.jaxpr.eqns) > len(jaxpr_off.jaxpr.eqns)
    # and a single index of refraction traces one channel
    assert jax.eval_shape(lambda s: twopass.prepass(s, 1, 1, 2, 1), off).flux.shape[0] == 1


def test_auto_window_under_jit_says_what_to_do():
    scene = make_scene(sines((9, 11)), shape=(9, 11))
    for transform in (jax.jit, jax.vmap):
        batch = scene if transform is jax.jit else jax.tree_util.tree_map(lambda x: x[None], scene)
        with pytest.raises(ValueError, match="method_for"):
            transform(lambda s: jc.render(s))(batch)  # the default window is "auto"
    method = jc.method_for(scene)  # what the message says to call
    assert (method.samples_x, method.channels_y) == jc.internal.auto_window(scene)
    image = jax.jit(lambda s: jc.render(s, method))(scene)
    np.testing.assert_allclose(np.asarray(image), np.asarray(jc.render(scene, samples_x="auto")))


def test_default_window_under_grad_is_a_constant():
    """Under `grad` the scene's values are known, so the default "auto" window works
    and gives the gradient of the render with that window."""
    scene = make_scene(sines((9, 11)), shape=(9, 11), zenith=40.0)
    n, m = jc.internal.auto_window(scene)

    def loss(h, **knobs):
        changed = eqx_set(scene, h, scene.rest_depth, scene.light.direction)
        return jnp.sum(jc.render(changed, **knobs) ** 2)

    auto = jax.grad(loss)(scene.surface.heights)
    fixed = jax.grad(loss)(scene.surface.heights, samples_x=n, channels_y=m)
    np.testing.assert_array_equal(np.asarray(auto), np.asarray(fixed))
    assert float(jnp.max(jnp.abs(auto))) > 0.0


@pytest.mark.slow
def test_larger_maps_agree_tightly_with_a_dense_reference():
    """128 x 128, crossing waves at 30 degrees, reference with 32 x 32 photons per pixel.

    Measured in benchmarks/bench_twopass.py (float32): relative L1 after the 1-pixel blur 0.0177
    with one sample per pixel and 0.0035 with 4 x 4; the tolerances leave ~40% margin.
    """
    extent = (0.0, 1.0, 0.0, 1.0)
    terms = ((5, 2, 0.002, 0.0), (3, 6, 0.0015, 1.0))
    heights = np.asarray(jc.sine_sum((128, 128), extent, terms=terms))
    scene = make_scene(heights, extent, zenith=30.0, azimuth=20.0)
    ref = reference.trace_water(scene, photons_per_axis=32)
    n, m = jc.internal.auto_window(scene)
    assert periodic_error(jc.render(scene, samples_x=n, channels_y=m), ref) < 0.025
    assert periodic_error(jc.render(scene, samples_x=n, channels_y=m, supersample=4), ref) < 0.005


# on request (slow), for the default run's budget: the central-difference gradient test
# checks the same gradients by default
@pytest.mark.slow
def test_gradient_at_flat_water_is_a_descent_direction():
    """At flat water every sample lands on a pixel centre, on the kinks of the tents: the
    image is not differentiable there. The gradient uses the derivative from the right
    at every kink (light one pixel loses, its neighbour gains), so it is not zero and a
    small step against it lowers a loss; an optimiser started from flat water moves."""
    heights = np.zeros((16, 16))
    scene = make_scene(heights, zenith=20.0, depth=0.5)
    target = np.asarray(
        jc.internal.two_pass(
            make_scene(bump((16, 16), amplitude=0.002), zenith=20.0, depth=0.5),
            samples_x=5,
            channels_y=4,
        ).image
    )

    def loss(h):
        s = eqx.tree_at(lambda s: s.surface.heights, scene, h)
        return jnp.sum((jc.internal.two_pass(s, samples_x=5, channels_y=4).image - target) ** 2)

    h0 = jnp.asarray(heights)
    grad = jax.grad(loss)(h0)
    assert float(jnp.abs(grad).max()) > 0
    step = 1e-4 / float(jnp.abs(grad).max())  # moves the surface by 0.1 mm at most
    assert float(loss(h0 - step * grad)) < float(loss(h0))


def test_defaults_are_accurate_under_grazing_light():
    """The sea of the README's example (and of docs/getting-started.md), at half its wave
    height (with 2 mm waves at 80 degrees the reference's own ray/surface intersection
    does not converge), under light 80 degrees from vertical, rendered as a new user
    would: ``render(scene)``.

    Measured against this 12-photon-per-axis reference (8 photons differ from it by
    0.0039): the defaults (window sized from the scene, 2 x 2 samples) 0.0073, the
    paper's 7 x 7 window 0.051 (it misses 3.8% of the light, and says so)."""
    extent = (0.0, 2.0, 0.0, 1.5)
    heights = jc.wave_heights(
        (150, 200), extent, amplitude=0.001, depth=0.5, wavelength_range=(0.1, 0.5)
    )
    scene = jc.WaterScene(
        jc.HeightField(heights, extent),
        jc.DirectionalLight.from_angles(80.0),
        jc.PlaneReceiver(extent, (150, 200)),
        rest_depth=0.5,
    )
    ref = reference.trace_water(scene, photons_per_axis=12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing missed, nothing said
        image = jc.render(scene)
    assert jc.image_error(np.asarray(image), ref) <= 0.01
    with pytest.warns(UserWarning, match="missed"):
        paper = jc.render(scene, jc.TwoPass.paper())
    assert jc.image_error(np.asarray(paper), ref) > 0.03
