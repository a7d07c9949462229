"""Caustic lens design: from a target image to the height field of a lens (`design_lens`).

The forward model is the lens scene (`LensScene`: screen ``z = 0``, flat bottom face at
``z = screen_distance``, top surface ``z = screen_distance + thickness + H(x, y)``).

The method: the light transport equation on the lens plane. A photon grid over the
aperture is traced exactly (the physics of `lens_photons`, the forward model of the
caustic triangles); each cell of the grid lands on a quadrilateral of the screen whose
area times the target irradiance at its centroid must equal the flux the cell carries:
``r = log E(centroid) + log A_landed - log flux = 0`` per cell, plus the second boundary
condition (the aperture's edge lands on the screen's edge) and a weak curvature prior.
The system is solved as a nonlinear least-squares problem by Optimistix
(Levenberg-Marquardt or Gauss-Newton) with matrix-free Lineax normal conjugate gradients
(JVPs and VJPs of the residual), right-preconditioned by the inverse of the weak-lens
Laplacian (``h = P u``, ``P = ((n - 1) D Laplacian)^-1`` by a DCT Poisson solve with
Neumann boundaries), started from (half) the weak-lens Poisson solution and run coarse to
fine, each level against the target averaged to its grid (`_level_target`).

**The transport start (default, ``start="transport"``).** The irradiance residual above
needs light everywhere (``log E``) and a start close to the solution; high-contrast
targets (black backgrounds, thin lettering, bright dots) meet neither. So by default
the design first solves where every photon must land: the quadratic-cost optimal
transport (`jaxcaustics.inverse.transport.transport_map`, the back-and-forth method) from the
flux the aperture sends (uniform for collimated light, the point light's falloff
otherwise) to the target on the screen, both on the heights grid (four times the
target's resolution up to 512 samples a side); zeros need no floor. The map's corners
are the landing points of the photon grid's vertices. The heights are then fitted to
those landing points with the exact optics (`_Problem.landing`: Snell at both faces,
the thickness, point or oblique light) by Optimistix's fixed-point iteration of a
preconditioned Gauss-Newton step: the exact gradient ``J^T r`` (a VJP), divided in the
DCT basis by the weak-lens normal operator ``(D / pixel)^2 G^T G`` (``G``: the gradient
of the heights at the photon vertices). In the weak-lens limit the first step is the
Brenier potential itself (heights = (potential - |x|^2 / 2) / D); the next ones correct
for the real optics. The lens's surface keeps its edge slope out to the rim
(`HeightField`'s "extrapolate"): a clamped one levels off over the outermost half sample
and sends that light back towards the screen's edge (measured on twelve dots: the
outermost ring of cells put all its light on black; 3.07% of the light on black in all,
2.65% with the rim extrapolated). Under point or oblique light, rays that lean outwards at an edge
lying below the top's rest plane would meet the surface beyond the aperture (where no
heights steer them: their light lined the screen's edge); there the edge is bevelled up
to the rest plane, the transport is solved again without the band of the aperture whose
light the bevel throws away, and the fit continues from its heights (`_edge_bevel`;
measured on a silhouette under a point light: relative L2 0.133 to 0.055, at the cost
of a second transport). Where the target has dark regions the map jumps across them and
the fitted surface (smooth on its grid) spreads a little light over the gaps; there a
few L-BFGS steps on the image misfit (caustic triangles, plus a penalty on the flux on
dark pixels) finish the design (`refine_steps`). The irradiance residual of the Poisson
start, run after the fit instead, raised the error on a silhouette (relative L2 0.18 to
0.26, measured), since its logarithm needs light everywhere.

Weak-lens relation (collimated light along ``-z``): a photon through the aperture point
``p`` lands near ``p + D grad H(p)`` with ``D = (n - 1) (screen_distance + thickness / n)``; the
continuity equation linearised gives ``D Laplacian(H) = -log(E / mean E)`` (bright
target: locally convex lens).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import os
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._checks import (
    check_bool,
    check_int,
    check_number,
    check_real_array,
    check_shape,
    is_distance,
    renamed_keyword,
)
from ..devices import check_per_device, map_sharded, resolve_devices
from ..methods.triangles.method import (
    band_bytes,
    caustic_triangles,
    trace_photons,
    triangle_window,
    triangles_image,
)
from ..scene.scene import DirectionalLight, HeightField, LensScene, PlaneReceiver, PointLight
from ..scene.surface import (
    PAD_LOW,
    catmull_rom,
    pad_heights,
    ray_surface_hit,
    sample_grid,
)
from ..scene.surface import bilinear as _bilinear
from ..trace.optics import refract_components
from ..trace.photons import corner_grid
from .recover import MAX_CG_STEPS, check_irradiance, resample_heights
from .recover import weighted_laplacian as _five_point
from .solvers import SolverLike, check_solver, half_squares, is_minimiser, make_solver
from .transport import MAX_ITERATIONS, MAX_PIXELS, transport_map
from .transport import neumann_poisson as _neumann_poisson
from .water_start import safe_log_area as _safe_log_area

# the transport start's surface boundary (`HeightField`): its edge slope continues to the
# rim; "clamp" levels it off over the outermost half sample, whose light then lands near
# the screen's edge (measured on twelve dots at 512^2 heights: the outermost ring of
# cells, 0.8% of the light, put all of it on black). The Poisson start keeps "clamp":
# its edge condition (the aperture's edge lands on the screen's edge) stalled under
# "extrapolate" (measured on a 16^2 blob: relative L2 0.13 against 0.044)
LENS_BOUNDARY = "extrapolate"


# --------------------------------------------------------------------------- result


@dataclasses.dataclass
class LensDesign:
    """Result of `design_lens`.

    - `heights`: ``(rows, cols)`` NumPy array, metres: the top surface relative to its
      rest plane, with ``max(heights) = 0`` (``thickness`` is the blank's thickness, the
      design is milled into it; the thinnest point is ``thickness + min(heights)``).
    - `scene`: the `LensScene` (receiver: the screen's pixel grid, the target's shape).
    - `predicted`: the forward model's caustic on the screen (caustic triangles, exact
      reconstruction), ``(rows, cols)``, irradiance as `caustic_triangles` gives it.
    - `target`: the target as used (float, scaled to the flux of the lens, masked).
    - `loss_history`: ``0.5 * sum(residual^2)`` after every solver step, all levels.
    - `levels`: per level: heights shape, steps, final loss, Optimistix result code,
      seconds (compilation included) and seconds of the first call (compilation).
    - `result`: the Optimistix result of the last level (``optx.RESULTS``).
    - `timings`: ``{"total": s, "initial_guess": s, "predict": s}`` (and
      ``"transport"`` for the transport start).
    - `predicted_error`: relative L2 of `predicted` against `target` (both at unit mean).
    - `dark_flux`: the fraction of the predicted flux that lands on pixels where the
      target is below 5% of its mean.
    - `converged`: every level (and the transport) met its tolerance.
    - `warnings`: what `design_lens` warned about (also raised with `warnings.warn`).
    """

    heights: np.ndarray
    scene: LensScene
    predicted: np.ndarray
    target: np.ndarray
    loss_history: list[float]
    levels: list[dict[str, Any]]
    result: Any
    timings: dict[str, float]
    predicted_error: float = float("nan")
    dark_flux: float = float("nan")
    converged: bool = True
    warnings: list[str] = dataclasses.field(default_factory=list)

    @property
    def relief(self) -> float:
        """Depth of the relief, metres (``max(heights) - min(heights)``)."""
        return float(np.max(self.heights) - np.min(self.heights))


# --------------------------------------------------------------------------- validation


def _positive(value, name: str) -> float:
    if isinstance(value, (str, bytes, bool)):
        raise ValueError(f"`{name}` must be a positive number (metres), got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`{name}` must be a positive number (metres), got {value!r}") from err
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"`{name}` must be positive and finite (metres), got {value!r}")
    return v


def _is_number(value) -> bool:
    """A real number, not a bool or a string."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _check_target(target) -> np.ndarray:
    t = check_real_array(target, "target")
    if (t.shape[0] * t.shape[1] if t.ndim >= 2 else t.size) > MAX_PIXELS:
        raise ValueError(f"`target` {t.shape} has over {MAX_PIXELS} pixels (4096^2)")
    t = t.astype(float)
    if t.ndim == 3 and t.shape[-1] in (3, 4):
        t = t[..., :3] @ np.array([0.2126, 0.7152, 0.0722])  # luminance of an RGB image
    if t.ndim != 2:
        raise ValueError(f"`target` must be a 2-D image (rows, cols), got shape {t.shape}")
    if min(t.shape) < 4:
        raise ValueError(f"`target` needs at least 4x4 pixels, got shape {t.shape}")
    return check_irradiance(t, "there is nothing to design for")


def check_mask(mask, shape) -> np.ndarray:
    if mask is None:
        return np.ones(shape, bool)
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise ValueError(f"`mask` must have the target's shape {tuple(shape)}, got {m.shape}")
    if m.dtype != bool:
        if not np.issubdtype(m.dtype, np.number) or not np.all(np.isin(m, (0, 1))):
            raise ValueError("`mask` must be boolean (or 0/1)")
        m = m.astype(bool)
    if not m.any():
        raise ValueError("`mask` is all False: no pixel may receive light")
    return m


def _level_shape(n: int, width: float, height: float) -> tuple[int, int]:
    """Heights shape with `n` samples along the longer side of the aperture."""
    if width >= height:
        return max(4, round(n * height / width)), n
    return n, max(4, round(n * width / height))


# --------------------------------------------------------------------------- pieces


