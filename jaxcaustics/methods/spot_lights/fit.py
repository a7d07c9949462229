"""Fitting caustic spot lights to traced rays (Liu, Dong, Bao & Peng 2008, Section 3.1).

The rays leaving a caustic object (origin ``q``, unit direction ``d``, energy) are sorted
into bundles, and each bundle becomes one `SpotLights` slot:

1. `rasterise_lines`: every remaining ray adds its energy once to each cell of a
   ``cells^3`` grid that its whole (extended, both ways) line passes through, by an exact
   3-D DDA (Amanatides & Woo) over the box ``centre +- 2 size`` (paper Fig. 7).
2. `initial_axis`: the rays whose lines pass through the cell of maximum energy give the
   first bundle axis: their energy-weighted mean origin and normalised mean direction.
3. `refine_axis`: assign the rays near the axis (line-to-line distance and angle), re-fit
   the axis to them by least squares, repeat until the assignment stops changing.
4. `fit_focus_law`: fit ``alpha``, ``beta`` and the plane offset ``ell`` of the CSL on
   that axis by minimising Eq. 5 (Optimistix, trust-region Gauss-Newton); rays it
   represents badly are dismissed from the bundle (they stay for later bundles).
5. `splat_intensity`: EWA-splat the bundle's energies into the light-plane image.
6. The bundle's rays leave the remaining set; repeat (`fit_spot_lights`) until the lights
   hold ``energy_fraction`` of the energy or the ``max_lights`` slots are used.

Everything has fixed shapes (masks instead of subsets, loops as `lax` primitives), so
`fit_spot_lights` compiles once per set of static knobs and `jax.vmap`s over a leading
batch of ray sets. Lengths are metres, energies whatever the rays carry (the library's
flux units), intensities energy per square metre of light plane.
"""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

from ..._checks import check_array, check_fits, check_int, check_memory_limit, check_number
from ...scene.scene import as_float_array, check_finite, is_concrete
from ...trace.optics import orthonormal_basis
from .exit_rays import ExitRays
from .lights import SpotLights

BOX_HALF_WIDTH = 2.0
"""The rasterisation box is ``centre +- BOX_HALF_WIDTH x size`` (paper: "an extended
bounding volume"): four object sizes wide, so the focal regions of ordinary refractors
(a glass ball focuses about half a radius behind itself) lie inside it."""

DISTANCE_THRESHOLD = 0.1
"""Default bundle distance threshold, in units of the object's ``size``: about one cell
of the default 32^3 grid (``4 size / 32 = 0.125 size``), so the rays through the
maximum cell, which seed the bundle, lie within it of their own mean axis."""

ALPHA_MAX = 1e8
"""Largest ``alpha`` a fit returns, in units of ``size`` (a collimated bundle's focus)."""

BETA_START = 1e-6
"""Smallest ``beta`` a fit starts from, in units of ``1 / size``: ``beta = s^2`` has a
stationary point at ``s = 0``, so the optimisation starts a little off it."""

ELL_BOUND = 1.0
"""The light plane stays within ``ELL_BOUND x size`` of the bundle axis origin ``b``
(the foot of the bundle's mean ray origin): ``|ell| <= ELL_BOUND size``. Eq. 5 alone
often keeps improving, slowly, as the plane recedes upstream (a glass ball's bundle: 100x
lower cost at 8 sizes than at 0), which would leave a huge, coarse image and light the
space between the plane and the object that the bundle never reached."""

ELL_GRID = 33
"""Plane offsets tried for the initial guess: ``ELL_GRID`` values spanning
``[-ELL_BOUND, ELL_BOUND] size``."""

AXIS_RIDGE = 1e-6
"""Relative ridge that pins the along-axis coordinate of the least-squares axis point
for (nearly) parallel bundles, whose lines have no nearest point."""

LOWPASS_VARIANCE = 1.0
"""EWA screen-space low-pass filter variance, pixels^2 (Zwicker et al. 2002: ``V^h = I``)."""

SPLAT_MARGIN_PIXELS = 3
"""Pixels kept free around the outermost splat centre (with three footprint radii)."""


RaySet = ExitRays
"""Rays leaving a caustic object: the ray tracer's `ExitRays` (origin ``(R, 3)``, unit
direction ``(R, 3)``, energy ``(R,)`` (0: an invalid ray), emission grid `spacing`, the
object's bounding-box `centre` ``(3,)`` and `size`, metres)."""


class FitInfo(eqx.Module):
    """What `fit_spot_lights` did, per slot ``K``.

    - `energy`: ``(K,)`` energy of each light's bundle (= its image's power).
    - `total_energy`: ``()`` energy of all rays.
    - `fraction`: ``()`` share of `total_energy` the lights hold.
    - `discarded_energy`: ``()`` energy of rays set aside because a slot found no bundle
      that a CSL represents (they are in no light).
    - `rays`: ``(K,)`` number of rays in each bundle.
    - `rms`: ``(K,)`` energy-weighted RMS of the bundle's per-ray Eq. 5 error
      ``sqrt(E)``, metres.
    - `axis_iterations`: ``(K,)`` axis refinement iterations.
    - `fit_steps`: ``(K,)`` solver steps of the final focus-law fit.
    """

    energy: Float[Array, " K"]
    total_energy: Float[Array, ""]
    fraction: Float[Array, ""]
    discarded_energy: Float[Array, ""]
    rays: Int[Array, " K"]
    rms: Float[Array, " K"]
    axis_iterations: Int[Array, " K"]
    fit_steps: Int[Array, " K"]


# ---------------------------------------------------------------------------------------
# Input conversion and knob validation


