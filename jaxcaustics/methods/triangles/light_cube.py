"""The light cube map: caustic triangles (terminal photon hits of three neighbouring
photons) drawn onto the faces of a cube map around the distance map's centre
(`light_cube_map`), which stores, per texel, the irradiance and the surface the caustic
landed on; and the camera pass (`project_light_cube_map`), which looks it up in the
direction of a shaded point and, like a shadow map, accepts the texel only when its
stored distance matches the point's."""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ...reconstruct.raster import rasterize_gouraud, window_for
from .cube_faces import (
    _float_dtype,
    _texel_index,
    direction_face,
    face_coordinates,
    texel_directions,
)
from .layered_map import LayeredDistanceMap


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
