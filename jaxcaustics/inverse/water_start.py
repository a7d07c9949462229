"""The transport start of `recover_surface`: a water surface from a caustic without folds.

Three stages on the target's pixel grid: the optimal transport from uniform flux to the
target, a landing fit and an irradiance fit of the exact rays (`RayMap`), the fits by a
preconditioned Gauss-Newton (`gauss_newton`). See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..scene.surface import catmull_rom, pad_heights, sample_grid
from ..trace.optics import refract, refract_components
from .numerics import safe_log_area
from .solvers import half_squares
from .transport import transport_map

# conjugate-gradient iterations per Gauss-Newton step (measured under 30-degree light:
# with 20 the irradiance fit's loss still fell only 20% a step after five steps, at
# 0.79; with 60 it went from 158 to 0.17 in three)
CG_STEPS = 60
PERIODIC_PAD = 0.25  # the wrapped band round a periodic target, a fraction of its side
LOG_FLOOR = 1e-3  # the target's floor (relative to its mean) inside the logarithm


def flat_shift(direction, ior: float, rest_depth: float) -> np.ndarray:
    """``s``: where flat water lands the ray through a rest-plane point, minus that
    point, ``(2,)`` metres."""
    d = np.asarray(direction, float)
    refracted, _ = refract(
        jnp.asarray(d / np.linalg.norm(d)), jnp.array([0.0, 0.0, 1.0]), 1.0 / ior
    )
    t = np.asarray(refracted, float)
    return rest_depth * t[:2] / -t[2]


def corner_displacement(target: np.ndarray, boundary: str, iterations: int):
    """The transport's displacement of the pixel grid's corners, in pixels: for a
    periodic target the ``(rows, cols)`` corners of one period, else the
    ``(rows + 1, cols + 1)`` corners of the box. Returns ``(dx, dy, plan)``."""
    rows, cols = target.shape
    pad = max(4, round(PERIODIC_PAD * max(rows, cols))) if boundary == "periodic" else 0
    density = np.pad(target, pad, mode="wrap") if pad else target
    plan = transport_map(np.ones_like(density), density, iterations=iterations, warn=False)
    h = 1.0 / max(density.shape)
    jj, ii = np.meshgrid(np.arange(density.shape[1] + 1), np.arange(density.shape[0] + 1))
    dx, dy = plan.map_x / h - jj, plan.map_y / h - ii
    keep = (slice(pad, pad + rows), slice(pad, pad + cols)) if pad else (slice(None),) * 2
    dx, dy = dx[keep], dy[keep]
    if pad:  # the band's pull on the box's mean: a period moves as a whole by nothing
        dx, dy = dx - dx.mean(), dy - dy.mean()
    return dx, dy, plan


def at_corners(h: jax.Array, extent, boundary: str):
    """`HeightField`'s surface ``(H, H_x, H_y)`` at the ``(rows + 1, cols + 1)`` corners
    of its cells (every corner is a midpoint between samples, where the Catmull-Rom
    weights are fixed): 4 x 4 stencils of slices of the padded samples, not gathers,
    whose transposes (the gradient) are pads, not scatters (measured at 128^2: 47 ms a
    conjugate-gradient iteration through `height_and_gradient`'s gathers, 5 ms so)."""
    rows, cols = h.shape
    x0, x1, y0, y1 = extent
    w, dw, _ = catmull_rom(jnp.asarray(0.5, h.dtype))
    p = pad_heights(h, boundary)  # taps of corner (i, j): p[i + 1 + a, j + 1 + b]
    value: jax.Array | float
    hx: jax.Array | float
    hy: jax.Array | float
    value = hx = hy = 0.0
    for a in range(4):
        taps = [p[1 + a : 2 + a + rows, 1 + b : 2 + b + cols] for b in range(4)]
        across = sum(w[b] * taps[b] for b in range(4))
        value = value + w[a] * across
        hx = hx + w[a] * sum(dw[b] * taps[b] for b in range(4))
        hy = hy + dw[a] * across
    return value, hx * cols / (x1 - x0), hy * rows / (y1 - y0)


class RayMap(eqx.Module):
    """The exact rays that meet the surface above the corners of the target's pixel
    grid: heights ``(rows, cols)`` (metres, over the receiver's extent) to where those
    rays land on the ground, minus the corners, ``((rows + 1, cols + 1), (rows + 1,
    cols + 1))`` in receiver pixels. A directional light sends the same flux through
    every horizontal area of a height field, so the rays are parametrised by the point
    where they meet the surface: one differentiated surface evaluation per ray, no
    intersection to solve."""

    corner_x: jax.Array  # (rows + 1, cols + 1) metres
    corner_y: jax.Array
    direction: jax.Array  # (3,) unit, travelling down
    rest_depth: jax.Array
    extent: jax.Array
    pixel: jax.Array  # (2,) metres
    eta: float = eqx.field(static=True)  # 1 / ior
    boundary: str = eqx.field(static=True)

    def __call__(self, h):
        height, hx, hy = at_corners(h, self.extent, self.boundary)
        d = tuple(self.direction[k] for k in range(3))
        inv = jax.lax.rsqrt(1.0 + hx * hx + hy * hy)
        t, _, _ = refract_components(d, (-hx * inv, -hy * inv, inv), self.eta)
        s = (self.rest_depth + height) / -t[2]
        return s * t[0] / self.pixel[0], s * t[1] / self.pixel[1], self.flux(hx, hy)

    def flux(self, hx, hy):
        """The light a horizontal area of the surface receives, relative to flat water:
        ``|d . (-H_x, -H_y, 1)| / |d_z|`` (more where the surface faces the light)."""
        d = self.direction
        return 1.0 - (d[0] * hx + d[1] * hy) / d[2]


class Preconditioned(eqx.Module):
    """A residual of the heights, seen as a function of ``u = S h`` (`S`: the square
    root of the flat-water normal operator in the Fourier basis, `root`). The heights'
    mean is held at zero (the rest depth is flat water's): under oblique light a higher
    sea lands its light farther along the light, so a raised and shifted surface casts
    the same caustic, and the fit drifted along that valley (measured under 30-degree
    light, from the true surface: height error 0.5% after one step, 2.3% after six).
    So is the checkerboard (the Nyquist mode of both axes, where both are even): the
    cell corners' slopes do not see it, and it grew without bound (measured at 16^2 on a
    smooth sea: heights 0.76 m of checkerboard, 100x the truth, with the landing points
    fitted to 0.02 pixels)."""

    residual: eqx.Module  # heights -> residual (a pytree of arrays)
    root: jax.Array  # (rows, cols)

    def heights(self, u):
        rows, cols = u.shape
        coef = (jnp.fft.fft2(u) / self.root).at[0, 0].set(0.0)
        if rows % 2 == 0 and cols % 2 == 0:
            coef = coef.at[rows // 2, cols // 2].set(0.0)
        return jnp.real(jnp.fft.ifft2(coef)).astype(u.dtype)

    def variable(self, h):
        return jnp.real(jnp.fft.ifft2(jnp.fft.fft2(h) * self.root)).astype(h.dtype)

    def __call__(self, u):
        return self.residual(self.heights(u))


def _irradiance_residual(dx, dy, flux, log_target, boundary: str):
    """``log E(landed centre) + log(landed area / pixel area) - log(flux)`` per cell of
    the surface ``(rows, cols)``, from the corners' landing displacements `dx`, `dy`
    (pixels) and `flux` (`RayMap`; a cell's flux is the mean of its corners'): zero
    where the surface sends each cell's light onto as much of the target as that light
    makes."""
    rows, cols = log_target.shape
    jj, ii = jnp.meshgrid(jnp.arange(cols + 1.0), jnp.arange(rows + 1.0))
    x, y = jj.astype(dx.dtype) + dx, ii.astype(dy.dtype) + dy  # pixels
    xa, xb, xc, xd = x[:-1, :-1], x[:-1, 1:], x[1:, 1:], x[1:, :-1]
    ya, yb, yc, yd = y[:-1, :-1], y[:-1, 1:], y[1:, 1:], y[1:, :-1]
    area = 0.5 * ((xc - xa) * (yd - yb) - (xd - xb) * (yc - ya))
    cx, cy = 0.25 * (xa + xb + xc + xd), 0.25 * (ya + yb + yc + yd)
    log_e = sample_grid(log_target, cx, cy, boundary)
    log_area = safe_log_area(area, jnp.asarray(1e-3, area.dtype))  # folded cells: finite
    flux = 0.25 * (flux[:-1, :-1] + flux[:-1, 1:] + flux[1:, 1:] + flux[1:, :-1])
    return log_e + log_area - jnp.log(flux)


class StartMisfit(eqx.Module):
    """Both fits' residuals from one trace of the rays, weighted by `weights`: the
    landing misfit (landing points minus the transport's, pixels, ``(rows + 1, cols +
    1)`` twice) and the irradiance misfit (`_irradiance_residual`). One compiled
    Gauss-Newton step serves both fits, the weights telling them apart (measured at
    128^2: two compilations cost 4.4 s and 6.5 s)."""

    rays: RayMap
    goal_x: jax.Array  # (rows + 1, cols + 1) pixels of displacement
    goal_y: jax.Array
    log_target: jax.Array  # (rows, cols) log of the target at unit mean (floored)
    weights: jax.Array  # (2,): the landing fit's, the irradiance fit's

    def __call__(self, h):
        dx, dy, flux = self.rays(h)
        dx, dy, flux = jax.lax.optimization_barrier((dx, dy, flux))  # not re-traced per slice
        irradiance = _irradiance_residual(dx, dy, flux, self.log_target, self.rays.boundary)
        w = self.weights
        return w[0] * (dx - self.goal_x), w[0] * (dy - self.goal_y), w[1] * irradiance


@eqx.filter_jit
def _normal_response(residual, shape, dtype):
    """``J^T J`` at flat water applied to a unit height at sample ``(0, 0)`` (jitted:
    eagerly, its operations cost seconds of compilation one by one)."""
    zero = jnp.zeros(shape, dtype)
    _, lin = jax.linearize(residual, zero)
    return jax.linear_transpose(lin, zero)(lin(zero.at[0, 0].set(1.0)))[0]


@eqx.filter_jit
def _landing_goal(dx, dy, px, py, shift, boundary: str):
    """The transport's displacement read at the shifted corners, plus the shift."""
    goal_x = sample_grid(dx, px, py, boundary) + shift[0]
    return goal_x, sample_grid(dy, px, py, boundary) + shift[1]


def normal_root(residual, shape, dtype, order: int) -> jax.Array:
    """The square root of the normal operator ``J^T J`` of `residual` (a function of the
    heights) at flat water, in the 2-D Fourier basis: ``J^T J`` applied to one sample,
    transformed. `order`: the operator's order in derivatives of the heights (1: where
    rays land, 2: the irradiance). Modes that the cell corners hardly see (near the
    checkerboard) are kept above 5% of ``c L^order`` (``L``: the five-point Laplacian's
    symbol, ``c`` matching the smoothest modes): unseen, they would move without bound
    in the rescaled variable (measured under vertical light at 128^2: 5.1% height
    error with a floor of 1e-6 of the largest, 0.58% with this one, at the same
    misfit). The mean (not seen at all) keeps 1."""
    symbol = np.abs(np.fft.fft2(np.asarray(_normal_response(residual, shape, dtype), float)))
    rows, cols = shape
    ty = 4.0 * np.sin(np.pi * np.fft.fftfreq(rows)) ** 2
    tx = 4.0 * np.sin(np.pi * np.fft.fftfreq(cols)) ** 2
    lap = (ty[:, None] + tx[None, :]) ** order
    scale = 0.5 * (symbol[0, 1] / lap[0, 1] + symbol[1, 0] / lap[1, 0])
    root = np.sqrt(np.maximum(symbol, 0.05 * scale * lap))
    root[0, 0] = 1.0
    return jnp.asarray(root, dtype)


def _vdot(a, b):
    return sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def _axpy(alpha, x, y):
    return jax.tree.map(lambda a, b: alpha * a + b, x, y)


def _least_squares_step(lin, transpose, r, u, steps: int):
    """``argmin |J x + r|`` (`lin`: ``J``, `transpose`: ``J^T``) by `steps` iterations
    of CGLS (conjugate gradients on the normal equations without forming them). Each
    iteration applies ``J^T`` first and ``J`` last, so that the compiled loop holds one
    copy of each and the gradient ``J^T r`` is the first iteration's. The divisions are
    guarded: a zero residual or direction stops the progress, not NaN."""

    def body(_, carry):
        x, res, p, gamma = carry
        (s,) = transpose(res)
        gamma_new = jnp.vdot(s, s)
        beta = jnp.where(gamma > 0, gamma_new / jnp.where(gamma > 0, gamma, 1.0), 0.0)
        p = s + beta * p
        q = lin(p)
        qq = _vdot(q, q)
        alpha = jnp.where(qq > 0, gamma_new / jnp.where(qq > 0, qq, 1.0), 0.0)
        return x + alpha * p, _axpy(-alpha, q, res), p, gamma_new

    minus_r = jax.tree.map(jnp.negative, r)
    zero = jnp.zeros_like(u)
    init = (zero, minus_r, zero, jnp.zeros((), u.dtype))
    return jax.lax.fori_loop(0, steps, body, init)[0]


@eqx.filter_jit
def _gauss_newton_step(problem: Preconditioned, u, cg_steps: int):
    """One Gauss-Newton step with a backtracking line search (the full step, then
    halving, 10 tries). Returns ``(u_new, loss_before, loss_after)``; ``u_new = u`` if
    no try lowered the loss (half the sum of squares)."""
    r, lin = jax.linearize(problem, u)
    step = _least_squares_step(lin, jax.linear_transpose(lin, u), r, u, cg_steps)
    loss = half_squares(r)

    def cond(carry):
        k, _, trial_loss = carry
        return (k < 10) & ~(trial_loss < loss)

    def body(carry):  # one copy of the residual in the compiled search
        k, scale, _ = carry
        scale = jnp.where(k == 0, scale, 0.5 * scale)
        return k + 1, scale, half_squares(problem(u + scale * step))

    init = (jnp.array(0), jnp.asarray(1.0, u.dtype), jnp.asarray(jnp.inf, u.dtype))
    _, scale, trial_loss = jax.lax.while_loop(cond, body, init)
    accepted = trial_loss < loss
    u_new = jnp.where(accepted, u + scale * step, u)
    return u_new, loss, jnp.where(accepted, trial_loss, loss)


def gauss_newton(problem: Preconditioned, h0, steps: int, rtol: float, cg_steps: int, count: int):
    """Gauss-Newton from heights `h0` for at most `steps` steps, stopping when a step
    lowers the loss by less than `rtol` of it; `count`: the residuals that count in the
    reported root mean square (those of nonzero weight). Returns ``(heights, report)``: the report
    holds ``steps``, ``rms`` (the residual's root mean square at the end), ``history``
    (the loss before each step and at the end), ``stalled`` and ``seconds``."""
    t0 = time.perf_counter()
    u = problem.variable(h0)
    history, taken, stalled, after = [], 0, False, None
    for taken in range(1, steps + 1):  # noqa: B007 (the count is reported)
        u, before, after = _gauss_newton_step(problem, u, cg_steps)
        before, after = float(before), float(after)
        history.append(before)
        if not after < before * (1.0 - rtol):
            stalled = True
            break
    history.append(after if after is not None else float(half_squares(problem(u))))
    report = {
        "steps": taken,
        "rms": math.sqrt(2.0 * history[-1] / count),
        "history": history,
        "stalled": stalled,
        "seconds": time.perf_counter() - t0,
    }
    return problem.heights(u), report


def ray_map(extent, shape, direction, rest_depth: float, ior: float, boundary: str) -> RayMap:
    """The `RayMap` of the cell corners of a ``shape`` pixel grid over `extent`."""
    dtype = jnp.result_type(float)
    rows, cols = shape
    x0, x1, y0, y1 = (float(v) for v in extent)
    pixel = np.array([(x1 - x0) / cols, (y1 - y0) / rows])
    jj, ii = np.meshgrid(np.arange(cols + 1), np.arange(rows + 1))
    return RayMap(
        jnp.asarray(x0 + jj * pixel[0], dtype),
        jnp.asarray(y0 + ii * pixel[1], dtype),
        jnp.asarray(np.asarray(direction, float) / np.linalg.norm(direction), dtype),
        jnp.asarray(rest_depth, dtype),
        jnp.asarray([x0, x1, y0, y1], dtype),
        jnp.asarray(pixel, dtype),
        1.0 / ior,
        boundary,
    )


def transport_start(
    target: np.ndarray,
    *,
    extent,
    rest_depth: float,
    direction,
    ior: float,
    boundary: str,
    transport_iterations: int = 100,
    steps: int = 10,
    rtol: float = 0.05,
    cg_steps: int = CG_STEPS,
    initial: np.ndarray | None = None,
):
    """Heights ``target.shape`` (metres, over `extent`, which is also the target's) whose
    caustic is `target` (irradiance relative to flat water, mean about 1), by the three
    stages of the module, each fit at most `steps` Gauss-Newton steps of `cg_steps`
    conjugate-gradient iterations, stopping when a step lowers its loss by less than
    `rtol`. With `initial` (heights ``target.shape``, metres: a warm start, e.g. the
    previous frame of a sequence) only the irradiance fit runs, from `initial`.
    Returns ``(heights, stages)``: NumPy heights and a report per stage (``stage``,
    ``steps``, ``rms``, ``seconds`` and the stage's own entries)."""
    dtype = jnp.result_type(float)
    rows, cols = target.shape
    x0, x1, y0, y1 = (float(v) for v in extent)
    pixel = np.array([(x1 - x0) / cols, (y1 - y0) / rows])
    shift = flat_shift(direction, ior, rest_depth)
    jj, ii = np.meshgrid(np.arange(cols + 1), np.arange(rows + 1))
    rays = ray_map(extent, (rows, cols), direction, rest_depth, ior, boundary)
    stages: list[dict] = []
    fits: tuple[tuple[str, tuple[float, float], int, int], ...]
    fits = (("irradiance fit", (0.0, 1.0), 2, rows * cols),)
    if initial is None:
        t0 = time.perf_counter()
        dx, dy, plan = corner_displacement(target / target.mean(), boundary, transport_iterations)
        stages.append(
            {
                "stage": "transport",
                "steps": plan.iterations,
                "rms": float(plan.residual[-1]),  # relative L1 of the push-forward
                "converged": plan.converged,
                "seconds": time.perf_counter() - t0,
            }
        )
        # the displacement of corner a: the transport's at a + s (pixel coordinates of
        # the corner grid, whose sample (i, j) `_read` puts at (j + 0.5, i + 0.5))
        px = jnp.asarray(jj + shift[0] / pixel[0] + 0.5, dtype)
        py = jnp.asarray(ii + shift[1] / pixel[1] + 0.5, dtype)
        goal_x, goal_y = _landing_goal(
            jnp.asarray(dx, dtype), jnp.asarray(dy, dtype), px, py, shift / pixel, boundary
        )
        # the largest landing displacement asked for (pixels): the two-pass window of
        # the result, without a trace of its own
        # (the two-pass measures landing points from flat water's, hence less the shift)
        flat = shift / pixel
        stages[-1]["reach"] = (
            float(jnp.max(jnp.abs(goal_x - flat[0]))),
            float(jnp.max(jnp.abs(goal_y - flat[1]))),
        )
        h = jnp.zeros((rows, cols), dtype)
        fits = (("landing fit", (1.0, 0.0), 1, 2 * (rows + 1) * (cols + 1)),) + fits
    else:  # no landing goals: the irradiance fit alone
        goal_x = goal_y = jnp.zeros((rows + 1, cols + 1), dtype)
        h = jnp.asarray(initial - np.mean(initial), dtype)
    log_target = np.log(np.maximum(target / target.mean(), LOG_FLOOR))
    flat_log = jnp.zeros((rows, cols), dtype)
    misfit = StartMisfit(rays, goal_x, goal_y, jnp.asarray(log_target, dtype), jnp.ones(2, dtype))
    for name, weights, order, count in fits:
        misfit = eqx.tree_at(lambda m: m.weights, misfit, jnp.asarray(weights, dtype))
        # the operator at flat water, without the target's own variation
        linear = eqx.tree_at(lambda m: m.log_target, misfit, flat_log)
        problem = Preconditioned(misfit, normal_root(linear, (rows, cols), dtype, order))
        h, report = gauss_newton(problem, h, steps, rtol, cg_steps, count)
        stages.append({"stage": name, **report})
    return np.asarray(h), stages