def ray_set(origin, direction, energy, *, spacing=None, centre=None, size=None) -> RaySet:
    """A `RaySet` from plain arrays (shapes as in `RaySet`; directions are normalised).

    Missing `centre` and `size` come from the bounding box of the origins of rays with
    energy > 0; a missing `spacing` is ``size / sqrt(number of such rays)`` (rays spread
    evenly over a square of side `size`).
    """
    origin = as_float_array(origin, "origin")
    direction = as_float_array(direction, "direction")
    energy = as_float_array(energy, "energy")
    if origin.ndim != 2 or origin.shape[-1] != 3:
        raise ValueError(f"`origin` must have shape (R, 3), got {origin.shape}")
    n = origin.shape[0]
    if direction.shape != (n, 3):
        raise ValueError(
            f"`direction` must have shape ({n}, 3) like `origin`, got {direction.shape}"
        )
    if energy.shape != (n,):
        raise ValueError(f"`energy` must have shape ({n},), got {energy.shape}")
    if n == 0:
        raise ValueError("`origin` must hold at least one ray, got shape (0, 3)")
    for name, arr in (("origin", origin), ("direction", direction), ("energy", energy)):
        check_finite(arr, name)
    if is_concrete(energy) and np.any(np.asarray(energy) < 0):
        raise ValueError("`energy` must be >= 0")
    if is_concrete(direction) and is_concrete(energy):
        still = (np.sum(np.asarray(direction) ** 2, axis=-1) == 0) & (np.asarray(energy) > 0)
        if np.any(still):
            raise ValueError(
                f"`direction` must be non-zero for rays with energy > 0 (ray {np.argmax(still)})"
            )
    dtype = jnp.result_type(origin.dtype, direction.dtype, energy.dtype)
    origin, direction, energy = (x.astype(dtype) for x in (origin, direction, energy))
    norm = jnp.linalg.norm(direction, axis=-1, keepdims=True)
    direction = direction / jnp.where(norm > 0, norm, 1.0)
    valid = energy > 0
    if centre is None or size is None:
        big = jnp.finfo(dtype).max
        lo = jnp.min(jnp.where(valid[:, None], origin, big), axis=0)
        hi = jnp.max(jnp.where(valid[:, None], origin, -big), axis=0)
        any_valid = jnp.any(valid)
        lo, hi = jnp.where(any_valid, lo, 0.0), jnp.where(any_valid, hi, 0.0)
        if centre is None:
            centre = 0.5 * (lo + hi)
        if size is None:
            size = jnp.maximum(jnp.max(hi - lo), jnp.finfo(dtype).tiny)
    centre = as_float_array(centre, "centre").astype(dtype)
    size = as_float_array(size, "size").astype(dtype)
    if centre.shape != (3,):
        raise ValueError(f"`centre` must have shape (3,), got {centre.shape}")
    if size.shape != ():
        raise ValueError(f"`size` must be a scalar, got shape {size.shape}")
    if spacing is None:
        spacing = size / jnp.sqrt(jnp.maximum(jnp.sum(valid), 1).astype(dtype))
    spacing = as_float_array(spacing, "spacing").astype(dtype)
    if spacing.shape != ():
        raise ValueError(f"`spacing` must be a scalar, got shape {spacing.shape}")
    for name, arr in (("centre", centre), ("size", size), ("spacing", spacing)):
        check_finite(arr, name)
    for name, arr in (("size", size), ("spacing", spacing)):
        if is_concrete(arr) and not float(arr) > 0:
            raise ValueError(f"`{name}` must be positive, got {float(arr)}")
    return RaySet(origin, direction, energy, spacing, centre, size)


def as_ray_set(rays: Any) -> RaySet:
    """A `RaySet` from an ``ExitRays``-like object (attributes ``origin``, ``direction``,
    ``energy``, ``spacing``, ``centre``, ``size``) or a tuple of plain arrays
    ``(origin, direction, energy[, spacing[, centre[, size]]])`` (see `ray_set`)."""
    if isinstance(rays, tuple | list):
        if not 3 <= len(rays) <= 6:
            raise ValueError(
                "`rays` as a tuple must be (origin, direction, energy[, spacing[, centre"
                f"[, size]]]), got {len(rays)} items"
            )
        names = ("spacing", "centre", "size")
        return ray_set(*rays[:3], **dict(zip(names, rays[3:], strict=False)))
    missing = [
        f
        for f in ("origin", "direction", "energy", "spacing", "centre", "size")
        if not hasattr(rays, f)
    ]
    if missing:
        raise ValueError(f"`rays` lacks the field(s) {missing} of ExitRays")
    return ray_set(
        rays.origin,
        rays.direction,
        rays.energy,
        spacing=rays.spacing,
        centre=rays.centre,
        size=rays.size,
    )


def _check_float(value, name: str, *, low: float, high: float = math.inf, closed: bool = False):
    """A finite real number in ``(low, high)`` (``(low, high]`` if `closed`); bools and
    strings are refused; a traced value passes unchecked."""
    if not is_concrete(value):
        return value
    return check_number(value, name, low=low, high=high, low_open=True, high_open=not closed)


MAX_CELLS = 1290
"""Most `cells` per side of the rasterisation grid: ``cells^3`` cells indexed by int32."""

MAX_LOOP = 2**31 - 1
"""Most iterations of a loop counted by an int32 (`axis_iterations`, `fit_steps`)."""

FIT_RAY_FLOATS = 224
"""Numbers one ray takes in the fit (its arrays and XLA's temporaries: 1708 bytes a ray
measured in float64 at 65536 rays, plus 56 of input), for `fit_bytes`."""


