"""Quadratic-cost optimal transport between two densities on one pixel grid.

`transport_map` solves Monge's problem for the cost ``|x - y|^2 / 2`` by the
back-and-forth method (Jacobs & Léger, Numer. Math. 146, 2020): the Brenier map from a
source density to a target density on the same grid. It is the core of lens design and
of water recovery. See the design notes (``docs/design-notes.md``).

Coordinates: cell ``(i, j)``'s centre is ``((j + 0.5) h, (i + 0.5) h)`` with
``h = 1 / max(rows, cols)``: the grid covers ``[0, cols h] x [0, rows h]`` (with
`stretch`, x runs over ``[0, stretch cols h]``).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_bool, check_int, check_number, check_real_array
from ..scene.surface import bilinear
from .legendre import cell_centres, legendre
from .numerics import neumann_poisson

_ARMIJO = (0.95, 0.25, 0.75)  # step scale factor, lower and upper Armijo-Goldstein bounds
_PATIENCE = 8  # iterations without improvement that count as a stall
# no stall before this many iterations: the first ones can raise the misfit while the
# step size adapts (measured: a silhouette at 512^2 from 0.8 up to 1.8, then down to 0.09)
_MIN_ITERATIONS = 30
# most back-and-forth iterations (the residual history is a buffer of the next power of
# two: 10^12 overflowed the jitted loop's int32 counter after the checks)
MAX_ITERATIONS = 1 << 20
# most pixels of a density (4096^2: some 30 float64 arrays of this size, 4 GB)
MAX_PIXELS = 1 << 24


@dataclasses.dataclass
class TransportMap:
    """Result of `transport_map`.

    - `map_x`, `map_y`: ``(rows + 1, cols + 1)`` NumPy arrays: where the grid's cell
      corners go, in the grid's coordinates (``[0, cols h] x [0, rows h]``, see the
      module docstring); corner ``(i, j)`` is at ``(j h, i h)``.
    - `potential`: ``(rows, cols)``: ``psi``, the convex Brenier potential at the cell
      centres (``T = grad(psi)``).
    - `residual`: relative L1 difference between the target and the source pushed
      forward by the final map (``sum |T#mu - nu| / sum nu``), per iteration.
    - `iterations`: back-and-forth iterations taken.
    - `converged`: whether `residual` fell to `tol` or stopped falling (`stall`) before
      the iterations ran out.
    """

    map_x: np.ndarray
    map_y: np.ndarray
    potential: np.ndarray
    residual: np.ndarray
    iterations: int
    converged: bool


def pushforward(potential: jax.Array, density: jax.Array, h, samples: int = 3, hy=None):
    """The density ``(grad p*)# density`` on a grid, gathered cell by cell: the mass of
    `density` over the image of the cell under ``grad p``. `potential_ext` is the convex
    potential ``p`` on the grid grown by one ghost cell per side,
    ``(rows + 2, cols + 2)``; `density` lives on the grid ``grad p`` maps into. The image
    of a cell is the quadrilateral of ``grad p`` at its corners (`_corner_map`); its
    mass is its area times the mean of `density` at ``samples x samples`` points spread
    over it (bilinearly in the corners). Compressed cells (a bright region of the other
    side) and stretched ones (a jump across a dark region) are both measured, and the
    masses of a monotone map sum to the total (no holes, no overlaps). Cells are `h`
    wide and `hy` high (`h` if None)."""
    hy = h if hy is None else hy
    mx, my = _corner_map(potential, h, hy)
    xa, xb, xc, xd = mx[:-1, :-1], mx[:-1, 1:], mx[1:, 1:], mx[1:, :-1]
    ya, yb, yc, yd = my[:-1, :-1], my[:-1, 1:], my[1:, 1:], my[1:, :-1]
    area = 0.5 * ((xc - xa) * (yd - yb) - (xd - xb) * (yc - ya))

    def add_sample(k, total):  # a loop, not 9 unrolled copies: compiled in 1 s, not 24
        b = ((k // samples).astype(mx.dtype) + 0.5) / samples
        a = ((k % samples).astype(mx.dtype) + 0.5) / samples
        sx = (1 - b) * ((1 - a) * xa + a * xb) + b * ((1 - a) * xd + a * xc)
        sy = (1 - b) * ((1 - a) * ya + a * yb) + b * ((1 - a) * yd + a * yc)
        return total + bilinear(density, sx / h, sy / hy)

    total = jax.lax.fori_loop(0, samples * samples, add_sample, jnp.zeros_like(area))
    return jnp.maximum(area, 0.0) / (h * hy) * total / samples**2


def _normalised(rho: jax.Array, mass) -> jax.Array:
    total = jnp.sum(rho)
    return rho * (mass / jnp.where(total > 0, total, 1.0))


@functools.partial(jax.jit, static_argnames=("buffer", "smooth"))
def _back_and_forth(mu, nu, iterations, buffer: int, tol, sigma0, stall, stretch, smooth):
    """`iterations` at most (traced: passes of different lengths share one compilation),
    their residuals in a ``(buffer,)`` history (``buffer >= iterations``); cells
    `stretch` times as wide as high; `smooth`: see `transport_map`."""
    rows, cols = mu.shape
    dtype = mu.dtype
    hy = jnp.asarray(1.0 / max(rows, cols), dtype)
    h = hy * stretch.astype(dtype)
    xs = cell_centres(cols, h, 0, dtype)
    ys = cell_centres(rows, hy, 0, dtype)
    half_sq = 0.5 * (xs[None, :] ** 2 + ys[:, None] ** 2)
    mass = jnp.sum(nu)

    def value(phi, psi):  # the dual functional, maximised
        return jnp.sum((half_sq - phi) * nu + (half_sq - psi) * mu) * h * hy

    def half_step(p, rho, dens, other, sigma, old, dual):
        """Ascent on potential `p` (gradient ``rho - dens``), then conjugate twice.
        Returns the other side's potential (with a ghost ring), `p` again (convex),
        the step's new dual value and step size, and the push-forward of `other`
        onto the other side."""
        work = -neumann_poisson(rho - dens, h, hy)  # (-Laplacian)^-1 (rho - dens)
        grad_sq = jnp.sum(work * (rho - dens)) * h * hy
        # q's map is pushed forward (`smooth`: the smooth interpolant's, `legendre`); p is
        # only made convex again
        q = legendre(p + sigma * work, h, hy=hy, smooth=smooth)
        p = legendre(q, h, hy=hy)
        new = dual(p, q)
        scale, lower, upper = _ARMIJO
        diff = new - old
        sigma = jnp.where(
            diff > grad_sq * sigma * upper,
            sigma / scale,
            jnp.where(diff < grad_sq * sigma * lower, sigma * scale, sigma),
        )
        rho_other = _normalised(pushforward(q, other, h, hy=hy), mass)
        return p, q, new, sigma, rho_other

    def body(carry):
        k, phi, psi, rho_y, sigma, old, residuals = carry
        # phi (target side) ascent; rho on the source side
        phi, psi, old, sigma, rho_x = half_step(phi, rho_y, nu, nu, sigma, old, value)
        # psi (source side) ascent; rho on the target side
        psi, phi, new, sigma, rho_y = half_step(
            psi, rho_x, mu, mu, sigma, old, lambda a, b: value(b, a)
        )
        res = jnp.sum(jnp.abs(rho_y - nu)) / mass
        return k + 1, phi, psi, rho_y, sigma, new, residuals.at[k].set(res)

    def cond(carry):
        k, *_, residuals = carry
        last = jnp.where(k > 0, residuals[jnp.maximum(k - 1, 0)], jnp.inf)
        # stalled: the last `_PATIENCE` iterations did not improve on the best before
        # them by a fraction `stall`
        index = jnp.arange(buffer)
        earlier = jnp.min(jnp.where(index < k - _PATIENCE, residuals, jnp.inf))
        recent = jnp.min(jnp.where((index >= k - _PATIENCE) & (index < k), residuals, jnp.inf))
        moving = jnp.logical_or(k < _MIN_ITERATIONS, recent < earlier * (1 - stall))
        return jnp.logical_and(k < iterations, jnp.logical_and(last > tol, moving))

    phi = psi = half_sq
    residuals = jnp.full((buffer,), jnp.nan, dtype)
    carry = (0, phi, psi, mu, jnp.asarray(sigma0, dtype), value(phi, psi), residuals)
    k, phi, psi, rho_y, sigma, _, residuals = jax.lax.while_loop(cond, body, carry)
    return k, legendre(phi, h, hy=hy, smooth=smooth), residuals


def _extrapolate_ends(a: jax.Array, axis: int) -> jax.Array:
    """`a` grown by one entry at each end of `axis`, linearly extrapolated."""
    a = jnp.moveaxis(a, axis, 0)
    first, last = 2 * a[0] - a[1], 2 * a[-1] - a[-2]
    return jnp.moveaxis(jnp.concatenate([first[None], a, last[None]]), 0, axis)


@jax.jit
def _corner_map(potential: jax.Array, h, hy):
    """``grad p`` at the corners of the cells of potential `p` ``(rows, cols)``:
    differences across the interior cell edges, averaged over the two cells an edge
    has at a corner, linearly extrapolated to the outer corners, and clamped into the
    grid's domain. Returns ``(map_x, map_y)``, each ``(rows + 1, cols + 1)``."""
    rows, cols = potential.shape
    dx = _extrapolate_ends((potential[:, 1:] - potential[:, :-1]) / h, 1)  # (rows, cols+1)
    dy = _extrapolate_ends((potential[1:, :] - potential[:-1, :]) / hy, 0)  # (rows+1, cols)
    mx = _extrapolate_ends(0.5 * (dx[1:] + dx[:-1]), 0)
    my = _extrapolate_ends(0.5 * (dy[:, 1:] + dy[:, :-1]), 1)
    return jnp.clip(mx, 0.0, cols * h), jnp.clip(my, 0.0, rows * hy)


def _check_density(a, name: str) -> np.ndarray:
    d = check_real_array(a, name)
    if d.ndim != 2 or min(d.shape) < 2:
        raise ValueError(f"`{name}` must be a 2-D density of at least 2 x 2, got {d.shape}")
    if d.size > MAX_PIXELS:
        raise ValueError(f"`{name}` has {d.size} pixels, over the limit {MAX_PIXELS} (4096^2)")
    d = d.astype(float)
    if not np.all(np.isfinite(d)):
        raise ValueError(f"`{name}` contains NaN or infinite values")
    if np.any(d < 0):
        raise ValueError(f"`{name}` must be non-negative")
    if not np.any(d > 0):
        raise ValueError(f"`{name}` is all zeros: there is no mass to transport")
    return d


def transport_map(
    source,
    target,
    *,
    iterations: int = 100,
    tol: float = 1e-2,
    stall: float = 5e-3,
    warn: bool = True,
    stretch: float = 1.0,
    smooth: bool = False,
) -> TransportMap:
    """The optimal transport map (quadratic cost) from density `source` to `target`.

    **Arguments:**

    - `source`, `target`: non-negative ``(rows, cols)`` arrays (the same shape), any
      scale: both are scaled to the same total mass. Zeros are allowed anywhere (black
      regions of a target need no floor); an all-zero density is refused, and so is
      one over `MAX_PIXELS` pixels.
    - `iterations`: back-and-forth iterations at most (an int in ``[1, MAX_ITERATIONS]``).
    - `tol`: stop when the relative L1 misfit of the pushed-forward source falls below
      (a finite number >= 0).
    - `stall`: stop when 8 iterations in a row did not bring the misfit below
      ``(1 - stall)`` times its best before them: the grid's own floor (sharp edges
      and points are resolved to a pixel: a silhouette at 512^2 stalls near 0.085, a
      smooth pair near 0.02). A number in ``[0, 1)``.
    - `warn`: warn (``warnings.warn``) when neither `tol` nor a stall ended the
      iterations (they ran out).
    - `stretch`: the cells' width over their height (> 0; 1: square cells): the cost is
      then that of the grid stretched along x, ``((x1 - y1)^2 + (x2 - y2)^2) / 2`` over
      ``[0, stretch cols h] x [0, rows h]``, where the map's coordinates are (lens
      design under leaning light: `transport_start.transport_stretch`).
    - `smooth`: the map from the Legendre transforms of the potentials' smooth
      (piecewise quadratic) interpolants, not of their grid values. The grid's
      transforms put every maximiser on a cell centre, so where the map compresses (a
      target brighter than its source) it moves by a whole cell or not at all, and the
      cells' images alternate in area by about +-40%: a one-cell staircase, which shows
      as a cross-hatch unless each target pixel spans four cells a side. The smooth
      transforms' map moves continuously (measured on the camera at 512^2 pixels on a
      1024^2 grid: the pushed-forward misfit 0.111 -> 0.042, the image's relative L2
      0.041 -> 0.033 and 1 - SSIM 0.171 -> 0.088, in 25 s against 18 s). Where a
      density has features a few cells wide it converges worse (two equal Gaussians 3.8
      cells wide: misfit 0.058 against 0.028, the map 0.3 pixel off against 0.04).

    **Returns:** a `TransportMap` (corner map, potential, residual history).
    """
    mu = _check_density(source, "source")
    nu = _check_density(target, "target")
    if mu.shape != nu.shape:
        raise ValueError(f"`source` {mu.shape} and `target` {nu.shape} must have one shape")
    iterations = check_int(iterations, "iterations", 1, MAX_ITERATIONS)
    tol = check_number(tol, "tol", low=0.0)
    stall = check_number(stall, "stall", low=0.0, high=1.0, high_open=True)
    warn = check_bool(warn, "warn")
    smooth = check_bool(smooth, "smooth")
    dtype = jnp.result_type(float)
    mu = mu / mu.mean()
    nu = nu / nu.mean()
    sigma0 = 4.0 / max(mu.max(), nu.max())
    buffer = max(128, 1 << (iterations - 1).bit_length())  # few distinct compilations
    stretch = check_number(stretch, "stretch", low=0.0, low_open=True)
    k, psi, residuals = _back_and_forth(
        jnp.asarray(mu, dtype),
        jnp.asarray(nu, dtype),
        iterations,
        buffer,
        tol,
        sigma0,
        stall,
        jnp.asarray(stretch, dtype),
        smooth,
    )
    hy = jnp.asarray(1.0 / max(mu.shape), dtype)
    mx, my = _corner_map(psi, hy * jnp.asarray(stretch, dtype), hy)
    k = int(k)
    res = np.asarray(residuals)[:k]
    converged = bool(k < iterations or res[-1] <= tol)
    if warn and not converged:
        warnings.warn(
            f"transport_map: the push-forward misfit is {res[-1]:.3g} (relative L1) after "
            f"{k} iterations and still falling; raise `iterations`",
            stacklevel=2,
        )
    return TransportMap(
        map_x=np.asarray(mx),
        map_y=np.asarray(my),
        potential=np.asarray(psi),
        residual=res,
        iterations=k,
        converged=converged,
    )