def _area_average(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Resample `image` to `shape` by exact box (area) averaging, any ratio."""

    def matrix(n_in, n_out):
        edges_in = np.linspace(0, 1, n_in + 1)
        edges_out = np.linspace(0, 1, n_out + 1)
        lo = np.maximum(edges_out[:-1, None], edges_in[None, :-1])
        hi = np.minimum(edges_out[1:, None], edges_in[None, 1:])
        w = np.clip(hi - lo, 0, None)
        return w / w.sum(axis=1, keepdims=True)

    return matrix(image.shape[0], shape[0]) @ image @ matrix(image.shape[1], shape[1]).T


class _Problem(eqx.Module):
    """Everything a level's residual needs (arrays are leaves; shapes static)."""

    scene: LensScene
    log_target: jax.Array  # (rows, cols) log of the screen irradiance to reach
    screen: jax.Array  # (4,) extent
    weak: (
        jax.Array
    )  # D of the weak-lens relation (a leaf: designs for several screen_distances batch)
    grid: tuple[int, int] = eqx.field(static=True)  # photon grid (vertices)
    boundary_weight: float = eqx.field(static=True)
    regularization: float = eqx.field(static=True)
    hit_iterations: int = eqx.field(static=True)
    sampling: tuple | None  # separable bicubic weights at the photon grid (vertical light)
    dx: float = eqx.field(static=True)
    dy: float = eqx.field(static=True)

    def heights(self, u: jax.Array) -> jax.Array:
        """Right preconditioner: ``h = (D Laplacian)^-1 u`` (zero mean)."""
        return _neumann_poisson(u, self.dx, self.dy) / self.weak

    def landing(self, h: jax.Array):
        """Where the photons of the grid land, ``(x, y)``, and their flux density: the
        physics of `lens_photons` (unrotated aperture, one index), written lean."""
        h = h - jax.lax.stop_gradient(jnp.max(h))
        scene = self.scene
        surface = eqx.tree_at(lambda s: s.heights, scene.surface, h)
        x0, x1, y0, y1 = surface.extent
        px, py, cell_area = corner_grid(x0, x1, y0, y1, self.grid, h.dtype)
        top = scene.top
        if isinstance(scene.light, DirectionalLight):
            d = tuple(c.astype(h.dtype) for c in scene.light.unit_direction)
            density = jnp.ones_like(px)
        else:
            lp = scene.light.position.astype(h.dtype)
            offset = (px - lp[0], py - lp[1], top - lp[2])
            inv = jax.lax.rsqrt(sum(c * c for c in offset))
            d = tuple(c * inv for c in offset)
            density = scene.light.intensity * jnp.abs(d[2]) * inv * inv
        if self.sampling is not None:  # vertical light: the hits are the grid points
            wy, dwy, wx, dwx = self.sampling
            hit_x, hit_y = px, py
            hit_z = top + wy @ h @ wx.T
            hx, hy = wy @ h @ dwx.T, dwy @ h @ wx.T
        else:
            hit_x, hit_y, hit_z, hx, hy = ray_surface_hit(
                surface, top, px, py, d, self.hit_iterations
            )
        x, y = self.exit(hit_x, hit_y, hit_z, hx, hy, d)
        return x, y, density, cell_area

    def exit(self, hit_x, hit_y, hit_z, hx, hy, d):
        """Where a ray of direction `d` that hits the top surface at ``(hit_x, hit_y,
        hit_z)`` with slopes ``(hx, hy)`` lands on the screen: Snell at the top, the
        glass down to the bottom face, Snell there, the screen distance."""
        scene = self.scene
        inv = jax.lax.rsqrt(hx * hx + hy * hy + 1.0)
        normal = (-hx * inv, -hy * inv, inv)
        inside, _, _ = refract_components(d, normal, 1.0 / scene.ior)
        s = (hit_z - scene.screen_distance) / -jnp.minimum(inside[2], -1e-12)
        bx, by = hit_x + s * inside[0], hit_y + s * inside[1]
        up = (jnp.zeros_like(hx), jnp.zeros_like(hx), jnp.ones_like(hx))
        out, _, _ = refract_components(inside, up, scene.ior)
        t = scene.screen_distance / -jnp.minimum(out[2], -1e-12)
        return bx + t * out[0], by + t * out[1]

    def vertex_rays(self, h: jax.Array, sampling):
        """The rays that hit the top surface exactly above the photon grid's vertices:
        where they land on the screen, and where they crossed the top's rest plane
        (``x, y, rest_x, rest_y``; the two coincide for vertical light). Exact for any
        light, with no ray-surface iteration: the surface and its slopes are read at
        the vertices through the separable bicubic weights `sampling`."""
        h = h - jax.lax.stop_gradient(jnp.max(h))
        scene = self.scene
        x0, x1, y0, y1 = scene.surface.extent
        px, py, _ = corner_grid(x0, x1, y0, y1, self.grid, h.dtype)
        wy, dwy, wx, dwx = sampling
        height = wy @ h @ wx.T
        hx, hy = wy @ h @ dwx.T, dwy @ h @ wx.T
        top = scene.top
        if isinstance(scene.light, DirectionalLight):
            d = tuple(c.astype(h.dtype) * jnp.ones_like(px) for c in scene.light.unit_direction)
        else:
            lp = scene.light.position.astype(h.dtype)
            offset = (px - lp[0], py - lp[1], top + height - lp[2])
            inv = jax.lax.rsqrt(sum(c * c for c in offset))
            d = tuple(c * inv for c in offset)
        back = -height / d[2]  # along the ray from the hit up (or down) to the rest plane
        rest_x, rest_y = px + back * d[0], py + back * d[1]
        x, y = self.exit(px, py, top + height, hx, hy, d)
        return x, y, rest_x, rest_y

    def transport_residual(self, u: jax.Array, args=None):
        x, y, density, cell_area = self.landing(self.heights(u))
        # materialise the landing points: XLA would otherwise fuse (and recompute) the
        # whole trace into each of the shifted slices below, tens of times slower
        x, y = jax.lax.optimization_barrier((x, y))
        # quadrilateral a (i, j), b (i, j + 1), c (i + 1, j + 1), d (i + 1, j)
        xa, xb, xc, xd = x[:-1, :-1], x[:-1, 1:], x[1:, 1:], x[1:, :-1]
        ya, yb, yc, yd = y[:-1, :-1], y[:-1, 1:], y[1:, 1:], y[1:, :-1]
        area = 0.5 * ((xc - xa) * (yd - yb) - (xd - xb) * (yc - ya))
        flux = (
            cell_area
            * 0.25
            * (density[:-1, :-1] + density[:-1, 1:] + density[1:, 1:] + density[1:, :-1])
        )
        rows, cols = self.log_target.shape
        sx0, sx1, sy0, sy1 = self.screen
        pdx, pdy = (sx1 - sx0) / cols, (sy1 - sy0) / rows
        cx = 0.25 * (xa + xb + xc + xd)
        cy = 0.25 * (ya + yb + yc + yd)
        log_e = _bilinear(self.log_target, (cx - sx0) / pdx, (cy - sy0) / pdy)
        cell0 = jax.lax.stop_gradient(jnp.mean(flux))
        interior = log_e + _safe_log_area(area, 1e-3 * cell0) - jnp.log(flux)
        w = self.boundary_weight
        edges = jnp.concatenate(
            [
                (x[:, 0] - sx0) / pdx,
                (x[:, -1] - sx1) / pdx,
                (y[0, :] - sy0) / pdy,
                (y[-1, :] - sy1) / pdy,
            ]
        )
        # a weak prior on the curvature of u (the weak-lens irradiance change): without it
        # the coarse levels drift into modes that fold between the photon vertices
        prior = self.regularization * self.dx * self.dy * _laplacian(u, self.dx, self.dy)
        return interior, w * edges, prior


def _catmull_rom_matrix(n: int, lo: float, hi: float, points: np.ndarray, boundary: str):
    """Weights ``W (len(points), n)`` and their derivative ``dW`` (per metre) of the
    Catmull-Rom interpolant of `n` cell-centred samples over ``[lo, hi]`` with
    `boundary` (the library's `HeightField`, one axis: the surface is separable)."""
    step = (hi - lo) / n
    u = np.clip((points - lo) / step - 0.5, -2.0, n + 1.0)
    base = np.floor(u)
    t = u - base
    w, dw, _ = catmull_rom(t)  # the library's own Catmull-Rom weights
    # row p of `taps`: padded sample p - _PAD as a combination of the samples
    taps = np.asarray(pad_heights(jnp.eye(n), boundary, axes=(0,)))
    weights = np.zeros((points.size, n))
    deriv = np.zeros((points.size, n))
    for k in range(4):
        rows = taps[base.astype(int) - 1 + k + PAD_LOW]
        weights += np.asarray(w[k])[:, None] * rows
        deriv += np.asarray(dw[k])[:, None] * rows / step
    return weights, deriv


def _sampling(shape, aperture, grid, boundary: str):
    """Separable weights of the heights' bicubic (with `boundary`) at the photon grid's
    vertices."""
    (rows, cols), (prow, pcol) = shape, grid
    x0, x1, y0, y1 = aperture
    wx, dwx = _catmull_rom_matrix(cols, x0, x1, np.linspace(x0, x1, pcol), boundary)
    wy, dwy = _catmull_rom_matrix(rows, y0, y1, np.linspace(y0, y1, prow), boundary)
    return tuple(jnp.asarray(a) for a in (wy, dwy, wx, dwx))


# --------------------------------------------------------------------------- transport start

TRANSPORT_MAX = 512  # the transport grid's longest side, at most


def transport_shape(target_shape: Sequence[int], width: float, height: float) -> tuple[int, int]:
    """The heights (and transport) grid of the transport start: the target's longer side
    times the largest factor in 1..4 that stays within `TRANSPORT_MAX` samples (at least
    the target's own size), the other side in proportion to the aperture."""
    n = max(int(v) for v in target_shape)
    factor = max(1, min(4, TRANSPORT_MAX // n))
    return _level_shape(min(n * factor, max(n, TRANSPORT_MAX)), width, height)


def _source_density(light, aperture, shape, top: float) -> np.ndarray:
    """The flux density the aperture receives at its cells' centres, ``(rows, cols)``:
    uniform for a directional light, ``I |cos| / r^2`` for a point light."""
    if isinstance(light, DirectionalLight):
        return np.ones(shape)
    x0, x1, y0, y1 = aperture
    rows, cols = shape
    px, py = np.meshgrid(
        x0 + (np.arange(cols) + 0.5) * (x1 - x0) / cols,
        y0 + (np.arange(rows) + 0.5) * (y1 - y0) / rows,
    )
    offset = np.stack([px, py, np.full_like(px, top)], axis=-1) - np.asarray(light.position)
    r2 = np.sum(offset**2, axis=-1)
    return np.abs(offset[..., 2]) / r2**1.5


def _gradient_at_vertices(h: jax.Array, dx: float, dy: float):
    """``G h``: the gradient of cell-centred heights at the cell corners (2 x 2 stencils,
    edge values extended), ``((rows + 1, cols + 1), (rows + 1, cols + 1))``."""
    p = jnp.pad(h, 1, mode="edge")
    gx = ((p[:-1, 1:] + p[1:, 1:]) - (p[:-1, :-1] + p[1:, :-1])) / (2 * dx)
    gy = ((p[1:, :-1] + p[1:, 1:]) - (p[:-1, :-1] + p[:-1, 1:])) / (2 * dy)
    return gx, gy


def _fit_symbol(shape, dx, dy, scale_x, scale_y) -> np.ndarray:
    """The DCT-II symbol of the weak-lens normal operator ``J^T J`` of the landing fit:
    ``J = (scale_x dH/dx, scale_y dH/dy)`` at the photon vertices (the cell corners) of
    the clamped Catmull-Rom surface (`HeightField`), whose derivative at a midpoint has
    the symbol ``2.75 sin(t/2) - 0.25 sin(3t/2)`` and whose value there
    ``(9 cos(t/2) - cos(3t/2)) / 8`` (``t``: the mode's phase per sample). Checkerboards
    (which no vertex sees) are kept above 5% of the five-point Laplacian's symbol; the
    mean (unobservable) is 1."""

    def factors(n):
        t = np.pi * np.arange(n) / n
        deriv = (2.75 * np.sin(t / 2) - 0.25 * np.sin(1.5 * t)) ** 2
        value = ((9 * np.cos(t / 2) - np.cos(1.5 * t)) / 8) ** 2
        return deriv, value, 4 * np.sin(t / 2) ** 2

    rows, cols = shape
    dy2, vy2, ly = factors(rows)
    dx2, vx2, lx_ = factors(cols)
    ax, ay = scale_x**2 / dx**2, scale_y**2 / dy**2
    symbol = ax * dx2[None, :] * vy2[:, None] + ay * dy2[:, None] * vx2[None, :]
    symbol = np.maximum(symbol, 0.05 * (ax * lx_[None, :] + ay * ly[:, None]))
    symbol[0, 0] = 1.0
    return symbol


def _bicubic(image: jax.Array, px: jax.Array, py: jax.Array) -> jax.Array:
    """`sample_grid` with edge samples extended: the landing goals read at the rest-plane
    crossings of oblique rays, which drift across the cells."""
    return sample_grid(image, px, py, "clamp")


class _LandingFit(eqx.Module):
    """The landing-point fit as a fixed point ``h = h - M^-1 J^T r(h)`` (Optimistix
    `FixedPointIteration`): `r` the misplacement of the photon grid's vertices in
    screen pixels, `J^T r` its exact gradient, `M` the weak-lens normal operator in the
    DCT basis (`_fit_symbol`). The auxiliary output is the RMS misplacement (pixels)."""

    problem: _Problem
    goal_x: jax.Array  # (P0, P1) where the rays through the vertices must land, metres
    goal_y: jax.Array
    symbol: jax.Array  # (rows, cols)
    pixel: jax.Array  # (2,) screen pixel size, metres
    sampling: tuple  # bicubic weights at the vertices (`_sampling`)

    def residual(self, h):
        """Misplacement (screen pixels) of the rays hitting the surface above the
        vertices: each should land where the transport sends the rest-plane point it
        crossed (the goal read there by `_bicubic`; the vertex itself for vertical
        light)."""
        x, y, rest_x, rest_y = self.problem.vertex_rays(h, self.sampling)
        rows, cols = self.goal_x.shape
        x0, x1, y0, y1 = self.problem.scene.surface.extent
        u = (rest_x - x0) / (x1 - x0) * (cols - 1) + 0.5  # pixel-centre convention
        v = (rest_y - y0) / (y1 - y0) * (rows - 1) + 0.5
        gx, gy = _bicubic(self.goal_x, u, v), _bicubic(self.goal_y, u, v)
        return (x - gx) / self.pixel[0], (y - gy) / self.pixel[1]

    def __call__(self, h, args=None):
        r, vjp = jax.vjp(self.residual, h)
        (g,) = vjp(tuple(_edge_weighted(c) for c in r))
        coef = jax.scipy.fft.dctn(g, type=2, norm="ortho") / self.symbol
        step = jax.scipy.fft.idctn(coef.at[0, 0].set(0.0), type=2, norm="ortho")
        rms = jnp.sqrt(0.5 * (jnp.mean(r[0] ** 2) + jnp.mean(r[1] ** 2)))
        return h - step, rms


def _edge_weighted(r: jax.Array) -> jax.Array:
    """`r` with its border rows and columns weighted by `_EDGE_WEIGHT` (corners by its
    square), for the fit's step. Under the "extrapolate" boundary an edge vertex sees the
    checkerboards of the edge samples (``h[-1] = 2 h[0] - h[1]``) that the interior
    vertices, and so the DCT symbol, hardly see: the step's largest gain over the
    symbol's is 7.6 unweighted (the fit diverged at 512^2), 1.69 weighted, 1.65 for the
    clamped surface (measured on a 24^2 grid)."""
    rows = jnp.ones(r.shape[0], r.dtype).at[jnp.array([0, -1])].set(_EDGE_WEIGHT)
    cols = jnp.ones(r.shape[1], r.dtype).at[jnp.array([0, -1])].set(_EDGE_WEIGHT)
    return r * rows[:, None] * cols[None, :]


_EDGE_WEIGHT = 0.2


@eqx.filter_jit
def _fit_init(fit, solver, h):
    f_struct, aux_struct = jax.eval_shape(fit, h)
    return solver.init(fit, h, None, {}, f_struct, aux_struct, frozenset())


@eqx.filter_jit
def _fit_step(fit, solver, h, state):
    """One fixed-point step; returns the new heights, state, done, result and the RMS
    misplacement (pixels) of the heights it started from."""
    h_new, state, rms = solver.step(fit, h, None, {}, state, frozenset())
    done, result = solver.terminate(fit, h_new, None, {}, state, frozenset())
    return h_new, state, done, result, rms


def _run_fit(fit, solver, h0, max_steps: int, history: list, callback, info, patience=3):
    """Step the landing fit from Python (a loss after each step, the callback), keeping
    the best heights: the misplacement that the heights cannot follow (the map's curl,
    its jumps across dark regions) stays, and once it stops falling for `patience`
    steps the fit has done what it can. Returns ``(h, steps, result, compile_s,
    seconds, stalled)``."""
    t0 = time.perf_counter()
    state = _fit_init(fit, solver, h0)
    h, best_h, best, worse = h0, h0, np.inf, 0
    result, compile_s, stalled, steps = optx.RESULTS.successful, None, False, 0
    for steps in range(1, max_steps + 1):
        h_new, state, done, result, rms = _fit_step(fit, solver, h, state)
        rms = float(rms)  # the misplacement at `h`
        if compile_s is None:
            compile_s = time.perf_counter() - t0
        history.append(0.5 * rms**2)
        if callback is not None:
            callback({**info, "step": steps, "loss": 0.5 * rms**2, "rms_pixels": rms})
        if rms < best * (1 - 1e-3):
            best, best_h, worse = rms, h, 0
        else:
            worse += 1
        h = h_new
        if bool(done):
            best_h, best = h, rms
            break
        if worse >= patience:
            stalled = True
            break
    else:
        result = optx.RESULTS.max_steps_reached
    return best_h, steps, result, compile_s or 0.0, time.perf_counter() - t0, stalled, best


@eqx.filter_jit
def _landing_jvp(problem: _Problem, sampling, v: jax.Array):
    """How the vertices' landing points ``(x, y)`` move for a change `v` of the flat
    lens's heights (a JVP; jitted: eagerly it costs seconds in per-op compilations)."""

    def landing(h):
        return problem.vertex_rays(h, sampling)[:2]

    return jax.jvp(landing, (jnp.zeros_like(v),), (v,))[1]


def _landing_gain(problem: _Problem, sampling, shape, dx, dy, pixel) -> tuple[float, float]:
    """How far the vertices move on the screen (pixels) per unit slope of the heights,
    along x and y, measured on the flat lens (a JVP along the smoothest cosine mode):
    the weak-lens ``D / pixel``, for any light (a point light's diverging rays, oblique
    incidence) without a formula per case."""
    rows, cols = shape
    y = np.cos(np.pi * (np.arange(rows) + 0.5) / rows)
    x = np.cos(np.pi * (np.arange(cols) + 0.5) / cols)
    gains = []
    for axis, mode in enumerate((np.broadcast_to(x, shape), np.broadcast_to(y[:, None], shape))):
        v = jnp.asarray(mode * 1e-3 * (dx if axis == 0 else dy), pixel.dtype)
        moved = _landing_jvp(problem, sampling, v)[axis]
        slope = _gradient_at_vertices(v, dx, dy)[axis]
        gains.append(float(jnp.sum(moved * slope) / jnp.sum(slope * slope)) / float(pixel[axis]))
    return gains[0], gains[1]


def _transport_goal(
    setup: _Setup, shape, problem: _Problem, keep=None, iterations=None, smooth=False
):
    """The landing points of the photon vertices: the optimal transport from the
    aperture's flux (times `keep` per cell, if given) to the target, on the heights
    grid, in `iterations` (default: the design's); `smooth`: the map smoothed by a
    [1, 2, 1] / 4 kernel along each axis (for a fit that reads it between its samples:
    leaning light). Returns ``(goal_x, goal_y, transport)`` (metres; the
    `TransportMap`)."""

    top = setup.screen_distance + setup.thickness
    source = _source_density(setup.light, setup.aperture, shape, top)
    if keep is not None:
        source = source * keep
    target = _area_average(setup.goal, shape)
    iterations = iterations or setup.transport_iterations
    plan = transport_map(source, target, iterations=iterations, warn=False)
    rows, cols = shape
    h = 1.0 / max(rows, cols)
    sx0, sx1, sy0, sy1 = setup.screen
    gx = sx0 + (sx1 - sx0) * plan.map_x / (cols * h)
    gy = sy0 + (sy1 - sy0) * plan.map_y / (rows * h)
    if smooth:  # the discrete Legendre transforms' one-cell staircase, read between cells
        gx, gy = _binomial_smooth(gx), _binomial_smooth(gy)
    if gx.shape != tuple(problem.grid):  # a photon grid finer than the heights
        gx, gy = (_resample_corners(g, problem.grid) for g in (gx, gy))
    dtype = jnp.result_type(float)
    return jnp.asarray(gx, dtype), jnp.asarray(gy, dtype), plan


def _binomial_smooth(a: np.ndarray) -> np.ndarray:
    """`a` smoothed by [1, 2, 1] / 4 along each axis, edge samples repeated."""
    p = np.pad(a, 1, mode="edge")
    rows = 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:]
    return 0.25 * rows[:, :-2] + 0.5 * rows[:, 1:-1] + 0.25 * rows[:, 2:]


def _resample_corners(values: np.ndarray, shape) -> np.ndarray:
    """Bilinear resampling of a corner grid (edges to edges) to `shape` corners."""
    rows = np.linspace(0, values.shape[0] - 1, shape[0])
    cols = np.linspace(0, values.shape[1] - 1, shape[1])
    first = np.array([np.interp(rows, np.arange(values.shape[0]), c) for c in values.T]).T
    return np.array([np.interp(cols, np.arange(values.shape[1]), r) for r in first])


def _resolved_modes(shape, modes: int) -> np.ndarray:
    """The DCT-II modes of a ``shape`` grid of heights below `modes` half-cycles along
    each axis (the refinement moves these). ``(rows, cols)`` bool."""
    rows, cols = shape
    return (np.arange(rows)[:, None] < modes) & (np.arange(cols)[None, :] < modes)


class _ImageRefine(eqx.Module):
    """The image-space finish of the transport start: ``0.5 |E / mean(E) - T|^2 / |T|^2
    + dark_weight * (flux on dark pixels) / (all flux)``, ``E`` the caustic-triangles
    image of the heights ``h = C^-1/2 u`` (`C` the landing fit's DCT symbol: ``u`` is in
    pixels of displacement, so that L-BFGS sees a well-scaled problem)."""

    scene: LensScene
    goal: jax.Array  # (rows, cols) target at unit mean
    dark: jax.Array  # (rows, cols) bool: the target below 5% of its mean
    root_symbol: jax.Array  # (hrows, hcols)
    resolved: jax.Array  # (hrows, hcols) bool: the DCT modes the refinement moves
    photons: int = eqx.field(static=True)
    window: int = eqx.field(static=True)
    dark_weight: float = eqx.field(static=True)

    def heights(self, u):
        coef = jax.scipy.fft.dctn(u, type=2, norm="ortho") / self.root_symbol
        # the other modes stay as they are (`_refine_in_image` says which and why)
        coef = jnp.where(self.resolved, coef, jax.lax.stop_gradient(coef))
        return jax.scipy.fft.idctn(coef, type=2, norm="ortho")

    def variable(self, h):
        coef = jax.scipy.fft.dctn(h, type=2, norm="ortho") * self.root_symbol
        return jax.scipy.fft.idctn(coef, type=2, norm="ortho")

    def image(self, u):

        h = self.heights(u)
        scene = eqx.tree_at(lambda sc: sc.surface.heights, self.scene, h - jnp.max(h))
        e = caustic_triangles.unchecked(
            scene, photons=self.photons, window=self.window, memory_limit=_REFINE_MEMORY
        ).image
        return e / jnp.mean(e)

    def loss(self, u):
        e = self.image(u)
        misfit = 0.5 * jnp.sum((e - self.goal) ** 2) / jnp.sum(self.goal**2)
        return misfit + self.dark_weight * jnp.sum(jnp.where(self.dark, e, 0.0)) / jnp.sum(e)


# the refinement's caustic-triangles buffers (bytes): one rasteriser batch at 513^2
# photons (2.7 GB peak with the gradient; at the 1 GiB default, two batches and a
# checkpointed scan cost 1.6x the time per step)
_REFINE_MEMORY = 4 << 30


# jitted: eager, the DCTs at 512^2 cost seconds in per-op compilations
@eqx.filter_jit
def _refine_variable(refine: _ImageRefine, h):
    return refine.variable(h)


@eqx.filter_jit
def _refine_heights(refine: _ImageRefine, u):
    return refine.heights(u)


@jax.custom_jvp
def _image_loss(u, refine: _ImageRefine):
    return refine.loss(u)


@_image_loss.defjvp
def _image_loss_jvp(primals, tangents):
    """The gradient by reverse mode where the loss is linearised: L-BFGS linearises it
    and transposes the linearisation inside a `lax.cond` (accept or reject the step),
    which cost 2.3-3.0 s a step against 1.3-1.8 s this way (20-degree light, 513^2
    photons). Tangents of `refine` are not taken."""
    u, refine = primals
    loss, grad = jax.value_and_grad(lambda u: refine.loss(u))(u)
    return loss, jnp.sum(grad * tangents[0])


# the first pass under leaning light (transport iterations, fit steps): enough to know
# the edges' heights, which set the bevel (measured on a silhouette under a point light:
# relative L2 0.055 as after a full first pass, 79 s -> 70 s)
_ROUGH_PASS = (30, 3)


def _edge_bevel(setup: _Setup, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Where the aperture's edges must rise to the top's rest plane, and how much of the
    aperture's light that bevel takes.

    Photons enter the lens through the rest plane of the top face (the reference's
    convention, `trace_lens`); a ray that leans outwards and crosses the rest plane
    within ``ring = -h_edge * tan(lean)`` of an edge lying below it meets the surface
    beyond the aperture, where the surface is flat: that light cannot be steered and
    lands along the screen's edge (measured, a point light 1.5 screen distances above the lens:
    1.2% of the flux on the edge pixels, relative L2 0.133 where it is 0.097 without
    the screen's 3-pixel border). On each edge whose ring is wider than a tenth of a
    cell, the heights rise linearly to 0 over ``k = ceil(ring / cell) + 1`` cells (the
    bevel, steep enough to throw its light off the screen); the transport must leave
    out the band whose rays reach the bevel: at each position along the edge, as far
    in as the ray that meets the bevel's inner end crossed the rest plane.

    Returns ``(weight, keep, k)``: the bevel's weight (``h <- (1 - weight) h``), the
    fraction of each cell's light outside the band (both ``(rows, cols)``) and the
    widest bevel in cells (0: no edge needs one)."""
    rows, cols = h.shape
    h = h - h.max()
    x0, x1, y0, y1 = setup.aperture
    dx, dy = (x1 - x0) / cols, (y1 - y0) / rows
    top = setup.screen_distance + setup.thickness
    xs = x0 + (np.arange(cols) + 0.5) * dx
    ys = y0 + (np.arange(rows) + 0.5) * dy
    j, i = np.arange(cols), np.arange(rows)
    # per edge: the heights inwards from it (index 0 on the edge), its points, the
    # outward axis and sign, the cell, the distance of every sample from it in cells
    sides = [
        (h[:, ::-1], np.c_[np.full(rows, x1), ys], 0, 1.0, dx, (cols - 1 - j)[None, :]),
        (h, np.c_[np.full(rows, x0), ys], 0, -1.0, dx, j[None, :]),
        (h[::-1, :].T, np.c_[xs, np.full(cols, y1)], 1, 1.0, dy, (rows - 1 - i)[:, None]),
        (h.T, np.c_[xs, np.full(cols, y0)], 1, -1.0, dy, i[:, None]),
    ]
    weight = np.zeros_like(h)
    keep = np.ones_like(h)
    widest = 0
    for inwards, points, axis, sign, cell, distance in sides:
        if isinstance(setup.light, DirectionalLight):
            d = np.asarray(setup.light.direction, float)[None, :]
        else:
            d = np.c_[points, np.full(len(points), top)] - np.asarray(setup.light.position, float)
        lean = np.maximum(sign * d[:, axis] / np.abs(d[:, 2]), 0.0)  # outward run per descent
        ring = float(np.max(-inwards[:, 0] * lean))
        if ring <= 0.1 * cell:
            continue
        k = int(np.ceil(ring / cell)) + 1
        most = len(inwards[0]) // 4  # wider, a bevel would take most of the light
        if k > most:
            warnings.warn(
                f"design_lens: light leaning out at an edge meets the surface beyond the "
                f"aperture over {k - 1} cells, more than the bevel's {most}: its light "
                f"lines the screen's edge (a smaller relief, a farther light or a larger "
                f"aperture shrink it)",
                stacklevel=4,
            )
            k = most
        widest = max(widest, k)
        weight = np.maximum(weight, np.clip(1.0 - distance / k, 0.0, 1.0))
        width = k - inwards[:, k] * lean / cell  # in cells, per position along the edge
        width = width[:, None] if axis == 0 else width[None, :]
        keep = np.minimum(keep, np.clip(distance + 1.0 - width, 0.0, 1.0))
    return weight, keep, widest


def _refine_in_image(setup: _Setup, h: np.ndarray, symbol, history, callback):
    """L-BFGS (Optimistix) on the image misfit from the landing fit's heights, when the
    target has dark regions (below 5% of its mean on more than 10% of the screen: there
    the map jumps and the fit's surface spreads light across the gaps); `refine_steps`
    steps, kept only if the misfit fell. Returns ``(heights, report or None)``."""
    if setup.refine_steps == 0:
        return h, None
    dtype = jnp.result_type(float)
    goal = setup.goal / setup.goal.mean()
    n = setup.refine_photons or 4 * max(setup.target_shape) + 1
    # modes the photon grid resolves (finer ones it sees aliased, as coarser ones, and
    # grows into a texture), and at most two per target pixel (finer ones the image does
    # not resolve: measured, all 512 modes of a 128^2 target under 20-degree light gave
    # 1 - SSIM 0.160 against 0.152 with 256)
    modes = min(n - 1, 2 * max(setup.target_shape))
    refine = _ImageRefine(
        _lens_scene(setup, np.asarray(h)),
        jnp.asarray(goal, dtype),
        jnp.asarray(goal < 0.05),
        jnp.asarray(np.sqrt(symbol), dtype),
        jnp.asarray(_resolved_modes(symbol.shape, modes)),
        n,
        4,
        0.3,
    )
    dark_pixels = float(np.mean(goal < 0.05))
    if dark_pixels <= 0.1:  # no large dark regions: few jumps of the map to clean up
        return h, None
    u0 = _refine_variable(refine, jnp.asarray(h, dtype))
    t0 = time.perf_counter()
    # Armijo's classic sufficient decrease (1e-4 of the linear prediction), not
    # Optimistix's 0.1: the caustic of a tiny triangle (a bright dot) is far from linear
    # in its vertices, and a first step that cut the misfit 13% was rejected eight times
    # (measured on the dots at 513^2 photons: 3-7% of the decrease the gradient predicts
    # at every step length from 1 to 0.001)
    solver = eqx.tree_at(
        lambda s: s.search, optx.LBFGS(rtol=1e-6, atol=1e-9), optx.BacktrackingArmijo(slope=1e-4)
    )
    before = len(history)
    info = {"level": 1, "shape": tuple(h.shape), "residuals": 1}
    u, steps, result, compile_s, seconds = _run_level(
        _image_loss, solver, u0, refine, setup.refine_steps, history, callback, info
    )
    losses = history[before:]
    kept = bool(losses) and losses[-1] < losses[0]
    h_new = np.asarray(_refine_heights(refine, u)) if kept else h
    h_new = h_new - h_new.max()
    report = {
        "stage": "image refinement",
        "shape": tuple(h.shape),
        "steps": steps,
        "loss": losses[-1] if losses else float("nan"),
        "loss_per_pixel": losses[-1] if losses else float("nan"),
        "first_loss": losses[0] if losses else float("nan"),
        "kept": kept,
        # a step budget (the fit's misfit polished), not a convergence target
        "result": "budget" if result == optx.RESULTS.max_steps_reached else result,
        "seconds": time.perf_counter() - t0,
        "first_step_seconds": compile_s,
    }
    return h_new, report


def _design_by_transport(setup: _Setup, history: list, callback):
    """The transport start and the landing fit (one level on the heights grid).
    Returns ``(heights, level_reports, result, converged)``."""
    shape = setup.shapes[-1]
    t0 = time.perf_counter()
    u, problem = _level_problem(setup, 0, None)
    # light that leans out at the edges may need a bevel (`_edge_bevel`) and a second
    # transport; the first pass then only has to find the edges' heights: a short one
    leaning = not (isinstance(setup.light, DirectionalLight) and _vertical(setup.light))
    iterations = min(_ROUGH_PASS[0], setup.transport_iterations) if leaning else None
    goal_x, goal_y, plan = _transport_goal(
        setup, shape, problem, iterations=iterations, smooth=leaning
    )
    transport_s = time.perf_counter() - t0
    transport_steps = plan.iterations
    rows, cols = shape
    dx, dy = setup.width / cols, setup.height / rows
    trows, tcols = setup.target_shape
    pixel = np.array(
        [(setup.screen[1] - setup.screen[0]) / tcols, (setup.screen[3] - setup.screen[2]) / trows]
    )
    dtype = jnp.result_type(float)
    pixel_j = jnp.asarray(pixel, dtype)
    sampling = _sampling(shape, setup.aperture, problem.grid, setup.boundary)
    gain = _landing_gain(problem, sampling, shape, dx, dy, pixel_j)
    fit = _LandingFit(
        problem,
        goal_x,
        goal_y,
        jnp.asarray(_fit_symbol(shape, dx, dy, *gain), dtype),
        pixel_j,
        sampling,
    )
    # converged: a step moves no vertex by more than 1/100 of a pixel (weak-lens estimate)
    atol = 0.01 * min(dx / gain[0], dy / gain[1])
    solver = optx.FixedPointIteration(rtol=0.0, atol=atol)
    if setup.initial is not None:
        h0 = jnp.asarray(
            resample_corners(np.asarray(setup.initial, float), shape, setup.boundary), dtype
        )
    else:
        h0 = jnp.zeros(shape, dtype)
    info = {"level": 0, "shape": shape}
    first_steps = min(_ROUGH_PASS[1], setup.max_steps) if leaning else setup.max_steps
    h, steps, result, compile_s, seconds, stalled, rms = _run_fit(
        fit, solver, h0, first_steps, history, callback, info
    )
    h = np.asarray(h)
    if not np.all(np.isfinite(h)):
        raise RuntimeError(f"the landing fit ({shape}) gave heights that are not finite")
    weight, keep, bevel = _edge_bevel(setup, h)
    if leaning:  # in full, without the band that the bevel takes, from these heights
        t1 = time.perf_counter()
        goal_x, goal_y, plan = _transport_goal(setup, shape, problem, keep, smooth=True)
        transport_s += time.perf_counter() - t1
        transport_steps += plan.iterations
        fit = eqx.tree_at(lambda f: (f.goal_x, f.goal_y), fit, (goal_x, goal_y))
        h, more, result, _, more_s, stalled, rms = _run_fit(
            fit, solver, jnp.asarray(h, dtype), setup.max_steps, history, callback, info
        )
        steps, seconds = steps + more, seconds + more_s
        h = np.asarray(h)
        h = (1.0 - weight) * (h - h.max())
    h = h - h.max()
    # the refinement's variable: heights scaled by the fit's symbol without its gain
    # (u ~ slope x samples; measured: with the gain L-BFGS barely moved in 12 steps)
    symbol = _fit_symbol(shape, dx, dy, 1.0, 1.0)
    h, refinement = _refine_in_image(setup, h, symbol, history, callback)
    reports = [
        {
            "stage": "transport",
            "shape": shape,
            "steps": transport_steps,  # both passes' under leaning light
            "loss": float(plan.residual[-1]),
            "result": "converged" if plan.converged else "max_steps_reached",
            "seconds": transport_s,
            "first_step_seconds": float("nan"),
        },
        {
            "stage": "landing fit",
            "shape": shape,
            "steps": steps,
            "loss": 0.5 * rms**2,
            "rms_pixels": rms,
            "loss_per_pixel": 0.5 * rms**2,
            "result": result,
            "stalled": stalled,
            "bevel_cells": bevel,
            "seconds": seconds,
            "first_step_seconds": compile_s,
        },
    ]
    if refinement is not None:
        reports.append(refinement)
    converged = bool(result == optx.RESULTS.successful) or stalled
    return h, reports, result, converged


def fresnel_zones(heights, depth: float) -> np.ndarray:
    """Fold a relief deeper than `depth` into Fresnel zones: the heights modulo `depth`.

    The slopes, which steer the light, are kept everywhere but on the folds, where the
    surface steps down by `depth` (over one sample of the bicubic surface, which sends the
    light falling on the step astray). Returns heights in ``[-depth, 0]`` (metres, the
    same shape)."""
    h = check_real_array(heights, "heights").astype(float)
    if h.size == 0 or not np.all(np.isfinite(h)):
        raise ValueError(f"`heights` must be finite and not empty, got shape {h.shape}")
    depth = _positive(depth, "depth")
    folded = -np.mod(h.max() - h, depth)
    return folded - folded.max()


def _predict_photons(target_shape) -> int:
    """The predicted caustic's photons per side by default: 4 per pixel side."""
    return 4 * max(target_shape) + 1


def default_levels(shape: Sequence[int]) -> tuple[int, ...]:
    """Coarse-to-fine heights grids for a target of `shape`: powers of two from 32 up to
    twice its longer side (at least one level)."""
    top = 2 * max(int(s) for s in shape)
    levels = [32]
    while levels[-1] * 2 <= top:
        levels.append(levels[-1] * 2)
    return tuple(levels)


def _level_target(goal: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The target a level with `shape` heights (and as many photon cells) is solved for.

    Coarser than the target: its area average on the level's grid (a coarse level
    cannot follow finer detail, and point samples of it would be inconsistent). Twice
    as fine or finer: each pixel split into 2 x 2 equal sub-pixels, so that the bilinear
    lookup at the cells' centroids blurs over half a pixel instead of a whole one (the
    pixel average of a bilinear interpolant is the image blurred by (1/8, 3/4, 1/8);
    of the split image, by (1/16, 7/8, 1/16))."""
    rows, cols = shape
    if rows < goal.shape[0] or cols < goal.shape[1]:
        return _area_average(goal, (min(rows, goal.shape[0]), min(cols, goal.shape[1])))
    if rows >= 2 * goal.shape[0] and cols >= 2 * goal.shape[1]:
        return np.kron(goal, np.ones((2, 2)))
    return goal


def _vertical(light: DirectionalLight) -> bool:
    d = np.asarray(light.direction, dtype=float)
    return bool(abs(d[0]) + abs(d[1]) == 0.0)


def _flat_lens(light, aperture, thickness: float, screen_distance: float, ior: float):
    """The flat lens (a parallel slab) in NumPy: where the aperture's corners land on the
    screen, ``(x_min, x_max, y_min, y_max)``, and the flux through the aperture (the
    density `lens_photons` gives, integrated over a 64 x 64 midpoint grid).

    A ray leaves a parallel slab in its incoming direction, shifted by its refracted
    path through the glass; no compilation is needed for this."""
    x0, x1, y0, y1 = aperture
    top = screen_distance + thickness
    n = 64
    xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
    ys = y0 + (np.arange(n) + 0.5) * (y1 - y0) / n
    px, py = np.meshgrid(np.r_[x0, xs, x1], np.r_[y0, ys, y1])
    if isinstance(light, DirectionalLight):
        d = np.asarray(light.direction, float)
        d = np.broadcast_to(d / np.linalg.norm(d), px.shape + (3,))
        density = np.ones_like(px)
    else:
        offset = np.stack([px, py, np.full_like(px, top)], axis=-1) - np.asarray(
            light.position, float
        )
        r2 = np.sum(offset**2, axis=-1)
        d = offset / np.sqrt(r2)[..., None]
        density = float(light.intensity) * np.abs(d[..., 2]) / r2
    cos_in = -d[..., 2]
    if np.any(cos_in <= 0):
        raise ValueError("`light` does not reach the screen through the flat lens")
    eta = 1.0 / ior
    cos_t = np.sqrt(1.0 - eta**2 * (1.0 - cos_in**2))
    inside = eta * d[..., :2]  # the refracted direction's x, y; its z is -cos_t
    lx = px + thickness * inside[..., 0] / cos_t + screen_distance * d[..., 0] / cos_in
    ly = py + thickness * inside[..., 1] / cos_t + screen_distance * d[..., 1] / cos_in
    corners_x = lx[[0, 0, -1, -1], [0, -1, 0, -1]]
    corners_y = ly[[0, 0, -1, -1], [0, -1, 0, -1]]
    extent = np.array([corners_x.min(), corners_x.max(), corners_y.min(), corners_y.max()])
    flux = float(np.mean(density[1:-1, 1:-1]) * (x1 - x0) * (y1 - y0))
    return extent, flux


@jax.jit
def _laplacian(h: jax.Array, dx: float, dy: float) -> jax.Array:
    """The 5-point Laplacian with zero-flux boundaries (the inverse of `_neumann_poisson`
    up to the mean): the water recovery's kernel with edge padding."""
    return _five_point(h, "clamp", 1.0 / dx**2, 1.0 / dy**2)


def resample_corners(h: np.ndarray, shape: tuple[int, int], boundary: str) -> np.ndarray:
    """The bicubic surface of `h` (with `boundary`) at the sample centres of a `shape`
    grid."""
    return np.asarray(_resample_jit(h, (0.0, 1.0, 0.0, 1.0), tuple(shape), boundary))


# one compilation per pair of shapes instead of one per operation
_resample_jit = jax.jit(resample_heights, static_argnums=(1, 2, 3))


def _transport_residual(u, problem: _Problem):
    return problem.transport_residual(u)


# --------------------------------------------------------------------------- solver loop


def _half_squares(u, problem: _Problem):
    """The least-squares loss ``0.5 * sum(residual^2)`` (for the minimisers)."""
    return half_squares(problem.transport_residual(u))


def _make_solver(solver, cg_steps: int, rtol: float):
    """The built solver and the objective it takes (the residual, or its loss)."""
    built = make_solver(solver, rtol=rtol, atol=1e-9, cg_steps=cg_steps, cg_rtol=1e-3, cg_atol=1e-8)
    return built, (_half_squares if is_minimiser(built) else _transport_residual)


class _WithAux(eqx.Module):
    fn: Callable = eqx.field(static=True)

    def __call__(self, y, args):
        return self.fn(y, args), None


@eqx.filter_jit
def _solver_init(fn, solver, y, args):
    wrapped = _WithAux(fn)
    f_struct = jax.eval_shape(fn, y, args)
    return solver.init(wrapped, y, args, {}, f_struct, None, frozenset())


@eqx.filter_jit
def _solver_step(fn, solver, y, state, args):
    """One solver step (module level, so repeated designs of one shape reuse it)."""
    wrapped = _WithAux(fn)
    y, state, _ = solver.step(wrapped, y, args, {}, state, frozenset())
    done, result = solver.terminate(wrapped, y, args, {}, state, frozenset())
    f_info = getattr(state, "f_info", None)
    if isinstance(getattr(f_info, "f", None), jax.Array) and f_info.f.ndim == 0:
        loss = f_info.f  # a quasi-Newton minimiser's loss at `y` (the accepted point)
    else:
        r = fn(y, args)
        if isinstance(r, jax.Array) and r.ndim == 0:  # a minimiser's loss
            loss = r
        else:
            loss = 0.5 * sum(jnp.sum(c**2) for c in jax.tree_util.tree_leaves(r))
    return y, state, done, result, loss


def _run_level(fn, solver, u0, args, max_steps: int, history: list, callback, level_info):
    """Step an Optimistix least-squares solver interactively (loss after each step).

    `fn(u, args)` is the residual; `args` (the problem's arrays) is passed through
    `filter_jit` as an argument, not closed over, so XLA does not constant-fold it."""
    t0 = time.perf_counter()
    state = _solver_init(fn, solver, u0, args)
    y = u0
    result = optx.RESULTS.successful
    compile_s = None
    steps = 0
    for steps in range(1, max_steps + 1):
        y, state, done, result, loss = _solver_step(fn, solver, y, state, args)
        loss = float(loss)
        if compile_s is None:
            compile_s = time.perf_counter() - t0
        history.append(loss)
        if callback is not None:
            callback({**level_info, "step": steps, "loss": loss})
        if bool(done):
            break
    else:
        result = optx.RESULTS.max_steps_reached
    return y, steps, result, compile_s or 0.0, time.perf_counter() - t0


def _solve_level(fn, solver, u0, args, max_steps: int):
    """`_run_level`'s steps as one traceable loop (`jax.lax.while_loop`), for batches of
    designs spread over devices (`design_lens_variants`): the same step, termination test
    and loss as `_solver_step`, ``max_steps`` at most.

    **Returns:** ``(u, steps, result, losses)``; ``losses``: ``(max_steps,)``, the loss
    after each step, NaN after the last."""
    state = _solver_init(fn, solver, u0, args)
    dynamic, static = eqx.partition(state, eqx.is_array)

    def cond(carry):
        _, _, step, done, _, _ = carry
        return jnp.logical_and(jnp.logical_not(done), step < max_steps)

    def body(carry):
        y, dynamic, step, _, _, losses = carry
        y, state, done, result, loss = _solver_step(
            fn, solver, y, eqx.combine(dynamic, static), args
        )
        dynamic = eqx.partition(state, eqx.is_array)[0]
        return y, dynamic, step + 1, done, result, losses.at[step].set(loss)

    losses = jnp.full((max_steps,), jnp.nan, dtype=jnp.result_type(u0))
    carry = (u0, dynamic, jnp.array(0), jnp.array(False), optx.RESULTS.successful, losses)
    y, _, steps, done, result, losses = jax.lax.while_loop(cond, body, carry)
    result = optx.RESULTS.where(done, result, optx.RESULTS.max_steps_reached)
    return y, steps, result, losses


# --------------------------------------------------------------------------- the API


def _renamed_keywords(where: str, screen_distance, throw, throw_errors):
    """``(screen_distance, throw)`` from the keywords before their rename: ``throw=0.5``
    was the screen distance (a number, not a bool) and ``throw_errors`` the raising flag
    now called `throw`, each with a `DeprecationWarning`."""
    if is_distance(throw):
        screen_distance = renamed_keyword(where, "throw", "screen_distance", throw, screen_distance)
        throw = True
    if throw_errors is not None:
        throw = renamed_keyword(where, "throw_errors", "throw", throw_errors, None)
    if screen_distance is None:
        raise ValueError(
            f"{where}: `screen_distance` is required (metres from the lens's bottom face to "
            "the screen)"
        )
    return screen_distance, throw


def design_lens(
    target,
    *,
    width: float,
    height: float,
    thickness: float,
    screen_distance: float | None = None,
    ior: float = 1.5,
    light: DirectionalLight | PointLight | None = None,
    mask=None,
    heights_shape: tuple[int, int] | None = None,
    screen_extent: Sequence[float] | None = None,
    levels: Sequence[int] | None = None,
    max_steps: int = 40,
    solver: SolverLike = "levenberg_marquardt",
    oversample: int = 1,
    floor: float | None = None,
    boundary_weight: float = 1.0,
    regularization: float = 0.01,
    start_scale: float = 0.5,
    cg_steps: int = 30,
    rtol: float = 1e-4,
    predict_photons: int | None = None,
    max_relief: float | None = None,
    throw: bool = True,
    throw_errors: bool | None = None,
    callback: Callable[[dict], None] | None = None,
    initial=None,
    start: Literal["transport", "poisson"] = "transport",
    transport_iterations: int = 100,
    warn_error: float = 0.15,
    refine_steps: int = 8,
    refine_photons: int | None = None,
) -> LensDesign:
    """Design the height-field top surface of a caustic lens whose caustic on a screen
    matches `target`.

    **Arguments** (lengths in metres):

    - `target`: the image to project, ``(rows, cols)`` (an RGB image is turned into
      luminance), non-negative; only its shape matters for the screen's pixel grid and
      its relative brightness (the design is invariant to scaling it).
    - `width`, `height`: the lens aperture (x and y extents), centred on ``x = y = 0``.
    - `thickness`: the blank's thickness, bottom face to the top surface's highest point.
    - `screen_distance`: distance from the bottom face to the screen.
    - `ior`: index of refraction of the glass.
    - `light`: a `DirectionalLight` or a `PointLight`; default: collimated, straight down.
    - `mask`: boolean ``(rows, cols)``: pixels that may receive light; outside it the
      target is dark (up to the `floor`).
    - `heights_shape`: the final heights grid; default: the last level along the longer
      side of the aperture, the other side in proportion.
    - `screen_extent`: ``(x_min, x_max, y_min, y_max)`` of the screen; default: the
      flat lens's footprint (the aperture traced to the screen).
    - `start`: ``"transport"`` (default): the optimal transport from the aperture's flux
      to the target gives every photon's landing point, and the heights are fitted to
      them with the exact optics (one level, see the module docstring; `solver`,
      `floor`, `regularization`, `start_scale`, `boundary_weight`, `cg_steps`, `rtol`
      and `oversample` belong to the other start). ``"poisson"``: the weak-lens Poisson
      start and the irradiance residual solved coarse to fine by `solver` (needs
      light everywhere: a `floor`).
    - `levels`: heights samples along the longer side, coarse to fine; default: powers
      of two from 32 up to twice the target's longer side (heights finer than the
      pixels: a photon cell per half pixel). With the transport start only the last
      entry counts (the heights grid); default: the target's longer side times 4, at
      most 512 (`transport_shape`).
    - `max_steps`: solver steps per level (the landing fit's steps).
    - `solver`: ``"levenberg_marquardt"`` or ``"gauss_newton"`` (least squares, both
      with Lineax `NormalCG`, matrix-free, `cg_steps` iterations at most), a minimiser
      on ``0.5 * sum(residual^2)``: ``"lbfgs"``, ``"bfgs"`` or ``"adam"`` (Optax's,
      through `optimistix.OptaxMinimiser`), or an Optimistix solver object (the same
      names and rules as `recover_surface`: `jaxcaustics.inverse.solvers`);
      the Poisson start's.
    - `transport_iterations`: back-and-forth iterations of the transport at most.
    - `refine_steps`: the transport start's finish, for targets with dark regions
      (below 5% of the mean on more than 10% of the screen: there the map jumps and the
      fitted surface spreads light across the gaps): this many L-BFGS steps on the
      image misfit plus the flux on dark pixels, with the caustic-triangles forward
      model (`refine_photons` photons per side, default 4 per pixel, window 4), moving
      the heights' modes up to two per pixel; kept only if the misfit fell. 0: no
      finish. Measured on the white-lettering target (128 x 128), judged by the
      reference: relative L2 0.049 and 2.6% of the flux on dark pixels after 8 steps
      (0.085 and 3.2% without them, measured in an earlier version).
    - `warn_error`: warn when the predicted caustic's relative L2 error against the
      target exceeds this.
    - `max_relief`: the deepest relief the blank allows (metres), e.g. Mitsuba's
      tutorial bound of +-0.5% of the width; a deeper design is folded into Fresnel
      zones (`fresnel_zones`) after the optimisation. ``None``: no bound.
    - `oversample`: photon cells per heights sample along each axis.
    - `floor`: a uniform irradiance added to the unit-mean target; black regions get
      this much. Default: 0 with the transport start (black stays black), 0.02 with
      the Poisson start (its irradiance equation needs light everywhere).
    - `boundary_weight`: weight of the boundary condition (pixels of misplacement).
    - `regularization`: weight of a curvature prior on the preconditioned variable
      (transport); 0.01 by default. Measured while tuning on the camera benchmark's
      setting (128 x 128): 0.003 gave 0.14 relative L2, 0.01 0.048, 0.02 0.047 (and 0.1,
      with 20 steps per level, 0.065).
    - `start_scale`: the weak-lens start is scaled by this (1: the full weak-lens
      solution, which folds where the target is dark; 0.5 by default).
    - `predict_photons`: photon grid of the predicted caustic (default 4 per pixel side;
      caustic triangles, their window at most 16 pixels).
    - `throw`: raise if a level's solver fails (otherwise the result says so). Before
      the rename, ``throw=<metres>`` was `screen_distance` and `throw_errors` this flag:
      both still work, with a `DeprecationWarning`.
    - `callback`: called after every solver step with a dict (level, shape, step, loss,
      and the number of residuals the loss sums: ``loss / residuals`` is comparable
      between levels; the transport start's loss is already a mean).
    - `initial`: heights (metres, any grid shape) to start the first level from instead
      of the weak-lens Poisson solution (how a run is continued level by level), or
      the landing fit from instead of flat.

    **Returns:** a `LensDesign`. Invalid specifications raise `ValueError` naming the
    argument before any optimisation starts. A design whose predicted error exceeds
    `warn_error`, or whose levels stopped at `max_steps`, is returned with a
    `warnings.warn` that says so and what to change (also in `LensDesign.warnings`).
    """
    t_start = time.perf_counter()
    screen_distance, throw = _renamed_keywords("design_lens", screen_distance, throw, throw_errors)
    throw = check_bool(throw, "throw")
    if callback is not None and not callable(callback):
        raise ValueError(f"`callback` must be callable or None, got {type(callback).__name__}")
    setup = _prepare(
        target,
        width=width,
        height=height,
        thickness=thickness,
        screen_distance=screen_distance,
        ior=ior,
        light=light,
        mask=mask,
        heights_shape=heights_shape,
        screen_extent=screen_extent,
        levels=levels,
        max_steps=max_steps,
        solver=solver,
        oversample=oversample,
        floor=floor,
        boundary_weight=boundary_weight,
        regularization=regularization,
        start_scale=start_scale,
        cg_steps=cg_steps,
        rtol=rtol,
        predict_photons=predict_photons,
        max_relief=max_relief,
        initial=initial,
        start=start,
        transport_iterations=transport_iterations,
        warn_error=warn_error,
        refine_steps=refine_steps,
        refine_photons=refine_photons,
    )
    history: list[float] = []
    if setup.start == "transport":
        h, level_reports, result, _ = _design_by_transport(setup, history, callback)
        return _finish(setup, h, history, level_reports, result, t_start)
    level_reports: list[dict[str, Any]] = []
    result = optx.RESULTS.successful
    sol, objective = _make_solver(setup.solver, setup.cg_steps, setup.rtol)
    h = None
    for k, shape in enumerate(setup.shapes):
        u, problem = _level_problem(setup, k, h)
        info = {"level": k, "shape": shape, "residuals": _residual_count(problem)}
        u, steps, result, compile_s, seconds = _run_level(
            objective, sol, u, problem, setup.max_steps, history, callback, info
        )
        h = _level_heights(problem, u, k, shape, result, throw)
        loss = history[-1] if history else float("nan")
        level_reports.append(
            {
                "stage": "irradiance",
                "shape": shape,
                "steps": steps,
                "loss": loss,
                "loss_per_pixel": loss / _residual_count(problem),
                "result": result,
                "seconds": seconds,
                "first_step_seconds": compile_s,
            }
        )
    assert h is not None
    return _finish(setup, h, history, level_reports, result, t_start)


@dataclasses.dataclass
class _Setup:
    """A checked specification and what every level needs (`_prepare`)."""

    width: float
    height: float
    thickness: float
    screen_distance: float
    ior: float
    light: Any
    target_shape: tuple[int, int]
    shapes: list[tuple[int, int]]
    aperture: np.ndarray
    screen: np.ndarray
    receiver: PlaneReceiver
    goal: np.ndarray
    goal0: np.ndarray
    flux_scale: float
    vertical: bool
    weak: float
    max_steps: int
    solver: SolverLike
    oversample: int
    boundary_weight: float
    regularization: float
    start_scale: float
    cg_steps: int
    rtol: float
    predict_photons: int | None
    max_relief: float | None
    initial: Any
    timings: dict[str, float]
    start: str = "poisson"
    transport_iterations: int = 100
    warn_error: float = 0.15
    refine_steps: int = 8
    refine_photons: int | None = None

    @property
    def boundary(self) -> str:
        """The designed surface's `HeightField` boundary (`LENS_BOUNDARY` says why)."""
        return LENS_BOUNDARY if self.start == "transport" else "clamp"


# bytes per height sample of the finest level (measured: peak memory of one Poisson step,
# 0.83 GB at 256^2 heights and 1.08 GB at 512^2: 1.3 kB a sample), and the fixed part
_BYTES_PER_SAMPLE, _BYTES_FIXED = 1300, 1 << 30


def _physical_memory() -> int | None:
    """This machine's memory in bytes (None where the platform does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _check_design_memory(shape, oversample: int, extra: int, photons: int = 0) -> None:
    """Refuse, before anything is compiled, a design whose estimated memory exceeds
    half of this machine's (it would swap or be killed after minutes of work): the
    (largest) heights grid `shape` times `oversample`^2 photon cells, `extra` bytes,
    and the predicted caustic's grid of `photons`^2 photons (traced at once)."""

    samples = shape[0] * shape[1] * oversample**2
    grid = _BYTES_PER_SAMPLE * samples
    predicted = band_bytes(photons * photons, 1, jnp.result_type(float))
    estimate = _BYTES_FIXED + extra + grid + predicted
    physical = _physical_memory()
    if physical is None or estimate <= 0.5 * physical:
        return
    knobs = "`levels` (or `heights_shape`" + (", `oversample`" if oversample > 1 else "")
    if predicted > grid:
        knobs = "`predict_photons` (by default 4 per pixel side: or the target's size)"
    raise ValueError(
        f"the design needs about {estimate / 2**30:.1f} GiB (heights grid {tuple(shape)}: "
        f"{grid / 2**30:.1f} GiB at {_BYTES_PER_SAMPLE} bytes a sample; the predicted "
        f"caustic's {photons}^2 photons: {predicted / 2**30:.1f} GiB), more than half of "
        f"this machine's {physical / 2**30:.1f} GiB: lower {knobs}"
        + (")" if knobs.startswith("`levels`") else "")
    )


def _residual_count(problem: _Problem) -> int:
    """The number of irradiance residuals of a level (cells, edges, curvature prior):
    the loss divided by it is comparable between levels."""
    rows, cols = problem.grid
    return (rows - 1) * (cols - 1) + 2 * (rows + cols) + int(problem.scene.surface.heights.size)


def _prepare(
    target,
    *,
    width,
    height,
    thickness,
    screen_distance,
    ior,
    light,
    mask,
    heights_shape,
    screen_extent,
    levels,
    max_steps,
    solver,
    oversample,
    floor,
    boundary_weight,
    regularization,
    start_scale,
    cg_steps,
    rtol,
    predict_photons,
    max_relief,
    initial,
    start="poisson",
    transport_iterations=100,
    warn_error=0.15,
    refine_steps=8,
    refine_photons=None,
) -> _Setup:
    """Check a specification (`ValueError` naming the argument) and compute what the
    levels need: the screen, the scaled target, the weak-lens constant, the level shapes."""
    width = _positive(width, "width")
    height = _positive(height, "height")
    thickness = _positive(thickness, "thickness")
    screen_distance = _positive(screen_distance, "screen_distance")
    if isinstance(ior, (list, tuple)):
        raise ValueError("`ior` must be a single number (design one channel at a time)")
    ior = _positive(ior, "ior")
    if ior <= 1.0:
        raise ValueError(f"`ior` must be > 1 for a glass lens in air, got {ior}")
    t = _check_target(target)
    m = check_mask(mask, t.shape)
    if not np.any(t[m] > 0):
        raise ValueError("`target` is zero everywhere inside `mask`: there is no light to place")
    solver = check_solver(solver)
    levels_given = levels is not None
    if levels is None:
        levels = default_levels(t.shape)
    if isinstance(levels, (str, bytes)) or not isinstance(levels, (Sequence, np.ndarray)):
        raise ValueError(f"`levels` must be a sequence of ints, got {levels!r}")
    if len(levels) == 0:
        raise ValueError(f"`levels` must be a non-empty sequence of ints >= 4, got {levels!r}")
    levels = [check_int(n, "levels", 4) for n in levels]
    max_steps = check_int(max_steps, "max_steps", 1)
    oversample = check_int(oversample, "oversample", 1)
    cg_steps = check_int(cg_steps, "cg_steps", 1, MAX_CG_STEPS)
    for name, value in (
        ("regularization", regularization),
        ("start_scale", start_scale),
        ("boundary_weight", boundary_weight),
    ):
        if not (_is_number(value) and math.isfinite(value) and value >= 0):
            raise ValueError(f"`{name}` must be a finite number >= 0, got {value!r}")
    if not (_is_number(rtol) and math.isfinite(rtol) and rtol > 0):
        raise ValueError(f"`rtol` must be a finite number > 0, got {rtol!r}")
    for name, value in (("predict_photons", predict_photons), ("refine_photons", refine_photons)):
        if value is not None:
            check_int(value, name, 2)
    if initial is not None:
        start_heights = np.asarray(initial)
        if start_heights.ndim != 2 or min(start_heights.shape) < 2:
            raise ValueError(f"`initial` must be (rows, cols) heights, got {start_heights.shape}")
        real = np.issubdtype(start_heights.dtype, np.floating) or np.issubdtype(
            start_heights.dtype, np.integer
        )
        if not real:
            raise ValueError(f"`initial` must hold real numbers, got {start_heights.dtype}")
        if not np.all(np.isfinite(start_heights)):
            raise ValueError("`initial` contains NaN or infinite heights")
    if max_relief is not None:
        max_relief = _positive(max_relief, "max_relief")
    if start not in ("transport", "poisson"):
        raise ValueError(f"`start` must be 'transport' or 'poisson', got {start!r}")
    if floor is None:
        floor = 0.0 if start == "transport" else 0.02
    floor = check_number(floor, "floor", low=0.0, high=1.0, high_open=True)
    if start == "poisson" and floor == 0:
        raise ValueError("`floor` must be in (0, 1) with the poisson start, got 0")
    transport_iterations = check_int(
        transport_iterations, "transport_iterations", 1, MAX_ITERATIONS
    )
    warn_error = check_number(warn_error, "warn_error", low=0.0, low_open=True)
    refine_steps = check_int(refine_steps, "refine_steps", 0)
    if start == "transport" and levels_given:
        shapes = [_level_shape(levels[-1], width, height)]
    elif start == "transport":
        shapes = [transport_shape(t.shape, width, height)]
    else:
        shapes = [_level_shape(n, width, height) for n in levels]
    if heights_shape is not None:
        shapes[-1] = check_shape(heights_shape, "heights_shape", 4)
    # the transport start's image refinement adds its rasteriser budget
    extra = _REFINE_MEMORY if start == "transport" else 0
    if screen_extent is not None:
        given_screen = check_real_array(screen_extent, "screen_extent").astype(float)
        ordered = given_screen.shape == (4,) and given_screen[1] > given_screen[0]
        if not (ordered and given_screen[3] > given_screen[2] and np.isfinite(given_screen).all()):
            raise ValueError(
                f"`screen_extent` must be (x_min, x_max, y_min, y_max), got {screen_extent!r}"
            )
    largest = max(shapes, key=lambda s: s[0] * s[1])
    _check_design_memory(largest, oversample, extra, predict_photons or _predict_photons(t.shape))
    if light is None:
        light = DirectionalLight(np.array([0.0, 0.0, -1.0]))
    elif not isinstance(light, (DirectionalLight, PointLight)):
        raise ValueError(
            f"`light` must be a DirectionalLight or a PointLight, got {type(light).__name__}"
        )
    aperture = np.array([-width / 2, width / 2, -height / 2, height / 2])
    dtype = jnp.result_type(float)
    LensScene(  # checks the light against the lens (a point light inside it, ...)
        HeightField(np.zeros((4, 4)), aperture, "clamp"),
        light,
        PlaneReceiver(np.array([-1.0, 1.0, -1.0, 1.0]), t.shape),
        thickness,
        screen_distance,
        ior=ior,
    )
    footprint, flat_flux = _flat_lens(light, aperture, thickness, screen_distance, ior)
    screen = footprint if screen_extent is None else given_screen
    receiver = PlaneReceiver(screen, t.shape)

    # the target: unit mean over the screen, masked, plus the floor, scaled to the flux
    tm = np.where(m, t, 0.0)
    tm = tm / tm.mean()
    goal = (tm + floor) / (1.0 + floor)
    pixel_area = (screen[1] - screen[0]) * (screen[3] - screen[2]) / t.size
    flux_scale = flat_flux / (goal.sum() * pixel_area)

    vertical = isinstance(light, DirectionalLight) and _vertical(light)
    weak = (ior - 1.0) * (screen_distance + thickness / ior)
    if isinstance(light, PointLight):  # a diverging beam: the screen is magnified
        lz = float(np.asarray(light.position)[2])
        weak *= (lz) / max(lz - screen_distance - thickness, 1e-12)

    # ------------------------------------------------------------ initial guess
    t0 = time.perf_counter()
    rows0, cols0 = shapes[0]
    goal0 = _area_average(goal, (rows0, cols0))
    dx0, dy0 = width / cols0, height / rows0
    # the weak-lens estimate of the relief (black regions counted at 1% of the mean)
    u = jnp.asarray(-np.log(np.maximum(goal0, 1e-2)), dtype)
    h0 = np.asarray(_neumann_poisson(u, dx0, dy0)) / weak
    relief0 = float(h0.max() - h0.min())
    if start == "poisson" and relief0 >= thickness:
        raise ValueError(
            f"`thickness` {thickness} m is too thin: the weak-lens estimate of the relief is "
            f"{relief0:.4g} m, so the surface would dip through the bottom face"
        )
    timings = {"initial_guess": time.perf_counter() - t0}

    return _Setup(
        width=width,
        height=height,
        thickness=thickness,
        screen_distance=screen_distance,
        ior=ior,
        light=light,
        target_shape=tuple(t.shape),
        shapes=shapes,
        aperture=aperture,
        screen=screen,
        receiver=receiver,
        goal=goal,
        goal0=goal0,
        flux_scale=flux_scale,
        vertical=vertical,
        weak=weak,
        max_steps=max_steps,
        solver=solver,
        oversample=oversample,
        boundary_weight=float(boundary_weight),
        regularization=float(regularization),
        start_scale=float(start_scale),
        cg_steps=cg_steps,
        rtol=rtol,
        predict_photons=predict_photons,
        max_relief=max_relief,
        initial=initial,
        timings=timings,
        start=start,
        transport_iterations=transport_iterations,
        warn_error=float(warn_error),
        refine_steps=refine_steps,
        refine_photons=refine_photons,
    )


def _lens_scene(setup: _Setup, heights) -> LensScene:
    """The design's lens with `heights` (bicubic over the aperture, `setup.boundary`)."""
    return LensScene(
        HeightField(heights, setup.aperture, setup.boundary),
        setup.light,
        setup.receiver,
        setup.thickness,
        setup.screen_distance,
        ior=setup.ior,
    )


def _level_problem(setup: _Setup, k: int, h: np.ndarray | None) -> tuple[jax.Array, _Problem]:
    """Level `k`'s start (the preconditioned variable ``u``) and its `_Problem`; `h`: the
    previous level's heights (``None`` for the first level)."""
    shape = setup.shapes[k]
    rows, cols = shape
    dx, dy = setup.width / cols, setup.height / rows
    dtype = jnp.result_type(float)
    weak = setup.weak
    if k == 0 and setup.initial is not None:  # continue from given heights
        h_start = resample_corners(np.asarray(setup.initial, float), shape, setup.boundary)
        u = _laplacian(jnp.asarray(h_start), dx, dy) * weak
    elif k == 0 and setup.start == "transport":
        u = jnp.zeros(shape, dtype)  # unused: the landing fit works on the heights
    elif k == 0:
        u = jnp.asarray(-setup.start_scale * np.log(setup.goal0), dtype)
    else:
        # carry the heights to the finer grid, then back to the preconditioned variable
        h_fine = resample_corners(h, shape, setup.boundary)
        u = _laplacian(jnp.asarray(h_fine), dx, dy) * weak
    scene = _lens_scene(setup, np.zeros(shape))
    level_goal = jnp.asarray(_level_target(setup.goal, shape), dtype)
    problem_grid = (setup.oversample * rows + 1, setup.oversample * cols + 1)
    problem = _Problem(
        scene,
        jnp.log(jnp.maximum(level_goal * setup.flux_scale, jnp.finfo(dtype).tiny)),
        jnp.asarray(setup.screen, dtype),
        jnp.asarray(weak, dtype),
        problem_grid,
        setup.boundary_weight,
        setup.regularization,
        3,
        _sampling(shape, setup.aperture, problem_grid, setup.boundary) if setup.vertical else None,
        dx,
        dy,
    )
    return u, problem


def _level_heights(problem: _Problem, u, k: int, shape, result, throw: bool) -> np.ndarray:
    """The heights of a solved level (``max = 0``); raises if the solver failed."""
    h = np.asarray(problem.heights(jnp.asarray(u)))
    h = h - h.max()
    if throw and result not in (
        optx.RESULTS.successful,
        optx.RESULTS.max_steps_reached,
    ):
        raise RuntimeError(f"level {k} ({shape}): the solver failed: {result}")
    if not np.all(np.isfinite(h)):
        raise RuntimeError(f"level {k} ({shape}): the heights are not finite")
    return h


_PREDICT_WINDOW = 16  # pixels: the prediction's largest triangle window


def _finish(setup: _Setup, h, history, level_reports, result, t_start: float) -> LensDesign:
    """Fold the relief if asked, check the blank, predict the caustic: the `LensDesign`."""
    thickness, timings = setup.thickness, dict(setup.timings)
    if setup.max_relief is not None and h.max() - h.min() > setup.max_relief:
        h = fresnel_zones(h, setup.max_relief)
    if thickness + h.min() <= 0.0:
        msg = (
            f"`thickness` {thickness} m is too thin for the design: its relief is "
            f"{h.max() - h.min():.4g} m, so the surface dips through the bottom face"
        )
        raise ValueError(msg)
    final = _lens_scene(setup, h)
    t0 = time.perf_counter()

    n_pred = setup.predict_photons or _predict_photons(setup.target_shape)
    # the window that holds 99.9% of the flux, at most _PREDICT_WINDOW pixels: the few
    # triangles stretched across a dark gap would otherwise size it (32 pixels: 4x the
    # time of 16 for 0.26% of the image, measured on a design for a dozen dots)
    photons = trace_photons(final, (n_pred, n_pred))
    window = min(_PREDICT_WINDOW, triangle_window(photons, final.receiver))
    # drawn from these photons (`caustic_triangles` would trace them again: 4.5 s against
    # 2.5 s at 513^2, compilation included, the same image to 1e-7)
    images, missed = triangles_image(photons, final.receiver, window=window)
    predicted, missed = np.asarray(images[0]), float(missed[0])
    timings["predict"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    target = setup.goal * setup.flux_scale
    error = _relative_l2(predicted, target)
    dark = target < 0.05 * target.mean()
    dark_flux = float(predicted[dark].sum() / max(predicted.sum(), 1e-300))
    notes = _design_warnings(setup, level_reports, error, dark_flux)
    # measured: 0.1% on the dots' design (the 16-pixel window); 11.5% on a 32^2
    # silhouette under a point light, nearly all off the screen (11.5% at a 64-pixel
    # window): the light its bevel throws away
    if missed > 0.01:
        notes.append(
            f"design_lens: {100 * missed:.1f}% of the lens's light is not in the "
            f"prediction: it lands off the screen (an edge bevel under leaning light "
            f"throws some away) or beyond the {window}-pixel triangle window; "
            "`predicted`, `predicted_error` and `dark_flux` leave it out"
        )
    for note in notes:
        warnings.warn(note, stacklevel=3)
    converged = not any(
        bool(r["result"] == optx.RESULTS.max_steps_reached)
        if not isinstance(r["result"], str)
        else r["result"] == "max_steps_reached"
        for r in level_reports
    )
    return LensDesign(
        heights=h,
        scene=final,
        predicted=predicted,
        target=target,
        loss_history=history,
        levels=level_reports,
        result=result,
        timings=timings,
        predicted_error=error,
        dark_flux=dark_flux,
        converged=converged,
        warnings=notes,
    )


def _relative_l2(image: np.ndarray, target: np.ndarray) -> float:
    """``|a - b| / |b|`` of the two images scaled to unit mean."""
    a = image / image.mean() if image.mean() > 0 else image
    b = target / target.mean()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _design_warnings(setup: _Setup, reports, error: float, dark_flux: float) -> list[str]:
    """What a design missed, with what to change (`design_lens` warns each)."""
    notes = []
    for r in reports:
        stopped = (
            r["result"] == "max_steps_reached"
            if isinstance(r["result"], str)
            else bool(r["result"] == optx.RESULTS.max_steps_reached)
        )
        if stopped:
            what = "transport" if r.get("stage") == "transport" else f"level {r['shape']}"
            limit = "transport_iterations" if r.get("stage") == "transport" else "max_steps"
            notes.append(
                f"design_lens: the {what} stopped at {limit}={r['steps']} before converging "
                f"(loss {r['loss']:.3g}); raise `{limit}`"
            )
    if error > setup.warn_error:
        notes.append(
            f"design_lens: the predicted caustic misses the target by {error:.3f} (relative L2, "
            f"above warn_error={setup.warn_error:g}; {100 * dark_flux:.1f}% of the flux on "
            "dark pixels): try more steps, a longer screen distance or a thicker blank (more "
            "relief), "
            "or a softer target (blur its edges, fewer isolated points)"
        )
    return notes


class _LevelSolve(eqx.Module):
    """``(shared, (u0, problem)) -> _solve_level(...)`` for `map_sharded`: a hashable
    callable, so that designs with the same settings reuse the compiled solve."""

    objective: Callable = eqx.field(static=True)
    solver: Any = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)

    def __call__(self, shared, item):
        u0, problem = item
        return _solve_level(self.objective, self.solver, u0, problem, self.max_steps)


def design_lens_variants(
    target,
    *,
    screen_distances: Sequence[float] | None = None,
    devices: Sequence[jax.Device] | int | None = None,
    per_device: Literal["map", "vmap"] | None = None,
    throw: bool = True,
    throws: Sequence[float] | None = None,
    throw_errors: bool | None = None,
    **design_kwargs,
) -> list[LensDesign]:
    """Design one lens per screen distance of `screen_distances` (the same target, blank and light),
    the designs spread over `devices`.

    `design_lens` steps its solver from Python (a loss after every step, a callback, a
    progress report), so it cannot itself run inside a sharded program; here each level's
    solve runs as one traced loop (the same solver steps, `jax.lax.while_loop`) for every
    variant at once, the variants split across the devices by `map_sharded` (each device
    solves its share one after the other with ``jax.lax.map`` on CPU, vectorised on
    GPU/TPU; on several hosts each process solves its own devices' shares and the results
    are gathered on every process). The set-up between levels (resampling, the next
    level's start) and the final predicted caustics run on the host.

    **Arguments:**

    - `target`: as for `design_lens`.
    - `screen_distances`: distances from the bottom face to the screen, metres, one design each.
    - `devices`: ``None`` (all of `jax.devices()`), an int ``n`` (the first ``n``) or a
      sequence of devices.
    - `per_device`: ``"map"`` or ``"vmap"``; see `map_sharded`.
    - `throw`: raise if a variant's solver fails at some level (`throws` and
      `throw_errors`, the names before the rename, still work with a
      `DeprecationWarning`).
    - `**design_kwargs`: the keyword arguments of `design_lens` (``width``, ``height``,
      ``thickness`` required), except ``screen_distance`` and ``callback`` (no per-step calls from
      inside the sharded loop).

    **Returns:** a list of `LensDesign`, one per screen distance, in order; each one's
    ``loss_history`` holds its own steps, its ``levels`` report the steps and final loss
    of each level, and their ``seconds`` the wall time of the level's sharded solve (all
    variants together; ``first_step_seconds`` is NaN). Invalid specifications raise
    `ValueError` before any optimisation starts.
    """

    t_start = time.perf_counter()
    where = "design_lens_variants"
    screen_distances = renamed_keyword(
        where, "throws", "screen_distances", throws, screen_distances
    )
    if throw_errors is not None:
        throw = renamed_keyword(where, "throw_errors", "throw", throw_errors, None)
    if screen_distances is None:
        raise ValueError(f"{where}: `screen_distances` is required (metres, one design each)")
    for name in ("screen_distance", "callback"):
        if name in design_kwargs:
            raise ValueError(
                f"`{name}` is not an argument of design_lens_variants"
                + (
                    " (give `screen_distances`)"
                    if name == "screen_distance"
                    else " (no per-step calls)"
                )
            )
    if isinstance(screen_distances, (str, bytes)) or not isinstance(
        screen_distances, (Sequence, np.ndarray)
    ):
        raise ValueError(
            f"`screen_distances` must be a sequence of numbers, got {screen_distances!r}"
        )
    if len(screen_distances) == 0:
        raise ValueError("`screen_distances` must hold at least one screen distance")
    screen_distances = [
        check_number(t, f"screen_distances[{i}]") for i, t in enumerate(screen_distances)
    ]  # > 0: `_prepare`
    throw = check_bool(throw, "throw")
    # bad `devices` or `per_device` fail before the set-up
    check_per_device(per_device, resolve_devices(devices))
    unknown = set(design_kwargs) - set(inspect.signature(design_lens).parameters)
    if unknown:
        raise ValueError(f"unknown arguments of design_lens: {sorted(unknown)}")
    defaults = {
        k: p.default
        for k, p in inspect.signature(design_lens).parameters.items()
        if p.default is not inspect.Parameter.empty
        and k not in ("throw", "throw_errors", "callback", "screen_distance")
    }
    spec = {**defaults, "start": "poisson", **design_kwargs}
    if spec["start"] != "poisson":
        raise ValueError(
            "design_lens_variants runs the Poisson start's levels (start='poisson'); "
            "design transport-start variants with design_lens, one screen distance at a time"
        )
    for name in ("width", "height", "thickness"):
        if name not in spec:
            raise ValueError(f"`{name}` is required (metres)")
    setups = []
    for i, screen_distance in enumerate(screen_distances):
        try:
            setups.append(_prepare(target, **{**spec, "screen_distance": screen_distance}))
        except ValueError as err:
            raise ValueError(f"screen_distances[{i}] = {screen_distance}: {err}") from err
    first = setups[0]
    sol, objective = _make_solver(first.solver, first.cg_steps, first.rtol)
    max_steps = first.max_steps

    solve = _LevelSolve(objective, sol, max_steps)

    histories: list[list[float]] = [[] for _ in screen_distances]
    reports: list[list[dict[str, Any]]] = [[] for _ in screen_distances]
    results = [optx.RESULTS.successful] * len(screen_distances)
    heights: list[np.ndarray | None] = [None] * len(screen_distances)
    for k, shape in enumerate(first.shapes):
        t0 = time.perf_counter()
        items = [_level_problem(setup, k, h) for setup, h in zip(setups, heights, strict=True)]
        batch = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *items)
        u, steps, result, losses = map_sharded(
            solve, None, batch, devices=devices, per_device=per_device
        )
        seconds = time.perf_counter() - t0
        for i, (_, problem) in enumerate(items):
            n_steps = int(steps[i])
            results[i] = jax.tree.map(lambda x, i=i: jnp.asarray(x[i]), result)
            histories[i].extend(float(v) for v in losses[i, :n_steps])
            try:
                heights[i] = _level_heights(problem, u[i], k, shape, results[i], throw)
            except RuntimeError as err:
                raise RuntimeError(f"screen_distances[{i}] = {screen_distances[i]}: {err}") from err
            reports[i].append(
                {
                    "shape": shape,
                    "steps": n_steps,
                    "loss": histories[i][-1] if histories[i] else float("nan"),
                    "result": results[i],
                    "seconds": seconds,
                    "first_step_seconds": float("nan"),
                }
            )
    return [
        _finish(setup, h, history, report, result, t_start)
        for setup, h, history, report, result in zip(
            setups, heights, histories, reports, results, strict=True
        )
    ]
