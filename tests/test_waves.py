"""Procedural surfaces: periodic animated waves, Gaussian bump, sine sums."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.scene.waves import GRAVITY, gaussian_bump, sine_sum, wave_heights

EXTENT = (-0.5, 1.5, 0.25, 1.25)  # 2 m x 1 m, off the origin
SHAPE = (32, 48)  # (rows, cols): 6 pixels per shortest default wavelength along x


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def test_shape_dtype_rms_and_mean():
    for t in (0.0, 0.7, 13.0):
        h = wave_heights(SHAPE, EXTENT, t, amplitude=0.03)
        assert h.shape == SHAPE and h.dtype == jnp.result_type(
            float
        )  # float64 under the suite-wide x64
        h = np.asarray(h, np.float64)
        # Every wave is below Nyquist, so the grid RMS is the continuous one exactly.
        assert math.sqrt(np.mean(h**2)) == pytest.approx(0.03, rel=1e-5)
        assert abs(h.mean()) < 1e-8
    assert np.all(np.asarray(wave_heights(SHAPE, EXTENT, amplitude=0.0)) == 0.0)


def test_periodic_only_integer_frequencies_and_shifted_grid():
    h = np.asarray(wave_heights(SHAPE, EXTENT, 0.4), np.float64)
    # A sum of waves periodic over the extent: a DFT over one period is exactly sparse
    # (at most num_waves pairs of +-k bins), with no leakage between bins.
    power = np.abs(np.fft.fft2(h)) ** 2
    top = np.sort(power.ravel())[::-1]
    assert np.count_nonzero(power > 1e-9 * top[0]) <= 2 * 24
    assert top[48:].sum() < 1e-9 * top.sum()
    # Absolute coordinates: on the grid shifted by whole periods (which only the
    # periodicity maps onto the same points) the samples are the same.
    x0, x1, y0, y1 = EXTENT
    lx, ly = x1 - x0, y1 - y0
    for sx, sy in ((1, 0), (0, -1), (3, 2)):
        shifted = (x0 + sx * lx, x1 + sx * lx, y0 + sy * ly, y1 + sy * ly)
        np.testing.assert_allclose(wave_heights(SHAPE, shifted, 0.4), h, atol=1e-7)
    # Half a period is not a period: the samples differ.
    half = (x0 + lx / 2, x1 + lx / 2, y0, y1)
    assert np.max(np.abs(np.asarray(wave_heights(SHAPE, half, 0.4)) - h)) > 1e-3


def test_spectrum_falls_with_frequency():
    # Power-weighted mean wavenumber is well below the band's upper end: smooth surfaces.
    h = np.asarray(wave_heights((64, 64), (0, 1, 0, 1), 0.0, num_waves=40, seed=3))
    power = np.abs(np.fft.fft2(h)) ** 2
    f = np.fft.fftfreq(64, d=1 / 64)
    kk = np.hypot(*np.meshgrid(f, f, indexing="ij"))
    mean_k = (kk * power).sum() / power.sum()
    assert 1.0 <= mean_k < 4.0  # default band: 1 to 8 periods per extent


def test_deterministic_in_seed_and_resolution_independent():
    a = wave_heights(SHAPE, EXTENT, 0.2, seed=5)
    np.testing.assert_array_equal(a, wave_heights(SHAPE, EXTENT, 0.2, seed=5))
    assert not np.allclose(a, wave_heights(SHAPE, EXTENT, 0.2, seed=6))
    # The same sea at 3x the resolution: fine pixel 3 i + 1 has the centre of coarse
    # pixel i.
    fine = wave_heights((96, 144), EXTENT, 0.2, seed=5)
    np.testing.assert_allclose(fine[1::3, 1::3], a, atol=1e-6)


def test_time_moves_waves_with_dispersion():
    # A single wave: its phase speed is omega / k with omega^2 = g k tanh(k d).
    ext = (0.0, 4.0, 0.0, 1.0)
    kw = dict(num_waves=1, wavelength_range=(4.0, 4.0), direction=0.0, amplitude=1.0)
    h0 = np.asarray(wave_heights((1, 256), ext, 0.0, depth=0.5, **kw), np.float64)[0]
    k = 2 * np.pi / 4.0
    omega = math.sqrt(GRAVITY * k * math.tanh(k * 0.5))
    t = 0.1
    h1 = np.asarray(wave_heights((1, 256), ext, t, depth=0.5, **kw), np.float64)[0]
    x = (np.arange(256) + 0.5) * 4.0 / 256
    phase0 = np.angle(np.sum(h0 * np.exp(-1j * k * x)))
    phase1 = np.angle(np.sum(h1 * np.exp(-1j * k * x)))
    assert (phase0 - phase1) % (2 * np.pi) == pytest.approx(omega * t, rel=1e-4)


def test_jit_and_vmap_over_time():
    f = jax.jit(lambda t: wave_heights(SHAPE, EXTENT, t))
    np.testing.assert_allclose(f(1.5), wave_heights(SHAPE, EXTENT, 1.5), atol=1e-7)
    times = jnp.array([0.0, 0.5, 1.0, 2.0])
    batch = jax.vmap(lambda t: wave_heights(SHAPE, EXTENT, t))(times)
    assert batch.shape == (4, *SHAPE)
    for i, t in enumerate(times):
        np.testing.assert_allclose(batch[i], wave_heights(SHAPE, EXTENT, t), atol=1e-6)


def test_time_derivative_matches_finite_differences(x64):
    def h(t):
        return wave_heights(SHAPE, EXTENT, t, amplitude=0.02, depth=0.8)

    t0 = jnp.asarray(1.3, jnp.float64)
    h0, dh = jax.jvp(h, (t0,), (jnp.ones_like(t0),))
    assert h0.dtype == dh.dtype == jnp.float64
    assert dh.shape == SHAPE and bool(jnp.all(jnp.isfinite(dh)))
    eps = 1e-5
    one = (jnp.ones_like(t0),)
    # (the primal outputs of jvp: the same compiled program, evaluated at t0 +- eps)
    fd = (jax.jvp(h, (t0 + eps,), one)[0] - jax.jvp(h, (t0 - eps,), one)[0]) / (2 * eps)
    np.testing.assert_allclose(dh, fd, rtol=1e-6, atol=1e-8)  # |dh| ~ 0.1

    # Reverse mode, in time, amplitude and depth together.
    def loss(t, a, d):
        return jnp.sum(wave_heights(SHAPE, EXTENT, t, amplitude=a, depth=d) ** 2)

    g_t, g_a, g_d = jax.grad(loss, argnums=(0, 1, 2))(t0, 0.02, 0.8)
    assert all(bool(jnp.isfinite(g)) for g in (g_t, g_a, g_d))
    # loss = amplitude^2 * rows * cols exactly (the RMS is exact): d/da = 2 loss / a.
    assert float(g_a) == pytest.approx(2 * 0.02 * SHAPE[0] * SHAPE[1], rel=1e-9)
    assert abs(float(g_t)) < 1e-9  # ... and constant in time and depth
    assert abs(float(g_d)) < 1e-9


def test_deep_water_and_direction():
    deep = wave_heights(SHAPE, EXTENT, 2.0, depth=math.inf)
    assert bool(jnp.all(jnp.isfinite(deep)))
    np.testing.assert_allclose(deep, wave_heights(SHAPE, EXTENT, 2.0, depth=1e3), atol=1e-6)
    # A narrow spread around +y: waves vary along y only when the spread excludes x.
    h = np.asarray(
        wave_heights(
            (32, 32), (0, 1, 0, 1), direction=math.pi / 2, direction_spread=1e-6, num_waves=5
        )
    )
    np.testing.assert_allclose(h, h[:, :1] * np.ones((1, 32)), atol=1e-7)


def test_aliasing_warns():
    with pytest.warns(UserWarning, match="not resolved"):
        wave_heights((8, 8), (0, 1, 0, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wave_heights(SHAPE, EXTENT)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"shape": (0, 4)}, "`shape`"),
        ({"shape": (4,)}, "`shape`"),
        ({"shape": (4.5, 4)}, "`shape`"),
        ({"shape": 4}, "`shape`"),
        ({"extent": (1, 0, 0, 1)}, "`extent`"),
        ({"extent": (0, 1, 0)}, "`extent`"),
        ({"extent": (0, np.nan, 0, 1)}, "`extent`"),
        ({"extent": "abc"}, "`extent`"),
        ({"amplitude": -0.1}, "`amplitude` must be >= 0"),
        ({"amplitude": np.inf}, "`amplitude` must be finite"),
        ({"num_waves": 0}, "`num_waves` must be >= 1"),
        ({"num_waves": 2.0}, "`num_waves` must be an int"),
        ({"num_waves": 10_000}, "`num_waves` = 10000 exceeds"),
        ({"depth": 0.0}, "`depth` must be > 0"),
        ({"time": np.array([0.0, 1.0])}, "`time` must be a scalar"),
        ({"time": np.nan}, "`time` must be finite"),
        ({"seed": -1}, "`seed`"),
        ({"wavelength_range": (0.5,)}, "`wavelength_range`"),
        ({"wavelength_range": (1.0, 0.5)}, "`wavelength_range` must be \\(min, max\\)"),
        ({"wavelength_range": (0.0, 0.5)}, "`wavelength_range`"),
        ({"wavelength_range": (1e-5, 1.0)}, "`wavelength_range` minimum"),
        ({"direction_spread": 0.0}, "`direction_spread`"),
        ({"direction_spread": 4.0}, "`direction_spread`"),
        ({"direction": np.inf}, "`direction`"),
    ],
)
def test_wave_heights_bad_arguments(kwargs, match):
    args = {"shape": SHAPE, "extent": EXTENT, **kwargs}
    with pytest.raises(ValueError, match=match):
        wave_heights(**args)


def test_traced_extent_is_rejected():
    with pytest.raises(ValueError, match="`extent` must be concrete"):
        jax.jit(lambda e: wave_heights(SHAPE, e))(jnp.asarray(EXTENT))


# --------------------------------------------------------------------------- test surfaces


def test_gaussian_bump_peak_and_centres():
    ext = (0.0, 1.0, 0.0, 2.0)
    # 5 x 5 pixels over 1 x 2 m: the centre pixel's centre is the extent's centre.
    h = np.asarray(gaussian_bump((5, 5), ext, sigma=0.3, amplitude=0.01))
    assert h.shape == (5, 5)
    assert h[2, 2] == pytest.approx(0.01, rel=1e-6)
    assert np.unravel_index(np.argmax(h), h.shape) == (2, 2)
    # Pixel (i, j) has its centre at x = (j + 0.5) * 0.2, y = (i + 0.5) * 0.4.
    x, y = (0 + 0.5) * 0.2, (4 + 0.5) * 0.4
    r2 = (x - 0.5) ** 2 + (y - 1.0) ** 2
    assert h[4, 0] == pytest.approx(0.01 * math.exp(-r2 / (2 * 0.09)), rel=1e-5)
    # An explicit centre at pixel (row 1, col 3) puts the peak there.
    h2 = np.asarray(gaussian_bump((5, 5), ext, center=(0.7, 0.6), sigma=0.1, amplitude=-2.0))
    assert np.unravel_index(np.argmin(h2), h2.shape) == (1, 3)
    assert h2[1, 3] == pytest.approx(-2.0)
    # Differentiable in its parameters, jittable.
    g = jax.grad(lambda s: gaussian_bump((5, 5), ext, sigma=s, amplitude=1.0).sum())(0.3)
    assert jnp.isfinite(g) and g > 0
    j = jax.jit(lambda c: gaussian_bump((5, 5), ext, center=c, sigma=0.3, amplitude=0.01))
    np.testing.assert_allclose(j(jnp.array([0.5, 1.0])), h, rtol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sigma": 0.0}, "`sigma` must be > 0"),
        ({"sigma": -1.0}, "`sigma`"),
        ({"amplitude": np.nan}, "`amplitude` must be finite"),
        ({"center": (0.5,)}, "`center`"),
        ({"center": (0.5, np.inf)}, "`center` must be finite"),
        ({"shape": (3, 0)}, "`shape`"),
        ({"extent": (0, 0, 0, 1)}, "`extent`"),
        ({"extent": (0, 1, 0)}, "`extent`"),
    ],
)
def test_gaussian_bump_bad_arguments(kwargs, match):
    args = {"shape": (4, 4), "extent": (0, 1, 0, 1), "sigma": 0.2, "amplitude": 1.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        gaussian_bump(**args)


def test_sine_sum_values_at_pixel_centres():
    ext = (2.0, 4.0, -1.0, 0.0)
    shape = (4, 8)
    terms = ((1, 0, 0.5, 0.0), (2, 3, 0.25, 1.0), (-1, 1, 0.1, 0.3))
    h = np.asarray(sine_sum(shape, ext, terms=terms))
    x = (2.0 + (np.arange(8) + 0.5) * 2.0 / 8)[None, :]  # pixel centres, Lx = 2 m
    y = (-1.0 + (np.arange(4) + 0.5) * 1.0 / 4)[:, None]  # Ly = 1 m
    expected = sum(
        a * np.sin(2 * np.pi * (kx * x / 2.0 + ky * y / 1.0) + ph) for kx, ky, a, ph in terms
    )
    np.testing.assert_allclose(h, expected, atol=1e-6)
    # Periodic: the same terms over another tile give the same samples.
    np.testing.assert_allclose(sine_sum(shape, (4.0, 6.0, 1.0, 2.0), terms=terms), h, atol=1e-6)
    # Amplitude and phase may be traced.
    g = jax.grad(lambda a: sine_sum(shape, ext, terms=((1, 1, a, 0.2),)).sum())(1.0)
    assert jnp.isfinite(g)


@pytest.mark.parametrize(
    ("terms", "match"),
    [
        ((), "`terms` must hold at least one"),
        (((1, 0, 1.0),), r"`terms\[0\]` must be"),
        (((1.5, 0, 1.0, 0.0),), r"`terms\[0\]` kx must be an integer"),
        (((1, 0, 1.0, 0.0), (0, np.nan, 1.0, 0.0)), r"`terms\[1\]` ky"),
        (((1, 0, np.inf, 0.0),), r"`terms\[0\] amplitude` must be finite"),
        (5, "`terms` must be a sequence"),
    ],
)
def test_sine_sum_bad_terms(terms, match):
    with pytest.raises(ValueError, match=match):
        sine_sum((4, 4), (0, 1, 0, 1), terms=terms)
