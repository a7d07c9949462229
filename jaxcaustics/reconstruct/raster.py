"""Differentiable reconstruction kernels: 2-D triangles and points to an image.

Used by the caustic-triangles method (Umenhoffer et al.: every triangle of the refracted
mesh carries the flux of its source triangle) and by photon splatting.

Coordinates are *pixel units*: ``x`` runs along columns and ``y`` along rows; pixel
``(i, j)`` (row ``i``, column ``j``) covers ``x`` in ``[j, j + 1]``, ``y`` in
``[i, i + 1]`` and its centre is ``(j + 0.5, i + 0.5)`` (`pixel_coordinates` maps world
coordinates there). Images have shape ``(rows, cols)``.

Every kernel is jit-compatible and vectorised over primitives: each primitive touches a
``window x window`` block of pixels (a static Python int) and the blocks are scattered
into the image with ``image.at[rows, cols].add(..., mode="drop")`` (whose transpose is a
gather). Whatever of a primitive falls outside its block or outside the image is not
deposited; a caller measures the missed flux as ``flux.sum() - image.sum()``.

Invalid primitives (``valid == False``) deposit nothing, even when their coordinates or
flux are NaN: they are replaced by zeros before any arithmetic, so they cannot poison the
image or its gradients.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec
from jaxtyping import Array, Bool, Float


def _float_dtype(*arrays) -> jnp.dtype:
    dtype = jnp.result_type(*arrays)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    return dtype


def _static_shape(shape) -> tuple[int, int]:
    rows, cols = shape
    return int(rows), int(cols)


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _origin(low: Array, size: int, window: int) -> Array:
    """``floor(low)`` as an int, clipped to ``[-window, size]`` (enough to keep every
    block that reaches the image unchanged, and every other one outside it)."""
    low = jnp.where(jnp.isfinite(low), low, 0.0)
    return jnp.clip(jnp.floor(jax.lax.stop_gradient(low)), -window, size).astype(jnp.int32)


def _scatter(shape, dtype, rows: Array, cols: Array, values: Array) -> Array:
    """Add `values` at ``(rows, cols)``; indices outside the image are dropped."""
    n_rows, n_cols = shape
    inside = (rows >= 0) & (rows < n_rows) & (cols >= 0) & (cols < n_cols)
    rows = jnp.where(inside, rows, n_rows).ravel()
    cols = jnp.where(inside, cols, n_cols).ravel()
    image = jnp.zeros(shape, dtype)
    return image.at[rows, cols].add(values.ravel().astype(dtype), mode="drop")


def pixel_coordinates(
    xy: Float[Array, "... 2"], extent, shape: tuple[int, int]
) -> Float[Array, "... 2"]:
    """Map world ``(x, y)`` (metres) to pixel units.

    **Arguments:**

    - `xy`: world coordinates, shape ``(..., 2)``.
    - `extent`: ``(x_min, x_max, y_min, y_max)``, the outer pixel *edges* of the image:
      column ``j`` is centred at ``x_min + (j + 0.5) dx`` and row ``i`` at
      ``y_min + (i + 0.5) dy``, with ``dx = (x_max - x_min) / cols`` and
      ``dy = (y_max - y_min) / rows``.
    - `shape`: ``(rows, cols)`` of the image.

    **Returns:** pixel coordinates ``(x, y)``, shape ``(..., 2)``: ``x`` in columns,
    ``y`` in rows, so that a pixel centre maps to ``(j + 0.5, i + 0.5)``.
    """
    rows, cols = shape
    x_min, x_max, y_min, y_max = (extent[k] for k in range(4))
    px = (xy[..., 0] - x_min) * (cols / (x_max - x_min))  # columns per metre
    py = (xy[..., 1] - y_min) * (rows / (y_max - y_min))  # rows per metre
    return jnp.stack([px, py], axis=-1)


def signed_area(vertices: Float[Array, "... 3 2"]) -> Float[Array, "..."]:
    """Signed area of triangles: ``((v1 - v0) x (v2 - v0)) / 2``.

    **Arguments:**

    - `vertices`: shape ``(..., 3, 2)``, ``(x, y)`` of the three vertices.

    **Returns:** shape ``(...)``; positive when the 2-D cross product
    ``(v1 - v0) x (v2 - v0) = e1_x e2_y - e1_y e2_x`` is positive (counter-clockwise with
    ``y`` up, clockwise as drawn with ``y`` down), in the squared units of `vertices`.
    """
    e1 = vertices[..., 1, :] - vertices[..., 0, :]
    e2 = vertices[..., 2, :] - vertices[..., 0, :]
    return 0.5 * _cross(e1[..., 0], e1[..., 1], e2[..., 0], e2[..., 1])


def _degenerate(vertices: Array, area: Array) -> Array:
    """Triangles whose area is indistinguishable from rounding error.

    The area (a cross product of edges of length up to ``L``) and the overlap areas (sums
    of products of clipped ``y`` extents, at most ``L``, and local ``x`` offsets, at most
    ``L + 1``) carry absolute rounding errors of a few ``eps L (L + 1)``. Below
    ``64 eps L (L + 1)`` the ratio overlap / area would have a relative error above
    about 1/64, so such a triangle (collinear or coincident vertices in particular, where
    ``L = 0`` or ``area = 0``) is treated as a point instead.
    """
    eps = jnp.finfo(area.dtype).eps
    edges = vertices - jnp.roll(vertices, 1, axis=-2)
    length = jnp.max(jnp.abs(edges), axis=(-2, -1))
    threshold = 64.0 * eps * length * (length + 1.0)
    return jnp.abs(area) <= jax.lax.stop_gradient(threshold)


def _sanitise(vertices: Array, valid: Array, dtype) -> Array:
    return jnp.where(valid[:, None, None], vertices.astype(dtype), 0.0)


def _tent(points: Array, weight: Array, shape, dtype) -> tuple[Array, Array, Array]:
    """Bilinear (tent) weights of `weight` at `points` ``(N, 2)``, pixel centres as nodes.

    Returns ``(rows, cols, values)``, each ``(N, 2, 2)``, for `_scatter`.
    """
    f = points - 0.5
    base = jnp.floor(jax.lax.stop_gradient(f))
    t = f - base
    base = jnp.clip(base, -2, jnp.array(shape[::-1]) + 1).astype(jnp.int32)
    wx = jnp.stack([1.0 - t[:, 0], t[:, 0]], axis=-1)  # (N, 2)
    wy = jnp.stack([1.0 - t[:, 1], t[:, 1]], axis=-1)
    values = weight[:, None, None] * wy[:, :, None] * wx[:, None, :]
    offsets = jnp.arange(2)
    rows = base[:, 1, None, None] + offsets[None, :, None]
    cols = base[:, 0, None, None] + offsets[None, None, :]
    rows, cols = jnp.broadcast_arrays(rows, cols)
    return rows, cols, values


def _overlap_areas(local: Array, window: int) -> Array:
    """Signed overlap areas of triangles with the unit boxes of their window.

    `local`: vertices ``(T, 3, 2)`` relative to the window origin. Returns ``(T, window,
    window)`` (rows, columns): ``sign(area) * area(T ∩ box)`` up to rounding.

    Green's theorem: ``area(P ∩ box) = ∮_∂P g_j(x) 1[i <= y < i + 1] dy`` with
    ``g_j(x) = clamp(x - j, 0, 1) = ramp(x - j) - ramp(x - j - 1)``. Along an edge
    ``x(u) = a_x + u dx``, ``y(u) = a_y + u dy`` (``u`` in ``[0, 1]``) this is
    ``dy ∫_U g_j(x(u)) du`` with ``U = [lo, hi]`` the part of the edge inside the row,
    and ``∫ ramp(x(u) - c) du`` over the part of ``U`` where ``x >= c`` is
    ``length * (x(midpoint) - c)``: exact, and no division by ``dx`` or ``dy`` in the
    result.

    Ties (a vertex exactly on a pixel line, an edge exactly along one) are broken as if
    every coordinate were larger by an infinitesimal: a point on a line belongs to the
    row below it / the column right of it, and at such points the gradient is the
    derivative from that side. Triangles sharing a vertex thus agree on the side, so
    where the image is differentiable (e.g. a flat mesh aligned with the pixel grid)
    their summed gradient is exact. Divisions are guarded by the "double where": an edge
    crosses a row line only when its endpoints lie on either side (``dy != 0``), and
    ``|dx| <= eps**2`` counts as exactly vertical. The crossings of column lines carry no
    gradient (``g_j`` is continuous there, so their derivative is exactly zero; dropping
    it avoids large cancelling terms for steep edges).
    """
    dtype = local.dtype
    tiny = jnp.finfo(dtype).eps ** 2
    a = local
    b = jnp.roll(local, -1, axis=1)  # edge k runs from vertex k to vertex k + 1
    ax, ay = a[..., 0][..., None, None], a[..., 1][..., None, None]  # (T, 3, 1, 1)
    by = b[..., 1][..., None, None]
    dx = (b[..., 0] - a[..., 0])[..., None, None]
    dy = by - ay

    # the edge against each row line L = 0 .. W: parameter t of the crossing and the
    # parts with y >= L ([lo_ge, hi_ge]) and y < L ([lo_lt, hi_lt]); (T, 3, W + 1, 1)
    lines = jnp.arange(window + 1, dtype=dtype)[:, None]
    a_below, b_below = ay >= lines, by >= lines
    crosses = (a_below != b_below) & (jnp.abs(dy) > tiny)
    t = jnp.where(crosses, (lines - ay) / jnp.where(crosses, dy, 1.0), 0.5)
    t = jnp.where(t < 0.0, 0.0, jnp.where(t > 1.0, 1.0, t))  # rounding only
    lo_ge = jnp.where(a_below, 0.0, jnp.where(b_below, t, 1.0))
    hi_ge = jnp.where(b_below, 1.0, jnp.where(a_below, t, 0.0))
    lo_lt = jnp.where(a_below, jnp.where(b_below, 1.0, t), 0.0)
    hi_lt = jnp.where(b_below, jnp.where(a_below, 0.0, t), 1.0)
    # row r: y >= r and y < r + 1; at ties keep the crossing (it moves inwards)
    lo_ge, hi_ge, lo_lt, hi_lt = (
        lo_ge[..., :-1, :],
        hi_ge[..., :-1, :],
        lo_lt[..., 1:, :],
        hi_lt[..., 1:, :],
    )
    lo = jnp.where(lo_ge > lo_lt, lo_ge, lo_lt)  # (T, 3, W, 1)
    hi = jnp.where(hi_ge < hi_lt, hi_ge, hi_lt)

    # part of [lo, hi] where x >= c, for column lines c = 0 .. W: [start, stop]
    c = jnp.arange(window + 1, dtype=dtype)[None, :]  # (1, W + 1)
    steep = jnp.abs(dx) <= tiny
    dx_safe = jnp.where(steep, 1.0, dx)
    # crossing of line c; kept out of [0, 1] when the edge does not cross it (a clipped
    # crossing would make an empty piece with a gradient and a nonzero x - c)
    tc = jax.lax.stop_gradient(jnp.clip((c - ax) / dx_safe, -1.0, 2.0))
    start = jnp.where(steep | (dx < 0), lo, jnp.maximum(lo, tc))
    stop = jnp.where(steep, jnp.where(ax >= c, hi, lo), jnp.where(dx < 0, jnp.minimum(hi, tc), hi))
    length = jnp.where(stop >= start, stop - start, 0.0)
    ramp = length * (ax + 0.5 * (start + stop) * dx - c)  # ∫ ramp(x(u) - c) du
    per_edge = dy * (ramp[..., :-1] - ramp[..., 1:])  # (T, 3, W, W)
    return jnp.sum(per_edge, axis=1)


def rasterize_exact(
    vertices: Float[Array, "T 3 2"],
    flux: Float[Array, " T"],
    valid: Bool[Array, " T"],
    shape: tuple[int, int],
    window: int,
) -> Float[Array, "rows cols"]:
    """Deposit the flux of each triangle uniformly over its area, with exact overlaps.

    Pixel ``p`` receives ``flux * area(T ∩ p) / area(T)`` from triangle ``T``; the
    overlap areas are exact (Green's theorem, evaluated analytically per edge), so the
    image is a continuous, piecewise-smooth function of the vertices with exact
    gradients almost everywhere. Where a vertex or an edge lies exactly on a pixel line
    the gradient is the one-sided derivative for increasing coordinates, the same side
    for every triangle, so it is exact wherever the image itself is differentiable (a
    flat mesh aligned with the pixel grid, for instance).

    The overlap is computed with orientation (it has the sign of the triangle's signed
    area) and divided by the signed area, so a clockwise triangle (a fold-over of the
    mesh) is rasterised exactly like its counter-clockwise twin: a fold-over triangle
    keeps its flux and spreads it over its absolute area.

    **Arguments:**

    - `vertices`: triangles in pixel units, shape ``(T, 3, 2)``.
    - `flux`: flux carried by each triangle, shape ``(T,)``.
    - `valid`: which triangles to deposit, shape ``(T,)``; invalid ones may hold NaN.
    - `shape`: ``(rows, cols)`` of the image (static).
    - `window`: static block size: each triangle touches the ``window x window`` pixels
      starting at ``(floor(min y), floor(min x))`` of its bounding box; whatever lies
      outside its block or outside the image is not deposited (see `window_for`).

    **Returns:** flux per pixel, shape ``(rows, cols)``, of the dtype of `vertices` and
    `flux` (float32 or float64).

    Degenerate triangles (area within rounding error of zero, e.g. collinear or
    coincident vertices; see `_degenerate`) deposit their flux at their centroid with
    bilinear (tent) weights on the pixel centres, so they keep their flux and stay finite
    with finite gradients.
    """
    return _rasterize_exact(vertices, flux, valid, _static_shape(shape), int(window))


@functools.partial(jax.jit, static_argnums=(3, 4))
def _rasterize_exact(vertices, flux, valid, shape, window):
    dtype = _float_dtype(vertices, flux)
    v = _sanitise(vertices, valid, dtype)
    flux = jnp.where(valid, flux.astype(dtype), 0.0)
    area = signed_area(v)
    degenerate = _degenerate(v, area)

    low = jnp.min(v, axis=1)  # (T, 2)
    ox = _origin(low[:, 0], shape[1], window)
    oy = _origin(low[:, 1], shape[0], window)
    origin = jnp.stack([ox, oy], axis=-1).astype(dtype)
    overlap = _overlap_areas(v - origin[:, None, :], window)  # (T, W, W)
    area_safe = jnp.where(degenerate, 1.0, area)
    weight = jnp.where(degenerate, 0.0, flux / area_safe)
    values = weight[:, None, None] * overlap
    offsets = jnp.arange(window)
    rows = oy[:, None, None] + offsets[None, :, None]
    cols = ox[:, None, None] + offsets[None, None, :]
    rows, cols = jnp.broadcast_arrays(rows, cols)

    t_rows, t_cols, t_values = _tent(
        jnp.mean(v, axis=1), jnp.where(degenerate, flux, 0.0), shape, dtype
    )
    return _scatter(
        shape,
        dtype,
        jnp.concatenate([rows.ravel(), t_rows.ravel()]),
        jnp.concatenate([cols.ravel(), t_cols.ravel()]),
        jnp.concatenate([values.ravel(), t_values.ravel()]),
    )


def window_for(vertices, valid, cap: int = 64) -> int:
    """The smallest `window` whose blocks cover every valid triangle's bounding box.

    Runs on concrete arrays, outside `jax.jit`.

    **Arguments:**

    - `vertices`: triangles in pixel units, shape ``(T, 3, 2)``.
    - `valid`: shape ``(T,)``; invalid and non-finite triangles are ignored.
    - `cap`: the largest window returned.

    **Returns:** a Python int in ``[1, cap]``: ``max(ceil(max) - floor(min))`` over
    valid triangles and both axes (at least 1), capped at `cap`.
    """
    v = np.asarray(vertices, dtype=np.float64)
    keep = np.asarray(valid, dtype=bool) & np.all(np.isfinite(v), axis=(1, 2))
    if not np.any(keep):
        return 1
    v = v[keep]
    span = np.ceil(v.max(axis=1)) - np.floor(v.min(axis=1))  # (T, 2)
    return int(min(max(int(span.max()), 1), cap))


def _edge_functions(v: Array, px: Array, py: Array):
    """Edge functions ``e_k(p) = (v_{k+1} - v_k) x (p - v_k)`` of the three edges.

    Each edge is evaluated from its lexicographically smaller endpoint, so the two
    triangles sharing an edge get bitwise opposite values (a watertight inside test).
    `v`: ``(T, 3, 2)``; `px`: ``(T, 1, S)``, `py`: ``(T, S, 1)``. Returns a list of three
    ``(T, S, S)`` arrays and the three edge vectors ``(T, 2)``.
    """
    out = []
    directions = []
    for k in range(3):
        a, b = v[:, k], v[:, (k + 1) % 3]
        swap = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] > b[:, 1]))
        p0 = jnp.where(swap[:, None], b, a)
        p1 = jnp.where(swap[:, None], a, b)
        ex = (p1[:, 0] - p0[:, 0])[:, None, None]
        ey = (p1[:, 1] - p0[:, 1])[:, None, None]
        e = _cross(ex, ey, px - p0[:, 0, None, None], py - p0[:, 1, None, None])
        out.append(jnp.where(swap[:, None, None], -e, e))
        directions.append(b - a)
    return out, directions


def rasterize_gouraud(
    vertices: Float[Array, "T 3 2"],
    values: Float[Array, "T 3"],
    valid: Bool[Array, " T"],
    shape: tuple[int, int],
    window: int,
    supersample: int = 1,
) -> Float[Array, "rows cols"]:
    """Point-sampled rasterisation with linear (Gouraud) interpolation, as a GPU does it.

    Each pixel is sampled at ``supersample x supersample`` stratified sub-pixel centres
    (``supersample = 1``: the pixel centre). A sample inside a valid triangle receives the
    barycentric interpolation of the triangle's three vertex `values`; overlapping
    triangles add (additive blending); a pixel holds the mean over its samples.

    Tie rule: inside means every edge function (normalised to the triangle's
    orientation) is positive, or zero on an edge that *owns* its samples: an edge owns
    them when its orientation-normalised direction points to ``-y``, or to ``+x`` when
    horizontal (a top-left-style rule). Edge functions are evaluated bitwise
    antisymmetrically for the two triangles that share an edge, so a sample on a shared
    edge or vertex of a non-overlapping mesh is counted exactly once. Clockwise
    (folded) triangles are rasterised like their counter-clockwise twins; degenerate
    triangles (see `rasterize_exact`) cover no sample.

    **Arguments:**

    - `vertices`: triangles in pixel units, shape ``(T, 3, 2)``.
    - `values`: per-vertex values, shape ``(T, 3)``.
    - `valid`: which triangles to draw, shape ``(T,)``; invalid ones may hold NaN.
    - `shape`: ``(rows, cols)`` of the image (static).
    - `window`: static block size, as in `rasterize_exact`.
    - `supersample`: static number of samples per pixel along each axis.

    **Returns:** the mean over each pixel's samples of the summed interpolated values,
    shape ``(rows, cols)``. Differentiable almost everywhere with respect to `vertices`
    and `values` (through the barycentric weights; coverage is piecewise constant).
    """
    return _rasterize_gouraud(
        vertices, values, valid, _static_shape(shape), int(window), int(supersample)
    )


@functools.partial(jax.jit, static_argnums=(3, 4, 5))
def _rasterize_gouraud(vertices, values, valid, shape, window, s):
    dtype = _float_dtype(vertices, values)
    v = _sanitise(vertices, valid, dtype)
    values = jnp.where(valid[:, None], values.astype(dtype), 0.0)
    area = signed_area(v)
    degenerate = _degenerate(v, area)
    orientation = jnp.where(area > 0, 1.0, -1.0).astype(dtype)
    two_area = 2.0 * jnp.where(degenerate, 1.0, area)

    low = jnp.min(v, axis=1)
    ox = _origin(low[:, 0], shape[1], window)
    oy = _origin(low[:, 1], shape[0], window)
    offsets = jnp.arange(window)
    sub = (jnp.arange(s, dtype=dtype) + 0.5) / s
    # sample = pixel index (an exact integer) + sub-pixel offset: bitwise the same for
    # every triangle whatever its window origin
    col_index = ox[:, None] + offsets[None, :]  # (T, W)
    row_index = oy[:, None] + offsets[None, :]
    px = (col_index.astype(dtype)[:, :, None] + sub).reshape(-1, 1, window * s)
    py = (row_index.astype(dtype)[:, :, None] + sub).reshape(-1, window * s, 1)

    edges, directions = _edge_functions(v, px, py)
    inside = ~degenerate[:, None, None]
    for e, d in zip(edges, directions, strict=True):
        e_n = orientation[:, None, None] * e
        dx_n, dy_n = orientation * d[:, 0], orientation * d[:, 1]
        owns = (dy_n < 0) | ((dy_n == 0) & (dx_n > 0))
        inside = inside & ((e_n > 0) | ((e_n == 0) & owns[:, None, None]))
    # barycentric weight of vertex k: edge function of the opposite edge over 2 area
    interp = (
        edges[1] * values[:, 0, None, None]
        + edges[2] * values[:, 1, None, None]
        + edges[0] * values[:, 2, None, None]
    ) / two_area[:, None, None]
    samples = jnp.where(inside, interp, 0.0)  # (T, W s, W s)
    pixels = samples.reshape(-1, window, s, window, s).mean(axis=(2, 4))
    rows, cols = jnp.broadcast_arrays(row_index[:, :, None], col_index[:, None, :])
    return _scatter(shape, dtype, rows, cols, pixels)


def splat_gaussian(
    points: Float[Array, "P 2"],
    flux: Float[Array, " P"],
    valid: Bool[Array, " P"],
    shape: tuple[int, int],
    sigma,
    window: int | None = None,
) -> Float[Array, "rows cols"]:
    """Splat the flux of each point with a normalised, truncated isotropic Gaussian.

    Each valid point spreads its flux over the ``window x window`` pixels centred on the
    pixel that contains it, with weights ``exp(-|c - p|^2 / (2 sigma^2))`` at the pixel
    centres ``c``, normalised to sum to 1 over the window: flux is conserved for points
    whose window lies inside the image. (The truncation is not symmetric about a point
    off its pixel centre: with the default window the centre of mass of a splat can be
    off by about 1e-3 pixel for ``sigma = 1.5``; a window of ``2 ceil(6 sigma) + 1``
    brings that below 1e-8.)

    **Arguments:**

    - `points`: positions in pixel units, shape ``(P, 2)``.
    - `flux`: flux of each point, shape ``(P,)``.
    - `valid`: which points to splat, shape ``(P,)``; invalid ones may hold NaN.
    - `shape`: ``(rows, cols)`` of the image (static).
    - `sigma`: standard deviation in pixels, a scalar (may be traced).
    - `window`: static odd block size; default ``2 ceil(3 sigma) + 1``, which needs a
      concrete `sigma`.

    **Returns:** flux per pixel, shape ``(rows, cols)``. Differentiable in `points`,
    `flux` and `sigma`.
    """
    if window is None:
        try:
            window = 2 * math.ceil(3.0 * float(sigma)) + 1
        except (TypeError, jax.errors.ConcretizationTypeError) as error:
            raise ValueError("splat_gaussian: pass `window` when `sigma` is traced") from error
    return _splat_gaussian(points, flux, valid, _static_shape(shape), sigma, int(window))


@functools.partial(jax.jit, static_argnums=(3, 5))
def _splat_gaussian(points, flux, valid, shape, sigma, window):
    dtype = _float_dtype(points, flux)
    p = jnp.where(valid[:, None], points.astype(dtype), 0.0)
    flux = jnp.where(valid, flux.astype(dtype), 0.0)
    sigma = jnp.asarray(sigma, dtype)

    half = window // 2
    offsets = jnp.arange(window) - half
    centre = jnp.floor(jax.lax.stop_gradient(p))
    limit = jnp.array([shape[1], shape[0]], dtype) + window
    centre = jnp.clip(centre, -limit, limit).astype(jnp.int32)  # (P, 2)
    index = centre[:, None, :] + offsets[None, :, None]  # (P, W, 2)
    d2 = (index.astype(dtype) + 0.5 - p[:, None, :]) ** 2
    # shift by the smallest distance so the largest weight is 1: no 0 / 0 for tiny sigma
    d2 = d2 - jnp.min(d2, axis=1, keepdims=True)
    w = jnp.exp(-d2 / (2.0 * sigma**2))
    w = w / jnp.sum(w, axis=1, keepdims=True)  # separable: normalise each axis
    splat = flux[:, None, None] * w[:, :, None, 1] * w[:, None, :, 0]  # (P, rows, cols)
    rows, cols = jnp.broadcast_arrays(index[:, :, None, 1], index[:, None, :, 0])
    return _scatter(shape, dtype, rows, cols, splat)


def _scan_sum(fn, xs):
    """``sum(fn(x) for x in xs)`` over the leading axis of the pytree `xs` (size >= 1) as a
    checkpointed scan: one step in memory at a time, each step recomputed in the reverse
    pass."""
    first = jax.tree.map(lambda x: x[0], xs)
    if jax.tree.leaves(xs)[0].shape[0] == 1:
        return fn(first)

    @jax.checkpoint
    def step(total, x):
        return jax.tree.map(jnp.add, total, fn(x)), None

    zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(fn, first))
    total, _ = jax.lax.scan(step, zeros, xs)
    return total


def sum_over_batches(fn, operands, batches: int, *, mesh=None):
    """``sum(fn(operands, k) for k in range(batches))``, one batch in memory at a time.

    The shared loop of the photon renderers: batch ``k`` builds its primitives itself
    (from its index), so nothing of size ``batches x batch`` is ever materialised and
    the compiled graph does not grow with `batches`.

    **Arguments:**

    - `fn`: ``fn(operands, k) -> pytree of arrays``, ``k`` a traced int32 scalar. With a
      `mesh` it is also called with ``k >= batches`` (padding to whole shares): it must
      then give zeros (its primitives are all invalid).
    - `operands`: a pytree (the scene, buffers...) passed to `fn`; with a `mesh` its
      arrays are replicated on every device. `fn` must not close over traced values.
    - `batches`: a static int ``>= 1``.
    - `mesh`: ``None`` (a scan on the default device) or a one-axis
      `jax.sharding.Mesh` (`jaxcaustics.devices.device_mesh`): the batch indices are
      split along its axis with `jax.shard_map`, each device sums its contiguous share
      with a scan, and the partial sums are added with ``psum``.

    **Returns:** the summed pytree (replicated on the mesh's devices). Differentiable;
    each step is recomputed in the reverse pass (`jax.checkpoint`).
    """
    if mesh is None:
        return _scan_sum(lambda k: fn(operands, k), jnp.arange(batches, dtype=jnp.int32))
    (axis,) = mesh.axis_names
    n = mesh.size
    index = jnp.arange(-(-batches // n) * n, dtype=jnp.int32)
    arrays, static = eqx.partition(operands, eqx.is_array)

    def local(arrays, index):
        total = _scan_sum(lambda k: fn(eqx.combine(arrays, static), k), index)
        return jax.tree.map(lambda t: jax.lax.psum(t, axis), total)

    sharded = jax.shard_map(
        local,
        mesh=mesh,
        in_specs=(PartitionSpec(), PartitionSpec(axis)),
        out_specs=PartitionSpec(),
        # the renderers' inner loops (rasteriser batches) start from unsharded zeros:
        # varying-axis types are not tracked through them; the psum makes the result
        # replicated
        check_vma=False,
    )
    return sharded(arrays, index)


def sum_in_batches(raster, batch_size: int, *arrays):
    """Sum ``raster(*chunk)`` (an array or a pytree of arrays) over chunks of
    `batch_size` primitives (triangles, photons) given as `arrays` with the primitives
    along their first axis, the last array being the validity mask (padding is
    invalid): the memory bound of the methods, one chunk at a time; each step is
    recomputed in the reverse pass."""
    count = arrays[0].shape[0]
    if count <= batch_size:
        return raster(*arrays)
    chunks = -(-count // batch_size)
    pad = chunks * batch_size - count
    padded = [jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)) for a in arrays]
    stacked = [a.reshape((chunks, batch_size) + a.shape[1:]) for a in padded]
    return _scan_sum(lambda chunk: raster(*chunk), stacked)


def sum_in_tiers(raster, tiers, size: Array, *arrays):
    """Sum ``raster(window, *chunk)`` over tiers of primitives by size, each tier with
    the window its primitives need: a few wide triangles no longer set the window (and
    the cost, ``window^2`` per primitive) of all the others.

    **Arguments:**

    - `raster`: ``raster(window, *chunk)``, a static int `window`.
    - `tiers`: static ``((window, capacity, batch), ...)``, windows decreasing. A tier
      draws the primitives wider than the next tier's window (the last tier: down to
      size 0) and no wider than its own (the first tier: any size), with its `window`,
      `batch` at a time (`sum_in_batches`), at most `capacity` of them (the caller sizes
      it from a count of the sizes: where more come, the rest, by index, are not drawn).
      Which primitives fall in which tier is found here, from `size` (`jnp.nonzero` with
      a static size: one pass, where a sort of 32,768 took 3.8 ms): the compiled function
      depends on the tiers' windows and capacities only. One tier whose capacity is
      ``None``: every primitive, in place (`sum_in_batches`).
    - `size`: ``(N,)``, the pixels a primitive spans; negative: not drawn (no gradient
      flows through it).
    - `arrays`: as `sum_in_batches`: primitives along the first axis, the validity mask
      last.
    """
    if len(tiers) == 1 and tiers[0][1] is None:
        window, _, batch = tiers[0]
        return sum_in_batches(functools.partial(raster, window), batch, *arrays)
    size = jax.lax.stop_gradient(size)
    lower = [w for w, _, _ in tiers[1:]] + [-1]
    total = None
    for k, ((window, capacity, batch), low) in enumerate(zip(tiers, lower, strict=True)):
        mine = (size > low) & ((size <= window) | (k == 0))
        (index,) = jnp.nonzero(mine, size=capacity, fill_value=0)
        picked = [a[index] for a in arrays]
        picked[-1] = picked[-1] & (jnp.arange(capacity) < jnp.sum(mine))
        image = sum_in_batches(functools.partial(raster, window), batch, *picked)
        total = image if total is None else jax.tree.map(jnp.add, total, image)
    return total
