"""Quadratic-cost optimal transport between two densities on one pixel grid.

`transport_map` solves Monge's problem for the cost ``|x - y|^2 / 2`` by the
back-and-forth method (Jacobs & Léger, Numer. Math. 146, 2020): the Brenier map from a
source density to a target density on the same grid. It is the core of lens design and
of water recovery. See the design notes (``docs/design-notes.md``).

Multiscale: a grid over `COARSEST` cells a side is solved first on grids halved down to
it, each level's potential starting the next (bicubically resampled), so the finest
grid spends a few iterations where a cold start spends dozens on overshoots while its
step size adapts. Measured (float32, 2 cores, one process, compilation included; each
target pixel 2 x 2 cells), misfit and time on 1024^2 cells, one level against two:
the camera (smooth transforms) 0.036 in 29 s against 0.024 in 20 s; the silhouette
0.115 in 35 s against 0.105 in 23 s; the lettering 0.066 in 68 s against 0.068 in
42 s. From 256^2 (three levels) all three were worse (0.025, 0.113, 0.071: thin
strokes a coarse level cannot resolve start the finer ones off). On 2048^2 cells, from
256^2: the silhouette's cold start spent its first 30 iterations between misfits 1.1
and 1.9 while the step adapted, and the stall rule ended it at 0.71 in 165 s;
multiscale, 0.13 in 59 s.

The potentials are kept as ``u = psi - |x|^2 / 2`` (`legendre`): near 0.5 a float32
``psi`` rounds at 3e-8, an eighth of a cell's ``dx^2`` at 2048^2, and the map it gave
was noise at that scale (the camera's misfit on 2048^2 cells 0.092, in float64 0.013;
with ``u``, 0.045). Float32 still loses the potential's updates below ``u``'s own
rounding (2-4e-9) near convergence: on 1024^2 cells the camera's misfit is 0.024 in
float32 and 0.019 in float64.

Coordinates: cell ``(i, j)``'s centre is ``((j + 0.5) h, (i + 0.5) h)`` with
``h = 1 / max(rows, cols)``: the grid covers ``[0, cols h] x [0, rows h]`` (with
`stretch`, x runs over ``[0, stretch cols h]``).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_bool, check_int, check_number, check_real_array
from ..scene.surface import bilinear
from .legendre import legendre
from .numerics import area_average, neumann_poisson

_ARMIJO = (0.95, 0.25, 0.75)  # step scale factor, lower and upper Armijo-Goldstein bounds
_PATIENCE = 8  # iterations without improvement that count as a stall
# no stall before this many iterations: the first ones can raise the misfit while the
# step size adapts (measured: a silhouette at 512^2 from 0.8 up to 1.8, then down to 0.09)
_MIN_ITERATIONS = 30
# a warm-started level (multiscale): its stall counted over this many iterations, and
# a coarse level's looser stall (its end only starts the next level)
_WARM_PATIENCE = 4
_COARSE_STALL = 0.02
# a warm level's step size: the coarser level's last, but at least this fraction of
# the cold start's. At a stall the Armijo test shrinks the step every half-iteration:
# the silhouette's 256^2 level ended at 1/125 of its start, from which the 512^2 level
# crept from 0.29 to 0.19 in 30 iterations; at 10x that step it reached 0.086 in 20,
# at 30x the 1024^2 level diverged. The camera's step barely shrinks (2.0 -> 1.15), and
# at 1.75x its levels' misfits rose for a few iterations
_WARM_STEP = 1 / 8
# the multiscale transport's coarsest level, longer side (cells), by default
COARSEST = 512
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
    - `potential`: ``(rows, cols)``: ``u`` at the cell centres, where ``psi = |x|^2 / 2
      + u`` is the convex Brenier potential (``T = grad psi = x + grad u``; `legendre`
      says why ``u``).
    - `residual`: relative L1 difference between the target and the source pushed
      forward by the final map (``sum |T#mu - nu| / sum nu``), per iteration of the
      finest level.
    - `iterations`: back-and-forth iterations taken on the finest level.
    - `converged`: whether `residual` fell to `tol` or stopped falling (`stall`) before
      the iterations ran out.
    - `levels`: ``(shape, iterations, last residual)`` of each level, coarsest first
      (`transport_map`'s `coarsest`).
    """

    map_x: np.ndarray
    map_y: np.ndarray
    potential: np.ndarray
    residual: np.ndarray
    iterations: int
    converged: bool
    levels: list[tuple[tuple[int, int], int, float]] = dataclasses.field(default_factory=list)


