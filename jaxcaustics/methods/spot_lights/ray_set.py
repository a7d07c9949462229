"""The input of the spot-light fit (`fit.py`): `RaySet`, the rays leaving a caustic
object, and its conversion from plain arrays (`ray_set`) or an ``ExitRays``-like object
(`as_ray_set`)."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from ...scene.scene import as_float_array, check_finite, is_concrete
from .exit_rays import ExitRays

RaySet = ExitRays
"""Rays leaving a caustic object: the ray tracer's `ExitRays` (origin ``(R, 3)``, unit
direction ``(R, 3)``, energy ``(R,)`` (0: an invalid ray), emission grid `spacing`, the
object's bounding-box `centre` ``(3,)`` and `size`, metres)."""


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
