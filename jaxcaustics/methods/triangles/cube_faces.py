"""The cube-map faces that the layered distance map and the light cube map share: each
face's frame, the face of a direction (`direction_face`), the gnomonic projection onto a
face (`face_coordinates`) and the directions through the texel centres
(`texel_directions`).

**Cube-map convention.** Faces are numbered ``0..5`` = ``+x, -x, +y, -y, +z, -z``.
Face ``f`` has outward axis ``N`` and image axes ``U`` (columns, pixel ``x``) and ``V``
(rows, pixel ``y``); for a positive face of axis ``k`` they are ``U = e[k+1]``,
``V = e[k+2]``, for a negative face ``U = e[k+2]``, ``V = e[k+1]`` (indices mod 3), so
that ``U x V = N`` always:

====  ==========  ==========  ==========
face  N           U (x)       V (y)
====  ==========  ==========  ==========
0     +x          +y          +z
1     -x          +z          +y
2     +y          +z          +x
3     -y          +x          +z
4     +z          +x          +y
5     -z          +y          +x
====  ==========  ==========  ==========

A direction ``d`` with ``d.N > 0`` projects (gnomonic projection) to
``u = d.U / d.N``, ``v = d.V / d.N`` in ``[-1, 1]`` on its own face, and to pixel
coordinates ``x = (u + 1) R / 2``, ``y = (v + 1) R / 2`` of an ``R x R`` face. Texel
``(i, j)`` (row ``i``, column ``j``) covers ``x`` in ``[j, j + 1]``, ``y`` in
``[i, i + 1]``, the convention of `jaxcaustics.reconstruct.raster`; its centre direction is
``N + u U + v V`` at ``x = j + 1/2``, ``y = i + 1/2``. A direction belongs to the face of
its largest absolute component (ties go to the lower face number).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

# (N, U, V) per face, in the order +x, -x, +y, -y, +z, -z.
_FRAMES = np.zeros((6, 3, 3))
for _k in range(3):
    _e = np.eye(3)
    _FRAMES[2 * _k] = [_e[_k], _e[(_k + 1) % 3], _e[(_k + 2) % 3]]
    _FRAMES[2 * _k + 1] = [-_e[_k], _e[(_k + 2) % 3], _e[(_k + 1) % 3]]
del _k, _e


def _frames(dtype) -> Array:
    return jnp.asarray(_FRAMES, dtype=dtype)


def _float_dtype(*arrays) -> jnp.dtype:
    dtype = jnp.result_type(*arrays)
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


def direction_face(directions: Float[Array, "... 3"]) -> Int[Array, "..."]:
    """The cube face (``0..5`` = ``+x, -x, +y, -y, +z, -z``) of each direction: the
    axis of the largest absolute component and its sign (the zero vector gives 0)."""
    axis = jnp.argmax(jnp.abs(directions), axis=-1)
    comp = jnp.take_along_axis(directions, axis[..., None], axis=-1)[..., 0]
    return (2 * axis + (comp < 0)).astype(jnp.int32)


def face_coordinates(
    directions: Float[Array, "... 3"], face: Int[Array, "..."] | int, resolution: int
) -> tuple[Float[Array, "..."], Float[Array, "..."], Float[Array, "..."]]:
    """Gnomonic projection of directions onto a given cube face, in pixel units.

    Works for any face, not only the direction's own: a triangle whose vertices spill
    over a face edge keeps straight edges on the face's (extended) image plane, so it can
    be drawn there and clipped to the image.

    **Arguments:**

    - `directions`: shape ``(..., 3)``, need not be unit (points relative to the centre).
    - `face`: face index ``0..5``, broadcasting against ``directions[..., 0]``.
    - `resolution`: ``R``, texels per face edge.

    **Returns:** ``(x, y, depth)``: pixel coordinates on the face (``[0, R]`` inside the
    face's image) and ``depth = d . N``, the component along the face's outward axis.
    Only where ``depth > 0`` is the projection meaningful; elsewhere ``x, y`` are finite
    but arbitrary (the direction is behind the face's plane).
    """
    frames = _frames(_float_dtype(directions))[face]
    n, u_axis, v_axis = frames[..., 0, :], frames[..., 1, :], frames[..., 2, :]
    depth = jnp.sum(directions * n, axis=-1)
    safe = jnp.where(depth > 0, depth, 1.0)
    u = jnp.where(depth > 0, jnp.sum(directions * u_axis, axis=-1) / safe, 0.0)
    v = jnp.where(depth > 0, jnp.sum(directions * v_axis, axis=-1) / safe, 0.0)
    half = 0.5 * resolution
    return (u + 1.0) * half, (v + 1.0) * half, depth


def texel_directions(resolution: int, *, normalize: bool = True, dtype=None) -> Array:
    """Directions through the texel centres, shape ``(6, R, R, 3)`` indexed
    ``[face, row, column]``; unit vectors, or (``normalize=False``) ``N + u U + v V``
    (component 1 along the face axis)."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    frames = _frames(dtype)
    c = (jnp.arange(resolution, dtype=dtype) + 0.5) * (2.0 / resolution) - 1.0
    v, u = jnp.meshgrid(c, c, indexing="ij")
    w = (
        frames[:, None, None, 0, :]
        + u[None, :, :, None] * frames[:, None, None, 1, :]
        + v[None, :, :, None] * frames[:, None, None, 2, :]
    )
    if normalize:
        w = w / jnp.linalg.norm(w, axis=-1, keepdims=True)
    return w


def _texel_index(x: Array, y: Array, resolution: int) -> tuple[Array, Array]:
    """Row and column of the texel holding pixel coordinates ``(x, y)`` (clamped)."""
    col = jnp.clip(jnp.floor(x), 0, resolution - 1).astype(jnp.int32)
    row = jnp.clip(jnp.floor(y), 0, resolution - 1).astype(jnp.int32)
    return row, col
