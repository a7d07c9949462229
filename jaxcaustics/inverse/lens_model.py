"""The element as the design sees it: the exact optics of a height-field lens or mirror
written lean for the solvers (`LensModel`), and the grids it is solved on.

The lens scene (`LensScene`): screen ``z = 0`` (or posed: `ScreenPose`), flat bottom
face at ``z = screen_distance``, top surface ``z = screen_distance + thickness + H(x,
y)``. A photon grid over the aperture (the grid's vertices) is traced exactly: Snell at
the top, the glass down to the bottom face, Snell there, the screen
(`LensModel.landing`, the physics of `lens_photons`). A mirror (`MirrorScene`): the face
``z = H(x, y)``, the reflection, the posed screen (`mirror_photons`). The surface is
read through separable Catmull-Rom weights where the hits are known in advance
(`vertex_sampling`).

Weak-lens relation (collimated light along ``-z``): a photon through the aperture point
``p`` lands near ``p + D grad H(p)`` with ``D = (n - 1) (screen_distance + thickness /
n)``; the continuity equation linearised gives ``D Laplacian(H) = -log(E / mean E)``
(bright target: locally convex lens).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..scene.mirror import MirrorScene
from ..scene.outline import inside_outline
from ..scene.scene import DirectionalLight, LensScene, emission
from ..scene.surface import PAD_LOW, catmull_rom, pad_heights, ray_surface_hit
from ..scene.surface import bilinear as _bilinear
from ..trace.optics import refract_components
from ..trace.photons import corner_grid, reflect_components
from .design_setup import Setup
from .numerics import area_average, neumann_laplacian, neumann_poisson, safe_log_area

# the transport start's surface boundary (`HeightField`): its edge slope continues to the
# rim; "clamp" levels it off over the outermost half sample, whose light then lands near
# the screen's edge (measured on twelve dots at 512^2 heights: the outermost ring of
# cells, 0.8% of the light, put all of it on black). The Poisson start keeps "clamp":
# its edge condition (the aperture's edge lands on the screen's edge) stalled under
# "extrapolate" (measured on a 16^2 blob: relative L2 0.13 against 0.044)
LENS_BOUNDARY = "extrapolate"


class LensModel(eqx.Module):
    """The lens's optics on one grid: everything a residual needs (arrays are leaves;
    shapes static)."""

    scene: LensScene | MirrorScene
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
        return neumann_poisson(u, self.dx, self.dy) / self.weak

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
            density = density * emission(scene.light, d[2])
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
        if isinstance(scene, MirrorScene):  # reflected, onto the screen's (s, t)
            out = reflect_components(d, normal)
            return scene.screen_pose.land((hit_x, hit_y, hit_z), out)[:2]
        inside, _, _ = refract_components(d, normal, 1.0 / scene.ior)
        s = (hit_z - scene.screen_distance) / -jnp.minimum(inside[2], -1e-12)
        bx, by = hit_x + s * inside[0], hit_y + s * inside[1]
        up = (jnp.zeros_like(hx), jnp.zeros_like(hx), jnp.ones_like(hx))
        out, _, _ = refract_components(inside, up, scene.ior)
        if scene.screen_pose is not None:
            bottom = (bx, by, jnp.broadcast_to(scene.screen_distance, bx.shape))
            return scene.screen_pose.land(bottom, out)[:2]
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
        interior = log_e + safe_log_area(area, 1e-3 * cell0) - jnp.log(flux)
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
        prior = self.regularization * self.dx * self.dy * neumann_laplacian(u, self.dx, self.dy)
        return interior, w * edges, prior


def catmull_rom_matrix(n: int, lo: float, hi: float, points: np.ndarray, boundary: str):
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


def vertex_sampling(shape, aperture, grid, boundary: str):
    """Separable weights of the heights' bicubic (with `boundary`) at the photon grid's
    vertices."""
    (rows, cols), (prow, pcol) = shape, grid
    x0, x1, y0, y1 = aperture
    wx, dwx = catmull_rom_matrix(cols, x0, x1, np.linspace(x0, x1, pcol), boundary)
    wy, dwy = catmull_rom_matrix(rows, y0, y1, np.linspace(y0, y1, prow), boundary)
    return tuple(jnp.asarray(a) for a in (wy, dwy, wx, dwx))


def gradient_at_vertices(h: jax.Array, dx: float, dy: float):
    """``G h``: the gradient of cell-centred heights at the cell corners (2 x 2 stencils,
    edge values extended), ``((rows + 1, cols + 1), (rows + 1, cols + 1))``."""
    p = jnp.pad(h, 1, mode="edge")
    gx = ((p[:-1, 1:] + p[1:, 1:]) - (p[:-1, :-1] + p[1:, :-1])) / (2 * dx)
    gy = ((p[1:, :-1] + p[1:, 1:]) - (p[:-1, :-1] + p[:-1, 1:])) / (2 * dy)
    return gx, gy


def fit_symbol(shape, dx, dy, scale_x, scale_y) -> np.ndarray:
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


def level_target(goal: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The target a level with `shape` heights (and as many photon cells) is solved for.

    Coarser than the target: its area average on the level's grid (a coarse level
    cannot follow finer detail, and point samples of it would be inconsistent). Twice
    as fine or finer: each pixel split into 2 x 2 equal sub-pixels, so that the bilinear
    lookup at the cells' centroids blurs over half a pixel instead of a whole one (the
    pixel average of a bilinear interpolant is the image blurred by (1/8, 3/4, 1/8);
    of the split image, by (1/16, 7/8, 1/16))."""
    rows, cols = shape
    if rows < goal.shape[0] or cols < goal.shape[1]:
        return area_average(goal, (min(rows, goal.shape[0]), min(cols, goal.shape[1])))
    if rows >= 2 * goal.shape[0] and cols >= 2 * goal.shape[1]:
        return np.kron(goal, np.ones((2, 2)))
    return goal


