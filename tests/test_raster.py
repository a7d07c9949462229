"""Rasterisation kernels: exact overlaps, tie rules, folds, degenerate triangles, splats."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.reconstruct.raster import (
    pixel_coordinates,
    rasterize_exact,
    rasterize_gouraud,
    signed_area,
    splat_gaussian,
    sum_in_tiers,
    window_for,
)

# ----------------------------------------------------------------------------- reference


def _clip(polygon, inside, intersect):
    out = []
    for k in range(len(polygon)):
        cur, prev = polygon[k], polygon[k - 1]
        if inside(cur):
            if not inside(prev):
                out.append(intersect(prev, cur))
            out.append(cur)
        elif inside(prev):
            out.append(intersect(prev, cur))
    return out


def _clip_box(polygon, x0, x1, y0, y1):
    """Sutherland–Hodgman clipping of a polygon (list of (x, y)) to a box."""

    def at_x(c):
        return lambda p, q: (c, p[1] + (q[1] - p[1]) * (c - p[0]) / (q[0] - p[0]))

    def at_y(c):
        return lambda p, q: (p[0] + (q[0] - p[0]) * (c - p[1]) / (q[1] - p[1]), c)

    for inside, intersect in [
        (lambda p: p[0] >= x0, at_x(x0)),
        (lambda p: p[0] <= x1, at_x(x1)),
        (lambda p: p[1] >= y0, at_y(y0)),
        (lambda p: p[1] <= y1, at_y(y1)),
    ]:
        polygon = _clip(polygon, inside, intersect)
        if not polygon:
            return []
    return polygon


def _shoelace(polygon):
    if len(polygon) < 3:
        return 0.0
    x, y = np.array(polygon).T
    return 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _reference_image(vertices, flux, shape):
    image = np.zeros(shape)
    for tri, f in zip(vertices, flux, strict=True):
        area = _shoelace(list(map(tuple, tri)))
        lo = np.clip(np.floor(tri.min(axis=0)).astype(int), 0, None)
        hi = np.ceil(tri.max(axis=0)).astype(int)
        for i in range(lo[1], min(hi[1], shape[0])):
            for j in range(lo[0], min(hi[0], shape[1])):
                piece = _clip_box(list(map(tuple, tri)), j, j + 1, i, i + 1)
                image[i, j] += f * _shoelace(piece) / area
    return image


def _random_triangles(rng, n, low, high, scale):
    centres = rng.uniform(low, high, (n, 1, 2))
    return centres + scale[:, None, None] * rng.normal(size=(n, 3, 2))


def _grid_triangles(nx, ny, spacing, origin, jitter=None):
    """Two triangles per cell of a grid, counter-clockwise (positive signed area)."""
    gx, gy = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="xy")
    points = np.stack([gx, gy], axis=-1) * np.asarray(spacing, float) + origin
    if jitter is not None:
        points[1:-1, 1:-1] += jitter[1:-1, 1:-1]
    tris = []
    for i in range(ny):
        for j in range(nx):
            a, b = points[i, j], points[i, j + 1]
            c, d = points[i + 1, j], points[i + 1, j + 1]
            if (i + j) % 2:  # alternate the diagonal
                tris += [[a, b, d], [a, d, c]]
            else:
                tris += [[a, b, c], [b, d, c]]
    return np.array(tris)


# Shared, jitted value-and-gradient functions: the tests below call them with the same
# shapes (triangles padded to PAD with NaN, invalid ones) so each compiles once per dtype.
PAD, SHAPE, WINDOW = 64, (32, 32), 8


def _padded(tris, other, dtype=np.float64):
    """Pad triangles ``(n, 3, 2)`` and per-triangle data to `PAD` with invalid NaN rows."""
    n = len(tris)
    tris = np.concatenate([tris, np.full((PAD - n, 3, 2), np.nan)])
    other = np.asarray(other, float)
    other = np.concatenate([other, np.full((PAD - n,) + other.shape[1:], np.nan)])
    valid = np.arange(PAD) < n
    return jnp.array(tris, dtype), jnp.array(other, dtype), jnp.array(valid)


@jax.jit
@functools.partial(jax.value_and_grad, argnums=(0, 1), has_aux=True)
def _exact_grad(vertices, flux, valid, weights):
    image = rasterize_exact(vertices, flux, valid, SHAPE, WINDOW)
    return jnp.sum(weights * image), image


@jax.jit
@functools.partial(jax.value_and_grad, argnums=(0, 1), has_aux=True)
def _gouraud_grad(vertices, values, valid, weights):
    image = rasterize_gouraud(vertices, values, valid, SHAPE, WINDOW, 2)
    return jnp.sum(weights * image), image


# ----------------------------------------------------------------------------- exact


def _exact(tris, flux, dtype=np.float64):
    """`rasterize_exact` on the shared shapes (one compilation per dtype)."""
    return np.asarray(rasterize_exact(*_padded(tris, flux, dtype), SHAPE, WINDOW))


def test_signed_area_orientation():
    tri = jnp.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    assert float(signed_area(tri)) == 1.0
    assert float(signed_area(tri[::-1])) == -1.0


def test_exact_areas_match_polygon_clipping(rng):
    shape = (12, 10)
    n = 60
    scale = np.concatenate([rng.uniform(0.6, 4.0, n - 20), rng.uniform(1e-3, 0.2, 20)])
    tris = _random_triangles(rng, n, -2.0, 13.0, scale)  # some cross the border
    # axis-aligned edges and vertices on pixel lines (the flat and steep special cases)
    tris[:4] = [
        [[1.5, 1.5], [4.5, 1.5], [1.5, 3.25]],
        [[2.0, 2.0], [5.0, 2.0], [2.0, 7.0]],
        [[6.0, 1.0], [6.0, 4.0], [9.0, 4.0]],
        [[3.0, 8.5], [3.0, 8.51], [7.2, 9.9]],  # thin
    ]
    assert np.any(np.asarray(signed_area(jnp.array(tris))) < 0)
    flux = rng.uniform(0.5, 2.0, n)
    window = window_for(tris, np.ones(n, bool))
    image = rasterize_exact(jnp.array(tris), jnp.array(flux), jnp.ones(n, bool), shape, window)
    expected = _reference_image(tris, flux, shape)
    np.testing.assert_allclose(np.asarray(image), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 1e-5)])
def test_exact_conserves_flux_and_ignores_invalid(rng, dtype, tol):
    n = 40
    tris = _random_triangles(rng, n, 10.0, 22.0, rng.uniform(0.05, 1.2, n))
    assert window_for(tris, np.ones(n, bool)) <= WINDOW
    flux = rng.uniform(0.5, 1.5, n)
    weights = jnp.array(rng.uniform(size=SHAPE), dtype)
    # padding (invalid, NaN vertices and flux) and some more invalid triangles
    v, f, valid = _padded(tris, flux, dtype)
    valid = valid.at[:8].set(False)
    (_, image), (gv, gf) = _exact_grad(v, f, valid, weights)
    image = np.asarray(image)
    assert image.dtype == dtype
    assert np.all(np.isfinite(image))
    np.testing.assert_allclose(image.sum(), flux[8:].sum(), rtol=tol)
    # the same image as with the invalid triangles present but carrying no flux
    clean = jnp.array(np.where(np.asarray(valid)[:, None, None], np.asarray(v), 5.0), dtype)
    (_, expected), _ = _exact_grad(clean, jnp.where(valid, f, 0.0), jnp.ones(PAD, bool), weights)
    np.testing.assert_allclose(image, np.asarray(expected), rtol=0, atol=tol)
    gv, gf = np.asarray(gv), np.asarray(gf)
    assert np.all(np.isfinite(gv)) and np.all(np.isfinite(gf))
    assert np.all(gv[~valid] == 0.0) and np.all(gf[~valid] == 0.0)
    assert np.abs(gv[valid]).max() > 0


def test_exact_tiling_gives_constant_density(rng):
    n, spacing, origin = 5, 1.37, np.array([2.3, 3.1])
    jitter = rng.uniform(-0.3, 0.3, (n + 1, n + 1, 2))
    tris = _grid_triangles(n, n, spacing, origin, jitter)
    areas = np.asarray(signed_area(jnp.array(tris)))
    assert np.all(areas > 0)
    density = 2.5
    image = _exact(tris, density * areas)
    # pixels entirely inside the tiled rectangle [2.3, 9.15] x [3.1, 9.95]
    np.testing.assert_allclose(image[4:9, 3:9], density, rtol=0, atol=1e-12)
    np.testing.assert_allclose(image.sum(), density * areas.sum(), rtol=1e-12)


def test_exact_fold_equals_counter_clockwise_twin(rng):
    tris = _random_triangles(rng, 10, 4.0, 8.0, rng.uniform(0.5, 1.5, 10))
    flux = rng.uniform(0.5, 2.0, 10)
    assert np.any(np.asarray(signed_area(jnp.array(tris))) < 0)
    np.testing.assert_allclose(_exact(tris, flux), _exact(tris[:, ::-1], flux), atol=1e-14)
    # a folded pair (second triangle flipped over the shared edge) keeps all its flux
    pair = np.array([[[1.0, 1.0], [9.0, 1.0], [1.0, 9.0]], [[1.0, 9.0], [9.0, 1.0], [3.0, 3.0]]])
    areas = np.asarray(signed_area(jnp.array(pair)))
    assert areas[0] * areas[1] < 0
    image = _exact(pair, [1.0, 2.0])
    np.testing.assert_allclose(image.sum(), 3.0, rtol=1e-13)
    assert np.all(image >= 0)
    # where both cover a pixel fully, the densities add
    np.testing.assert_allclose(image[4, 4], 1 / 32 + 2 / 16, rtol=1e-12)


DEGENERATE = np.array(
    [
        [[3.3, 4.4], [3.3, 4.4], [3.3, 4.4]],  # coincident
        [[3.3, 4.4], [3.3, 4.4], [5.1, 2.2]],  # two coincident
        [[1.25, 2.5], [2.5, 5.0], [3.75, 7.5]],  # collinear
        [[2.0, 3.0], [6.0, 3.0], [4.0, 3.0]],  # collinear, horizontal
        [[2.5, 3.0], [2.5, 6.0], [2.5, 4.0]],  # collinear, vertical
        [[1.1, 7.3], [5.9, 7.3 + 3e-8], [3.5, 7.3 + 1.5e-8]],  # collinear up to rounding
    ]
)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_degenerate_triangles_are_finite_and_keep_flux(dtype):
    # one triangle per 10 x 10 tile of the image, so each is checked on its own
    n = len(DEGENERATE)
    tile = np.stack(np.divmod(np.arange(n), 3)[::-1], axis=-1)  # (column, row) of the tile
    shifted = DEGENERATE + 10.0 * tile[:, None, :]
    v, f, valid = _padded(shifted, np.full(n, 1.5), dtype)
    weights = jnp.array(np.random.default_rng(1).uniform(size=SHAPE), dtype)
    (_, image), grads = _exact_grad(v, f, valid, weights)
    image = np.asarray(image)
    assert image.dtype == dtype and np.all(np.isfinite(image))
    tiles = [image[10 * r : 10 * r + 10, 10 * c : 10 * c + 10] for c, r in tile]
    np.testing.assert_allclose([t.sum() for t in tiles], 1.5, rtol=1e-6)
    # the flux lands at the centroid (bilinear weights): its centre of mass is there
    rows, cols = np.indices((10, 10)) + 0.5
    com = [[np.sum(t * cols) / 1.5, np.sum(t * rows) / 1.5] for t in tiles]
    np.testing.assert_allclose(com, DEGENERATE.mean(axis=1), atol=1e-5)
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))
    assert np.all(np.abs(np.asarray(grads[0][:n])).max(axis=(1, 2)) > 0)  # tent follows
    if dtype == np.float64:  # degenerate triangles cover no sample
        (_, image), grads = _gouraud_grad(v, jnp.ones((PAD, 3)), valid, weights)
        assert np.all(np.asarray(image) == 0.0)
        for g in grads:
            assert np.all(np.isfinite(np.asarray(g)))


def test_exact_gradient_matches_finite_differences(rng):
    tris = np.array(
        [
            [[1.3, 1.7], [5.6, 2.4], [2.9, 5.2]],  # general
            [[11.3, 1.7], [14.6, 1.7], [11.3, 4.2]],  # axis-aligned legs (flat, steep edges)
        ]
    )
    v, f, valid = _padded(tris, [1.7, 0.8])
    weights = jnp.array(rng.uniform(size=SHAPE))
    _, (grad, _) = _exact_grad(v, f, valid, weights)
    grad = np.asarray(grad)[:2]
    h = 1e-6
    fd = np.zeros(tris.shape)
    for index in np.ndindex(*tris.shape):
        step = np.zeros((PAD, 3, 2))
        step[index] = h
        plus, minus = (_exact_grad(v + s, f, valid, weights)[0][0] for s in (step, -step))
        fd[index] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-8)
    assert np.all(np.abs(grad).max(axis=(1, 2)) > 1e-3)


def test_exact_gradient_on_a_pixel_aligned_mesh(rng):
    # a flat mesh whose vertices sit on pixel corners: every edge lies on a pixel line. The
    # image is not differentiable there (unequal densities); the gradient is the one-sided
    # derivative for coordinates increasing, consistently across triangles.
    n = 4
    points = np.stack(np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0)), axis=-1) + 3.0
    corners = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = (i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)
            corners += [[a, b, d], [a, d, c]] if (i + j) % 2 else [[a, b, c], [b, d, c]]
    corners = np.array(corners)  # (T, 3, 2) grid indices
    flux = rng.uniform(0.5, 1.5, len(corners))
    weights = jnp.array(rng.uniform(size=SHAPE))

    def run(p):
        (value, _), (grad, _) = _exact_grad(
            *_padded(p[corners[..., 0], corners[..., 1]], flux), weights
        )
        return float(value), np.asarray(grad)[: len(corners)]

    value, grad = run(points)
    grad_points = np.zeros_like(points)
    np.add.at(grad_points, (corners[..., 0], corners[..., 1]), grad)
    h = 1e-7
    forward, backward = np.zeros_like(points), np.zeros_like(points)
    for index in np.ndindex(*points.shape):
        step = np.zeros_like(points)
        step[index] = h
        forward[index] = (run(points + step)[0] - value) / h
        backward[index] = (value - run(points - step)[0]) / h
    np.testing.assert_allclose(grad_points, forward, rtol=0, atol=1e-5)
    assert np.abs(forward - backward).max() > 0.1  # really not differentiable
    # equal densities: differentiable, and the image sum does not move at all
    (_, _), (grad, _) = _exact_grad(
        *_padded(points[corners[..., 0], corners[..., 1]], np.full(len(corners), 0.5)),
        jnp.ones(SHAPE),
    )
    assert np.abs(np.asarray(grad)).max() < 1e-12


def test_window_for_and_jit(rng):
    tris = _random_triangles(rng, 30, 8.0, 16.0, rng.uniform(0.2, 2.5, 30))
    valid = np.ones(30, bool)
    valid[0] = False
    tris[0] = [[0.0, 0.0], [20.0, 0.0], [0.0, 20.0]]  # huge but invalid: ignored
    window = window_for(tris, valid)
    span = np.ceil(tris[1:].max(axis=1)) - np.floor(tris[1:].min(axis=1))
    assert window == int(span.max())
    assert window_for(tris, valid, cap=3) == 3
    flux = jnp.array(rng.uniform(0.5, 1.5, 30))
    args = (jnp.array(tris), flux, jnp.array(valid))
    total = float(flux[1:].sum())
    fast = jax.jit(rasterize_exact, static_argnums=(3, 4))
    np.testing.assert_allclose(float(fast(*args, (24, 24), window).sum()), total, rtol=1e-12)
    # one pixel less and the largest triangle loses some of its flux
    assert float(fast(*args, (24, 24), window - 1).sum()) < total - 1e-6


@pytest.mark.slow  # 14 s (the default run's budget); one window's flux and its width
# stay checked in the default run (test_window_for_and_jit)
def test_tiers_draw_every_triangle_once_with_the_wide_windows_image(rng):
    """Triangles drawn in tiers of narrower windows, by span, give the image (and
    gradient) of one window wide enough for all; a tier draws no more than its
    capacity."""
    scale = np.concatenate([rng.uniform(0.1, 0.4, 40), rng.uniform(1.0, 2.5, 8)])
    tris = _random_triangles(rng, 48, 4.0, 28.0, scale)
    flux = rng.uniform(0.5, 1.5, 48)
    v, f, valid = _padded(tris, flux)  # 16 invalid NaN triangles sort last
    span = np.max(np.ceil(tris.max(axis=1)) - np.floor(tris.min(axis=1)), axis=1)
    wide = int(span.max())
    assert wide > 4 and (span <= 2).sum() > 10  # the tiers below have work to do
    size = jnp.where(valid, jnp.asarray(np.pad(span, (0, PAD - 48))), -1.0)
    last = int((span <= 2).sum())
    # the middle tier's capacity is larger than it needs: its padding draws nothing
    tiers = ((wide, int((span > 4).sum()), 64), (4, PAD, 64), (2, last, 16))
    weights = jnp.asarray(rng.uniform(size=SHAPE))

    def raster(w, vertices, flux, valid):
        return rasterize_exact(vertices, flux, valid, SHAPE, w)

    def loss(vertices, tiers):
        image = sum_in_tiers(raster, tiers, size, vertices, f, valid)
        return jnp.sum(weights * image), image

    run = jax.jit(jax.value_and_grad(loss, has_aux=True), static_argnums=1)
    (_, image), grad = run(v, tiers)
    (_, one), one_grad = run(v, ((wide, None, PAD),))
    np.testing.assert_allclose(image, one, rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(image.sum()), flux[span <= 28].sum(), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(grad)[:48], np.asarray(one_grad)[:48], atol=1e-12)
    assert np.abs(np.asarray(grad)[:48]).max() > 1e-3
    # the last tier holds three fewer than come to it: its last three are not drawn
    short = tiers[:2] + ((2, last - 3, 16),)
    dropped = np.flatnonzero(span <= 2)[-3:]
    (_, image), _ = run(v, short)
    np.testing.assert_allclose(float(image.sum()), flux.sum() - flux[dropped].sum(), rtol=1e-12)


# ----------------------------------------------------------------------------- Gouraud


@pytest.mark.parametrize("supersample", [1, 2])
def test_gouraud_tiling_counts_shared_edges_once(rng, supersample):
    # vertices exactly on sample points, edges through rows of samples and vertices
    step = 1.0 / supersample
    spacing = 3 * step
    n, size = 5, SHAPE[0]
    origin = np.array([2.0, 3.0]) + 0.5 * step
    while True:  # a random jitter by whole samples that folds no triangle
        jitter = step * rng.integers(-1, 2, (n + 1, n + 1, 2)).astype(float)
        tris = _grid_triangles(n, n, spacing, origin, jitter)
        if np.all(np.asarray(signed_area(jnp.array(tris))) > 0):
            break
    flip = rng.uniform(size=len(tris)) < 0.5  # listing order does not matter
    tris[flip] = tris[flip, ::-1]
    assert window_for(tris, np.ones(len(tris), bool)) <= WINDOW
    v, values, valid = _padded(tris, np.full((len(tris), 3), 3.0))
    image = np.asarray(rasterize_gouraud(v, values, valid, SHAPE, WINDOW, supersample))
    # every sample strictly inside the tiled square is counted once, none outside it
    lo, hi = origin, origin + n * spacing
    ys = (np.arange(size)[:, None] + (np.arange(supersample) + 0.5) / supersample).ravel()
    open_ = ((ys[:, None] > lo[1]) & (ys[:, None] < hi[1])) & (
        (ys[None, :] > lo[0]) & (ys[None, :] < hi[0])
    )
    closed = ((ys[:, None] >= lo[1]) & (ys[:, None] <= hi[1])) & (
        (ys[None, :] >= lo[0]) & (ys[None, :] <= hi[0])
    )
    blocks = (size, supersample, size, supersample)
    inside = open_.reshape(blocks).all(axis=(1, 3))
    assert inside.sum() > 20
    np.testing.assert_array_equal(image[inside], 3.0)
    assert np.all(image[~closed.reshape(blocks).any(axis=(1, 3))] == 0.0)


def test_gouraud_reproduces_a_linear_function(rng):
    # one triangle per 8 x 8 tile, so that the coverage of each pixel is 0 or 1
    n = 16
    tile = np.stack(np.divmod(np.arange(n), 4)[::-1], axis=-1)
    tris = 8.0 * tile[:, None, :] + _random_triangles(rng, n, 3.5, 4.5, np.full(n, 2.0))
    tris = np.clip(tris, 8.0 * tile[:, None, :] + 0.01, 8.0 * tile[:, None, :] + 7.99)
    assert np.any(np.asarray(signed_area(jnp.array(tris))) < 0)
    coeff = np.array([0.3, 0.7, -0.2])

    def f(x, y):
        return coeff[0] + coeff[1] * x + coeff[2] * y

    rows, cols = np.indices(SHAPE) + 0.5
    ones = np.ones((n, 3))
    values = f(tris[..., 0], tris[..., 1])
    # pixel centres
    cover = np.round(np.asarray(rasterize_gouraud(*_padded(tris, ones), SHAPE, WINDOW)), 12)
    image = np.asarray(rasterize_gouraud(*_padded(tris, values), SHAPE, WINDOW))
    assert set(np.unique(cover)) == {0.0, 1.0} and cover.sum() > 20
    np.testing.assert_allclose(image, np.where(cover == 1, f(cols, rows), 0.0), atol=1e-12)
    # 2 x 2 samples: a fully covered pixel holds the value at its centre
    cover = np.asarray(rasterize_gouraud(*_padded(tris, ones), SHAPE, WINDOW, 2))
    image = np.asarray(rasterize_gouraud(*_padded(tris, values), SHAPE, WINDOW, 2))
    full = np.isclose(cover, 1.0, rtol=0, atol=1e-12)
    assert full.sum() > 10
    np.testing.assert_allclose(image[full], f(cols, rows)[full], atol=1e-12)


def test_gouraud_fold_equals_twin_and_has_gradients(rng):
    tris = _random_triangles(rng, 10, 4.0, 8.0, rng.uniform(0.5, 1.5, 10))
    values = rng.uniform(0.5, 2.0, (10, 3))
    assert np.any(np.asarray(signed_area(jnp.array(tris))) < 0)
    weights = jnp.array(rng.uniform(size=SHAPE))
    (_, a), (gv, gval) = _gouraud_grad(*_padded(tris, values), weights)
    (_, b), _ = _gouraud_grad(*_padded(tris[:, ::-1], values[:, ::-1]), weights)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-13)
    assert float(a.sum()) > 0
    gv, gval = np.asarray(gv)[:10], np.asarray(gval)[:10]
    assert np.all(np.isfinite(gv)) and np.abs(gv).max() > 0
    assert np.all(np.isfinite(gval)) and np.abs(gval).max() > 0


# ----------------------------------------------------------------------------- splats


def test_splat_conserves_flux_and_centre_of_mass():
    points = jnp.array([[10.3, 12.8], [15.9, 9.1], [-30.0, 5.0], [np.nan, 1.0]])
    flux = jnp.array([1.0, 2.0, 5.0, np.nan])
    valid = jnp.array([True, True, True, False])
    image = splat_gaussian(points, flux, valid, (24, 28), 1.5)
    np.testing.assert_allclose(float(image.sum()), 3.0, rtol=1e-13)  # third point: outside
    rows, cols = np.indices((24, 28)) + 0.5
    for k in range(2):
        one = jnp.zeros(4).at[k].set(1.0)
        # a wide window: the truncated Gaussian is centred on the point
        wide = np.asarray(splat_gaussian(points, one, valid, (24, 28), 1.5, 19))
        com = [np.sum(wide * c) / wide.sum() for c in (cols, rows)]
        np.testing.assert_allclose(com, np.asarray(points[k]), atol=1e-6)
        # the default window (11 pixels) truncates asymmetrically: about 1e-3 pixel off
        narrow = np.asarray(splat_gaussian(points, one, valid, (24, 28), 1.5))
        com = [np.sum(narrow * c) / narrow.sum() for c in (cols, rows)]
        np.testing.assert_allclose(com, np.asarray(points[k]), atol=3e-3)
    # tiny sigma: all the flux in one pixel, no 0 / 0
    sharp = np.asarray(splat_gaussian(points, flux, valid, (24, 28), 1e-3, 11))
    assert np.all(np.isfinite(sharp))
    assert sharp[12, 10] == pytest.approx(1.0, rel=1e-12)


def test_splat_gradients():
    points = jnp.array([[10.3, 12.8], [15.9, 9.1]])
    flux = jnp.array([1.0, 2.0])
    valid = jnp.ones(2, bool)
    weights = jnp.array(np.random.default_rng(2).uniform(size=(24, 28)))

    @jax.jit
    def loss(p, f, sigma):
        return jnp.sum(weights * splat_gaussian(p, f, valid, (24, 28), sigma, 11))

    gp, gf, gs = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(points, flux, 1.5)
    for g in (gp, gf, gs):
        assert np.all(np.isfinite(np.asarray(g)))
    h = 1e-6
    fd = (loss(points, flux, 1.5 + h) - loss(points, flux, 1.5 - h)) / (2 * h)
    np.testing.assert_allclose(float(gs), float(fd), rtol=1e-6)
    assert abs(float(gs)) > 1e-4
    fd = (loss(points.at[0, 0].add(h), flux, 1.5) - loss(points.at[0, 0].add(-h), flux, 1.5)) / (
        2 * h
    )
    np.testing.assert_allclose(float(gp[0, 0]), float(fd), rtol=1e-6)
    with pytest.raises(ValueError):
        jax.jit(lambda s: splat_gaussian(points, flux, valid, (24, 28), s))(1.5)


def test_pixel_coordinates():
    extent = (-1.0, 1.0, 0.0, 3.0)
    xy = jnp.array([[-1.0, 0.0], [1.0, 3.0], [-1.0 + 0.5 * 0.2, 0.5 * 0.1]])
    px = np.asarray(pixel_coordinates(xy, extent, (30, 10)))
    np.testing.assert_allclose(px, [[0.0, 0.0], [10.0, 30.0], [0.5, 0.5]], atol=1e-12)
