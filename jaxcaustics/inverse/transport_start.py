"""The transport start of lens design (`TransportStart`): the optimal transport from the
aperture's flux to the target says where every photon must land, and the heights are
fitted to those landing points with the exact optics (Optimistix's fixed-point iteration
of a Gauss-Newton step preconditioned in the DCT basis). See the design notes
(``docs/design-notes.md``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._checks import check_bool, check_int, check_number
from .._warnings import warn_user
from ..scene.outline import inside_outline
from ..scene.scene import DirectionalLight
from ..scene.surface import sample_grid
from .design_setup import Setup, has_dark_regions
from .driver import iterate
from .lens_model import (
    LENS_BOUNDARY,
    LensModel,
    aperture_coverage,
    fit_symbol,
    gradient_at_vertices,
    level_model,
    level_shape,
    vertex_sampling,
)
from .numerics import area_average, binomial_smooth, resample_corner_grid, resample_corners
from .screen_geometry import flat_landing
from .transport import MAX_ITERATIONS, transport_map

# the transport grid's longest side, at most. Up to it, four heights samples (and
# transport cells) a target pixel side. Measured on the camera at 256^2 with the grid's
# own Legendre transforms, judged by the exported solid's facets: relative L2 0.041 and
# 1 - SSIM 0.167 at 512^2 heights (two a pixel side: the transforms' one-cell staircase
# is a cross-hatch over the sky), 0.020 and 0.047 at 1024^2. With the smooth transforms
# (`TransportStart.smooth`) at 512^2: 0.038 and 0.097 (the height map 0.030 and 0.033),
# 14 s; at 1024^2: 0.020 and 0.036 (0.019 and 0.021), 32 s
TRANSPORT_MAX = 1024


def transport_shape(target_shape: Sequence[int], width: float, height: float) -> tuple[int, int]:
    """The heights (and transport) grid of the transport start: the target's longer side
    times the largest factor in 1..4 that stays within `TRANSPORT_MAX` samples (at least
    the target's own size), the other side in proportion to the aperture."""
    n = max(int(v) for v in target_shape)
    factor = max(1, min(4, TRANSPORT_MAX // n))
    return level_shape(min(n * factor, max(n, TRANSPORT_MAX)), width, height)


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


def _bicubic(image: jax.Array, px: jax.Array, py: jax.Array) -> jax.Array:
    """`sample_grid` with edge samples extended: the landing goals read at the rest-plane
    crossings of oblique rays, which drift across the cells."""
    return sample_grid(image, px, py, "clamp")


class _LandingFit(eqx.Module):
    """The landing-point fit as a fixed point ``h = h - M^-1 J^T r(h)`` (Optimistix
    `FixedPointIteration`): `r` the misplacement of the photon grid's vertices in
    screen pixels, `J^T r` its exact gradient, `M` the weak-lens normal operator in the
    DCT basis (`fit_symbol`). The auxiliary output is the RMS misplacement (pixels)."""

    problem: LensModel
    goal_x: jax.Array  # (P0, P1) where the rays through the vertices must land, metres
    goal_y: jax.Array
    symbol: jax.Array  # (rows, cols)
    pixel: jax.Array  # (2,) screen pixel size, metres
    sampling: tuple  # bicubic weights at the vertices (`vertex_sampling`)

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
def _landing_jvp(problem: LensModel, sampling, v: jax.Array):
    """How the vertices' landing points ``(x, y)`` move for a change `v` of the flat
    lens's heights (a JVP; jitted: eagerly it costs seconds in per-op compilations)."""

    def landing(h):
        return problem.vertex_rays(h, sampling)[:2]

    return jax.jvp(landing, (jnp.zeros_like(v),), (v,))[1]


def _landing_gain(problem: LensModel, sampling, shape, dx, dy, pixel) -> tuple[float, float]:
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
        slope = gradient_at_vertices(v, dx, dy)[axis]
        gains.append(float(jnp.sum(moved * slope) / jnp.sum(slope * slope)) / float(pixel[axis]))
    return gains[0], gains[1]


def transport_stretch(gain, setup: Setup, shape) -> float:
    """How much the transport's grid is stretched along x (against y) so that the map it
    finds is one the element can make.

    An element moves a vertex's landing point by ``gain`` pixels per unit slope along
    each axis (`_landing_gain`); in the transport's coordinates (the aperture and the
    screen each scaled to the grid) the landing is then the identity plus ``(gx, gy)``
    times the slope, with ``g = gain * side / target pixels`` (``side``: the aperture's
    width or height). That is the gradient of a potential, as the optimal transport's
    map is, only if ``gx = gy``: vertical light (any aspect) has it; leaning light, a
    mirror's screen facing the reflected beam, do not (a mirror under 30 degrees:
    ``gy / gx = cos^2 30``, and its landing fit stalled at 0.37 pixels RMS where vertical
    light reaches 0.01, measured on the camera at 64^2). Transporting between both
    densities stretched by ``sqrt(gy / gx)`` along x makes the map such a gradient (the
    transport's cells that much wider than high). Returns 1 within 1% of it."""
    trows, tcols = setup.target_shape
    gx = abs(gain[0]) * setup.width / tcols
    gy = abs(gain[1]) * setup.height / trows
    stretch = float(np.sqrt(gy / gx))
    return 1.0 if abs(stretch - 1.0) < 0.01 else stretch


def _transport_goal(
    setup: Setup,
    shape,
    problem: LensModel,
    iterations: int,
    keep=None,
    smooth=False,
    stretch: float = 1.0,
    smooth_map: bool = False,
):
    """The landing points of the photon vertices: the optimal transport from the
    aperture's flux (times `keep` per cell, if given) to the target, on the heights
    grid (its cells `stretch` times as wide as high in the transport's cost:
    `transport_stretch`), in `iterations` at most; `smooth`: the map smoothed by a
    [1, 2, 1] / 4 kernel along each axis (for a fit that reads it between its samples:
    leaning light); `smooth_map`: the transport's `smooth` transforms. Returns
    ``(goal_x, goal_y, transport)`` (metres; the `TransportMap`)."""

    dtype = jnp.result_type(float)
    if not setup.vertical:  # on the screen, through the flat element's map
        gx, gy, plan = _screen_goal(setup, shape, problem, iterations, keep, stretch, smooth_map)
        if smooth:
            gx, gy = binomial_smooth(gx), binomial_smooth(gy)
        return jnp.asarray(gx, dtype), jnp.asarray(gy, dtype), plan
    top = setup.top
    source = _source_density(setup.light, setup.aperture, shape, top)
    source = source * aperture_coverage(setup.problem.outline.lens_outline, setup.aperture, shape)
    if keep is not None:
        source = source * keep
    target = area_average(setup.goal, shape)
    # (vertical light: the screen's axes run along the blank's; every other case is
    # transported on the screen, `_screen_goal`)
    sx0, sx1, sy0, sy1 = setup.screen
    plan = transport_map(
        source, target, iterations=iterations, warn=False, stretch=stretch, smooth=smooth_map
    )
    rows, cols = shape
    h = 1.0 / max(rows, cols)
    gx = sx0 + (sx1 - sx0) * plan.map_x / (stretch * cols * h)
    gy = sy0 + (sy1 - sy0) * plan.map_y / (rows * h)
    if smooth:  # the discrete Legendre transforms' one-cell staircase, read between cells
        gx, gy = binomial_smooth(gx), binomial_smooth(gy)
    if gx.shape != tuple(problem.grid):  # a photon grid finer than the heights
        gx, gy = (resample_corner_grid(g, problem.grid) for g in (gx, gy))
    dtype = jnp.result_type(float)
    return jnp.asarray(gx, dtype), jnp.asarray(gy, dtype), plan


def _flat_image(setup: Setup, shape, keep=None, sub: int = 2):
    """The flat element's caustic on the screen, on a ``shape`` grid of its cells: the
    aperture's light (the outline's, times `keep` per heights cell) carried by the flat
    element (`flat_landing`), ``sub x sub`` rays per heights cell splatted bilinearly
    onto the cells' centres."""
    rows, cols = shape
    x0, x1, y0, y1 = setup.aperture
    fx = (np.arange(cols * sub) + 0.5) / sub  # in cells
    fy = (np.arange(rows * sub) + 0.5) / sub
    px, py = np.meshgrid(x0 + fx * (x1 - x0) / cols, y0 + fy * (y1 - y0) / rows)
    s, t, weight = flat_landing(setup.problem, setup.pose, px, py)
    weight = weight * inside_outline(setup.problem.outline.lens_outline, setup.aperture, px, py)
    if keep is not None:
        weight = weight * np.repeat(np.repeat(keep, sub, axis=0), sub, axis=1)
    sx0, sx1, sy0, sy1 = setup.screen
    u = (s - sx0) / (sx1 - sx0) * cols - 0.5  # in cells, 0 at the first centre
    v = (t - sy0) / (sy1 - sy0) * rows - 0.5
    image = np.zeros((rows + 2, cols + 2))  # a ring for the splat's overhang
    j, i = np.floor(u), np.floor(v)
    a, b = u - j, v - i
    j = np.clip(j.astype(int) + 1, 0, cols)
    i = np.clip(i.astype(int) + 1, 0, rows)
    for di, dj, w in (
        (0, 0, (1 - a) * (1 - b)),
        (0, 1, a * (1 - b)),
        (1, 0, (1 - a) * b),
        (1, 1, a * b),
    ):
        # (a bincount: np.add.at took seconds at 2048^2 rays)
        cells = ((i + di) * (cols + 2) + j + dj).ravel()
        image += np.bincount(cells, (weight * w).ravel(), image.size).reshape(image.shape)
    image[1, :] += image[0, :]  # the overhang folded back onto the edge cells
    image[-2, :] += image[-1, :]
    image[:, 1] += image[:, 0]
    image[:, -2] += image[:, -1]
    return image[1:-1, 1:-1]


def _screen_goal(setup: Setup, shape, problem: LensModel, iterations, keep, stretch, smooth_map):
    """The landing points of the photon vertices, by a transport on the screen: from the
    flat element's caustic (`_flat_image`) to the target, both on the screen's grid of
    `shape` cells, composed with the flat element's map (a vertex goes where the
    transport sends its flat landing point). The flat element's own distortions (a
    point light's keystone on a tilted screen, a mirror's reversal, the foreshortening
    of a leaning beam) then stay out of what the heights must make. Returns
    ``(goal_x, goal_y, transport)`` on the photon grid (metres)."""
    source = _flat_image(setup, shape, keep)
    target = area_average(setup.goal, shape)
    plan = transport_map(
        source, target, iterations=iterations, warn=False, stretch=stretch, smooth=smooth_map
    )
    rows, cols = shape
    h = 1.0 / max(rows, cols)
    sx0, sx1, sy0, sy1 = setup.screen
    map_s = sx0 + (sx1 - sx0) * plan.map_x / (stretch * cols * h)  # (rows + 1, cols + 1)
    map_t = sy0 + (sy1 - sy0) * plan.map_y / (rows * h)
    x0, x1, y0, y1 = setup.aperture
    prow, pcol = problem.grid
    vx, vy = np.meshgrid(np.linspace(x0, x1, pcol), np.linspace(y0, y1, prow))
    s, t, _ = flat_landing(setup.problem, setup.pose, vx, vy)
    u = np.clip((s - sx0) / (sx1 - sx0) * cols, 0.0, cols)  # in corner units
    v = np.clip((t - sy0) / (sy1 - sy0) * rows, 0.0, rows)
    return _corner_bilinear(map_s, u, v), _corner_bilinear(map_t, u, v), plan


def _corner_bilinear(grid: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """`grid` ``(rows + 1, cols + 1)`` of corner values read bilinearly at ``(u, v)``
    (corner units)."""
    j = np.clip(np.floor(u).astype(int), 0, grid.shape[1] - 2)
    i = np.clip(np.floor(v).astype(int), 0, grid.shape[0] - 2)
    a, b = u - j, v - i
    return (
        (1 - a) * (1 - b) * grid[i, j]
        + a * (1 - b) * grid[i, j + 1]
        + (1 - a) * b * grid[i + 1, j]
        + a * b * grid[i + 1, j + 1]
    )


# the first pass under leaning light (transport iterations, fit steps): enough to know
# the edges' heights, which set the bevel (measured on a silhouette under a point light:
# relative L2 0.055 as after a full first pass, 79 s -> 70 s)
_ROUGH_PASS = (30, 3)


def _edge_bevel(setup: Setup, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
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
    top = setup.top
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
        if setup.is_mirror:  # no bevel: the ray passes the edge and misses the mirror
            width = -inwards[:, 0] * lean / cell  # the band, in cells
            width = width[:, None] if axis == 0 else width[None, :]
            keep = np.minimum(keep, np.clip(distance + 1.0 - width, 0.0, 1.0))
            widest = max(widest, int(np.ceil(ring / cell)))
            continue
        k = int(np.ceil(ring / cell)) + 1
        most = len(inwards[0]) // 4  # wider, a bevel would take most of the light
        if k > most:
            warn_user(
                f"design: light leaning out at an edge meets the surface beyond the "
                f"aperture over {k - 1} cells, more than the bevel's {most}: its light "
                f"lines the screen's edge (a smaller relief, a farther light or a larger "
                f"aperture shrink it)",
            )
            k = most
        widest = max(widest, k)
        weight = np.maximum(weight, np.clip(1.0 - distance / k, 0.0, 1.0))
        width = k - inwards[:, k] * lean / cell  # in cells, per position along the edge
        width = width[:, None] if axis == 0 else width[None, :]
        keep = np.minimum(keep, np.clip(distance + 1.0 - width, 0.0, 1.0))
    return weight, keep, widest


class TransportStart(eqx.Module):
    """The transport start and its landing fit: one level on the heights grid.

    **Arguments:**

    - `grid`: heights samples along the aperture's longer side (the other side in
      proportion); ``None``: the target's longer side times 4, at most `TRANSPORT_MAX`
      (`transport_shape`).
    - `iterations`: back-and-forth iterations of the transport, at most.
    - `max_steps`: steps of the landing fit, at most (it also stops when a step moves no
      vertex by 1/100 of a pixel, or when its misfit stops falling for three steps).
    - `floor`: a uniform irradiance added to the unit-mean target (black regions get
      this much); 0: black stays black.
    - `oversample`: photon vertices per heights sample along each axis (the map
      resampled bilinearly to them).
    - `corrections`: rounds of target correction after the fit (`prediction.py`: the
      target corrected by the predicted caustic, the transport and fit solved again from
      the heights reached; under leaning light the landing fit cannot match the
      transport's map exactly); ``None``: one for a mirror or a posed screen, none for a
      lens over the ground (where one halves what is left of the error at twice the
      time: ask for it).
    - `smooth`: the transport's map from smooth Legendre transforms (`transport_map`'s
      `smooth`: no one-cell staircase where the map compresses); ``None`` (default):
      for targets without dark regions (`design_setup.has_dark_regions`: photographs),
      where it takes the staircase's cross-hatch out of a design on two cells a target
      pixel side, and not where the map jumps across dark regions (there the
      interpolants bridge the jumps: the silhouette at 512 pixels judged 0.121, not
      0.071).
    """

    grid: int | None = None
    iterations: int = 100
    max_steps: int = 40
    floor: float = 0.0
    oversample: int = 1
    corrections: int | None = None
    smooth: bool | None = None
    # the designed surface's `HeightField` boundary (`LENS_BOUNDARY` says why)
    boundary: ClassVar[str] = LENS_BOUNDARY

    def __init__(
        self,
        grid=None,
        iterations=100,
        max_steps=40,
        floor=0.0,
        oversample=1,
        corrections=None,
        smooth=None,
    ):
        self.grid = None if grid is None else check_int(grid, "grid", 4)
        self.iterations = check_int(iterations, "iterations", 1, MAX_ITERATIONS)
        self.max_steps = check_int(max_steps, "max_steps", 1)
        self.floor = check_number(floor, "floor", low=0.0, high=1.0, high_open=True)
        self.oversample = check_int(oversample, "oversample", 1)
        self.corrections = (
            None if corrections is None else check_int(corrections, "corrections", 0, 8)
        )
        self.smooth = None if smooth is None else check_bool(smooth, "smooth")

    def correction_rounds(self, setup: Setup) -> int:
        """Rounds of target correction for `setup` (`corrections`, or its default)."""
        if self.corrections is not None:
            return self.corrections
        # measured, 128^2 camera under 30-degree light, judged by the reference: a mirror
        # 0.047 -> 0.035 (23 s); a lens with its screen facing the beam 0.048 -> 0.035
        # (20 s -> 39 s); a lens over the ground 0.054 -> 0.038, at twice the time (19 s
        # -> 40 s; before the screen's transport 0.127 in 22 s): there it is asked for
        return 1 if setup.is_mirror or setup.pose is not None else 0

    def shape(self, target_shape: Sequence[int], width: float, height: float):
        """The heights grid for a target of `target_shape` on a `width` x `height`
        aperture."""
        if self.grid is not None:
            return level_shape(self.grid, width, height)
        return transport_shape(target_shape, width, height)

    def solve(self, setup: Setup, history: list, callback):
        """The transport and the landing fit. Returns ``(heights, level_reports,
        result)``: heights ``(rows, cols)`` with ``max = 0`` (metres), a report per stage
        (``"result"``: ``optx.RESULTS``)."""
        shape = setup.shapes[-1]
        t0 = time.perf_counter()
        model = level_model(setup, shape, self.oversample)
        # light that leans out at the edges may need a bevel (`_edge_bevel`) and a second
        # transport; the first pass then only has to find the edges' heights: a short one
        leaning = not setup.vertical
        rows, cols = shape
        dx, dy = setup.width / cols, setup.height / rows
        trows, tcols = setup.target_shape
        sx0, sx1, sy0, sy1 = setup.screen
        dtype = jnp.result_type(float)
        pixel = jnp.asarray([(sx1 - sx0) / tcols, (sy1 - sy0) / trows], dtype)
        sampling = vertex_sampling(shape, setup.aperture, model.grid, setup.boundary)
        gain = _landing_gain(model, sampling, shape, dx, dy, pixel)
        stretch = transport_stretch(gain, setup, shape)
        symbol = jnp.asarray(fit_symbol(shape, dx, dy, *gain), dtype)
        zeros = jnp.zeros(model.grid, dtype)
        fit = _LandingFit(model, zeros, zeros, symbol, pixel, sampling)
        # converged: a step moves no vertex by more than 1/100 of a pixel (weak-lens
        # estimate)
        atol = 0.01 * min(dx / abs(gain[0]), dy / abs(gain[1]))
        solver: optx.FixedPointIteration[Any, Any] = optx.FixedPointIteration(rtol=0.0, atol=atol)
        if setup.initial is not None:
            initial = np.asarray(setup.initial, float)
            h0 = jnp.asarray(resample_corners(initial, shape, setup.boundary), dtype)
        else:
            h0 = jnp.zeros(shape, dtype)
        info = {"level": 0, "shape": shape}
        smooth_map = not has_dark_regions(setup.goal) if self.smooth is None else self.smooth
        transport_s, transport_steps = 0.0, 0
        steps, seconds, compile_s = 0, 0.0, float("nan")
        # a mirror's warm start under leaning light (a target correction's) knows its
        # edges' heights already: no first pass (a lens's heights have their bevel in
        # them: it needs the first pass's unbevelled edges)
        if leaning and setup.is_mirror and setup.initial is not None:
            h = np.asarray(h0)
        else:
            t0 = time.perf_counter()
            rough = min(_ROUGH_PASS[0], self.iterations) if leaning else self.iterations
            goal_x, goal_y, plan = _transport_goal(
                setup, shape, model, rough, smooth=leaning, stretch=stretch,
                smooth_map=smooth_map,
            )  # fmt: skip
            transport_s = time.perf_counter() - t0
            transport_steps = plan.iterations
            fit = eqx.tree_at(lambda f: (f.goal_x, f.goal_y), fit, (goal_x, goal_y))
            first_steps = min(_ROUGH_PASS[1], self.max_steps) if leaning else self.max_steps
            run = iterate(
                fit, solver, h0, None, max_steps=first_steps, history=history,
                callback=callback, info=info, patience=_PATIENCE,
            )  # fmt: skip
            h = np.asarray(run.y)
            if not np.all(np.isfinite(h)):
                raise RuntimeError(f"the landing fit ({shape}) gave heights that are not finite")
            steps, seconds, compile_s = run.steps, run.seconds, run.compile_seconds
        weight, keep, bevel = _edge_bevel(setup, h)
        if leaning:  # in full, without the band that the bevel takes, from these heights
            t1 = time.perf_counter()
            goal_x, goal_y, plan = _transport_goal(
                setup, shape, model, self.iterations, keep, smooth=True, stretch=stretch,
                smooth_map=smooth_map,
            )  # fmt: skip
            transport_s += time.perf_counter() - t1
            transport_steps += plan.iterations
            fit = eqx.tree_at(lambda f: (f.goal_x, f.goal_y), fit, (goal_x, goal_y))
            run = iterate(
                fit, solver, jnp.asarray(h, dtype), None, max_steps=self.max_steps,
                history=history, callback=callback, info=info, patience=_PATIENCE,
            )  # fmt: skip
            steps, seconds = steps + run.steps, seconds + run.seconds
            if np.isnan(compile_s):
                compile_s = run.compile_seconds
            h = np.asarray(run.y)
            h = (1.0 - weight) * (h - h.max())
        h = h - h.max()
        rms = run.misfit
        reports = [
            {
                "stage": "transport",
                "shape": shape,
                "steps": transport_steps,  # both passes' under leaning light
                "levels": plan.levels,  # the multiscale levels' (shape, steps, misfit)
                "smooth": smooth_map,  # the smooth Legendre transforms
                "loss": float(plan.residual[-1]),
                "result": (
                    optx.RESULTS.successful if plan.converged else optx.RESULTS.max_steps_reached
                ),
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
                "result": run.result,  # stalled: it has done what it can
                "stalled": run.stalled,
                "bevel_cells": bevel,
                "stretch": stretch,
                "seconds": seconds,
                "first_step_seconds": compile_s,
            },
        ]
        return h, reports, run.result


# steps without a 0.1% fall of the landing fit's misfit that end it (`iterate`)
_PATIENCE = 3
