"""Layered distance maps and light cube maps (Umenhoffer, Patow & Szirmay-Kalos).

T. Umenhoffer, G. Patow, L. Szirmay-Kalos, "Caustic Triangles on the GPU" (2008), and
"Robust Multiple Specular Reflections and Refractions" (GPU Gems 3, 2007).

The scene around a caustic generator is sampled from one *reference point* ``c`` (the
centre) into a cube map: every texel stores, per layer, the distance, normal and
material of a surface seen in the texel's direction (`build_distance_map`). Rays that
leave the generator are traced against this sampled scene (`trace_distance_map`): a
linear search along the ray for the first sample that passes from *undershooting*
(``|l - c| < |l' - c|``, the point is in front of the stored surface seen in its
direction) to *overshooting* in some layer, then a secant search inside that bracket.

Caustic triangles (terminal photon hits of three neighbouring photons) are then drawn
onto the faces of a *light cube map* around the same centre (`light_cube_map`), which
stores, per texel, the irradiance and the distance of the surface the caustic landed
on. The camera pass (`project_light_cube_map`) looks the light cube map up in the
direction of a shaded point and, like a shadow map, accepts the texel only when its
stored distance matches the point's: caustics do not leak behind occluders.

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

from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ...reconstruct.raster import rasterize_gouraud, window_for
from ...scene.mesh import Mesh
from ...trace.intersect import face_normals, nearest_hits, ray_triangle_distances

# (N, U, V) per face, in the order +x, -x, +y, -y, +z, -z.
_FRAMES = np.zeros((6, 3, 3))
for _k in range(3):
    _e = np.eye(3)
    _FRAMES[2 * _k] = [_e[_k], _e[(_k + 1) % 3], _e[(_k + 2) % 3]]
    _FRAMES[2 * _k + 1] = [-_e[_k], _e[(_k + 2) % 3], _e[(_k + 1) % 3]]
del _k, _e

MATERIAL_EMPTY = 0
MATERIAL_RECEIVER = 1
MATERIAL_OCCLUDER = 2  # occluder k has material 2 + k


def _frames(dtype) -> Array:
    return jnp.asarray(_FRAMES, dtype=dtype)


def _float_dtype(*arrays) -> jnp.dtype:
    dtype = jnp.result_type(*arrays)
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


# --------------------------------------------------------------------------------------
# Cube-map geometry
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Layered distance map
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Ray tracing in the layered distance map
# --------------------------------------------------------------------------------------


class DistanceMapHit(eqx.Module):
    """Result of `trace_distance_map`, per ray.

    - `point`: shape ``(P, 3)``, the hit point (the ray's origin where not found).
    - `distance`: shape ``(P,)``, the ray parameter ``d`` with ``point = o + d R``
      (in units of ``|R|``; ``inf`` where not found).
    - `layer`: shape ``(P,)`` int32, the layer whose surface was hit (-1: none).
    - `material`: shape ``(P,)`` int32, that surface's material (0: none).
    - `normal`: shape ``(P, 3)``, its stored unit normal (zero where not found).
    - `found`: shape ``(P,)`` bool.
    """

    point: Float[Array, "P 3"]
    distance: Float[Array, " P"]
    layer: Int[Array, " P"]
    material: Int[Array, " P"]
    normal: Float[Array, "P 3"]
    found: Bool[Array, " P"]


def _lookup(planes, present, h, resolution: int, lookup: str, layer=None):
    """Evaluate the stored surfaces at the offsets `h` (``(..., 3)``, relative to c).

    **Returns:** ``(gh, g_near, ok, face, row, col)`` where ``gh = g . h`` (per layer,
    ``(..., L)``, or for the given `layer` ``(...)``) is the ratio ``|l - c| / |l' - c|``
    times the homogeneous weight, ``g_near`` the nearest texel's plane vector, ``ok``
    whether the nearest texel is non-empty.
    """
    face = direction_face(jax.lax.stop_gradient(h))
    x, y, _ = face_coordinates(h, face, resolution)  # differentiable (bilinear weights)
    row, col = _texel_index(jax.lax.stop_gradient(x), jax.lax.stop_gradient(y), resolution)
    if layer is None:
        g_near = jnp.moveaxis(planes[:, face, row, col], 0, -2)  # (..., L, 3)
        ok = jnp.moveaxis(present[:, face, row, col], 0, -1)  # (..., L)
        hh = h[..., None, :]
    else:
        g_near = planes[layer, face, row, col]
        ok = present[layer, face, row, col]
        hh = h
    if lookup == "planar":
        return jnp.sum(g_near * hh, axis=-1), g_near, ok, face, row, col
    # bilinear: blend the four nearest texel centres' tangent-plane predictions, within
    # the face (clamp to edge at the seams).
    xs, ys = x - 0.5, y - 0.5
    c0 = jnp.clip(jnp.floor(xs), 0, resolution - 2).astype(jnp.int32)
    r0 = jnp.clip(jnp.floor(ys), 0, resolution - 2).astype(jnp.int32)
    fx = jnp.clip(xs - c0, 0.0, 1.0)
    fy = jnp.clip(ys - r0, 0.0, 1.0)
    gh: Array | float = 0.0
    for dr, dc, wgt in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy))) + (
        (1, 0, (1 - fx) * fy),
        (1, 1, fx * fy),
    ):
        if layer is None:
            gc = jnp.moveaxis(planes[:, face, r0 + dr, c0 + dc], 0, -2)
            gh = gh + wgt[..., None] * jnp.sum(gc * hh, axis=-1)
        else:
            gc = planes[layer, face, r0 + dr, c0 + dc]
            gh = gh + wgt * jnp.sum(gc * hh, axis=-1)
    return gh, g_near, ok, face, row, col


def default_scale(dmap: LayeredDistanceMap) -> Float[Array, ""]:
    """The median finite layer-0 distance of `dmap` (1 if there is none): the distance
    the linear search of `trace_distance_map` reaches half-way."""
    d = dmap.distance[0]
    med = jnp.nanmedian(jnp.where(jnp.isfinite(d), d, jnp.nan))
    return jnp.where(jnp.isfinite(med), med, 1.0)


def trace_distance_map(
    dmap: LayeredDistanceMap,
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    *,
    linear_steps: int = 32,
    secant_iterations: int = 4,
    max_distance: float | None = None,
    scale: float | None = None,
    lookup: Literal["planar", "bilinear"] = "planar",
    tolerance: float = 1e-2,
    attempts: int = 4,
) -> DistanceMapHit:
    """Trace rays in a layered distance map: linear search, then secant search.

    **Search function.** For a point ``l`` on the ray and a layer, let ``l'`` be the
    layer's surface point seen from ``c`` in the direction of ``l``. The point
    *undershoots* where ``|l - c| < |l' - c|`` and *overshoots* where it is larger; the
    hit is the root of ``f = |l - c| / |l' - c| - 1`` (the paper's ``|l|`` vs ``|l'|``
    comparison, as a ratio).

    **Lookup** (`lookup`). Every texel stores a point and a normal, i.e. a tangent plane,
    and ``|l - c| / |l' - c| = g . (l - c)`` for that plane (`LayeredDistanceMap.planes`).

    - ``"planar"`` (default): the texel the direction of ``l`` falls into supplies the
      plane (nearest-texel lookup, each texel a planar facet). Planar surfaces (the
      receiver, box faces) are reproduced exactly, and silhouettes stay sharp (at texel
      edges), so there are no "rubber sheets" across depth discontinuities.
    - ``"bilinear"``: the texture filter of the paper: bilinear interpolation, within a
      face, between the four nearest texel centres of their tangent-plane predictions
      (still exact for planes, smooth for curved surfaces, but blending foreground and
      background at silhouettes).

    Face seams: the lookup never blends across faces; the face is chosen from the
    direction of ``l`` and the bilinear weights are clamped to the face (clamp to edge),
    each corner's plane being evaluated at the exact direction, so a planar surface is
    continuous across seams.

    **Linear search.** Samples ``t_i = i / N``, ``i = 0..N`` (``N = linear_steps``) of a
    homogeneous parameter: ``l(t) = o + R d(t)`` with ``d(t) = s t / (1 - t + t s / M)``
    (``s = scale``, ``M = max_distance``). With ``max_distance=None`` (the default)
    ``M = inf``: ``d = s t / (1 - t)`` maps ``[0, 1]`` to ``[0, inf]`` (the last sample
    is the ray's point at infinity, whose direction is ``R``), so the search covers the
    whole receiver plane, out to its horizon, with steps that grow with the distance
    (the direction of ``l`` seen from ``c`` changes less and less). With a finite ``M``
    and ``scale=None`` the samples are uniform in ``d`` on ``[0, M]``. Otherwise `scale`
    defaults to `default_scale` (the median stored distance), reached half-way. The
    search function is evaluated in the finite form ``G = (1 - t + t s / M) f`` (same
    sign as ``f``, finite at ``t = 1``; for a planar facet it is linear in ``t``, so one
    secant step inside a facet is exact).

    **Bracket.** A candidate is an interval ``[t_i, t_i+1]`` and a layer where the first
    sample undershoots and the second overshoots a non-empty texel, taken in order along
    the ray (nearer intervals first, then lower layers). `secant_iterations` secant
    (false-position) steps shrink it, each costing one lookup in that layer; the estimate
    is the last secant point (with 0 iterations: the overshooting sample of the linear
    search, the paper's linear search alone). The candidate is accepted if one of the
    two final bracket ends' planes is really crossed inside the bracket (within
    `tolerance`, relative): otherwise the sign change came from a jump between surfaces
    (the ray passed an occluder's edge into the region hidden behind it), and the next
    candidate is tried, up to `attempts` of them. A ray that passes below a box's edge
    thus finds the plane behind it in the next layer instead of a false hit on the edge.

    **Arguments:**

    - `dmap`: the `LayeredDistanceMap`.
    - `origins`: shape ``(P, 3)``, ray origins (metres; near the reference point, e.g.
      on the caustic generator).
    - `directions`: shape ``(P, 3)``, ray directions (need not be unit).
    - `linear_steps`, `secant_iterations`: the knobs of the search (static).
    - `max_distance`: farthest ray parameter searched (``None``: infinity; static).
    - `scale`: the ray parameter reached half-way (``None``: see above; static).
    - `lookup`: ``"planar"`` or ``"bilinear"`` (static).
    - `tolerance`: relative mismatch that still counts as crossing a plane.
    - `attempts`: how many candidate brackets to try per ray (static).

    **Returns:** a `DistanceMapHit`. Rays that find nothing have ``found = False`` (no
    NaN). The hit is differentiable with respect to `origins` and `directions`: inside a
    bracket the secant result is a smooth function of them (the choice of texels, layer
    and bracket is discrete and carries no derivative).
    """
    _check_trace_args(lookup, linear_steps, secant_iterations, attempts)
    return _trace(
        dmap,
        origins,
        directions,
        max_distance,
        scale,
        jnp.asarray(tolerance),
        linear_steps=int(linear_steps),
        max_steps=int(linear_steps),
        record=(int(secant_iterations),),
        lookup=lookup,
        attempts=attempts,
    )[0]


def _check_trace_args(lookup, linear_steps, secant_iterations, attempts):
    if lookup not in ("planar", "bilinear"):
        raise ValueError(f"`lookup` must be 'planar' or 'bilinear', got {lookup!r}")
    for name, val, low in (
        ("linear_steps", linear_steps, 1),
        ("secant_iterations", secant_iterations, 0),
        ("attempts", attempts, 1),
    ):
        if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < low:
            raise ValueError(f"`{name}` must be an integer >= {low}, got {val!r}")


@eqx.filter_jit
def _trace(
    dmap,
    origins,
    directions,
    max_distance,
    scale,
    tolerance,
    *,
    linear_steps,
    max_steps,
    record,
    lookup,
    attempts,
):
    dtype = _float_dtype(origins, directions)
    origins = jnp.asarray(origins, dtype)
    directions = jnp.asarray(directions, dtype)
    sg = jax.lax.stop_gradient
    center = sg(dmap.center).astype(dtype)
    planes, present = dmap.planes()
    planes = sg(planes).astype(dtype)
    resolution, n_layers = dmap.resolution, dmap.layers
    if scale is None:
        s = jnp.asarray(max_distance if max_distance is not None else default_scale(dmap))
    else:
        s = jnp.asarray(scale)
    s = sg(s).astype(dtype)
    inv_m = 0.0 if max_distance is None else 1.0 / jnp.asarray(max_distance, dtype)
    rel = origins - center  # (P, 3)

    def weight(t):
        return 1.0 - t + t * s * inv_m

    def offset(t, rel_, dir_):  # homogeneous offset from c: weight * (l - c)
        return weight(t)[..., None] * rel_ + (t * s)[..., None] * dir_

    # --- linear search ---------------------------------------------------------------
    # samples i / linear_steps, padded with copies of t = 1 up to `max_steps` (a padded
    # interval [1, 1] holds no sign change): one compilation serves every step count
    steps = jnp.asarray(linear_steps)
    ts = jnp.minimum(jnp.arange(max_steps + 1, dtype=dtype) / steps.astype(dtype), 1.0)
    n = max_steps
    tt = jnp.broadcast_to(ts, (origins.shape[0], n + 1))
    h = offset(tt, rel[:, None], directions[:, None])  # (P, n+1, 3)
    gh, g_near, ok, *_ = _lookup(planes, present, h, resolution, lookup)
    w = weight(tt)[..., None]  # (P, n+1, 1)
    big = gh - w  # G per layer, (P, n+1, L)
    under = big < 0
    over = ok & (big >= 0)
    cand = under[:, :-1] & over[:, 1:]  # (P, n, L)
    flat = cand.reshape(cand.shape[0], -1)
    n_cand = flat.shape[1]
    key = jnp.where(flat, jnp.arange(n_cand, dtype=jnp.int32), n_cand)
    a_cnt = min(attempts, n_cand)
    chosen = -jax.lax.top_k(-key, a_cnt)[0]  # (P, A) ascending
    usable = chosen < n_cand
    chosen = jnp.where(usable, chosen, 0)
    interval, layer = chosen // n_layers, chosen % n_layers

    rows = jnp.arange(origins.shape[0], dtype=jnp.int32)[:, None]

    def take(arr, idx, lay):  # arr (P, n+1, L, ...) -> (P, A, ...)
        return arr[rows, idx, lay]

    ta = ts[interval]
    tb = ts[interval + 1]
    ga, gb = take(big, interval, layer), take(big, interval + 1, layer)
    pa, pb = take(g_near, interval, layer), take(g_near, interval + 1, layer)
    oka, okb = take(ok, interval, layer), take(ok, interval + 1, layer)

    # --- secant search (scan; the state after every recorded count is finalised) -----
    rel_a = jnp.broadcast_to(rel[:, None], ta.shape + (3,))
    dir_a = jnp.broadcast_to(directions[:, None], ta.shape + (3,))

    def step(state, _):
        ta, tb, ga, gb, pa, pb, oka, okb, _est = state
        denom = gb - ga
        frac = jnp.where(denom > 0, -ga / jnp.where(denom > 0, denom, 1.0), 0.5)
        tn = ta + (tb - ta) * jnp.clip(frac, 0.0, 1.0)
        hn = offset(tn, rel_a, dir_a)
        ghn, gnn, okn, *_ = _lookup(planes, present, hn, resolution, lookup, layer=layer)
        gn = ghn - weight(tn)
        over_n = okn & (gn >= 0)
        new = (
            jnp.where(over_n, ta, tn),
            jnp.where(over_n, tn, tb),
            jnp.where(over_n, ga, gn),
            jnp.where(over_n, gn, gb),
            jnp.where(over_n[..., None], pa, gnn),
            jnp.where(over_n[..., None], gnn, pb),
            jnp.where(over_n, oka, okn),
            jnp.where(over_n, okn, okb),
            tn,
        )
        return new, new

    state0 = (ta, tb, ga, gb, pa, pb, oka, okb, tb)
    n_iter = max(record)
    if n_iter:
        _, states = jax.lax.scan(step, state0, None, length=n_iter)
    results = []
    for k in record:
        state = state0 if k == 0 else jax.tree_util.tree_map(lambda x, k=k: x[k - 1], states)
        results.append(
            _finish(
                dmap,
                planes,
                present,
                origins,
                directions,
                center,
                state,
                usable,
                layer,
                weight,
                offset,
                rel_a,
                dir_a,
                s,
                tolerance,
            )
        )
    return tuple(results)


def _finish(
    dmap,
    planes,
    present,
    origins,
    directions,
    center,
    state,
    usable,
    layer,
    weight,
    offset,
    rel_a,
    dir_a,
    s,
    tolerance,
):
    """Accept a bracket if one of its final ends' planes is crossed inside it; pick the
    first accepted candidate of every ray."""
    sg = jax.lax.stop_gradient
    ta, tb, _, _, pa, pb, oka, okb, est = state
    ha, hb = offset(ta, rel_a, dir_a), offset(tb, rel_a, dir_a)
    wa, wb = weight(ta), weight(tb)
    crossed_a = oka & (jnp.sum(pa * hb, axis=-1) - wb >= -tolerance * wb)
    crossed_b = okb & (jnp.sum(pb * ha, axis=-1) - wa <= tolerance * wa)
    accept = usable & (crossed_a | crossed_b) & (weight(est) > 0)
    first = jnp.argmax(accept, axis=1)
    found = jnp.any(accept, axis=1)

    def pick(arr):
        return jnp.take_along_axis(arr, first[:, None], 1)[:, 0]

    t_hit = pick(est)
    lay = pick(layer)
    w_hit = weight(t_hit)
    w_safe = jnp.where(found & (w_hit > 0), w_hit, 1.0)
    dist = jnp.where(found, s * t_hit / w_safe, jnp.inf)
    point = origins + directions * jnp.where(found, dist, 0.0)[:, None]
    _, _, _, face, row, col = _lookup(
        planes, present, sg(point - center), dmap.resolution, "planar", layer=lay
    )
    material = jnp.where(found, dmap.material[lay, face, row, col], MATERIAL_EMPTY)
    normal = dmap.normal[lay, face, row, col]
    normal = jnp.where(found[:, None], sg(normal).astype(point.dtype), 0.0)
    return DistanceMapHit(
        point=point,
        distance=dist,
        layer=jnp.where(found, lay, -1).astype(jnp.int32),
        material=material.astype(jnp.int32),
        normal=normal,
        found=found,
    )


def exact_hits(
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    occluders: Sequence[Mesh] = (),
    receiver: bool = True,
) -> tuple[Float[Array, " P"], Int[Array, " P"]]:
    """Exact nearest hits of rays with the receiver plane ``z = 0`` and the occluders
    (every triangle, both sides), for checking `trace_distance_map`.

    **Returns:** ``(distance, material)``: the ray parameter (``inf`` for a miss) and the
    material (0 none, 1 receiver, ``2 + k`` occluder ``k``).
    """
    origins = jnp.asarray(origins)
    directions = jnp.asarray(directions)
    dtype = _float_dtype(origins, directions)
    best = jnp.full(origins.shape[:1], jnp.inf, dtype)
    mat = jnp.zeros(origins.shape[:1], jnp.int32)
    if receiver:
        dz = directions[:, 2]
        safe = jnp.where(dz != 0, dz, 1.0)
        t = jnp.where(dz != 0, -origins[:, 2] / safe, jnp.inf)
        t = jnp.where(t > 0, t, jnp.inf)
        mat = jnp.where(t < best, MATERIAL_RECEIVER, mat)
        best = jnp.minimum(best, t)
    for k, occ in enumerate(occluders):
        t, _ = nearest_hits(origins, directions, jnp.asarray(occ.triangles, dtype))
        mat = jnp.where(t < best, MATERIAL_OCCLUDER + k, mat)
        best = jnp.minimum(best, t)
    return best, mat


def tracing_error_table(
    dmap: LayeredDistanceMap,
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    occluders: Sequence[Mesh] = (),
    *,
    receiver: bool = True,
    linear_steps: Sequence[int] = (8, 16, 32, 64),
    secant_iterations: Sequence[int] = (0, 1, 2, 4),
    max_distance: float | None = None,
    scale: float | None = None,
    lookup: Literal["planar", "bilinear"] = "planar",
    tolerance: float = 1e-2,
    attempts: int = 4,
) -> dict[str, np.ndarray]:
    """Accuracy of `trace_distance_map` against exact ray casting, per search setting.

    Hit points are compared with `exact_hits` for every combination of `linear_steps`
    and `secant_iterations` (the other keywords are those of `trace_distance_map`). It
    compiles the search once: every step count runs with ``max(linear_steps)`` samples,
    the extra ones parked at the ray's end, so timings here say nothing of speed.

    **Returns:** a dict of NumPy arrays of shape ``(len(linear_steps),
    len(secant_iterations))``: ``"median"``, ``"p95"`` and ``"max"`` of the distance
    between the traced and the exact hit point (metres), over rays that both find;
    ``"missed"``, the fraction of rays with an exact hit that the search did not find;
    ``"false"``, the fraction of rays found by the search with no exact hit or a
    different material. Also ``"linear_steps"`` and ``"secant_iterations"`` (1-D).
    """
    for n in linear_steps:
        _check_trace_args(lookup, n, 0, attempts)
    for it in secant_iterations:
        _check_trace_args(lookup, 1, it, attempts)
    origins, directions = jnp.asarray(origins), jnp.asarray(directions)
    t_hit, m_hit = exact_hits(origins, directions, occluders, receiver)
    t_exact, m_exact = np.asarray(t_hit), np.asarray(m_hit)
    has = np.isfinite(t_exact)
    p_exact = np.asarray(origins) + np.asarray(directions) * np.where(has, t_exact, 0)[:, None]
    shape = (len(linear_steps), len(secant_iterations))
    out = {k: np.zeros(shape) for k in ("median", "p95", "max", "missed", "false")}
    for i, n in enumerate(linear_steps):
        hits = _trace(
            dmap,
            origins,
            directions,
            max_distance,
            scale,
            jnp.asarray(tolerance),
            linear_steps=jnp.asarray(n),
            max_steps=max(linear_steps),
            record=tuple(secant_iterations),
            lookup=lookup,
            attempts=attempts,
        )
        for j, hit in enumerate(hits):
            found = np.asarray(hit.found)
            both = found & has
            err = np.linalg.norm(np.asarray(hit.point) - p_exact, axis=-1)[both]
            if err.size:
                out["median"][i, j] = np.median(err)
                out["p95"][i, j] = np.percentile(err, 95)
                out["max"][i, j] = err.max()
            else:
                out["median"][i, j] = out["p95"][i, j] = out["max"][i, j] = np.nan
            out["missed"][i, j] = np.mean(~found[has]) if has.any() else 0.0
            wrong = found & (~has | (np.asarray(hit.material) != m_exact))
            out["false"][i, j] = np.mean(wrong[found]) if found.any() else 0.0
    out["linear_steps"] = np.asarray(linear_steps)
    out["secant_iterations"] = np.asarray(secant_iterations)
    return out


# --------------------------------------------------------------------------------------
# Light cube map
# --------------------------------------------------------------------------------------


class LightCubeMap(eqx.Module):
    """Caustic irradiance reconstructed on the faces of a cube map around a centre.

    **Arguments:**

    - `irradiance`: shape ``(6, R, R)``, the sum of the caustic triangles' Gouraud-
      interpolated irradiance at each texel centre (W/m^2 on the receiving surface;
      overlapping triangles add, as with the paper's additive blending).
    - `distance`: shape ``(6, R, R)``, distance from the centre, along the texel's centre
      direction, of the surface the caustic landed on (``inf`` where uncovered).
    - `plane`: shape ``(6, R, R, 3)``, that surface as a plane: ``g = m / (m . (p - c))``
      for the plane through the caustic triangle's vertices ``p`` with normal ``m``, so a
      point ``x`` lies on it iff ``g . (x - c) = 1`` (averaged like `distance` where
      several triangles cover a texel; zero where uncovered). ``distance`` is
      ``1 / (g . w)`` for the unit texel direction ``w``.
    - `coverage`: shape ``(6, R, R)``, how many triangles cover the texel centre
      (fractional with supersampling).
    - `dropped`: scalar int32, valid triangles that could not be drawn on the face of
      their centroid's direction (a vertex behind that face's plane).
    - `resolution`: ``R`` (static).
    """

    irradiance: Float[Array, "6 R R"]
    distance: Float[Array, "6 R R"]
    plane: Float[Array, "6 R R 3"]
    coverage: Float[Array, "6 R R"]
    dropped: Int[Array, ""]
    resolution: int = eqx.field(static=True)


def _triangle_planes(h: Array) -> Array:
    """Per-vertex plane vectors ``g`` (``(T, 3, 3)``) of triangles with vertices `h`
    relative to the centre: ``m / (m . h0)`` for the triangle's plane; a triangle seen
    (almost) edge-on from the centre, or degenerate, falls back to the sphere through
    each vertex, ``h_v / |h_v|^2`` (a plain distance comparison)."""
    m = jnp.cross(h[:, 1] - h[:, 0], h[:, 2] - h[:, 0])  # (T, 3)
    q = jnp.sum(m * h[:, 0], axis=-1)
    scale = jnp.linalg.norm(m, axis=-1) * jnp.linalg.norm(h[:, 0], axis=-1)
    good = jnp.abs(q) > 1e-6 * scale
    g_plane = m / jnp.where(good, q, 1.0)[:, None]
    r2 = jnp.sum(h * h, axis=-1, keepdims=True)
    g_sphere = h / jnp.where(r2 > 0, r2, 1.0)
    return jnp.where(good[:, None, None], g_plane[:, None, :], g_sphere)


@eqx.filter_jit
def _face_triangles(center, hit_points, valid, resolution):
    """Every triangle projected onto every face: pixel vertices ``(6, T, 3, 2)``, the
    mask of drawable (face, triangle) pairs ``(6, T)`` and of triangles with all
    vertices in front of each face."""
    h = hit_points - center  # (T, 3, 3)
    faces = jnp.arange(6)[:, None, None]
    x, y, depth = face_coordinates(h[None], faces, resolution)  # (6, T, 3)
    norm = jnp.linalg.norm(h, axis=-1)[None]
    in_front = jnp.all(depth > 1e-6 * norm, axis=-1)  # (6, T)
    r = float(resolution)
    overlaps = (
        (jnp.min(x, -1) < r) & (jnp.max(x, -1) > 0) & (jnp.min(y, -1) < r) & (jnp.max(y, -1) > 0)
    )
    drawable = valid[None] & in_front & overlaps
    xy = jnp.stack([x, y], axis=-1)
    xy = jnp.where(drawable[..., None, None], xy, 0.0)
    return xy, drawable, in_front


def light_cube_map(
    dmap_or_center: LayeredDistanceMap | Float[Array, "3"],
    hit_points: Float[Array, "T 3 3"],
    vertex_irradiance: Float[Array, "T 3"],
    valid: Bool[Array, " T"],
    resolution: int,
    window: int | None = None,
    supersample: int = 1,
) -> LightCubeMap:
    """Draw caustic triangles onto the faces of a light cube map (paper, Section 4.2).

    Each caustic triangle's vertices are terminal photon hits (world space); seen from
    the centre they are projected (`face_coordinates`) onto the cube faces and drawn with
    Gouraud interpolation (`jaxcaustics.reconstruct.raster.rasterize_gouraud`: point samples at
    texel centres, additive, linear in face coordinates). A triangle is drawn on every
    face whose image it overlaps and that has all three vertices in front of its plane
    (the rasteriser clips it to the image), so a triangle across a seam is drawn on both
    faces and leaves no gap, and no texel is counted twice (each texel direction belongs
    to one face). A valid triangle with a vertex behind the plane of the face of its
    centroid's direction (one spanning about 90 degrees or more) is counted in
    ``dropped``; it is still drawn on the faces that have all its vertices in front.

    The surface the caustic landed on is recorded per texel as the plane of the
    covering triangle (`LightCubeMap.plane`), averaged over the covering triangles with
    the same (additive, supersampled) weights as the irradiance and divided by the
    coverage channel of ones; ``distance`` follows from it along the texel's direction.
    For a planar triangle this is exactly the distance of the triangle's plane, where
    Gouraud interpolation of the vertex distances would bow between the vertices.

    **Arguments:**

    - `dmap_or_center`: a `LayeredDistanceMap` (its centre is used) or the centre, shape
      ``(3,)``.
    - `hit_points`: shape ``(T, 3, 3)``, the vertices of each caustic triangle (metres).
    - `vertex_irradiance`: shape ``(T, 3)``, irradiance at each vertex on the receiving
      surface (W/m^2: power over area *there*); this function only carries it.
    - `valid`: shape ``(T,)`` bool, triangles to draw (invalid ones may hold NaN).
    - `resolution`: ``R``, texels per face edge (static).
    - `window`: the rasteriser's window (static); ``None`` picks it with
      `jaxcaustics.reconstruct.raster.window_for` (concrete arrays only, outside `jit`). A triangle
      whose image on a face spans more texels than the window is cut off.
    - `supersample`: samples per texel edge (static).

    **Returns:** a `LightCubeMap`.
    """

    if isinstance(dmap_or_center, LayeredDistanceMap):
        center = dmap_or_center.center
    else:
        center = dmap_or_center
    hit_points = jnp.asarray(hit_points)
    dtype = _float_dtype(hit_points, vertex_irradiance)
    center = jax.lax.stop_gradient(jnp.asarray(center, dtype))
    hit_points = hit_points.astype(dtype)
    vertex_irradiance = jnp.asarray(vertex_irradiance, dtype)
    valid = jnp.asarray(valid, bool)
    if hit_points.ndim != 3 or hit_points.shape[1:] != (3, 3):
        raise ValueError(f"`hit_points` must have shape (T, 3, 3), got {hit_points.shape}")
    if vertex_irradiance.shape != hit_points.shape[:2]:
        raise ValueError(
            f"`vertex_irradiance` must have shape {hit_points.shape[:2]}, "
            f"got {vertex_irradiance.shape}"
        )
    if valid.shape != hit_points.shape[:1]:
        raise ValueError(f"`valid` must have shape {hit_points.shape[:1]}, got {valid.shape}")
    # invalid triangles may hold NaN: replace them before any arithmetic
    hit_points = jnp.where(valid[:, None, None], hit_points, center + 1.0)
    vertex_irradiance = jnp.where(valid[:, None], vertex_irradiance, 0.0)
    if window is None:
        xy, drawable, _ = _face_triangles(center, hit_points, valid, resolution)
        if isinstance(xy, jax.core.Tracer) or isinstance(drawable, jax.core.Tracer):
            raise ValueError("`window` must be given when `light_cube_map` is traced (jit)")
        window = window_for(xy.reshape(-1, 3, 2), drawable.reshape(-1))
    return _light_cube_map(
        center, hit_points, vertex_irradiance, valid, resolution, int(window), int(supersample)
    )


@eqx.filter_jit
def _light_cube_map(center, hit_points, vertex_irradiance, valid, resolution, window, supersample):

    dtype = hit_points.dtype
    xy, drawable, in_front = _face_triangles(center, hit_points, valid, resolution)
    shape = (resolution, resolution)
    g = _triangle_planes(hit_points - center)  # (T, 3 vertices, 3 components)
    values = jnp.stack(
        [vertex_irradiance, g[..., 0], g[..., 1], g[..., 2], jnp.ones_like(vertex_irradiance)]
    )  # (5, T, 3)

    def draw(xy_f, valid_f):
        return jax.vmap(lambda v: rasterize_gouraud(xy_f, v, valid_f, shape, window, supersample))(
            values
        )

    maps = jax.vmap(draw)(xy, drawable)  # (6, 5, R, R)
    irradiance, coverage = maps[:, 0], maps[:, 4]
    covered = coverage > 0
    plane = jnp.moveaxis(maps[:, 1:4], 1, -1) / jnp.where(covered, coverage, 1.0)[..., None]
    plane = jnp.where(covered[..., None], plane, 0.0)
    inv = jnp.sum(plane * texel_directions(resolution, dtype=dtype), axis=-1)
    ok = covered & (inv > 0)
    distance = jnp.where(ok, 1.0 / jnp.where(ok, inv, 1.0), jnp.inf)
    own = direction_face(jnp.mean(hit_points, axis=1) - center)
    dropped = jnp.sum(valid & ~jnp.take_along_axis(in_front.T, own[:, None], 1)[:, 0])
    return LightCubeMap(
        irradiance=irradiance,
        distance=distance,
        plane=plane,
        coverage=coverage,
        dropped=dropped.astype(jnp.int32),
        resolution=resolution,
    )


def project_light_cube_map(
    lcm: LightCubeMap,
    center: Float[Array, "3"],
    points: Float[Array, "P 3"],
    *,
    shadow_test: bool = True,
    tolerance: float = 0.02,
    lookup: Literal["nearest", "bilinear"] = "nearest",
) -> Float[Array, " P"]:
    """Camera pass (paper, Section 4.3): caustic irradiance at shaded points.

    The light cube map is looked up in the direction of each point ``p`` from `center`.
    With `shadow_test` it acts as a shadow map: a texel counts only where the point's
    distance ``|p - c|`` is within `tolerance` (relative) of the distance, in the same
    direction, of the surface the texel's caustic landed on (its stored plane:
    ``|g . (p - c) - 1| <= tolerance``, exact for planar caustic triangles whatever the
    point's offset within the texel, so the test needs no depth bias). A point hidden
    behind that surface, or in front of it, gets 0: caustics do not leak behind
    occluders. Without it (naive projection) every covered texel counts.

    For a Lambertian receiver the returned value is the irradiance ``E`` (W/m^2); the
    caustic's reflected radiance is ``albedo / pi * E``.

    **Arguments:**

    - `lcm`: the `LightCubeMap`.
    - `center`: shape ``(3,)``, its centre (the one it was built with).
    - `points`: shape ``(P, 3)``, shaded points (metres).
    - `shadow_test`: apply the distance test.
    - `tolerance`: relative distance tolerance of the test.
    - `lookup`: ``"nearest"`` (default: the texel the direction falls into, as a point-
      sampled texture fetch) or ``"bilinear"`` (the four nearest texel centres within the
      face, each with its own test, percentage-closer style; clamped to the face at the
      seams, no blending across faces).

    **Returns:** shape ``(P,)``, the irradiance (0 where no caustic reaches the point).
    """
    if lookup not in ("nearest", "bilinear"):
        raise ValueError(f"`lookup` must be 'nearest' or 'bilinear', got {lookup!r}")
    return _project(lcm, center, points, jnp.asarray(tolerance), bool(shadow_test), lookup)


@eqx.filter_jit
def _project(lcm, center, points, tolerance, shadow_test, lookup):
    r = lcm.resolution
    points = jnp.asarray(points)
    dtype = _float_dtype(points, lcm.irradiance)
    h = points.astype(dtype) - jnp.asarray(center, dtype)
    face = direction_face(jax.lax.stop_gradient(h))
    x, y, _ = face_coordinates(h, face, r)

    def texel_value(row, col):
        e = lcm.irradiance[face, row, col]
        accept = lcm.coverage[face, row, col] > 0
        if shadow_test:
            ratio = jnp.sum(lcm.plane[face, row, col] * h, axis=-1)
            accept = accept & (jnp.abs(ratio - 1.0) <= tolerance)
        return jnp.where(accept, e, 0.0)

    if lookup == "nearest":
        row, col = _texel_index(x, y, r)
        return texel_value(row, col)
    xs, ys = x - 0.5, y - 0.5
    c0 = jnp.clip(jnp.floor(jax.lax.stop_gradient(xs)), 0, r - 2).astype(jnp.int32)
    r0 = jnp.clip(jnp.floor(jax.lax.stop_gradient(ys)), 0, r - 2).astype(jnp.int32)
    fx = jnp.clip(xs - c0, 0.0, 1.0)
    fy = jnp.clip(ys - r0, 0.0, 1.0)
    return (
        (1 - fx) * (1 - fy) * texel_value(r0, c0)
        + fx * (1 - fy) * texel_value(r0, c0 + 1)
        + (1 - fx) * fy * texel_value(r0 + 1, c0)
        + fx * fy * texel_value(r0 + 1, c0 + 1)
    )