def fit_bytes(
    rays: int, dtype, *, max_lights=16, resolution=64, cells=32, splat_window=8, chunk=8192
) -> int:
    """Estimated memory of `fit_spot_lights` on `rays` rays of `dtype`, bytes: the rays
    (`FIT_RAY_FLOATS` numbers each), the ``cells^3`` grid, a splat chunk of
    ``min(chunk, rays) x splat_window^2`` footprints (8 numbers a pixel) and three copies
    of the ``max_lights x resolution^2`` images (the loop's carry and its update)."""
    numbers = (
        FIT_RAY_FLOATS * rays
        + cells**3
        + 8 * min(chunk, rays) * splat_window**2
        + 3 * max_lights * resolution**2
    )
    return numbers * jnp.dtype(dtype).itemsize


def check_fit_knobs(**given) -> dict:
    """The knobs of `fit_spot_lights` (its defaults for those not given), checked: a
    `ValueError` names a bad one, or `fit_knobs` if one is not a knob of the fit (callers
    that fit later, `precompute_spot_lights`, check them before any work)."""
    import inspect

    defaults = {
        name: p.default
        for name, p in inspect.signature(fit_spot_lights).parameters.items()
        if p.kind is p.KEYWORD_ONLY and name != "memory_limit"
    }
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise ValueError(
            f"`fit_knobs` holds {unknown}, not knobs of fit_spot_lights (known: {sorted(defaults)})"
        )
    k = {**defaults, **given}
    knobs = {
        "max_lights": check_int(k["max_lights"], "max_lights", 1),
        "energy_fraction": _check_float(
            k["energy_fraction"], "energy_fraction", low=0.0, high=1.0, closed=True
        ),
        "resolution": check_int(k["resolution"], "resolution", 8),
        "cells": check_int(k["cells"], "cells", 1, MAX_CELLS),
        "angle_threshold_deg": _check_float(
            k["angle_threshold_deg"], "angle_threshold_deg", low=0.0, high=90.0
        ),
        "axis_iterations": check_int(k["axis_iterations"], "axis_iterations", 1, MAX_LOOP),
        "fit_steps": check_int(k["fit_steps"], "fit_steps", 1, MAX_LOOP),
        "splat_window": check_int(k["splat_window"], "splat_window", 1),
        "chunk": check_int(k["chunk"], "chunk", 1),
    }
    for name in ("distance_threshold", "dismiss_threshold", "splat_radius"):
        value = k[name]
        knobs[name] = None if value is None else _check_float(value, name, low=0.0)
    return knobs


def _check_fit_memory(count: int, dtype, knobs: dict, memory_limit: int) -> None:
    """Refuse a fit of `count` rays whose `fit_bytes` exceed `memory_limit`."""
    sizes = {n: knobs[n] for n in ("max_lights", "resolution", "cells", "splat_window", "chunk")}
    check_fits(
        fit_bytes(count, dtype, **sizes),
        memory_limit,
        f"fitting spot lights to {count} rays",
        "lower the number of `rays`, `max_lights`, `resolution`, `cells`, `splat_window` "
        "or `chunk`",
    )


# ---------------------------------------------------------------------------------------
# Geometry shared by the steps


def _tiny(dtype) -> float:
    return float(jnp.finfo(dtype).tiny)


def _floats(*values):
    """The values as JAX arrays of their common floating dtype (the default float type
    for integer input)."""
    arrays = [jnp.asarray(v) for v in values]
    dtype = jnp.result_type(*arrays)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    return tuple(a.astype(dtype) for a in arrays)


def _line_box(origin, direction, lo, hi):
    """Parameter interval ``[t0, t1]`` where the infinite lines ``origin + t direction``
    ``(R, 3)`` lie inside the box ``[lo, hi]`` ``(3,)`` (empty where ``t0 >= t1``)."""
    moving = direction != 0
    safe = jnp.where(moving, direction, 1.0)
    ta, tb = (lo - origin) / safe, (hi - origin) / safe
    inside = (origin >= lo) & (origin <= hi)
    t_lo = jnp.where(moving, jnp.minimum(ta, tb), jnp.where(inside, -jnp.inf, jnp.inf))
    t_hi = jnp.where(moving, jnp.maximum(ta, tb), jnp.where(inside, jnp.inf, -jnp.inf))
    return jnp.max(t_lo, axis=-1), jnp.min(t_hi, axis=-1)


def _box(rays: RaySet):
    """Lower corner ``(3,)`` and side ``()`` of the rasterisation box, metres."""
    half = BOX_HALF_WIDTH * rays.size
    return rays.centre - half, 2 * half


def _line_distance(origin, direction, point, axis):
    """Distance ``(R,)`` between the lines of rays ``(R, 3)`` and the axis line through
    `point` along unit `axis` ``(3,)``. (Nearly) parallel lines, whose skew formula is
    ill-conditioned, use the distance of the ray origin from the axis instead."""
    w0 = origin - point
    n = jnp.cross(direction, axis)
    nn = jnp.sum(n * n, axis=-1)
    skew_ok = nn > 100 * jnp.finfo(origin.dtype).eps
    skew = jnp.abs(jnp.sum(w0 * n, axis=-1)) / jnp.sqrt(jnp.where(skew_ok, nn, 1.0))
    radial = w0 - (w0 @ axis)[:, None] * axis
    return jnp.where(skew_ok, skew, jnp.linalg.norm(radial, axis=-1))


def _plane_hits(origin, direction, plane_origin, axis):
    """Where the (extended) rays ``(R, 3)`` cross the plane through `plane_origin` with
    unit normal `axis`: points ``p`` ``(R, 3)``, signed distances ``t`` ``(R,)`` from the
    ray origins along the rays, and ``cos = d . axis`` ``(R,)``. Rays parallel to the plane
    get ``t = 0`` (callers give them no weight)."""
    cos = direction @ axis
    safe = jnp.where(jnp.abs(cos) > _tiny(cos.dtype) ** 0.5, cos, 1.0)
    t = ((plane_origin - origin) @ axis) / safe
    return origin + t[:, None] * direction, t, cos


