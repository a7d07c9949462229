"""The layered distance map (Umenhoffer, Patow & Szirmay-Kalos): the receiver plane and
the occluders around a caustic generator, sampled from one reference point ``c`` (the
centre) into a cube map; every texel stores, per layer, the distance, normal and
material of a surface seen in the texel's direction (`LayeredDistanceMap`,
`build_distance_map`)."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ...scene.mesh import Mesh
from ...trace.intersect import face_normals, ray_triangle_distances
from .cube_faces import _float_dtype, texel_directions

MATERIAL_EMPTY = 0
MATERIAL_RECEIVER = 1
MATERIAL_OCCLUDER = 2  # occluder k has material 2 + k


class LayeredDistanceMap(eqx.Module):
    """The scene around a reference point, sampled into a layered cube map.

    **Arguments:**

    - `center`: shape ``(3,)``, the reference point ``c`` (metres).
    - `distance`: shape ``(layers, 6, R, R)``, distance from ``c`` to the surface seen in
      each texel's centre direction, per layer (metres); ``inf`` where the layer is
      empty.
    - `normal`: shape ``(layers, 6, R, R, 3)``, unit geometric normal of that surface,
      turned towards ``c`` (zero where empty).
    - `material`: shape ``(layers, 6, R, R)`` int32: 0 empty, 1 the receiver plane
      ``z = 0``, ``2 + k`` occluder ``k``.
    - `resolution`: ``R`` (static).
    - `layers`: number of layers (static).
    """

    center: Float[Array, "3"]
    distance: Float[Array, "layers 6 R R"]
    normal: Float[Array, "layers 6 R R 3"]
    material: Int[Array, "layers 6 R R"]
    resolution: int = eqx.field(static=True)
    layers: int = eqx.field(static=True)

    def planes(self) -> tuple[Float[Array, "layers 6 R R 3"], Bool[Array, "layers 6 R R"]]:
        """Each texel's surface as a plane, for `trace_distance_map`.

        **Returns:** ``(g, present)``: ``g = n / (n . (p - c))`` for the stored point
        ``p`` and normal ``n`` (so a point ``x`` lies on the texel's tangent plane iff
        ``g . (x - c) = 1``, and ``g . (x - c) = |x - c| / |x' - c|`` compares ``x`` with
        the plane's point ``x'`` in the same direction), shape ``(layers, 6, R, R, 3)``;
        and the mask of non-empty texels. Empty texels get ``g = 0``. A texel whose
        surface is seen almost edge-on (``|n . w| < 1e-3``) falls back to the sphere
        ``g = w / distance`` (``w``: unit texel direction): a plain distance comparison,
        as in the paper.
        """
        w = texel_directions(self.resolution, dtype=self.distance.dtype)[None]
        present = jnp.isfinite(self.distance)
        dist = jnp.where(present, self.distance, 1.0)
        cos = jnp.sum(self.normal * w, axis=-1)
        grazing = jnp.abs(cos) < 1e-3
        q = jnp.where(grazing, 1.0, cos * dist)
        g = jnp.where(grazing[..., None], w / dist[..., None], self.normal / q[..., None])
        return jnp.where(present[..., None], g, 0.0), present


def _occluder_triangles(occluders: Sequence[Mesh], dtype):
    tris, mats, normals = [], [], []
    for k, occ in enumerate(occluders):
        if not isinstance(occ, Mesh):
            raise ValueError(f"`occluders[{k}]` must be a Mesh, got {type(occ).__name__}")
        t = jnp.asarray(occ.triangles, dtype=dtype)
        n = face_normals(jnp.asarray(occ.vertices, dtype=dtype), occ.faces)
        tris.append(t)
        normals.append(n / jnp.maximum(jnp.linalg.norm(n, axis=-1, keepdims=True), 1e-30))
        mats.append(jnp.full((t.shape[0],), MATERIAL_OCCLUDER + k, jnp.int32))
    if not tris:
        return (
            jnp.zeros((0, 3, 3), dtype),
            jnp.zeros((0, 3), dtype),
            jnp.zeros((0,), jnp.int32),
        )
    return jnp.concatenate(tris), jnp.concatenate(normals), jnp.concatenate(mats)


def _all_hits(center, dirs, tris, tri_normals, receiver: bool, cull: bool):
    """Ray parameters ``(B, K)`` of every surface crossing of rays from `center`, with
    the surface normals ``(B, K, 3)`` (not yet oriented); receiver plane first."""
    b = dirs.shape[0]
    dtype = dirs.dtype
    ts, ns = [], []
    if receiver:
        dz = dirs[:, 2]
        safe = jnp.where(dz != 0, dz, 1.0)
        t = jnp.where(dz != 0, -center[2] / safe, jnp.inf)
        hit = t > 0
        if cull:
            hit = hit & (dz < 0)  # the plane faces +z: seen from above only
        ts.append(jnp.where(hit, t, jnp.inf)[:, None])
        ns.append(jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0], dtype), (b, 1, 3)))
    if tris.shape[0]:
        t = ray_triangle_distances(jnp.broadcast_to(center, dirs.shape), dirs, tris)
        if cull:
            t = jnp.where(dirs @ tri_normals.T < 0, t, jnp.inf)
        ts.append(t)
        ns.append(jnp.broadcast_to(tri_normals[None], (b,) + tri_normals.shape))
    return jnp.concatenate(ts, axis=1), jnp.concatenate(ns, axis=1)


def build_distance_map(
    center: Float[Array, "3"],
    occluders: Sequence[Mesh] = (),
    resolution: int = 128,
    layers: int = 2,
    receiver: bool = True,
    *,
    cull_back_faces: bool = True,
    batch_size: int = 4096,
) -> LayeredDistanceMap:
    """Sample the receiver plane and the occluders into a layered distance map.

    A ray is cast from `center` through every texel centre against the receiver plane
    ``z = 0`` (material 1, normal ``+z``) and every occluder triangle (material
    ``2 + k``); the `layers` nearest hits are kept, sorted by distance (depth-peeling
    order). The paper allows any assignment of surfaces to layers that keeps each layer
    smooth; we use nearest-first. Coincident hits (a texel ray through an edge shared by
    two triangles, or a face lying on the plane) are counted once. No derivatives flow
    through the map (`stop_gradient`).

    **Arguments:**

    - `center`: shape ``(3,)``, the reference point (metres), usually inside the caustic
      generator, above the receiver.
    - `occluders`: opaque `Mesh` objects.
    - `resolution`: ``R``, texels per face edge.
    - `layers`: how many surfaces to keep per texel.
    - `receiver`: include the receiver plane ``z = 0``.
    - `cull_back_faces`: keep only surfaces that face the centre (the receiver from
      above, occluder triangles whose outward normal, from the counter-clockwise winding,
      points towards ``c``). For closed, outward-oriented occluders this keeps the
      visible sides and gives the layer behind an occluder to the surface behind it
      rather than to the occluder's far side. With ``False`` every crossing counts
      (entry and exit of a closed mesh take one layer each).
    - `batch_size`: rays per step of the brute-force search (memory ``batch * F``).

    **Returns:** a `LayeredDistanceMap`.
    """
    if isinstance(layers, bool) or not isinstance(layers, int) or layers < 1:
        raise ValueError(f"`layers` must be an integer >= 1, got {layers!r}")
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 2:
        raise ValueError(f"`resolution` must be an integer >= 2, got {resolution!r}")
    center = jnp.asarray(center)
    dtype = _float_dtype(center, *[o.vertices for o in occluders])
    center = jax.lax.stop_gradient(center.astype(dtype))
    if center.shape != (3,):
        raise ValueError(f"`center` must have shape (3,), got {center.shape}")
    tris, tri_normals, tri_mats = _occluder_triangles(occluders, dtype)
    tris, tri_normals = jax.lax.stop_gradient(tris), jax.lax.stop_gradient(tri_normals)
    if not receiver and tris.shape[0] == 0:
        raise ValueError("nothing to sample: `receiver` is False and there are no occluders")
    mats = jnp.concatenate(
        ([jnp.full((1,), MATERIAL_RECEIVER, jnp.int32)] if receiver else []) + [tri_mats]
    )
    dirs = texel_directions(resolution, dtype=dtype).reshape(-1, 3)
    return _build(
        center,
        dirs,
        tris,
        tri_normals,
        mats,
        resolution,
        layers,
        receiver,
        cull_back_faces,
        batch_size,
    )


@eqx.filter_jit
def _build(center, dirs, tris, tri_normals, mats, resolution, layers, receiver, cull, batch):
    def one(d):
        t, n = _all_hits(center, d[None], tris, tri_normals, receiver, cull)
        t, n = t[0], n[0]
        order = jnp.argsort(t)
        ts = t[order]
        prev = jnp.concatenate([jnp.full((1,), -jnp.inf, t.dtype), ts[:-1]])
        dup = jnp.isfinite(ts) & (ts <= prev * (1.0 + 1e-9) + 1e-12)
        ts = jnp.where(dup, jnp.inf, ts)
        again = jnp.argsort(ts, stable=True)
        t, order = ts[again], order[again]
        k = min(layers, t.shape[0])
        t, idx = t[:k], order[:k]
        found = jnp.isfinite(t)
        nrm = n[idx]
        nrm = jnp.where(jnp.sum(nrm * d, axis=-1, keepdims=True) > 0, -nrm, nrm)
        mat = jnp.where(found, mats[idx], MATERIAL_EMPTY)
        pad = layers - k
        if pad:
            t = jnp.concatenate([t, jnp.full((pad,), jnp.inf, t.dtype)])
            nrm = jnp.concatenate([nrm, jnp.zeros((pad, 3), nrm.dtype)])
            mat = jnp.concatenate([mat, jnp.zeros((pad,), mat.dtype)])
            found = jnp.concatenate([found, jnp.zeros((pad,), bool)])
        return t, jnp.where(found[:, None], nrm, 0.0), mat.astype(jnp.int32)

    t, n, m = jax.lax.map(one, dirs, batch_size=batch)
    r = resolution

    def layout(a):
        return jnp.moveaxis(a.reshape((6, r, r) + a.shape[1:]), 3, 0)

    return LayeredDistanceMap(
        center=center,
        distance=layout(t),
        normal=layout(n),
        material=layout(m),
        resolution=resolution,
        layers=layers,
    )
