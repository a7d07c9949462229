"""`legendre`: the anchored, windowed search gives the brute-force maximum, on lines whose
maximisers jump (wide blocks), on lines too rough for the wide blocks provided for
(brute force per chunk), and in 2-D with ghost cells. Blocks of 4 slopes and windows of
16 points (the module's are 16 and 128) keep the lines short: the same code paths at 64
points a line, not 512.

The module transforms ``f = x^2 / 2 + u`` given ``u`` and returns ``f*(s) - s^2 / 2``;
the NumPy references here transform ``f`` itself (`brute`), and the tests convert
(`u_of`, `v_of`)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.inverse import legendre as lg

BLOCK, WINDOW = 4, 16
N = 4 * WINDOW  # the shortest line the windows are used on


@pytest.fixture(autouse=True)
def small_windows(monkeypatch):
    monkeypatch.setattr(lg, "_BLOCK", BLOCK)
    monkeypatch.setattr(lg, "_WINDOW", WINDOW)


def brute(f, x, s):
    """``max_j (s_i x_j - f[l, j])`` in NumPy, float64."""
    return np.max(s[None, :, None] * x[None, None, :] - f[:, None, :], axis=2)


def u_of(f, x):
    """The module's argument for lines `f` at points `x`: ``f - x^2 / 2``."""
    return jnp.asarray(f - 0.5 * x**2)


def v_of(fstar, s):
    """The module's result for the transform `fstar` at slopes `s`: ``f* - s^2 / 2``."""
    return fstar - 0.5 * s**2


def kinked_lines(lines=8, n=N, seed=0):
    """Convex lines, each linear over a stretch of 40% of its length (the maximiser jumps
    over it: wider than the window), plus a little noise."""
    x = (np.arange(n) + 0.5) / n
    a, b = 0.3, 0.7
    base = np.where(x < a, 0.5 * x**2, 0.5 * a**2 + a * (x - a))
    base = np.where(x > b, 0.5 * a**2 + a * (b - a) + a * (x - b) + 0.5 * (x - b) ** 2, base)
    rng = np.random.default_rng(seed)
    return base[None, :] + 1e-6 * rng.standard_normal((lines, n)), x


def test_wide_blocks_are_searched_whole(monkeypatch):
    f, x = kinked_lines()
    s = x.copy()
    with monkeypatch.context() as m:  # no wide block provided for: these lines have some
        m.setattr(lg, "_WIDE_PER_LINE", 0)
        assert bool(lg._bracketed_lines(u_of(f, x), jnp.asarray(x), jnp.asarray(s))[1])
    near, overflow = jax.jit(lg._bracketed_lines)(u_of(f, x), jnp.asarray(x), jnp.asarray(s))
    assert not bool(overflow)  # one wide block or so per line: within the budget
    np.testing.assert_allclose(np.asarray(near), v_of(brute(f, x, s), s), rtol=0, atol=1e-12)


def test_lines_with_many_jumps_fall_back_to_brute_force():
    n = 2 * N
    x = (np.arange(n) + 0.5) / n
    # convex, linear on 6 stretches of n / 6 points (wider than the window) with slopes
    # 0.1, 0.26, ...: the maximiser jumps 5 times, each jump widening 2 or 3 blocks
    slope = 0.1 + 0.16 * np.floor(6 * x)
    f = np.cumsum(slope) / n + 1e-7 * np.random.default_rng(1).standard_normal((8, n))
    _, overflow = jax.jit(lg._bracketed_lines)(u_of(f, x), jnp.asarray(x), jnp.asarray(x))
    assert bool(overflow)  # more wide blocks than provided for
    out = jax.jit(lg._legendre_lines)(u_of(f, x), jnp.asarray(x), jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(out), v_of(brute(f, x, x), x), rtol=0, atol=1e-12)


