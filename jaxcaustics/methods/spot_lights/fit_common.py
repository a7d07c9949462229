"""Low-level pieces shared by the steps of the spot-light fit (`fit.py`): the check of a
float knob with the loop bound `MAX_LOOP`, the dtype of the inputs (`_floats`, `_tiny`), and
the geometry of ray lines against a box, an axis line and a plane."""

from __future__ import annotations

import math

import jax.numpy as jnp

from ..._checks import check_number
from ...scene.scene import is_concrete

MAX_LOOP = 2**31 - 1
"""Most iterations of a loop counted by an int32 (`axis_iterations`, `fit_steps`)."""


def _check_float(value, name: str, *, low: float, high: float = math.inf, closed: bool = False):
    """A finite real number in ``(low, high)`` (``(low, high]`` if `closed`); bools and
    strings are refused; a traced value passes unchecked."""
    if not is_concrete(value):
        return value
    return check_number(value, name, low=low, high=high, low_open=True, high_open=not closed)


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