def residual_count(problem: LensModel) -> int:
    """The number of irradiance residuals of a level (cells, edges, curvature prior):
    the loss divided by it is comparable between levels."""
    rows, cols = problem.grid
    return (rows - 1) * (cols - 1) + 2 * (rows + cols) + int(problem.scene.surface.heights.size)


def aperture_coverage(outline: str | tuple, aperture, shape, sub: int = 8) -> np.ndarray:
    """The fraction of each cell of a ``shape`` grid over `aperture` that lies inside
    the blank's `outline` (``sub`` x ``sub`` points a cell), ``(rows, cols)``."""
    rows, cols = shape
    if outline == "rectangle":
        return np.ones(shape)
    x0, x1, y0, y1 = (float(v) for v in aperture)
    xs = x0 + (np.arange(cols * sub) + 0.5) * (x1 - x0) / (cols * sub)
    ys = y0 + (np.arange(rows * sub) + 0.5) * (y1 - y0) / (rows * sub)
    u, v = np.meshgrid(xs, ys)
    inside = inside_outline(outline, (x0, x1, y0, y1), u, v).astype(float)
    return inside.reshape(rows, sub, cols, sub).mean(axis=(1, 3))


def level_shape(n: int, width: float, height: float) -> tuple[int, int]:
    """Heights shape with `n` samples along the longer side of the aperture."""
    if width >= height:
        return max(4, round(n * height / width)), n
    return n, max(4, round(n * width / height))


def level_model(
    setup: Setup,
    shape: tuple[int, int],
    oversample: int = 1,
    boundary_weight: float = 1.0,
    regularization: float = 0.01,
) -> LensModel:
    """The flat lens of `setup` on a ``shape`` heights grid with ``oversample`` photon
    cells per sample along each axis, solved for the target on that grid
    (`level_target`)."""
    rows, cols = shape
    dx, dy = setup.width / cols, setup.height / rows
    dtype = jnp.result_type(float)
    level_goal = jnp.asarray(level_target(setup.goal, shape), dtype)
    grid = (oversample * rows + 1, oversample * cols + 1)
    # vertical light: the hits are the grid's vertices, read through fixed weights
    sampling = (
        vertex_sampling(shape, setup.aperture, grid, setup.boundary) if setup.vertical else None
    )
    return LensModel(
        setup.element_scene(np.zeros(shape)),
        jnp.log(jnp.maximum(level_goal * setup.flux_scale, jnp.finfo(dtype).tiny)),
        jnp.asarray(setup.screen, dtype),
        jnp.asarray(setup.weak, dtype),
        grid,
        boundary_weight,
        regularization,
        3,
        sampling,
        dx,
        dy,
    )
