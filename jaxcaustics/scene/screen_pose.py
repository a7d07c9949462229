"""Where a screen stands (`ScreenPose`): a plane anywhere, with its own pixel frame.

A caustic element's screen need not be the ground ``z = 0``: a mirror's screen faces the
reflected beam, and a lens under leaning light may have its screen facing the refracted
one. A pose gives the screen's centre, the normal of its lit face (pointing back towards
the element) and its up direction; the screen's coordinates of a point ``p`` are

    s = (p - centre) . right,   t = (p - centre) . up,   right = up x normal,

so that, seen from the lit side, ``s`` runs to the right and ``t`` up (the ground's pose,
``normal = +z``, ``up = +y``, gives ``s = x``, ``t = y``). A `PlaneReceiver`'s extent
and pixel grid are then read in ``(s, t)``: ``(s_min, s_max, t_min, t_max)``.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .values import as_float_array, check_finite, check_positive_scalar, is_concrete


def _vector(value, name: str) -> Array:
    v = as_float_array(value, name)
    if v.shape != (3,):
        raise ValueError(f"`{name}` must have shape (3,), got {v.shape}")
    check_finite(v, name)
    return v


def _unit(v: Array, name: str) -> Array:
    if is_concrete(v) and not float(np.linalg.norm(np.asarray(v, float))) > 0.0:
        raise ValueError(f"`{name}` must be non-zero")
    return v / jnp.linalg.norm(v)


class ScreenPose(eqx.Module):
    """A screen's place: its centre, the normal of its lit face, its up direction.

    **Arguments:**

    - `centre`: shape ``(3,)``, metres: the origin of the screen's ``(s, t)`` frame.
    - `normal`: shape ``(3,)``: the normal of the lit face, pointing towards the light
      that lands on it (normalised here).
    - `up`: shape ``(3,)``, default ``(0, 1, 0)``: the screen's ``t`` axis is this
      direction made perpendicular to `normal` (normalised); it must not be parallel to
      `normal`.

    Build the usual one with `ScreenPose.facing` (a screen across a beam).
    """

    centre: Float[Array, "3"]
    normal: Float[Array, "3"]
    up: Float[Array, "3"]

    def __init__(self, centre, normal, up=(0.0, 1.0, 0.0)):
        self.centre = _vector(centre, "centre")
        n = _unit(_vector(normal, "normal"), "normal")
        u = _vector(up, "up")
        u = u - jnp.dot(u, n) * n
        if is_concrete(u) and not float(np.linalg.norm(np.asarray(u, float))) > 1e-6 * float(
            np.linalg.norm(np.asarray(up, float))
        ):
            raise ValueError(f"`up` {np.asarray(up).tolist()} is parallel to `normal`")
        self.normal = n
        self.up = _unit(u, "up")

    @classmethod
    def facing(cls, point, direction, distance, up=(0.0, 1.0, 0.0)) -> ScreenPose:
        """The screen across a beam: centred `distance` metres from `point` along
        `direction` (the beam's direction of travel), its lit face towards `point`."""
        d = _unit(_vector(direction, "direction"), "direction")
        distance = check_positive_scalar(distance, "distance")
        return cls(_vector(point, "point") + distance * d, -d, up)

    @property
    def right(self) -> Float[Array, "3"]:
        """The screen's ``s`` axis, ``up x normal``."""
        return jnp.cross(self.up, self.normal)

    def land(self, point, direction):
        """Where rays from `point` along `direction` (3-tuples of arrays, broadcasting)
        meet the screen's plane: ``(s, t, valid)``; `valid` is false for rays that do
        not reach its lit face ahead of them (``s, t`` are then finite but meaningless)."""
        dtype = jnp.result_type(*point, *direction)
        n, c = self.normal.astype(dtype), self.centre.astype(dtype)
        rt, up = self.right.astype(dtype), self.up.astype(dtype)
        towards = sum(direction[k] * n[k] for k in range(3))
        valid = towards < 0.0
        gap = sum((c[k] - point[k]) * n[k] for k in range(3))
        run = gap / jnp.where(valid, towards, -1.0)
        valid = valid & (run > 0.0)
        q = [point[k] + run * direction[k] - c[k] for k in range(3)]
        s = sum(q[k] * rt[k] for k in range(3))
        t = sum(q[k] * up[k] for k in range(3))
        return s, t, valid