def _safe_norm(v):
    """``|v|`` over the last axis with a finite derivative at 0."""
    vv = jnp.sum(v * v, axis=-1)
    pos = vv > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, vv, 1.0)), 0.0)


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


# ---------------------------------------------------------------------------------------
# 4. Focus law (paper Section 3.1.2, Eq. 5)


def _eq5_terms(origin, direction, axis_point, axis, kappa, gamma, ell, width):
    """Per-ray pieces of Eq. 5 for the CSL with ``1 / alpha = kappa``,
    ``beta / alpha = gamma`` and ``c = axis_point + ell axis``: ``d - e`` ``(R, 3)`` and
    ``t1^2 + t2^2`` ``(R,)``. Uses ``e = unit(a - (kappa + gamma r)(p - c))``, which is
    ``unit(c + f(r) a - p)`` divided by ``f(r) > 0``, finite even for collimated lights."""
    c = axis_point + ell * axis
    p, t, _ = _plane_hits(origin, direction, c, axis)
    v = p - c
    r = _safe_norm(v)
    e = axis - (kappa + gamma * r)[:, None] * v
    e = e / jnp.linalg.norm(e, axis=-1, keepdims=True)
    t1 = jnp.abs(t)
    t2 = t1 + width
    return direction - e, t1 * t1 + t2 * t2


def _unpack(x, size):
    """``(kappa, gamma, ell)`` from the optimisation variables
    ``x = (log(alpha / size), sqrt(beta size), arcsin(ell / (ELL_BOUND size)))``: any
    ``x`` gives ``alpha > 0``, ``beta >= 0`` and ``|ell| <= ELL_BOUND size`` (the
    bounded-parameter transform of MINUIT)."""
    log_alpha = jnp.minimum(x[0], math.log(ALPHA_MAX))
    kappa = jnp.exp(-log_alpha) / size
    beta = x[1] ** 2 / size
    return kappa, kappa * beta, ELL_BOUND * size * jnp.sin(x[2])


def _pack(alpha, beta, ell, size):
    """Inverse of `_unpack`, starting off its stationary points: ``beta`` at least
    ``BETA_START / size``, ``|ell|`` at most 0.99 of its bound."""
    beta = jnp.maximum(beta, BETA_START / size)
    ell = jnp.clip(ell / (ELL_BOUND * size), -0.99, 0.99)
    return jnp.stack([jnp.log(alpha / size), jnp.sqrt(beta * size), jnp.arcsin(ell)])


def focus_law_error(origin, direction, axis_point, axis_direction, alpha, beta, ell, *, size):
    """Per-ray Eq. 5 error ``E = (t1^2 + t2^2) |d - e|^2`` ``(R,)``, metres^2.

    - `origin`, `direction`: ``(R, 3)`` bundle rays ``q``, ``d`` (unit directions).
    - `axis_point`, `axis_direction`: ``(3,)`` the axis origin ``b`` and unit axis ``a``.
    - `alpha` (metres), `beta` (1/metres), `ell` (metres): the CSL, ``c = b + ell a``.
    - `size`: the object's size; ``w = 4 size`` in ``t2 = t1 + w``.
    """
    origin, direction, axis_point, axis_direction, alpha, beta, ell, size = _floats(
        origin, direction, axis_point, axis_direction, alpha, beta, ell, size
    )
    diff, t_sq = _eq5_terms(
        origin, direction, axis_point, axis_direction, 1 / alpha, beta / alpha, ell, 4 * size
    )
    return t_sq * jnp.sum(diff * diff, axis=-1)


def _eq5_cost(origin, direction, weight, axis_point, axis, kappa, gamma, ell, width):
    diff, t_sq = _eq5_terms(origin, direction, axis_point, axis, kappa, gamma, ell, width)
    return jnp.sum(weight * t_sq * jnp.sum(diff * diff, axis=-1)), jnp.sum(weight * t_sq)


