"""Refining a water surface where its caustic folds: the exact rays, splatted, fitted.

The transport start (`water_start`) assumes that every surface cell lands on its own
part of the floor. Where rays cross (a fold: the bright networks of a real pool) that
fails, and its irradiance fit cannot follow. This fit compares images instead: the
rays of `water_start.RayMap` (the exact rays through the bicubic surface above the
cell corners) carry each cell's light onto the floor, where the two triangles of the
cell's landed quadrilateral deposit it with exact pixel overlaps
(`reconstruct.raster.rasterize_exact`, the caustic-triangles rasteriser: a folded triangle keeps
its flux over its absolute area, overlapping cells add). The residual is the
difference of that image and the target, both blurred by a Gaussian of ``sigma``
pixels; a schedule of decreasing ``sigma`` (coarse to fine in the image) fits the
broad light first, where the misfit is smooth in the heights, then the sharp lines.
Each level is Gauss-Newton (`water_start.gauss_newton`, preconditioned by the
flat-water normal operator of the level's own residual).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..methods.triangles.method import grid_triangles
from ..reconstruct.raster import rasterize_exact, window_for
from .camera import camera_blur
from .water_start import (
    Preconditioned,
    RayMap,
    flat_shift,
    gauss_newton,
    normal_root,
    ray_map,
)

FOLD_BLURS = (2.0, 1.0, 0.5)  # the schedule's Gaussian widths, target pixels
# Gauss-Newton steps per level and conjugate-gradient iterations per step. Measured on
# a 32^2 reference caustic folded 8x (peak 11x the mean, 30-degree light): 5 steps of
# 30 gave heights 4.0% off and the caustic 0.6% (54 s); 10 steps of 60 gave 4.2% and
# 0.7% (66 s); the start alone 8.8% and 3.2%
FOLD_STEPS = 5
FOLD_CG_STEPS = 30
WINDOW_MARGIN = 2  # pixels added to the start's largest landed triangle


class SplatMisfit(eqx.Module):
    """``blur(image of the rays) - blur(target)`` per pixel ``(rows, cols)`` (target at
    unit mean), for heights ``(rows, cols)``; `blur` is `camera.camera_blur` of width
    ``sqrt(camera^2 + sigma^2)`` on the model and `sigma` on the target."""

    rays: RayMap
    target: jax.Array  # (rows, cols), already blurred by `sigma`
    shift: tuple[int, int] = eqx.field(static=True)  # whole pixels of the flat shift,
    # taken off the landing points and rolled back onto the image
    model_blur: float = eqx.field(static=True)
    window: int = eqx.field(static=True)
    pad: int = eqx.field(static=True)

    def image(self, h):
        """The rays' caustic (irradiance relative to flat water) on the target's
        pixels: periodic floors wrap what lands outside, clamped ones lose it."""
        rows, cols = h.shape
        dx, dy, flux = self.rays(h)
        jj, ii = jnp.meshgrid(jnp.arange(cols + 1.0), jnp.arange(rows + 1.0))
        x = jj.astype(dx.dtype) + dx - self.shift[0] + self.pad
        y = ii.astype(dy.dtype) + dy - self.shift[1] + self.pad
        vertices = grid_triangles(jnp.stack([x, y], -1)[None])[0]  # (T, 3, 2)
        cell = 0.25 * (flux[:-1, :-1] + flux[:-1, 1:] + flux[1:, 1:] + flux[1:, :-1])
        tri_flux = jnp.repeat(0.5 * cell.reshape(-1), 2)  # (a, b, d), (a, d, c) per cell
        canvas = (rows + 2 * self.pad, cols + 2 * self.pad)
        valid = jnp.ones(tri_flux.shape, bool)
        image = rasterize_exact(vertices, tri_flux, valid, canvas, self.window)
        if self.rays.boundary == "periodic":
            image = _fold_periodic(image, rows, cols, self.pad)
            return jnp.roll(image, (self.shift[1], self.shift[0]), (0, 1))
        return image[self.pad : self.pad + rows, self.pad : self.pad + cols]

    def __call__(self, h):
        blurred = camera_blur(self.image(h), self.model_blur, self.rays.boundary)
        return (blurred - self.target,)


def _fold_periodic(canvas, rows: int, cols: int, pad: int):
    """A padded canvas summed onto one period (every pad cell onto its wrapped pixel)."""
    out = jnp.zeros((rows, cols), canvas.dtype)
    height, width = canvas.shape
    for r0 in range(0, height, rows):
        for c0 in range(0, width, cols):
            block = canvas[r0 : r0 + rows, c0 : c0 + cols]
            block = jnp.pad(block, ((0, rows - block.shape[0]), (0, cols - block.shape[1])))
            out = out + jnp.roll(block, (r0 - pad, c0 - pad), (0, 1))
    return out


def refine_folds(
    target: np.ndarray,
    heights: np.ndarray,
    *,
    extent,
    rest_depth: float,
    direction,
    ior: float,
    boundary: str,
    camera_blur_px: float = 0.0,
    blurs=FOLD_BLURS,
    steps: int = FOLD_STEPS,
    rtol: float = 0.01,
    cg_steps: int = FOLD_CG_STEPS,
):
    """Heights (``target.shape``, metres, over `extent`, also the target's) refined
    from `heights` so that their rays' image, seen through a camera blur of
    `camera_blur_px` pixels, matches `target` (unit mean), at each width of `blurs` in
    turn: at most `steps` Gauss-Newton steps a level, stopping when a step lowers the
    misfit by less than `rtol` of it. Returns
    ``(heights, stages)``: a report per level (``stage``, ``steps``, ``rms``: the RMS
    of the blurred image misfit, ``seconds``, ``window``)."""
    dtype = jnp.result_type(float)
    rows, cols = target.shape
    h = jnp.asarray(heights, dtype)
    rays = ray_map(extent, (rows, cols), direction, rest_depth, ior, boundary)
    pixel = np.array([(extent[1] - extent[0]) / cols, (extent[3] - extent[2]) / rows])
    shift = np.round(flat_shift(direction, ior, rest_depth) / pixel)
    dx, dy, _ = rays(h)
    jj, ii = np.meshgrid(np.arange(cols + 1.0), np.arange(rows + 1.0))
    x = jj + np.asarray(dx) - shift[0]
    y = ii + np.asarray(dy) - shift[1]
    vertices = np.asarray(grid_triangles(jnp.asarray(np.stack([x, y], -1))[None])[0])
    window = window_for(vertices, np.ones(len(vertices), bool)) + WINDOW_MARGIN
    reach = float(np.max(np.abs(np.stack([x - jj, y - ii]))))
    pad = int(math.ceil(reach)) + window
    stages = []
    for sigma in blurs:
        goal = camera_blur(jnp.asarray(target, dtype), float(sigma), rays.boundary)
        misfit = SplatMisfit(
            rays,
            goal,
            (int(shift[0]), int(shift[1])),
            math.hypot(camera_blur_px, sigma),
            window,
            pad,
        )
        flat = eqx.tree_at(lambda m: m.target, misfit, jnp.ones_like(goal))
        problem = Preconditioned(misfit, normal_root(flat, (rows, cols), dtype, 2))
        h, report = gauss_newton(problem, h, steps, rtol, cg_steps, rows * cols)
        stages.append({"stage": f"fold fit (blur {sigma:g} px)", "window": window, **report})
    return np.asarray(h), stages
