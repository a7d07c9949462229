"""Caustic spot lights under a moving directional light (Liu, Dong, Bao & Peng 2008, Sect. 4).

The per-scene phase fits a set of CSLs (`SpotLights`) for every vertex of a subdivided
icosahedron of light directions, matches the CSLs of neighbouring directions by tracking
their axes while the light moves along the edge (Sect. 4.2) and assembles CSL *triples* on
every face (Sect. 4.3). The per-frame phase (`interpolate_spot_lights`) finds the face the
current light direction falls in and blends each triple with the barycentric weights
(Sect. 4.1).

Conventions:

- A vertex of the icosphere is the unit direction *towards* the light; the light travels
  along ``-vertex``. `interpolate_spot_lights` takes the direction of travel.
- Edges are the sorted vertex pairs ``(a, b)``, ``a < b``, in the order of
  `direction_edges`. Tracking runs both ways along every edge: ``[e, 0]`` holds the lights
  of ``a`` moved to ``b`` and ``[e, 1]`` those of ``b`` moved to ``a``.
- Axis distance (Sect. 4.2): ``dist(A0, A1) = sqrt(|b0 - b1|^2 + D^2 |a0 - a1|^2)`` with
  ``b`` the point of the axis nearest to the object's centre (a point may slide along an
  axis) and ``D`` the object's size (the largest side of its bounding box, the bounding
  sphere's diameter for a round object); the paper's ``B`` is ``D^2`` so both terms are
  squared lengths.
- The lights of the table have canonical frames: ``frame_u = orthonormal_basis(axis)[0]``
  (a fitted light with another frame has its image resampled once, when the table is built),
  which is also the frame of every interpolated light; so interpolating at a vertex gives
  that vertex's lights exactly.

Tracking (Sect. 4.2). Every edge is tracked both ways (``a`` to ``b`` and ``b`` to ``a``;
`precompute_spot_lights`), refining the axes slot by slot with the rays of earlier slots
removed, as the fit found them; the lights of each edge are then matched and the triples of
each face assembled (`build_spot_light_table`, `matching.py`).

The pieces live in their own modules: `directions.py` (the icosphere of light directions),
`light_table.py` (`SpotLightTable`, its file form and the per-frame
`interpolate_spot_lights`), `frames.py` (light-plane frames, image resampling) and
`matching.py` (matching and triples); this module holds the precomputation and
re-exports their public names.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..._checks import check_bool, check_fits, check_int, check_memory_limit, check_number
from ...devices import check_per_device, map_sharded, resolve_devices
from .bundles import check_refine_knobs, refine_axis
from .directions import MAX_SUBDIVISIONS, direction_edges, icosphere_directions, slerp
from .exit_rays import EXIT_RAY_FLOATS, trace_exit_rays
from .fit import DISTANCE_THRESHOLD, check_fit_knobs, fit_bytes, fit_spot_lights
from .frames import _normalise
from .light_table import (
    _LIGHT_FIELDS,
    SpotLightTable,
    _stacked_spot_lights,
    interpolate_in_face,
    interpolate_spot_lights,
)
from .matching import DEFAULT_MATCH_FRACTION, axis_distance, build_spot_light_table, greedy_match

__all__ = [
    "DEFAULT_MATCH_FRACTION",
    "MAX_SUBDIVISIONS",
    "SpotLightTable",
    "axis_distance",
    "build_spot_light_table",
    "direction_edges",
    "fit_direction",
    "greedy_match",
    "icosphere_directions",
    "interpolate_in_face",
    "interpolate_spot_lights",
    "precompute_spot_lights",
    "slerp",
]


# --------------------------------------------------------------------------------------
# Precomputation


def fit_direction(scene, direction, *, rays_per_axis, fit_knobs, memory_limit=None):
    """The CSL set for a light travelling along `direction` ``(3,)``, and the object's
    centre and size: `trace_exit_rays` with `rays_per_axis`, then `fit_spot_lights` with
    `fit_knobs`, as `precompute_spot_lights` fits each direction of its table."""

    rays = trace_exit_rays(scene, rays_per_axis, direction=direction, memory_limit=memory_limit)
    lights, _ = fit_spot_lights(rays, memory_limit=memory_limit, **fit_knobs)
    return lights, rays.centre, rays.size


def _track_edge(scene, item, *, steps, rays_per_axis, refine_knobs, memory_limit=None):
    """Track the axes of one light set while the light moves from ``item["s0"]`` to
    ``item["s1"]`` (vertex directions) in `steps` slerp steps (Sect. 4.2).

    At every step rays are traced and each active axis moves with `refine_axis` from its
    previous position, slot by slot as the fit found them: the rays assigned to a slot
    leave the pool before the next slot is refined (as a fitted bundle's rays leave the
    set before the next bundle is sought), so a weak light is not pulled onto the rays of
    a strong one. The light-plane origin follows as the point of the new axis nearest to
    the old origin. An axis whose bundle lost all rays, or went non-finite, stays where it
    was. **Returns** the moved ``(origin (K, 3), axis (K, 3))``.
    """

    def step(carry, t):
        origin, axis = carry
        s = slerp(item["s0"], item["s1"], t)
        rays = trace_exit_rays(scene, rays_per_axis, direction=-s, memory_limit=memory_limit)

        def one(pool, light):
            old_origin, old_axis, active = light
            point, new_axis, member = refine_axis(
                rays.origin, rays.direction, pool, old_origin, old_axis, **refine_knobs
            )
            new_axis = _normalise(new_axis)
            ok = active & jnp.any(member) & jnp.all(jnp.isfinite(point))
            ok = ok & jnp.all(jnp.isfinite(new_axis))
            new_origin = point + jnp.dot(old_origin - point, new_axis) * new_axis
            pool = jnp.where(ok & member, 0.0, pool)
            return pool, (
                jnp.where(ok, new_origin, old_origin),
                jnp.where(ok, new_axis, old_axis),
            )

        pool = jnp.where(rays.energy > 0, rays.energy, 0.0)
        _, moved = jax.lax.scan(one, pool, (origin, axis, item["active"]))
        return moved, None

    ts = jnp.arange(1, steps + 1, dtype=item["s0"].dtype) / steps
    (origin, axis), _ = jax.lax.scan(step, (item["origin"], item["axis"]), ts)
    return origin, axis


_REFINE_KNOBS = {"distance_threshold": 1.0, "angle_threshold_deg": 60.0, "iterations": 100}
"""The knobs of `refine_axis` (with placeholder values, to check a partial dict)."""


def _check_table_memory(
    subdivisions, rays_per_axis, tracking_rays, tracking_steps, knobs, *, in_flight, memory_limit
) -> None:
    """Refuse a precomputation whose work in flight on a device does not fit in
    `memory_limit`: `in_flight` fits (`fit_bytes`) or edge trackings (`tracking_rays^2`
    rays of `EXIT_RAY_FLOATS` numbers: 21 measured in float64 with `refine_axis`; the
    `tracking_steps` slerp parameters), and the
    table's light images (``V x max_lights x resolution^2``, twice: fitted, canonical)."""

    itemsize = jnp.dtype(jnp.result_type(float)).itemsize
    sizes = {n: knobs[n] for n in ("max_lights", "resolution", "cells", "splat_window", "chunk")}
    fit = fit_bytes(rays_per_axis**2, jnp.result_type(float), **sizes)
    track = (EXIT_RAY_FLOATS * tracking_rays**2 + tracking_steps) * itemsize
    directions = 10 * 4**subdivisions + 2
    table = 2 * directions * knobs["max_lights"] * knobs["resolution"] ** 2 * itemsize
    check_fits(
        in_flight * max(fit, track) + table,
        memory_limit,
        f"precomputing spot lights for {directions} directions",
        "lower `rays_per_axis`, `tracking_rays_per_axis`, `tracking_steps`, `subdivisions`, "
        "`chunk` or the fit's `max_lights`, `resolution`, `cells`",
    )