def _ell_grid(dtype):
    """Plane offsets in units of size, ordered by distance from 0 (0, +s, -s, +2s, ...)."""
    k = np.arange(ELL_GRID)
    signed = np.where(k % 2 == 1, 1, -1) * ((k + 1) // 2)
    return jnp.asarray(signed * (ELL_BOUND / (ELL_GRID // 2)), dtype)


def _initial_focus_law(origin, direction, weight, axis_point, axis, size):
    """Initial ``x`` (see `_unpack`) for the focus-law fit.

    For each plane offset ``ell`` of `_ell_grid`, ``kappa = 1/alpha`` and
    ``gamma = beta/alpha`` solve the linear least-squares problem
    ``min sum w (t1^2 + t2^2) |g + (kappa + gamma r)(p - c)|^2``, where
    ``g = d_perp / (d . a)`` is the ray's transverse slope: exact for rays of a CSL, and
    Eq. 5 to first order in the ray angles. They are clamped into the constraints and
    scored by Eq. 5; the start is the grid offset nearest 0 whose cost is within rounding
    (and 0.1 %) of the least.
    """
    dtype = origin.dtype
    width = 4 * size
    eps = jnp.finfo(dtype).eps

    def at(ell_unit):
        ell = ell_unit * size
        c = axis_point + ell * axis
        p, t, cos = _plane_hits(origin, direction, c, axis)
        v = (p - c) / size
        r = _safe_norm(v)
        g = (direction - cos[:, None] * axis) / jnp.where(cos != 0, cos, 1.0)[:, None]
        t1 = jnp.abs(t)
        wt = weight * (t1 * t1 + (t1 + width) ** 2)
        vv = jnp.sum(v * v, axis=-1)
        gv = jnp.sum(g * v, axis=-1)
        m = jnp.array([[wt @ vv, wt @ (r * vv)], [wt @ (r * vv), wt @ (r * r * vv)]], dtype)
        rhs = -jnp.array([wt @ gv, wt @ (r * gv)], dtype)
        m = m + (1e-12 * jnp.trace(m) + _tiny(dtype)) * jnp.eye(2, dtype=dtype)
        k_unit, g_unit = jnp.linalg.solve(m, rhs)  # kappa size, gamma size^2
        k_unit = jnp.maximum(jnp.where(jnp.isfinite(k_unit), k_unit, 0.0), 1 / ALPHA_MAX)
        g_unit = jnp.maximum(jnp.where(jnp.isfinite(g_unit), g_unit, 0.0), 0.0)
        x = _pack(size / k_unit, g_unit / k_unit / size, ell, size)
        kappa, gamma, ell = _unpack(x, size)
        cost, scale = _eq5_cost(
            origin, direction, weight, axis_point, axis, kappa, gamma, ell, width
        )
        return x, cost, scale

    xs, costs, scales = jax.lax.map(at, _ell_grid(dtype))  # one offset at a time: memory O(R)
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
    best = jnp.min(costs)
    near = costs <= best * (1 + 1e-3) + 100 * eps * scales
    return xs[jnp.argmax(near)]


def _fit_x(origin, direction, weight, axis_point, axis, size, x0, steps, tolerance):
    """Trust-region Gauss-Newton (Optimistix's `Dogleg`, normal equations solved by SVD)
    on Eq. 5 from ``x0``; **returns** ``(x, steps taken)``.

    The solve runs in the default float type where that is wider than the data's
    (float32 rays with x64 enabled): Optimistix 0.1.0 then makes float64 internal scalars
    that clash with float32 residuals."""
    dtype = origin.dtype
    wide = jnp.promote_types(dtype, jnp.result_type(float))
    origin, direction, weight, axis_point, axis, size, x0 = (
        jnp.asarray(v, wide) for v in (origin, direction, weight, axis_point, axis, size, x0)
    )
    width = 4 * size
    root_weight = jnp.sqrt(weight)  # outside the residual: no derivative of sqrt at 0

    def residuals(x, _):
        kappa, gamma, ell = _unpack(x, size)
        diff, t_sq = _eq5_terms(origin, direction, axis_point, axis, kappa, gamma, ell, width)
        return (root_weight * jnp.sqrt(t_sq))[:, None] * diff  # t_sq >= width^2 > 0

    solver = optx.Dogleg(rtol=tolerance, atol=tolerance, linear_solver=lx.Normal(lx.SVD()))
    sol = optx.least_squares(residuals, solver, x0, max_steps=steps, throw=False)
    x = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, x0)
    return x.astype(dtype), jnp.asarray(sol.stats["num_steps"], jnp.int32)


def _default_tolerance(dtype) -> float:
    return max(1e-10, 100 * float(jnp.finfo(dtype).eps))


def _law(x, size):
    """``(alpha, beta, ell)`` in metres, 1/metres, metres from ``x``."""
    kappa, gamma, ell = _unpack(x, size)
    return 1 / kappa, gamma / kappa, ell


def fit_focus_law(
    origin,
    direction,
    energy,
    axis_point,
    axis_direction,
    *,
    size,
    steps: int = 100,
    initial=None,
    tolerance: float | None = None,
):
    """Fit a CSL's ``alpha``, ``beta`` and plane offset ``ell`` to a ray bundle (Eq. 5).

    Minimises ``sum_i w_i (t1^2 + t2^2) |d_i - e_i|^2`` with ``optx.least_squares``
    (residuals ``sqrt(w_i (t1^2 + t2^2)) (d_i - e_i)``, ``throw=False``) over
    ``x = (log(alpha / size), sqrt(beta size), arcsin(ell / (ELL_BOUND size)))``, which
    keeps ``alpha > 0``, ``beta >= 0`` and the plane within ``ELL_BOUND size`` of ``b``
    (``alpha`` is capped at ``ALPHA_MAX size``). The solver is
    `optx.Dogleg` (trust-region Gauss-Newton; the normal equations by SVD, since the
    problem is rank-deficient when ``beta = 0``): Levenberg-Marquardt's damping stalls
    the ``sqrt(beta)`` variable near ``beta = 0``, where Gauss-Newton steps halve it. The
    start is `initial` or a grid search over ``ell`` with a closed-form
    ``(alpha, beta)`` per offset (`_initial_focus_law`). With ``beta = 0`` all rays meet
    in one point and only ``ell + alpha`` (where the focus is) is determined; the search
    then prefers the offset nearest 0.

    - `origin`, `direction`: ``(R, 3)`` bundle rays (metres; unit directions).
    - `energy`: ``(R,)`` weights ``w`` (0: not in the bundle).
    - `axis_point`, `axis_direction`: ``(3,)`` the bundle axis ``b``, unit ``a``.
    - `size`: the object's size (metres): length scale and ``w = 4 size``.
    - `steps`: static, at most this many solver steps.
    - `initial`: optional ``(alpha, beta, ell)`` start.
    - `tolerance`: the solver's ``rtol = atol`` (default ``max(1e-10, 100 eps)``).

    **Returns** ``(alpha, beta, ell, rms)``: the law (metres, 1/metres, metres) and the
    energy-weighted RMS of ``sqrt(E)`` over the bundle, metres.
    """
    origin, direction, energy, axis_point, axis_direction, size = _floats(
        origin, direction, energy, axis_point, axis_direction, size
    )
    tolerance = _default_tolerance(origin.dtype) if tolerance is None else tolerance
    if initial is None:
        x0 = _initial_focus_law(origin, direction, energy, axis_point, axis_direction, size)
    else:
        alpha0, beta0, ell0 = (jnp.asarray(v, origin.dtype) for v in initial)
        x0 = _pack(alpha0, beta0, ell0, size)
    x, _ = _fit_x(origin, direction, energy, axis_point, axis_direction, size, x0, steps, tolerance)
    alpha, beta, ell = _law(x, size)
    error = focus_law_error(
        origin, direction, axis_point, axis_direction, alpha, beta, ell, size=size
    )
    return alpha, beta, ell, _rms(energy, error)


def _rms(weight, error):
    total = jnp.sum(weight)
    return jnp.sqrt((weight @ error) / jnp.where(total > 0, total, 1.0))


# ---------------------------------------------------------------------------------------
# 5. EWA splatting of the intensity image


def splat_half_width(origin, direction, energy, plane_origin, axis, *, radius, resolution: int):
    """Half-width ``w`` (metres) of a light-plane image holding every ray with energy > 0:
    the largest ``r = |p - c|`` plus three major footprint radii ``radius / |d . a|``,
    widened so that ``SPLAT_MARGIN_PIXELS`` pixels stay free at the border. Shapes as in
    `splat_intensity`; at least ``3 radius`` when no ray has energy."""
    origin, direction, energy, plane_origin, axis, radius = _floats(
        origin, direction, energy, plane_origin, axis, radius
    )
    p, _, cos = _plane_hits(origin, direction, plane_origin, axis)
    used = energy > 0
    r_max = jnp.max(jnp.where(used, _safe_norm(p - plane_origin), 0.0))
    stretch = jnp.max(jnp.where(used, 1 / jnp.maximum(jnp.abs(cos), 0.5), 1.0))
    return (r_max + 3 * radius * stretch) * resolution / (resolution - 2 * SPLAT_MARGIN_PIXELS)


def splat_intensity(
    origin,
    direction,
    energy,
    plane_origin,
    axis,
    frame_u,
    half_width,
    *,
    radius,
    resolution: int,
    window: int = 8,
    chunk: int = 8192,
):
    """EWA-splat ray energies into a light-plane intensity image (Zwicker et al. 2002).

    Each ray is a cylinder of radius `radius` around its line; it meets the plane (normal
    `axis`, through `plane_origin`) at ``p`` in an ellipse with semi-axes
    ``radius / |d . a|`` along the ray's in-plane direction and `radius` across it (for a
    ray of the CSL that direction is along ``p - c``, as in the paper; this form is also
    defined at ``p = c``). Its reconstruction kernel is the Gaussian with that ellipse's
    second moments (a uniform disc of radius ``R`` has variance ``R^2 / 4`` per axis):
    covariance ``(radius / 2)^2 (I + g g^T)``, ``g = d_perp / (d . a)``; the EWA
    resampling filter adds the low-pass ``LOWPASS_VARIANCE`` pixel^2. Each splat is
    evaluated on the ``window x window`` pixels nearest ``p`` (those inside the image),
    normalised to sum 1 and scaled by ``energy / pixel area``, so the image integrates to
    the total energy of the rays whose window meets the image (all, when
    `half_width` comes from `splat_half_width`). Rays are processed `chunk` at a time.

    - `origin`, `direction`: ``(R, 3)`` rays (metres; unit directions);
      `energy`: ``(R,)`` (0: not splatted).
    - `plane_origin` ``c``, `axis` ``a``, `frame_u`: ``(3,)`` the light plane and its
      image columns' direction (see `SpotLights`); `half_width`: ``()`` metres.
    - `radius`: ``()`` cylinder radius, metres. `resolution`, `window`, `chunk`: static.

    **Returns** ``(resolution, resolution)`` intensity (energy per m^2), rows along ``v``.
    """
    origin, direction, energy, plane_origin, axis, frame_u, half_width, radius = _floats(
        origin, direction, energy, plane_origin, axis, frame_u, half_width, radius
    )
    n = resolution
    dtype = origin.dtype
    pixel = 2 * half_width / n
    frame_v = jnp.cross(axis, frame_u)
    basis = jnp.stack([frame_u, frame_v])  # (2, 3)
    offsets = jnp.arange(window)
    base_var = (radius / 2) ** 2
    low_var = LOWPASS_VARIANCE * pixel**2

    def splat_chunk(image, rays):
        o, d, e = rays
        p, _, cos = _plane_hits(o, d, plane_origin, axis)
        uv = (p - plane_origin) @ basis.T  # (C, 2)
        g = (d @ basis.T) / jnp.where(cos != 0, cos, 1.0)[:, None]
        cov = base_var * (jnp.eye(2, dtype=dtype) + g[:, :, None] * g[:, None, :])
        cov = cov + low_var * jnp.eye(2, dtype=dtype)
        det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
        # continuous pixel coordinates: pixel j's centre at j
        xy = (uv + half_width) / pixel - 0.5
        start = jnp.ceil(xy - window / 2).astype(jnp.int32)  # (C, 2)
        cols = start[:, 0:1] + offsets  # (C, W)
        rows = start[:, 1:2] + offsets
        du = (xy[:, 0:1] - cols) * pixel  # (C, W) metres
        dv = (xy[:, 1:2] - rows) * pixel
        q = (
            cov[:, 1, 1, None, None] * du[:, None, :] ** 2
            - 2 * cov[:, 0, 1, None, None] * du[:, None, :] * dv[:, :, None]
            + cov[:, 0, 0, None, None] * dv[:, :, None] ** 2
        ) / det[:, None, None]  # (C, W rows, W cols)
        inside = ((rows >= 0) & (rows < n))[:, :, None] & ((cols >= 0) & (cols < n))[:, None, :]
        wgt = jnp.where(inside, jnp.exp(-0.5 * q), 0.0)
        total = jnp.sum(wgt, axis=(1, 2), keepdims=True)
        scale = jnp.where(e > 0, e, 0.0)[:, None, None] / pixel**2
        wgt = wgt * scale / jnp.where(total > 0, total, 1.0)
        flat = jnp.where(inside, rows[:, :, None] * n + cols[:, None, :], n * n)
        return image.at[flat.reshape(-1)].add(wgt.reshape(-1), mode="drop"), None

    count = origin.shape[0]
    chunk = max(1, min(chunk, count))
    pad = -count % chunk
    rays = (origin, direction, energy)
    rays = jax.tree.map(lambda a: jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)), rays)
    rays = jax.tree.map(lambda a: a.reshape(-1, chunk, *a.shape[1:]), rays)
    image, _ = jax.lax.scan(splat_chunk, jnp.zeros(n * n, dtype), rays)
    return image.reshape(n, n)


# ---------------------------------------------------------------------------------------
# 6. The whole fit


def _fit_one(rays: RaySet, pool, distance, cos_angle, dismiss, radius, knobs):
    """One slot: the bundle found among the rays with `pool` energy ``(R,)``.

    **Returns** ``(light fields, bundle mask, tried mask, info)``; the light is empty
    (``bundle`` all False) where no ray of the bundle is represented within `dismiss`.
    """
    cells, iterations, steps, resolution, window, chunk = knobs
    o, d, size = rays.origin, rays.direction, rays.size
    dtype = o.dtype
    box_lo, box_side = _box(rays)
    grid = rasterise_lines(o, d, pool, box_lo, box_side, cells)
    best = jnp.array(jnp.unravel_index(jnp.argmax(grid), grid.shape))
    through = lines_through_cell(o, d, box_lo, box_side, cells, best) & (pool > 0)
    fallback_axis = jnp.array([0.0, 0.0, 1.0], dtype)
    point, axis = initial_axis(o, d, jnp.where(through, pool, 0.0), rays.centre, fallback_axis)
    point, axis, member, iters = _refine_axis(
        o, d, pool, point, axis, distance, cos_angle, iterations
    )

    tolerance = _default_tolerance(dtype)
    limit = 2 * dismiss**2  # E = sum of two squared distances

    def kept(x, mask):
        alpha, beta, ell = _law(x, size)
        error = focus_law_error(o, d, point, axis, alpha, beta, ell, size=size)
        return mask & (error <= limit), error

    def fit_pass(_, carry):  # fit to the rays kept by the previous pass
        x, keep, _ = carry
        x, taken = _fit_x(o, d, jnp.where(keep, pool, 0.0), point, axis, size, x, steps, tolerance)
        return x, kept(x, member)[0], taken

    x = _initial_focus_law(o, d, jnp.where(member, pool, 0.0), point, axis, size)
    x, bundle, fit_steps = jax.lax.fori_loop(0, 2, fit_pass, (x, member, jnp.int32(0)))
    error = kept(x, member)[1]
    weight = jnp.where(bundle, pool, 0.0)

    alpha, beta, ell = _law(x, size)
    c = point + ell * axis
    frame_u, _ = orthonormal_basis(axis)
    half_width = splat_half_width(o, d, weight, c, axis, radius=radius, resolution=resolution)
    image = splat_intensity(
        o, d, weight, c, axis, frame_u, half_width,
        radius=radius, resolution=resolution, window=window, chunk=chunk,
    )  # fmt: skip
    light = (c, axis, frame_u, alpha, beta, half_width, image)
    count = jnp.sum(bundle, dtype=jnp.int32)
    info = (jnp.sum(weight), count, _rms(weight, error), iters, fit_steps)
    return light, bundle, through | member | (jnp.max(grid) <= 0), info


def _fit(rays: RaySet, fraction, distance, angle_deg, dismiss, radius, knobs, max_lights):
    dtype = rays.origin.dtype
    cells, iterations, steps, resolution, window, chunk = knobs
    size = rays.size
    distance = DISTANCE_THRESHOLD * size if distance is None else jnp.asarray(distance, dtype)
    dismiss = distance if dismiss is None else jnp.asarray(dismiss, dtype)
    radius = 3 * rays.spacing if radius is None else jnp.asarray(radius, dtype)
    cos_angle = jnp.cos(jnp.deg2rad(jnp.asarray(angle_deg, dtype)))
    energy = jnp.where(rays.energy > 0, rays.energy, 0.0)
    total = jnp.sum(energy)
    floor = (1 - jnp.asarray(fraction, dtype)) * total
    k_slots = max_lights

    zeros = jnp.zeros((k_slots,), dtype)
    default_axis = jnp.array([0.0, 0.0, 1.0], dtype)
    lights = (
        jnp.broadcast_to(rays.centre, (k_slots, 3)),
        jnp.broadcast_to(default_axis, (k_slots, 3)),
        jnp.broadcast_to(orthonormal_basis(default_axis)[0], (k_slots, 3)),
        zeros + size,
        zeros,
        zeros + size,
        jnp.zeros((k_slots, resolution, resolution), dtype),
    )
    ints = jnp.zeros((k_slots,), jnp.int32)
    infos = (zeros, ints, zeros, ints, ints)
    active = jnp.zeros((k_slots,), bool)
    remaining = energy > 0

    def needed(remaining):
        pool = jnp.sum(jnp.where(remaining, energy, 0.0))
        return (pool > floor) & (pool > 0)

    def cond(state):
        k, remaining, *_ = state
        return (k < k_slots) & needed(remaining)

    def body(state):
        k, remaining, discarded, lights, infos, active = state
        pool = jnp.where(remaining, energy, 0.0)
        light, bundle, tried, info = _fit_one(
            rays, pool, distance, cos_angle, dismiss, radius, knobs
        )
        ok = jnp.any(bundle)
        lights = jax.tree.map(
            lambda all_, one: all_.at[k].set(jnp.where(ok, one, all_[k])), lights, light
        )
        infos = jax.tree.map(lambda all_, one: all_.at[k].set(one), infos, info)
        drop = jnp.where(ok, bundle, tried)
        discarded = discarded + jnp.where(ok, 0.0, jnp.sum(jnp.where(drop, pool, 0.0)))
        return k + 1, remaining & ~drop, discarded, lights, infos, active.at[k].set(ok)

    state = (jnp.array(0, jnp.int32), remaining, jnp.zeros((), dtype), lights, infos, active)
    _, _, discarded, lights, infos, active = jax.lax.while_loop(cond, body, state)
    light_energy, count, rms, iters, fit_steps = infos
    light_energy = jnp.where(active, light_energy, 0.0)
    spot = SpotLights(*lights, active=active)
    info = FitInfo(
        energy=light_energy,
        total_energy=total,
        fraction=jnp.sum(light_energy) / jnp.where(total > 0, total, 1.0),
        discarded_energy=discarded,
        rays=jnp.where(active, count, 0),
        rms=jnp.where(active, rms, 0.0),
        axis_iterations=iters,
        fit_steps=fit_steps,
    )
    return spot, info


_fit_jit = jax.jit(_fit, static_argnames=("knobs", "max_lights"))


def fit_spot_lights(
    rays,
    *,
    max_lights: int = 16,
    energy_fraction: float = 0.95,
    resolution: int = 64,
    cells: int = 32,
    distance_threshold: float | None = None,
    angle_threshold_deg: float = 60.0,
    dismiss_threshold: float | None = None,
    axis_iterations: int = 100,
    fit_steps: int = 100,
    splat_radius: float | None = None,
    splat_window: int = 8,
    chunk: int = 8192,
    memory_limit: int | None = None,
) -> tuple[SpotLights, FitInfo]:
    """Caustic spot lights for the rays leaving a caustic object (Liu et al. 2008, 3.1).

    Slot by slot (``max_lights`` fixed slots), while the rays in no light yet carry more
    than ``1 - energy_fraction`` of the total energy: rasterise their lines
    (`rasterise_lines`, box ``centre +- 2 size``, ``cells^3``), seed an axis from the
    rays through the cell of most energy (`initial_axis`), refine it (`refine_axis`), fit
    the focus law to the assigned rays (`fit_focus_law`, then again without the rays
    whose ``sqrt(E / 2)`` exceeds `dismiss_threshold`), keep as the bundle the assigned
    rays within `dismiss_threshold` of the final law, splat them into the image
    (`splat_intensity`) and remove them. A slot whose bundle is empty stays inactive and
    sets aside (discards) the rays it tried, so the next slot looks elsewhere. Unused
    slots are inactive with black images, ``origin = centre``, ``axis = +z``,
    ``alpha = half_width = size`` and ``beta = 0``.

    - `rays`: an ``ExitRays``-like object or a tuple of arrays (see `as_ray_set`).
    - `max_lights`, `resolution` (>= 8), `cells`, `axis_iterations`, `fit_steps`,
      `splat_window`, `chunk`: static ints.
    - `energy_fraction`: in ``(0, 1]``.
    - `distance_threshold`: metres (default ``DISTANCE_THRESHOLD x size``);
      `angle_threshold_deg`: in ``(0, 90)``; `dismiss_threshold`: metres (default: the
      distance threshold); `splat_radius`: metres (default ``3 x spacing``).
    - `memory_limit`: bytes the fit may take (default 1 GiB; estimated by `fit_bytes`):
      more rays, or larger `max_lights`, `resolution`, `cells`, `splat_window` or `chunk`,
      raise a `ValueError` before anything is compiled.

    Jit-compiled (once per set of static knobs); it may itself be jitted or vmapped over
    a leading batch axis of the ray arrays.

    **Returns** ``(SpotLights, FitInfo)`` with ``K = max_lights``.
    """
    k = check_fit_knobs(
        max_lights=max_lights,
        energy_fraction=energy_fraction,
        resolution=resolution,
        cells=cells,
        distance_threshold=distance_threshold,
        angle_threshold_deg=angle_threshold_deg,
        dismiss_threshold=dismiss_threshold,
        axis_iterations=axis_iterations,
        fit_steps=fit_steps,
        splat_radius=splat_radius,
        splat_window=splat_window,
        chunk=chunk,
    )
    memory_limit = check_memory_limit(memory_limit)
    origin = rays[0] if isinstance(rays, tuple | list) and rays else getattr(rays, "origin", None)
    # before the rays are converted (work too)
    if origin is not None and len(getattr(origin, "shape", ())) == 2:
        kind = np.dtype(origin.dtype).kind
        _check_fit_memory(origin.shape[0], origin.dtype if kind == "f" else float, k, memory_limit)
    rays = as_ray_set(rays)
    _check_fit_memory(rays.origin.shape[0], rays.origin.dtype, k, memory_limit)
    knobs = tuple(
        k[n] for n in ("cells", "axis_iterations", "fit_steps", "resolution", "splat_window")
    ) + (k["chunk"],)
    return _fit_jit(
        rays,
        k["energy_fraction"],
        k["distance_threshold"],
        k["angle_threshold_deg"],
        k["dismiss_threshold"],
        k["splat_radius"],
        knobs=knobs,
        max_lights=k["max_lights"],
    )
