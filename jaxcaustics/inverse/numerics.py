"""The numerics that lens design and water recovery share: Poisson solves and Laplacians,
resampling between grids, area averages, the logarithm of a cell's area, the target's
checks.

Grids are cell-centred, indexed ``[row, col] = [y, x]``; extents are ``(x_min, x_max,
y_min, y_max)`` and cover the cells' edges. `neumann_poisson` is hand-written (a DCT-II
diagonalises the Neumann Laplacian exactly; `scipy.fft` has no JAX twin that `jit`
traces, and `jax.scipy.fft.dctn` is what it is built on).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..scene.scene import HeightField
from ..scene.surface import height_and_gradient


def check_irradiance(target: np.ndarray, if_dark: str) -> np.ndarray:
    """Checks that `target` (an array) is a usable irradiance image: finite,
    non-negative, not all zeros (the error then says `if_dark`). Returns it."""
    if not np.all(np.isfinite(target)):
        raise ValueError("`target` contains NaN or infinite values")
    if np.any(target < 0):
        raise ValueError("`target` must be non-negative (an irradiance image)")
    if not np.any(target > 0):
        raise ValueError(f"`target` is all zeros: {if_dark}")
    return target


# ----------------------------------------------------------------- Poisson and Laplacians


@jax.jit
def neumann_poisson(rhs: jax.Array, dx, dy) -> jax.Array:
    """Solve ``Laplacian(u) = rhs`` on a cell-centred grid with zero-flux (Neumann)
    boundaries by a DCT-II; the mean of ``rhs`` is ignored and ``u`` has zero mean."""
    rows, cols = rhs.shape
    coef = jax.scipy.fft.dctn(rhs, type=2, norm="ortho")
    ky = (2.0 * jnp.cos(jnp.pi * jnp.arange(rows) / rows) - 2.0) / dy**2
    kx = (2.0 * jnp.cos(jnp.pi * jnp.arange(cols) / cols) - 2.0) / dx**2
    lam = (ky[:, None] + kx[None, :]).at[0, 0].set(1.0)
    return jax.scipy.fft.idctn((coef / lam).at[0, 0].set(0.0), type=2, norm="ortho")


def weighted_laplacian(u: Array, boundary: str, wx: Array | float, wy: Array | float) -> Array:
    """The five-point Laplacian ``wx (east + west - 2u) + wy (north + south - 2u)``,
    periodic or with edge samples repeated (zero flux) for any other `boundary`."""
    if boundary == "periodic":
        east, west = jnp.roll(u, -1, 1), jnp.roll(u, 1, 1)
        north, south = jnp.roll(u, -1, 0), jnp.roll(u, 1, 0)
    else:
        p = jnp.pad(u, 1, mode="edge")
        east, west = p[1:-1, 2:], p[1:-1, :-2]
        north, south = p[2:, 1:-1], p[:-2, 1:-1]
    return wx * (east + west - 2.0 * u) + wy * (north + south - 2.0 * u)


@jax.jit
def neumann_laplacian(h: jax.Array, dx: float, dy: float) -> jax.Array:
    """The five-point Laplacian with zero-flux boundaries (the inverse of
    `neumann_poisson` up to the mean)."""
    return weighted_laplacian(h, "clamp", 1.0 / dx**2, 1.0 / dy**2)


def safe_log_area(area: jax.Array, floor) -> jax.Array:
    """``log(area)``, continued smoothly (and monotonically) below `floor` so that folded
    (negative) cells give a large finite residual with a useful gradient."""
    safe = jnp.where(area > floor, area, floor)
    return jnp.where(area > floor, jnp.log(safe), jnp.log(floor) + (area - floor) / floor)


# ----------------------------------------------------------------- resampling


def area_average(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Resample `image` ``(rows, cols)`` to `shape` by exact box (area) averaging, any
    ratio (each output cell the mean of the input over its area)."""

    def matrix(n_in, n_out):
        edges_in = np.linspace(0, 1, n_in + 1)
        edges_out = np.linspace(0, 1, n_out + 1)
        lo = np.maximum(edges_out[:-1, None], edges_in[None, :-1])
        hi = np.minimum(edges_out[1:, None], edges_in[None, 1:])
        w = np.clip(hi - lo, 0, None)
        return w / w.sum(axis=1, keepdims=True)

    return matrix(image.shape[0], shape[0]) @ image @ matrix(image.shape[1], shape[1]).T


def _cell_centres(extent: np.ndarray, shape: tuple[int, int], dtype) -> tuple[Array, Array]:
    rows, cols = shape
    x0, x1, y0, y1 = (float(v) for v in extent)
    xs = x0 + (np.arange(cols) + 0.5) * (x1 - x0) / cols
    ys = y0 + (np.arange(rows) + 0.5) * (y1 - y0) / rows
    gx, gy = np.meshgrid(xs, ys)
    return jnp.asarray(gx, dtype), jnp.asarray(gy, dtype)


def resample_heights(heights, extent, shape: tuple[int, int], boundary: str = "periodic"):
    """`heights` on a ``shape`` grid over the same `extent`, through the surface's own
    bicubic interpolant (`HeightField` with `boundary`): the coarse-to-fine upsampling."""
    heights = jnp.asarray(heights)
    if tuple(heights.shape) == tuple(shape):
        return heights
    surface = HeightField(heights, extent, boundary)
    gx, gy = _cell_centres(np.asarray(extent), shape, heights.dtype)
    return height_and_gradient(surface, gx, gy)[0]


# one compilation per pair of shapes instead of one per operation
_resample_jit = jax.jit(resample_heights, static_argnums=(1, 2, 3))


def resample_corners(h: np.ndarray, shape: tuple[int, int], boundary: str) -> np.ndarray:
    """The bicubic surface of `h` (with `boundary`) at the sample centres of a `shape`
    grid (NumPy in, NumPy out)."""
    return np.asarray(_resample_jit(h, (0.0, 1.0, 0.0, 1.0), tuple(shape), boundary))


def resample_corner_grid(values: np.ndarray, shape) -> np.ndarray:
    """Bilinear resampling of a corner grid (edges to edges) to `shape` corners."""
    rows = np.linspace(0, values.shape[0] - 1, shape[0])
    cols = np.linspace(0, values.shape[1] - 1, shape[1])
    first = np.array([np.interp(rows, np.arange(values.shape[0]), c) for c in values.T]).T
    return np.array([np.interp(cols, np.arange(values.shape[1]), r) for r in first])


def binomial_smooth(a: np.ndarray) -> np.ndarray:
    """`a` smoothed by [1, 2, 1] / 4 along each axis, edge samples repeated."""
    p = np.pad(a, 1, mode="edge")
    rows = 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:]
    return 0.25 * rows[:, :-2] + 0.5 * rows[:, 1:-1] + 0.25 * rows[:, 2:]
