"""Ray/triangle intersection kernels (JAX), shared by photon tracing and distance maps.

Visibility (*which* triangle a ray meets first) is a discrete choice and carries no
derivative: `nearest_hits` returns indices under `stop_gradient`. The hit itself is then
recomputed from that triangle's vertices by `hit_on_triangle` (Möller–Trumbore), which is
differentiable with respect to the ray and the vertices.

The search is brute force over all triangles, in batches of rays (`batch_size`) so that
memory stays at ``batch_size * F`` per step; it is exact and device-agnostic.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


def _cross(a: Array, b: Array) -> Array:
    return jnp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def _dot(a: Array, b: Array) -> Array:
    return jnp.sum(a * b, axis=-1)


def moller_trumbore(origin, direction, v0, v1, v2):
    """Ray ``origin + t direction`` against triangles ``(v0, v1, v2)`` (broadcasting).

    **Returns:** ``(t, b1, b2, det)``: the ray parameter, the barycentric weights of
    ``v1`` and ``v2`` (``b0 = 1 - b1 - b2``) and the determinant (0 for a ray parallel to
    the triangle's plane, where the other outputs are 0 instead of infinite).
    """
    e1, e2 = v1 - v0, v2 - v0
    p = _cross(direction, e2)
    det = _dot(e1, p)
    parallel = jnp.abs(det) < jnp.finfo(det.dtype).tiny
    inv = jnp.where(parallel, 0.0, 1.0 / jnp.where(parallel, 1.0, det))
    s = origin - v0
    b1 = _dot(s, p) * inv
    q = _cross(s, e1)
    b2 = _dot(direction, q) * inv
    t = _dot(e2, q) * inv
    return t, b1, b2, det


def ray_triangle_distances(
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    triangles: Float[Array, "F 3 3"],
    t_min: float | Array = 0.0,
) -> Float[Array, "P F"]:
    """Ray parameter of every ray/triangle hit with ``t > t_min``; ``inf`` for misses.

    Edges count as inside (``b >= 0``), so a ray through a shared edge or vertex of a
    closed mesh is not lost between its triangles.
    """
    o = origins[:, None, :]
    d = directions[:, None, :]
    t, b1, b2, det = moller_trumbore(
        o, d, triangles[None, :, 0], triangles[None, :, 1], triangles[None, :, 2]
    )
    hit = (det != 0) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > t_min)
    return jnp.where(hit, t, jnp.inf)


def nearest_hits(
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    triangles: Float[Array, "F 3 3"],
    t_min: float | Array = 0.0,
    batch_size: int = 4096,
    exclude: Int[Array, " P"] | None = None,
) -> tuple[Float[Array, " P"], Int[Array, " P"]]:
    """Nearest hit of each ray among `triangles` (no derivatives).

    `exclude` (optional, one index per ray, -1 for none) is a triangle each ray must not
    hit: the one it just left, which a straight ray cannot meet again.

    **Returns:** ``(t, index)``: the ray parameter (``inf`` when the ray misses every
    triangle) and the triangle's index (0 for a miss; check ``isfinite(t)``).
    """
    sg = jax.lax.stop_gradient
    origins, directions, triangles = sg(origins), sg(directions), sg(triangles)

    if exclude is None:
        exclude = jnp.full(origins.shape[:1], -1, jnp.int32)
    index = jnp.arange(triangles.shape[0], dtype=jnp.int32)

    def one(ray):
        o, d, skip = ray
        t = ray_triangle_distances(o[None], d[None], triangles, t_min)[0]
        t = jnp.where(index == skip, jnp.inf, t)
        k = jnp.argmin(t)
        return t[k], k.astype(jnp.int32)

    return jax.lax.map(one, (origins, directions, exclude), batch_size=batch_size)


def hit_on_triangle(
    origin: Float[Array, "... 3"],
    direction: Float[Array, "... 3"],
    triangle: Float[Array, "... 3 3"],
) -> tuple[Float[Array, "..."], Float[Array, "... 3"]]:
    """Differentiable hit of rays with given triangles (whose index was chosen already).

    **Returns:** ``(t, barycentric)`` with ``barycentric = (b0, b1, b2)`` along the last
    axis.
    """
    t, b1, b2, _ = moller_trumbore(
        origin, direction, triangle[..., 0, :], triangle[..., 1, :], triangle[..., 2, :]
    )
    return t, jnp.stack([1.0 - b1 - b2, b1, b2], axis=-1)


def face_normals(vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"]) -> Float[Array, "F 3"]:
    """Unnormalised face normals ``(v1 - v0) x (v2 - v0)`` (length = twice the area)."""
    tri = vertices[faces]
    return _cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def vertex_normals(vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"]) -> Float[Array, "V 3"]:
    """Unit vertex normals: the normalised sum of the area-weighted normals of the faces
    around each vertex."""
    fn = face_normals(vertices, faces)
    acc = jnp.zeros_like(vertices).at[faces.reshape(-1)].add(jnp.repeat(fn, 3, axis=0))
    norm = jnp.linalg.norm(acc, axis=-1, keepdims=True)
    return acc / jnp.where(norm > 0, norm, 1.0)