def _default_refine_knobs(fit_knobs: dict, size: float) -> dict:
    """`refine_axis` settings matching the fit's: its ``distance_threshold`` (default
    ``DISTANCE_THRESHOLD x size``), ``angle_threshold_deg`` and ``axis_iterations``, given
    in `fit_knobs` or defaulted by `fit_spot_lights`."""
    import inspect

    defaults = {
        name: p.default for name, p in inspect.signature(fit_spot_lights).parameters.items()
    }
    distance = fit_knobs.get("distance_threshold")
    return {
        "distance_threshold": DISTANCE_THRESHOLD * size if distance is None else distance,
        "angle_threshold_deg": fit_knobs.get(
            "angle_threshold_deg", defaults["angle_threshold_deg"]
        ),
        "iterations": fit_knobs.get("axis_iterations", defaults["axis_iterations"]),
    }


def precompute_spot_lights(
    scene,
    *,
    subdivisions: int = 2,
    rays_per_axis: int = 256,
    tracking_steps: int = 20,
    tracking_rays_per_axis: int | None = None,
    match_threshold: float | None = None,
    refine_knobs: dict | None = None,
    devices: Sequence[jax.Device] | int | None = None,
    chunk: int | None = None,
    progress: bool = True,
    per_device: str | None = None,
    memory_limit: int | None = None,
    **fit_knobs,
) -> SpotLightTable:
    """The per-scene phase of Sect. 4: CSL sets for the icosphere's directions, tracked
    matches along its edges and triples on its faces.

    1. For every vertex direction: `trace_exit_rays` with the light travelling along
       ``-vertex`` and `fit_spot_lights` (one jitted function, vmapped over directions).
    2. For every edge, both ways: the light moves from one end to the other in
       `tracking_steps` slerp steps, rays are traced at each and every active axis moves
       with `refine_axis` (vmapped over directed edges).
    3. On the host: greedy matching by axis distance (`build_spot_light_table`), triples.

    Steps 1 and 2 are sharded across `devices` (`map_sharded`).

    **Arguments:**

    - `scene`: a scene `trace_exit_rays` accepts (its light's direction is replaced).
    - `subdivisions`: of the icosahedron (2: 162 directions, 480 edges, 320 faces).
    - `rays_per_axis`: rays per side of the grid traced for each fit.
    - `tracking_steps`: steps per edge (the paper's 20).
    - `tracking_rays_per_axis`: rays per side while tracking (default `rays_per_axis`).
    - `match_threshold`: largest axis distance of a match (m); default
      `DEFAULT_MATCH_FRACTION` times the object's size.
    - `refine_knobs`: keyword arguments of `refine_axis` (``distance_threshold``,
      ``angle_threshold_deg``, ``iterations``); those not given: the fit's (given in
      `fit_knobs` or defaulted by `fit_spot_lights`).
    - `devices`: devices to shard over (default `jax.devices()`).
    - `chunk`: directions (or directed edges) per batch; default 4 per device.
    - `progress`: tqdm progress bars over the chunks.
    - `per_device`: ``"map"`` (items one after the other on each device; the default on
      CPU) or ``"vmap"`` (vectorised; the default on GPU/TPU); see `map_sharded`.
    - `memory_limit`: bytes per device (default 1 GiB): the fits and trackings in
      flight on a device (`fit_bytes` each; one, or a chunk's share with ``"vmap"``) and
      the table's light images; more raise a `ValueError` before any work.
    - `fit_knobs`: keyword arguments of `fit_spot_lights` (``max_lights``, ...).
    """

    subdivisions = check_int(subdivisions, "subdivisions", 0, MAX_SUBDIVISIONS)
    rays_per_axis = check_int(rays_per_axis, "rays_per_axis", 2)
    tracking_steps = check_int(tracking_steps, "tracking_steps", 1)
    tracking_rays = rays_per_axis if tracking_rays_per_axis is None else tracking_rays_per_axis
    tracking_rays = check_int(tracking_rays, "tracking_rays_per_axis", 2)
    if match_threshold is not None:
        match_threshold = check_number(match_threshold, "match_threshold", low=0.0, unit="metres")
    refine_knobs = {} if refine_knobs is None else refine_knobs
    if not isinstance(refine_knobs, dict):
        raise ValueError(f"`refine_knobs` must be a dict, got {type(refine_knobs).__name__}")
    unknown = sorted(set(refine_knobs) - set(_REFINE_KNOBS))
    if unknown:
        raise ValueError(f"`refine_knobs` holds {unknown}, not knobs of refine_axis")
    check_refine_knobs(**{**_REFINE_KNOBS, **refine_knobs})
    knob_values = check_fit_knobs(**fit_knobs)
    progress = check_bool(progress, "progress")
    devices = resolve_devices(devices)
    per_device = check_per_device(per_device, devices)
    chunk = check_int(4 * len(devices) if chunk is None else chunk, "chunk", 1)
    _check_table_memory(
        subdivisions,
        rays_per_axis,
        tracking_rays,
        tracking_steps,
        knob_values,
        in_flight=-(-chunk // len(devices)) if per_device == "vmap" else 1,
        memory_limit=check_memory_limit(memory_limit),
    )

    directions, faces = icosphere_directions(subdivisions)
    edges = direction_edges(faces)
    dtype = jnp.result_type(float)
    lights, centres, sizes = map_sharded(
        lambda sc, d: fit_direction(
            sc, d, rays_per_axis=rays_per_axis, fit_knobs=fit_knobs, memory_limit=memory_limit
        ),
        scene,
        jnp.asarray(-directions, dtype),
        devices=devices,
        chunk=chunk,
        progress=progress,
        desc="CSL sets",
        per_device=per_device,
    )
    centre, size = centres[0], float(sizes[0])
    knobs = {**_default_refine_knobs(fit_knobs, size), **refine_knobs}

    start = np.concatenate([edges[:, 0], edges[:, 1]])  # directed edges: a->b, then b->a
    end = np.concatenate([edges[:, 1], edges[:, 0]])
    items = {
        "s0": directions[start].astype(dtype),
        "s1": directions[end].astype(dtype),
        "origin": np.asarray(lights.origin)[start],
        "axis": np.asarray(lights.axis)[start],
        "active": np.asarray(lights.active)[start],
    }
    moved_origin, moved_axis = map_sharded(
        lambda sc, it: _track_edge(
            sc,
            it,
            steps=tracking_steps,
            rays_per_axis=tracking_rays,
            refine_knobs=knobs,
            memory_limit=memory_limit,
        ),
        scene,
        items,
        devices=devices,
        chunk=chunk,
        progress=progress,
        desc="tracking",
        per_device=per_device,
    )
    e = len(edges)
    moved_origin = np.stack([moved_origin[:e], moved_origin[e:]], axis=1)
    moved_axis = np.stack([moved_axis[:e], moved_axis[e:]], axis=1)
    return build_spot_light_table(
        directions,
        faces,
        _stacked_spot_lights({name: getattr(lights, name) for name in _LIGHT_FIELDS}),
        moved_origin,
        moved_axis,
        centre=centre,
        size=size,
        match_threshold=match_threshold,
    )