@pytest.mark.parametrize("ghost", [3])
def test_two_dimensional_transform_is_the_brute_forces(ghost):
    n = N
    h = 1.0 / n
    xs = (np.arange(n) + 0.5) * h
    X, Y = np.meshgrid(xs, xs)
    rng = np.random.default_rng(2)
    f = 0.5 * (X**2 + Y**2) + 0.02 * np.abs(X - 0.4) + 1e-3 * np.sin(9 * X) * np.cos(7 * Y)
    f = f + 1e-5 * rng.standard_normal(f.shape)
    s = (np.arange(-ghost, n + ghost) + 0.5) * h
    rows = brute(f, xs, s)  # (n, n + 2 ghost): along each row
    expected = brute(-rows.T, xs, s).T - 0.5 * (s[None, :] ** 2 + s[:, None] ** 2)
    u = f - 0.5 * (X**2 + Y**2)
    out = np.asarray(jax.jit(lambda a: lg.legendre(a, h, ghost=ghost))(jnp.asarray(u)))
    assert out.shape == (n + 2 * ghost, n + 2 * ghost)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)


def test_float32_agrees_with_the_float32_brute_force():
    f, x = kinked_lines(lines=4)
    u32, x32 = jnp.asarray(f - 0.5 * x**2, jnp.float32), jnp.asarray(x, jnp.float32)
    out = lg._legendre_lines(u32, x32, x32)
    expected = lg._brute_lines(u32, x32, x32)
    np.testing.assert_allclose(np.asarray(out), np.asarray(expected), rtol=0, atol=1e-7)


@pytest.mark.parametrize("smooth", [False, True])
def test_float32_keeps_the_digits_of_u(smooth):
    """At 2048 points a side the transport's potential differs from ``x^2 / 2`` by a
    small ``u``; the transform of ``f`` itself in float32 rounds at ``f``'s scale
    (3e-8 near 0.5: a tenth of a cell's ``dx^2 = 2.4e-7``), the module's at ``u``'s.
    Measured against float64: within 2e-9 here (u up to 0.01)."""
    n = 2048
    x = (np.arange(n) + 0.5) / n
    u = 0.01 * np.sin(3 * x + np.arange(4)[:, None]) ** 2  # convex f: u'' > -1
    lines = lg._smooth_lines if smooth else lg._legendre_lines
    exact = np.asarray(jax.jit(lines)(jnp.asarray(u), jnp.asarray(x), jnp.asarray(x)))
    x32 = jnp.asarray(x, jnp.float32)
    out = np.asarray(jax.jit(lines)(jnp.asarray(u, jnp.float32), x32, x32))
    assert np.max(np.abs(out - exact)) < 2e-9
    f32 = jnp.asarray(0.5 * x**2 + u, jnp.float32)  # the classic form, for contrast
    classic = np.asarray(jnp.max(x32[:, None] * x32[None, :] - f32[:, None, :], axis=2))
    assert np.max(np.abs(classic - 0.5 * x**2 - exact)) > 5e-9  # it could fail


def pieces_transform(f, x, s):
    """The smooth transform's rule in NumPy, by brute force: the best, over the pieces of
    the discrete maximiser and its two neighbours (piece ``j``: ``x_j +- dx / 2``, slope
    ``a_j`` and curvature ``b_j`` from central differences, the ends extrapolated
    quadratically), of ``max over t of (s (x_j + t) - f_j - a_j t - b_j t^2 / 2)``, and
    of the discrete transform; the best ``t`` in closed form."""
    dx = x[1] - x[0]
    first = 3 * f[:, :1] - 3 * f[:, 1:2] + f[:, 2:3]
    last = 3 * f[:, -1:] - 3 * f[:, -2:-1] + f[:, -3:-2]
    ext = np.concatenate([first, f, last], axis=1)
    a = (ext[:, 2:] - ext[:, :-2]) / (2 * dx)
    b = np.maximum((ext[:, 2:] - 2 * ext[:, 1:-1] + ext[:, :-2]) / dx**2, 0.0)
    scores = s[None, :, None] * x[None, None, :] - f[:, None, :]
    best = np.argmax(scores, axis=2)  # (lines, m)
    out = np.max(scores, axis=2)
    rows = np.arange(len(f))[:, None]
    for step in (-1, 0, 1):
        j = np.clip(best + step, 0, len(x) - 1)
        u = s[None, :] - a[rows, j]
        t = np.clip(u / np.maximum(b[rows, j], 1e-300), -0.5 * dx, 0.5 * dx)
        value = s[None, :] * (x[j] + t) - (f[rows, j] + a[rows, j] * t + 0.5 * b[rows, j] * t**2)
        out = np.maximum(out, value)
    return out


