"""Finding a bundle of rays for the spot-light fit (`fit.py`, Liu et al. 2008, Sect. 3.1,
steps 1-3): the rasterisation of the ray lines into a grid (`rasterise_lines`, paper Fig. 7),
the first axis from the rays through the cell of most energy (`initial_axis`) and its
refinement by ray assignment and least squares (`refine_axis`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..._checks import check_array, check_int
from ...scene.scene import is_concrete
from .fit_common import MAX_LOOP, _check_float, _floats, _line_box, _line_distance
from .ray_set import RaySet

BOX_HALF_WIDTH = 2.0
"""The rasterisation box is ``centre +- BOX_HALF_WIDTH x size`` (paper: "an extended
bounding volume"): four object sizes wide, so the focal regions of ordinary refractors
(a glass ball focuses about half a radius behind itself) lie inside it."""

AXIS_RIDGE = 1e-6
"""Relative ridge that pins the along-axis coordinate of the least-squares axis point
for (nearly) parallel bundles, whose lines have no nearest point."""


def _box(rays: RaySet):
    """Lower corner ``(3,)`` and side ``()`` of the rasterisation box, metres."""
    half = BOX_HALF_WIDTH * rays.size
    return rays.centre - half, 2 * half


# ---------------------------------------------------------------------------------------
# 1. Rasterisation (paper Fig. 7)


def rasterise_lines(origin, direction, energy, box_lo, box_side, cells: int):
    """Energy of the ray lines through each cell of a ``cells^3`` grid.

    Each ray's whole line (extended both ways) adds the ray's energy once to every cell
    it passes through, found by an exact 3-D DDA (Amanatides & Woo 1987): the line enters
    the box, then steps into the neighbouring cell across whichever cell face it meets
    first, at most ``3 cells`` times. Exact up to rounding where the line passes within
    rounding distance of a cell edge (it may then touch one extra cell, or miss one, with
    a path of length ~0).

    - `origin`, `direction`: ``(R, 3)`` rays, metres (directions need not be unit).
    - `energy`: ``(R,)`` energy per ray (0: the ray adds nothing).
    - `box_lo`: ``(3,)`` lower corner of the box, metres; `box_side`: ``()`` its side.
    - `cells`: static, cells per side.

    **Returns** ``(cells, cells, cells)`` energy per cell, indexed ``[ix, iy, iz]``.
    """
    origin, direction, energy, box_lo, box_side = _floats(
        origin, direction, energy, box_lo, box_side
    )
    n = cells
    h = box_side / n
    t0, t1 = _line_box(origin, direction, box_lo, box_lo + box_side)
    hits = t0 < t1
    entry = origin + jnp.where(hits, t0, 0.0)[:, None] * direction
    idx = jnp.clip(jnp.floor((entry - box_lo) / h), 0, n - 1).astype(jnp.int32)
    moving = direction != 0
    safe = jnp.where(moving, direction, 1.0)
    step = jnp.where(direction > 0, 1, -1).astype(jnp.int32)
    bound = box_lo + (idx + (step > 0)) * h
    t_next = jnp.where(moving, (bound - origin) / safe, jnp.inf)
    t_delta = jnp.where(moving, h / jnp.abs(safe), jnp.inf)
    axes = jnp.arange(3)

    def body(_, state):
        grid, idx, t_next, t_cell = state
        inside = jnp.all((idx >= 0) & (idx < n), axis=-1) & hits & (t_cell < t1)
        flat = (idx[:, 0] * n + idx[:, 1]) * n + idx[:, 2]
        grid = grid.at[jnp.where(inside, flat, n**3)].add(
            jnp.where(inside, energy, 0.0), mode="drop"
        )
        cross = jnp.argmin(t_next, axis=-1)
        onehot = axes == cross[:, None]
        t_cell = jnp.min(t_next, axis=-1)
        return (
            grid,
            idx + jnp.where(onehot, step, 0),
            t_next + jnp.where(onehot, t_delta, 0),
            t_cell,
        )

    grid = jnp.zeros(n**3, energy.dtype)
    grid, *_ = jax.lax.fori_loop(0, 3 * n, body, (grid, idx, t_next, jnp.where(hits, t0, 0.0)))
    return grid.reshape(n, n, n)


def lines_through_cell(origin, direction, box_lo, box_side, cells: int, index):
    """``(R,)`` bool: which ray lines pass through cell `index` (``(3,)`` ints
    ``[ix, iy, iz]``) of the grid of `rasterise_lines` (a slab test on the cell)."""
    origin, direction, box_lo, box_side = _floats(origin, direction, box_lo, box_side)
    h = box_side / cells
    lo = box_lo + index * h
    t0, t1 = _line_box(origin, direction, lo, lo + h)
    return t0 < t1


# ---------------------------------------------------------------------------------------
# 2-3. Bundle axis


def _mean_axis(origin, direction, weight):
    """Weighted mean origin ``(3,)``, unit mean direction ``(3,)`` and whether both are
    defined (positive total weight, non-vanishing mean direction)."""
    total = jnp.sum(weight)
    mean_o = (weight @ origin) / jnp.where(total > 0, total, 1.0)
    s = weight @ direction
    norm = jnp.linalg.norm(s)
    ok = (total > 0) & (norm > 1e-6 * total)
    return mean_o, s / jnp.where(ok, norm, 1.0), ok


def initial_axis(origin, direction, weight, fallback_point, fallback_direction):
    """The first bundle axis (paper step 2): the `weight`-ed mean origin and normalised
    mean direction of the rays ``(R, 3)``; `weight` ``(R,)`` is their energy, 0 for rays
    not through the maximum cell. Falls back to the given ``(3,)`` point and unit
    direction where the weights vanish. **Returns** ``(point (3,), direction (3,))``."""
    mean_o, mean_d, ok = _mean_axis(origin, direction, weight)
    return jnp.where(ok, mean_o, fallback_point), jnp.where(ok, mean_d, fallback_direction)


def estimate_axis(origin, direction, weight, point, axis):
    """Least-squares bundle axis of weighted rays (paper step 4).

    Direction: the unit vector ``a`` nearest in the weighted least-squares sense to the
    ray directions, ``a = unit(sum w d)``. Location: the point ``x`` minimising the
    weighted sum of squared distances to the ray lines,
    ``sum w |(I - d d^T)(x - q)|^2``, plus ``AXIS_RIDGE sum w ((x - m) . a)^2`` which
    pins the along-axis coordinate of ``x`` where the lines are (nearly) parallel (``m``:
    the weighted mean origin; the ridge does not act across the axis). The axis origin
    is then the foot of ``m`` on the line through ``x`` along ``a``.

    - `origin`, `direction`: ``(R, 3)``; `weight`: ``(R,)`` (0: not in the bundle).
    - `point`, `axis`: ``(3,)`` the current axis, returned where the weights vanish.

    **Returns** ``(point (3,), axis (3,))``.
    """
    mean_o, a, ok = _mean_axis(origin, direction, weight)
    total = jnp.sum(weight)
    eye = jnp.eye(3, dtype=origin.dtype)
    wd = weight[:, None] * direction
    s = total * eye - wd.T @ direction
    rhs = weight @ origin - wd.T @ jnp.sum(direction * origin, axis=-1)
    ridge = AXIS_RIDGE * jnp.where(total > 0, total, 1.0) * jnp.outer(a, a)
    x = jnp.linalg.solve(s + ridge, rhs + ridge @ mean_o)
    foot = x + ((mean_o - x) @ a) * a
    ok = ok & jnp.all(jnp.isfinite(foot))
    return jnp.where(ok, foot, point), jnp.where(ok, a, axis)


def assign_rays(origin, direction, energy, axis_point, axis_direction, *, distance, cos_angle):
    """``(R,)`` bool: rays with energy > 0 whose line lies within `distance` (metres) of
    the axis line and whose direction makes an angle with the axis whose cosine is at
    least `cos_angle` (paper step 3)."""
    near = _line_distance(origin, direction, axis_point, axis_direction) <= distance
    return near & (direction @ axis_direction >= cos_angle) & (energy > 0)


def _refine_axis(origin, direction, energy, point, axis, distance, cos_angle, iterations):
    """`refine_axis` that also returns the number of iterations it ran."""

    def assign(p, a):
        return assign_rays(origin, direction, energy, p, a, distance=distance, cos_angle=cos_angle)

    def cond(state):
        it, _, _, _, done = state
        return (it < iterations) & ~done

    def body(state):
        it, p, a, member, _ = state
        p, a = estimate_axis(origin, direction, jnp.where(member, energy, 0.0), p, a)
        new = assign(p, a)
        return it + 1, p, a, new, jnp.all(new == member)

    state = (jnp.array(0, jnp.int32), point, axis, assign(point, axis), jnp.array(False))
    it, point, axis, member, _ = jax.lax.while_loop(cond, body, state)
    return point, axis, member, it


def check_refine_knobs(distance_threshold, angle_threshold_deg, iterations) -> tuple:
    """The knobs of `refine_axis`, checked (a traced threshold passes unchecked)."""
    return (
        _check_float(distance_threshold, "distance_threshold", low=0.0),
        _check_float(angle_threshold_deg, "angle_threshold_deg", low=0.0, high=180.0, closed=True),
        check_int(iterations, "iterations", 1, MAX_LOOP),
    )


def refine_axis(
    origin,
    direction,
    energy,
    axis_point,
    axis_direction,
    *,
    distance_threshold,
    angle_threshold_deg,
    iterations: int,
):
    """Iterate ray assignment and least-squares axis estimation (paper steps 3-5).

    Each iteration assigns the rays with energy > 0 whose line lies within
    `distance_threshold` of the axis line and whose direction is within
    `angle_threshold_deg` of the axis (`assign_rays`), then re-estimates the axis from
    them (`estimate_axis`, energy-weighted). It stops when an iteration leaves the
    assignment unchanged (the axis is then a fixed point) or after `iterations`.

    - `origin`, `direction`: ``(R, 3)`` rays (metres; unit directions).
    - `energy`: ``(R,)`` their energy (>= 0); rays with 0 are never assigned.
    - `axis_point`, `axis_direction`: ``(3,)`` the starting axis (unit direction).
    - `distance_threshold`: metres (> 0); `angle_threshold_deg`: degrees, in ``(0, 180]``;
      `iterations`: static int >= 1.

    **Returns** ``(axis_point (3,), axis_direction (3,), member_mask (R,) bool)``: the
    final axis and the rays assigned to it.
    """
    origin = check_array(origin, "origin", (None, 3))
    r = origin.shape[0]
    direction = check_array(direction, "direction", (r, 3))
    energy = check_array(energy, "energy", (r,))
    axis_point = check_array(axis_point, "axis_point", (3,))
    axis_direction = check_array(axis_direction, "axis_direction", (3,))
    if is_concrete(energy) and np.any(np.asarray(energy) < 0):
        raise ValueError("`energy` must be >= 0")
    if is_concrete(axis_direction) and not np.any(np.asarray(axis_direction)):
        raise ValueError("`axis_direction` must be a non-zero (unit) vector")
    distance_threshold, angle_threshold_deg, iterations = check_refine_knobs(
        distance_threshold, angle_threshold_deg, iterations
    )
    origin, direction, energy, axis_point, axis_direction = _floats(
        origin, direction, energy, axis_point, axis_direction
    )
    cos_angle = jnp.cos(jnp.deg2rad(jnp.asarray(angle_threshold_deg, origin.dtype)))
    point, axis, member, _ = _refine_axis(
        origin, direction, energy, axis_point, axis_direction,
        distance_threshold, cos_angle, iterations,
    )  # fmt: skip
    return point, axis, member