def pushforward(potential: jax.Array, density: jax.Array, h, samples: int = 3, hy=None):
    """The density ``(grad p*)# density`` on a grid, gathered cell by cell: the mass of
    `density` over the image of the cell under ``grad p``. `potential` is ``u`` of the
    convex potential ``p = |x|^2 / 2 + u`` at the grid's cell centres (``legendre``
    says why); `density` lives on the grid ``grad p`` maps into. The image
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


class _Stop(NamedTuple):
    """When a level's iterations end (traced: calls that differ only in these share a
    compilation): at `iterations`, at the misfit `tol`, or stalled (the last `patience`
    iterations did not bring the misfit below ``(1 - stall)`` times its best before
    them), never stalled before `minimum` iterations."""

    iterations: int
    tol: float
    stall: float
    patience: int
    minimum: int


@functools.partial(jax.jit, static_argnames=("buffer", "smooth"))
def _back_and_forth(mu, nu, stop: _Stop, buffer: int, sigma0, stretch, smooth, psi0=None):
    """`stop.iterations` at most, their residuals in a ``(buffer,)`` history
    (``buffer >= iterations``), from the source-side potential `psi0` (None: the
    identity's); cells `stretch` times as wide as high; `smooth`: see `transport_map`.
    Returns ``(iterations, psi, residuals, last step size)``."""
    rows, cols = mu.shape
    dtype = mu.dtype
    hy = jnp.asarray(1.0 / max(rows, cols), dtype)
    h = hy * stretch.astype(dtype)
    mass = jnp.sum(nu)

    # the potentials are ``u`` of ``|x|^2 / 2 + u`` (`legendre`: float32 keeps u's
    # digits where it would lose them in the sum). The dual functional, maximised, is
    # ``-sum(phi nu + psi mu) h hy``; its change is summed from the potentials' changes
    # (the difference of two sums lost the Armijo test's digits at 2048^2)

    def half_step(p, q, rho, dens, other, sigma):
        """Ascent on potential `p` (gradient ``rho - dens``; `q` the other side's, paired
        with density `other`), then conjugate twice. Returns `p` again (convex), the
        other side's potential, the new step size, and the push-forward of `dens` onto
        the other side."""
        work = -neumann_poisson(rho - dens, h, hy)  # (-Laplacian)^-1 (rho - dens)
        grad_sq = jnp.sum(work * (rho - dens)) * h * hy
        # q's map is pushed forward (`smooth`: the smooth interpolant's, `legendre`); p is
        # only made convex again
        q_new = legendre(p + sigma * work, h, hy=hy, smooth=smooth)
        p_new = legendre(q_new, h, hy=hy)
        diff = -jnp.sum((p_new - p) * dens + (q_new - q) * other) * h * hy
        scale, lower, upper = _ARMIJO
        sigma = jnp.where(
            diff > grad_sq * sigma * upper,
            sigma / scale,
            jnp.where(diff < grad_sq * sigma * lower, sigma * scale, sigma),
        )
        rho_other = _normalised(pushforward(q_new, dens, h, hy=hy), mass)
        return p_new, q_new, sigma, rho_other

    def body(carry):
        k, phi, psi, rho_y, sigma, residuals = carry
        # phi (target side) ascent; rho on the source side
        phi, psi, sigma, rho_x = half_step(phi, psi, rho_y, nu, mu, sigma)
        # psi (source side) ascent; rho on the target side
        psi, phi, sigma, rho_y = half_step(psi, phi, rho_x, mu, nu, sigma)
        res = jnp.sum(jnp.abs(rho_y - nu)) / mass
        return k + 1, phi, psi, rho_y, sigma, residuals.at[k].set(res)

    def cond(carry):
        k, *_, residuals = carry
        last = jnp.where(k > 0, residuals[jnp.maximum(k - 1, 0)], jnp.inf)
        index = jnp.arange(buffer)
        earlier = jnp.min(jnp.where(index < k - stop.patience, residuals, jnp.inf))
        recent = jnp.where((index >= k - stop.patience) & (index < k), residuals, jnp.inf)
        early = k < jnp.maximum(stop.minimum, stop.patience + 1)
        moving = jnp.logical_or(early, jnp.min(recent) < earlier * (1 - stop.stall))
        return jnp.logical_and(k < stop.iterations, jnp.logical_and(last > stop.tol, moving))

    if psi0 is None:
        phi = psi = jnp.zeros_like(mu)
        rho0 = mu
    else:  # made convex (conjugated twice), and its push-forward
        phi = legendre(psi0, h, hy=hy, smooth=smooth)
        psi = legendre(phi, h, hy=hy)
        rho0 = _normalised(pushforward(phi, mu, h, hy=hy), mass)
    residuals = jnp.full((buffer,), jnp.nan, dtype)
    carry = (0, phi, psi, rho0, jnp.asarray(sigma0, dtype), residuals)
    k, phi, psi, rho_y, sigma, residuals = jax.lax.while_loop(cond, body, carry)
    return k, legendre(phi, h, hy=hy, smooth=smooth), residuals, sigma


def level_shapes(shape, coarsest: int | None) -> list[tuple[int, int]]:
    """The grids of a multiscale transport onto a ``(rows, cols)`` grid, coarsest first:
    `shape` halved (rounded up) while its longer side is over `coarsest` (and its
    shorter side at least 8); ``[shape]`` for None."""
    shapes = [(int(shape[0]), int(shape[1]))]
    while coarsest is not None and max(shapes[0]) > coarsest and min(shapes[0]) >= 8:
        rows, cols = shapes[0]
        shapes.insert(0, ((rows + 1) // 2, (cols + 1) // 2))
    return shapes


@functools.partial(jax.jit, static_argnames="shape")
def _finer(u: jax.Array, shape: tuple[int, int]) -> jax.Array:
    """A coarser level's potential `u` (of ``|x|^2 / 2 + u``) at the centres of the
    finer grid `shape` over the same domain, resampled bicubically."""
    return jax.image.resize(u, shape, "cubic")


def _extrapolate_ends(a: jax.Array, axis: int) -> jax.Array:
    """`a` grown by one entry at each end of `axis`, linearly extrapolated."""
    a = jnp.moveaxis(a, axis, 0)
    first, last = 2 * a[0] - a[1], 2 * a[-1] - a[-2]
    return jnp.moveaxis(jnp.concatenate([first[None], a, last[None]]), 0, axis)


@jax.jit
def _corner_map(potential: jax.Array, h, hy):
    """``grad p = x + grad u`` at the cell corners, for ``p = |x|^2 / 2 + u`` and `u`
    (`potential`) ``(rows, cols)`` at the cell centres: the differences of `u` across
    the interior cell edges, averaged over the two cells an edge has at a corner,
    linearly extrapolated to the outer corners, added to the corners' positions and
    clamped into the grid's domain. Returns ``(map_x, map_y)``, each
    ``(rows + 1, cols + 1)``."""
    rows, cols = potential.shape
    dx = _extrapolate_ends((potential[:, 1:] - potential[:, :-1]) / h, 1)  # (rows, cols+1)
    dy = _extrapolate_ends((potential[1:, :] - potential[:-1, :]) / hy, 0)  # (rows+1, cols)
    mx = _extrapolate_ends(0.5 * (dx[1:] + dx[:-1]), 0)
    my = _extrapolate_ends(0.5 * (dy[:, 1:] + dy[:, :-1]), 1)
    mx = mx + jnp.arange(cols + 1, dtype=mx.dtype)[None, :] * h
    my = my + jnp.arange(rows + 1, dtype=my.dtype)[:, None] * hy
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
    coarsest: int | None = COARSEST,
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
    - `coarsest`: the multiscale transport's coarsest grid, longer side (an int >= 4;
      module docstring): a grid over it is solved on grids halved down to it first.
      ``None``: one level. Every level takes up to `iterations`; a warm-started level
      counts its stall over 4 iterations, not 8, and a coarse one stops at a 2% stall.
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
    coarsest = None if coarsest is None else check_int(coarsest, "coarsest", 4)
    stretch = check_number(stretch, "stretch", low=0.0, low_open=True)
    dtype = jnp.result_type(float)
    mu = mu / mu.mean()
    nu = nu / nu.mean()
    sigma0 = 4.0 / max(mu.max(), nu.max())
    sigma = sigma0
    buffer = max(128, 1 << (iterations - 1).bit_length())  # few distinct compilations
    shapes = level_shapes(mu.shape, coarsest)
    psi, levels = None, []
    for shape in shapes:
        finest = shape == mu.shape
        if psi is None:  # cold: the first iterations overshoot while the step adapts
            patience, minimum = _PATIENCE, _MIN_ITERATIONS
        else:
            psi = _finer(psi, shape)
            sigma = jnp.maximum(sigma, sigma0 * _WARM_STEP)
            patience, minimum = _WARM_PATIENCE, 0
        # a coarse level ends at a looser stall: its end only starts the next level
        stop = _Stop(
            iterations, tol, stall if finest else max(stall, _COARSE_STALL), patience, minimum
        )
        k, psi, residuals, sigma = _back_and_forth(
            jnp.asarray(mu if finest else area_average(mu, shape), dtype),
            jnp.asarray(nu if finest else area_average(nu, shape), dtype),
            stop,
            buffer,
            sigma,
            jnp.asarray(stretch, dtype),
            smooth,
            psi,
        )
        levels.append((shape, int(k), float(residuals[int(k) - 1])))
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
        levels=levels,
    )
