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

The steps live in their own modules: `ray_set.py` (the input), `bundles.py` (steps 1-3),
`focus_law.py` (step 4), `splat.py` (step 5) and `fit_common.py` (the helpers they share);
this module holds the whole fit (step 6), its knobs and its memory estimate, and
re-exports the steps' public names.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..._checks import check_fits, check_int, check_memory_limit
from ...trace.optics import orthonormal_basis
from .bundles import (
    AXIS_RIDGE,
    BOX_HALF_WIDTH,
    _box,
    _refine_axis,
    assign_rays,
    check_refine_knobs,
    estimate_axis,
    initial_axis,
    lines_through_cell,
    rasterise_lines,
    refine_axis,
)
from .fit_common import MAX_LOOP, _check_float
from .focus_law import (
    ALPHA_MAX,
    BETA_START,
    ELL_BOUND,
    ELL_GRID,
    _default_tolerance,
    _fit_x,
    _initial_focus_law,
    _law,
    _rms,
    fit_focus_law,
    focus_law_error,
)
from .lights import SpotLights
from .ray_set import RaySet, as_ray_set, ray_set
from .splat import LOWPASS_VARIANCE, SPLAT_MARGIN_PIXELS, splat_half_width, splat_intensity

__all__ = [
    "ALPHA_MAX",
    "AXIS_RIDGE",
    "BETA_START",
    "BOX_HALF_WIDTH",
    "DISTANCE_THRESHOLD",
    "ELL_BOUND",
    "ELL_GRID",
    "FIT_RAY_FLOATS",
    "LOWPASS_VARIANCE",
    "MAX_CELLS",
    "MAX_LOOP",
    "SPLAT_MARGIN_PIXELS",
    "FitInfo",
    "RaySet",
    "as_ray_set",
    "assign_rays",
    "check_fit_knobs",
    "check_refine_knobs",
    "estimate_axis",
    "fit_bytes",
    "fit_focus_law",
    "fit_spot_lights",
    "focus_law_error",
    "initial_axis",
    "lines_through_cell",
    "rasterise_lines",
    "ray_set",
    "refine_axis",
    "splat_half_width",
    "splat_intensity",
]

DISTANCE_THRESHOLD = 0.1
"""Default bundle distance threshold, in units of the object's ``size``: about one cell
of the default 32^3 grid (``4 size / 32 = 0.125 size``), so the rays through the
maximum cell, which seed the bundle, lie within it of their own mean axis."""


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
# Knobs and memory


MAX_CELLS = 1290
"""Most `cells` per side of the rasterisation grid: ``cells^3`` cells indexed by int32."""

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