def test_smooth_transform_of_a_sampled_quadratic_is_the_exact_conjugate():
    """A quadratic's interpolant is the quadratic itself: its transform is exact wherever
    the maximiser lies on the grid (``s / k`` within ``[0, 1]``), in 2-D too; the
    discrete transform is a staircase's, off by up to ``k dx^2 / 8``."""
    n = N
    h = 1.0 / n
    x = (np.arange(n) + 0.5) * h
    X, Y = np.meshgrid(x, x)
    kx, ky = 1.3, 0.7  # ky < 1: some grid points lie between the discrete maximisers
    u = 0.5 * ((kx - 1) * X**2 + (ky - 1) * Y**2)
    exact = 0.5 * (X**2 / kx + Y**2 / ky) - 0.5 * (X**2 + Y**2)
    on_grid = Y / ky <= 1.0
    smooth = np.asarray(jax.jit(lambda a: lg.legendre(a, h, smooth=True))(jnp.asarray(u)))
    np.testing.assert_allclose(smooth[on_grid], exact[on_grid], rtol=0, atol=1e-13)
    discrete = np.asarray(jax.jit(lambda a: lg.legendre(a, h))(jnp.asarray(u)))
    assert np.max(np.abs(discrete - exact)[on_grid]) > 0.1 * h * h  # it could fail


@pytest.mark.parametrize("windowed", [False, True])
def test_smooth_lines_are_the_interpolants_transform(windowed):
    """Convex lines with a linear stretch (the maximiser jumps over it) and kinks, short
    (brute force) and long enough for the windows, at slopes beyond the ends too: the
    rule of `pieces_transform` (found there by an argmax, here by a sorted search)."""
    n = N if windowed else 24
    f, x = kinked_lines(lines=4, n=n)
    f = f + 0.05 * np.abs(x - 0.5)[None, :] * np.arange(4)[:, None]  # kinks of three sizes
    s = np.linspace(-0.2, 1.2, 3 * n)
    out = jax.jit(lg._smooth_lines)(u_of(f, x), jnp.asarray(x), jnp.asarray(s))
    expected = pieces_transform(f, x, s)
    np.testing.assert_allclose(np.asarray(out), v_of(expected, s), rtol=0, atol=1e-12)
    assert np.max(np.abs(brute(f, x, s) - expected)) > 1e-5  # not the discrete transform


def test_smooth_lines_never_fall_below_the_discrete_transform():
    """On lines that are not convex (noise of 1e-3), where the sorted search can miss
    the best piece, the result is at least the discrete transform, and at most half a
    point's step above it (a piece's gain is at most ``|s - a_j| dx / 2``)."""
    n = N
    x = (np.arange(n) + 0.5) / n
    f = 0.5 * x**2 + 1e-3 * np.random.default_rng(3).standard_normal((6, n))
    s = np.linspace(0.0, 1.0, n)
    out = np.asarray(jax.jit(lg._smooth_lines)(u_of(f, x), jnp.asarray(x), jnp.asarray(s)))
    discrete = v_of(brute(f, x, s), s)
    assert np.all(out >= discrete - 1e-15)
    assert np.all(out <= discrete + 0.5 / n * 2.0)
    assert np.max(out - discrete) > 0  # the pieces do add something
