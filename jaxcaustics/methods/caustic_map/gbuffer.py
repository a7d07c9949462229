"""Geometry buffers seen from the light, and photons shaded from them.

Shah et al.'s caustics mapping renders the refractor from the light into a texture of
positions and normals (the *refractive vertex grid*) and the receiver into a *positions
texture*; Wyman & Nichols' adaptive caustic maps keep the front and back surfaces of the
refractor as geometry buffers and create photons anywhere in the light's view by
*deferred shading*: sampling those buffers (bilinear interpolation, so the buffers can
be coarser than the photon grid) instead of rasterising the object again.

Here the buffers are made by casting the light's rays at the texel centres against the
mesh (`nearest_hits`, then a differentiable hit on the triangle found: the buffers are
differentiable with respect to the vertices). A photon at view point ``(u, v)`` is then
shaded with two interfaces, as image-space refraction does: refract at the interpolated
front surface, find where the refracted ray leaves through the back surface, refract out,
find where it meets the receiver. The two ray/surface intersections are either the
papers' image-space estimate (`ray_geo`: Shah et al.'s iterative ``rayGeo`` update on a
positions texture) or exact (`intersection="exact"`: the photon is traced through the
mesh, with as many interfaces as the scene allows, and onto the plane ``z = 0``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..._checks import check_array, check_broadcast, check_fits, check_int, check_memory_limit
from ...scene.mesh import MeshScene
from ...scene.surface import bilinear
from ...trace.intersect import (
    face_normals,
    hit_on_triangle,
    moller_trumbore,
    nearest_hits,
    vertex_normals,
)
from ...trace.optics import fresnel_transmittance, reflect, refract_components
from ...trace.photons import trace_mesh_rays
from .light_view import LightView

INTERSECTIONS = ("image_space", "exact")


class GeometryBuffers(eqx.Module):
    """The light's view of the generator and the receiver, ``(R, R)`` texels over
    `view.window`. Positions in metres, unit normals pointing out of the object.

    - `front_position`, `front_normal`: where the light's ray through each texel centre
      first meets the generator.
    - `back_position`, `back_normal`: where it last meets it (``None`` for a mirror).
    - `hit`: ``(R, R)`` bool: the ray meets the generator.
    - `receiver_position`: the receiver positions texture: where the ray meets ``z = 0``.
    """

    view: LightView
    front_position: Float[Array, "R R 3"]
    front_normal: Float[Array, "R R 3"]
    back_position: Float[Array, "R R 3"] | None
    back_normal: Float[Array, "R R 3"] | None
    hit: Bool[Array, "R R"]
    receiver_position: Float[Array, "R R 3"]

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.hit.shape)  # type: ignore[return-value]


def _surface_hits(scene: MeshScene, origins, directions, face, found):
    """Differentiable hits of rays on the generator's faces `face` (chosen already):
    points and outward unit shading normals."""
    verts = scene.generator.vertices
    faces = scene.generator.faces
    t, bary = hit_on_triangle(origins, directions, verts[faces][face])
    t = jnp.where(found, t, 0.0)
    points = origins + t[:, None] * directions
    if scene.normals == "smooth":
        vn = vertex_normals(verts, faces)
        normals = jnp.einsum("pk,pkc->pc", bary, vn[faces[face]])
    else:
        normals = face_normals(verts, faces)[face]
    return points, _unit(normals)


def raster_window(scene: MeshScene, view: LightView, resolution: int) -> int:
    """The rasteriser's window for the geometry buffers: texels per side of the largest
    face's footprint in the light's view (needs concrete vertices)."""
    tri = np.asarray(scene.generator.vertices)[np.asarray(scene.generator.faces)]
    u, v = view.project(jnp.asarray(tri))
    tx, ty = view.to_texels(u, v, (resolution, resolution))
    x, y = np.asarray(tx), np.asarray(ty)
    span = max(
        np.max(np.ceil(x.max(1)) - np.floor(x.min(1))),
        np.max(np.ceil(y.max(1)) - np.floor(y.min(1))),
    )
    return int(min(resolution, span + 2))


def _raster_faces(scene: MeshScene, view: LightView, resolution: int, window: int):
    """Rasterise the generator's faces into the light's view (no derivatives): for each
    texel, the face its ray meets first and the face it meets last (``-1``: none).
    Each face tests the texel centres of a ``window x window`` block from its
    footprint's corner with the exact ray/triangle test, then a depth test (scatter-min
    of the ray parameter) keeps the nearest, a scatter-max the farthest."""
    sg = jax.lax.stop_gradient
    tri = sg(scene.generator.vertices)[scene.generator.faces]  # (F, 3, 3)
    shape = (resolution, resolution)
    u, v = view.project(tri)
    x, y = view.to_texels(u, v, shape)
    col0 = jnp.floor(x.min(axis=1)).astype(jnp.int32)
    row0 = jnp.floor(y.min(axis=1)).astype(jnp.int32)
    offsets = jnp.arange(window, dtype=jnp.int32)
    cols = col0[:, None, None] + offsets[None, None, :]  # (F, 1, W)
    rows = row0[:, None, None] + offsets[None, :, None]  # (F, W, 1)
    cols, rows = jnp.broadcast_arrays(cols, rows)
    inside = (cols >= 0) & (cols < resolution) & (rows >= 0) & (rows < resolution)
    du = (view.window[1] - view.window[0]) / resolution
    dv = (view.window[3] - view.window[2]) / resolution
    tu = view.window[0] + (cols + 0.5) * du
    tv = view.window[2] + (rows + 0.5) * dv
    origins, directions = view.rays(tu, tv)
    t, b1, b2, det = moller_trumbore(
        origins, directions, tri[:, None, None, 0], tri[:, None, None, 1], tri[:, None, None, 2]
    )
    hit = inside & (det != 0) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > 0)
    texel = jnp.where(hit, rows * resolution + cols, resolution * resolution).ravel()
    face = jnp.broadcast_to(jnp.arange(tri.shape[0], dtype=jnp.int32)[:, None, None], t.shape)
    face = face.ravel()
    t = t.ravel()
    size = resolution * resolution
    nearest = jnp.full(size, jnp.inf, t.dtype).at[texel].min(t, mode="drop")
    farthest = jnp.full(size, -jnp.inf, t.dtype).at[texel].max(t, mode="drop")
    keep_near = jnp.where(t == nearest.at[texel].get(mode="fill", fill_value=jnp.nan), face, -1)
    keep_far = jnp.where(t == farthest.at[texel].get(mode="fill", fill_value=jnp.nan), face, -1)
    first = jnp.full(size, -1, jnp.int32).at[texel].max(keep_near, mode="drop")
    last = jnp.full(size, -1, jnp.int32).at[texel].max(keep_far, mode="drop")
    return first, last


TEXEL_FLOATS = 64
"""Numbers one texel of `geometry_buffers` takes (buffers, rays and XLA's temporaries: 59
measured in float64), for its memory estimate."""

FACE_TEXEL_FLOATS = 12
"""Numbers each face takes per texel of its ``window x window`` block while the faces are
rasterised (12 measured in float64), for the memory estimate of `geometry_buffers`."""

MAX_ITERATIONS = 1000
"""Most `iterations` of `ray_geo` (each one is traced anew: the graph grows with them)."""


def geometry_buffers(
    scene: MeshScene,
    view: LightView,
    resolution: int,
    window: int,
    *,
    memory_limit: int | None = None,
) -> GeometryBuffers:
    """Render the geometry buffers of `scene` from the light at ``resolution^2`` texels
    (`window`: see `raster_window`; in ``[1, resolution]``). Differentiable with respect
    to the vertices (the rasteriser picks the faces; the hits on them are recomputed from
    the vertices). `memory_limit`: bytes the buffers may take (default 1 GiB;
    ``TEXEL_FLOATS`` numbers a texel and ``FACE_TEXEL_FLOATS`` per face and texel of its
    window): more raise a `ValueError` before anything is compiled."""
    if not isinstance(scene, MeshScene):
        raise ValueError(f"`scene` must be a MeshScene, got {type(scene).__name__}")
    if not isinstance(view, LightView):
        raise ValueError(f"`view` must be a LightView (`light_view`), got {type(view).__name__}")
    resolution = check_int(resolution, "resolution", 1)
    window = check_int(window, "window", 1, resolution)
    faces = scene.generator.faces.shape[0]
    numbers = TEXEL_FLOATS * resolution**2 + FACE_TEXEL_FLOATS * faces * window**2
    check_fits(
        numbers * scene.generator.vertices.dtype.itemsize,
        check_memory_limit(memory_limit),
        f"geometry buffers of {resolution}^2 texels ({faces} faces, window {window})",
        "lower `resolution` or `window`",
    )
    shape = (resolution, resolution)
    u, v = view.texel_centres(shape)
    origins, directions = view.rays(u.reshape(-1), v.reshape(-1))
    origins = origins.astype(scene.generator.vertices.dtype)
    first, last = _raster_faces(scene, view, resolution, window)
    hit = first >= 0
    front, front_n = _surface_hits(scene, origins, directions, jnp.maximum(first, 0), hit)
    back = back_n = None
    if scene.material == "refractor":
        back, back_n = _surface_hits(scene, origins, directions, jnp.maximum(last, 0), hit)
        back = back.reshape(shape + (3,))
        back_n = back_n.reshape(shape + (3,))
    down = directions[:, 2] < 0
    t_floor = -origins[:, 2] / jnp.where(down, directions[:, 2], -1.0)
    receiver = origins + jnp.where(down, t_floor, 0.0)[:, None] * directions
    return GeometryBuffers(
        view,
        front.reshape(shape + (3,)),
        front_n.reshape(shape + (3,)),
        back,
        back_n,
        hit.reshape(shape),
        receiver.reshape(shape + (3,)),
    )


def _unit(vectors: Array) -> Array:
    """Normalise ``(..., 3)`` vectors; a zero vector (no surface sampled) becomes +z, with
    finite gradients."""
    norm2 = jnp.sum(vectors * vectors, axis=-1, keepdims=True)
    ok = norm2 > 0
    safe = jnp.where(ok, vectors, jnp.array([0.0, 0.0, 1.0], vectors.dtype))
    return safe * jax.lax.rsqrt(jnp.where(ok, norm2, 1.0))


def _length(vectors: Array) -> Array:
    """``|v|`` over the last axis, with a finite gradient at 0."""
    norm2 = jnp.sum(vectors * vectors, axis=-1)
    ok = norm2 > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, norm2, 1.0)), 0.0)


def _sample(view: LightView, texture: Array, points: Array, mask: Array | None = None):
    """Sample a texture over the view at the light's projection of world `points`."""
    u, v = view.project(points)
    x, y = view.to_texels(u, v, texture.shape[:2])
    return bilinear(texture, x, y, mask)


def ray_geo(
    view: LightView, positions: Array, origin: Array, direction: Array, iterations: int
) -> Array:
    """Shah et al.'s image-space ray/geometry intersection estimate.

    Starting from the distance between `origin` and the surface of the positions texture
    behind it in the light's view, repeat `iterations` times: step that distance along
    the ray, look up the surface point the light sees there, and take its distance from
    `origin` as the new distance (the paper's ``rayGeo``; it starts from 1 in scene
    units, which has no meaning in metres). `view`: a `LightView`; `positions`: an
    ``(R, R', 3)`` positions texture over its window; `origin`, `direction`: ``(..., 3)``
    (broadcasting); `iterations`: an int in ``[0, MAX_ITERATIONS]``. **Returns:** the
    estimated hit on the ray.
    """
    if not isinstance(view, LightView):
        raise ValueError(f"`view` must be a LightView (`light_view`), got {type(view).__name__}")
    positions = check_array(positions, "positions", (None, None, 3))
    origin = check_array(origin, "origin", (..., 3))
    direction = check_array(direction, "direction", (..., 3))
    check_broadcast(origin, "origin", direction, "direction")
    iterations = check_int(iterations, "iterations", 0, MAX_ITERATIONS)
    dist = _length(_sample(view, positions, origin) - origin)
    for _ in range(iterations):
        probe = origin + dist[..., None] * direction
        dist = _length(_sample(view, positions, probe) - origin)
    return origin + dist[..., None] * direction


def _leave(view, buffers, point, inside, ior, iterations):
    """Image-space refraction's second interface: where the ray refracted into the object
    at `point` (direction `inside`) leaves it through the back surface (`ray_geo`), and
    its direction out. **Returns:** ``(exit point, direction, TIR mask, cos of the
    incidence angle, coverage of the object at the exit)``."""
    exit_point = ray_geo(view, buffers.back_position, point, inside, iterations)
    exit_normal, cover = _sample(view, buffers.back_normal, exit_point, buffers.hit)
    out, tir, cos_out = refract_components(tuple(inside.T), tuple(_unit(exit_normal).T), ior)
    return exit_point, jnp.stack(out, axis=-1), tir, cos_out, cover


class PhotonHits(eqx.Module):
    """Photons shaded at view points: per channel ``(C, P, ...)``.

    - `position`: where each photon ends (on or near the receiver), metres.
    - `flux`: the flux it carries (0 where not valid).
    - `valid`: it went through the generator and reached the receiver.
    """

    position: Float[Array, "C P 3"]
    flux: Float[Array, "C P"]
    valid: Bool[Array, "C P"]


def shade_photons(
    scene: MeshScene,
    buffers: GeometryBuffers,
    u: Array,
    v: Array,
    cell_area,
    *,
    intersection: str = "image_space",
    iterations: int = 1,
    batch_size: int = 4096,
) -> PhotonHits:
    """Photons at view points ``(u, v)`` (each standing for `cell_area` of the view).

    ``intersection="image_space"``: deferred shading from the geometry buffers, two
    interfaces (a photon totally reflected at the back surface, or whose exit estimate
    falls off the object, is dropped), both intersections by `ray_geo` with `iterations`
    steps. ``"exact"``: traced through the mesh and onto ``z = 0`` exactly.
    """
    view = buffers.view
    flux0 = view.density(u, v) * cell_area
    if intersection == "exact":
        origins, directions = view.rays(u, v)
        paths = trace_mesh_rays(scene, origins, directions, flux0, batch_size)
        return PhotonHits(
            jnp.stack([p[0] for p in paths]),
            jnp.stack([p[2] for p in paths]),
            jnp.stack([p[3] for p in paths]),
        )
    shape = buffers.shape
    x, y = view.to_texels(u, v, shape)
    point, coverage = bilinear(buffers.front_position, x, y, buffers.hit)
    normal, _ = bilinear(buffers.front_normal, x, y, buffers.hit)
    normal = _unit(normal)
    on_object = coverage >= 0.5
    _, light_dir = view.rays(u, v)
    positions, fluxes, valids = [], [], []
    for ior in scene.iors:
        flux = flux0
        valid = on_object
        if scene.material == "mirror":
            origin, direction = point, reflect(light_dir, normal)
        else:
            inside, _, cos_in = refract_components(tuple(light_dir.T), tuple(normal.T), 1.0 / ior)
            inside = jnp.stack(inside, axis=-1)
            origin, direction, tir, cos_out, exit_cover = _leave(
                view, buffers, point, inside, ior, iterations
            )
            valid = valid & (exit_cover >= 0.5) & ~tir
            if scene.fresnel:
                flux = (
                    flux
                    * fresnel_transmittance(cos_in, 1.0 / ior)
                    * fresnel_transmittance(cos_out, ior)
                )
        valid = valid & (direction[..., 2] < 0)
        landed = ray_geo(view, buffers.receiver_position, origin, direction, iterations)
        positions.append(landed)
        fluxes.append(jnp.where(valid, flux, 0.0))
        valids.append(valid)
    return PhotonHits(jnp.stack(positions), jnp.stack(fluxes), jnp.stack(valids))


def intersection_errors(
    scene: MeshScene, buffers: GeometryBuffers, photons: int, iterations=(0, 1, 2, 4, 8, 16, 32)
) -> dict[int, tuple[float, ...]]:
    """How far the image-space estimate (`ray_geo`) lands from the exact intersection,
    per iteration count, for photons on a ``photons x photons`` grid over the view that
    hit the generator (a refractor): the refracted ray's exit through the back surface
    (against the exact ray/mesh hit) and the leaving ray's hit on the receiver plane
    (against the exact ray/plane hit). **Returns:** ``{k: (back median, back 90th
    percentile, receiver median, receiver 90th percentile)}``, distances in metres
    (needs concrete values). Near the silhouette the update contracts slowly (the
    refracted ray runs almost along the back surface in the light's view), so the 90th
    percentile lags far behind the median."""

    view = buffers.view
    u, v = view.texel_centres((photons, photons))
    u, v = u.reshape(-1), v.reshape(-1)
    x, y = view.to_texels(u, v, buffers.shape)
    point, coverage = bilinear(buffers.front_position, x, y, buffers.hit)
    normal = _unit(bilinear(buffers.front_normal, x, y, buffers.hit)[0])
    keep = np.asarray(coverage >= 1.0)  # well inside the object: no silhouette blending
    point, normal, u, v = point[keep], normal[keep], u[keep], v[keep]
    _, light_dir = view.rays(u, v)
    ior = scene.iors[0]
    inside = jnp.stack(refract_components(tuple(light_dir.T), tuple(normal.T), 1.0 / ior)[0], -1)
    triangles = scene.generator.vertices[scene.generator.faces]
    eps = 1e-9 * float(jnp.max(jnp.abs(scene.generator.vertices)))
    t_exact, _ = nearest_hits(point, inside, triangles, eps)
    exit_exact = point + t_exact[:, None] * inside
    found = np.asarray(jnp.isfinite(t_exact))
    result: dict[int, tuple[float, ...]] = {}
    for k in iterations:
        exit_point, landed, plane, down = _estimate(view, buffers, point, inside, ior, k)
        back_error = np.linalg.norm(np.asarray(exit_point - exit_exact), axis=-1)[found]
        receiver_error = np.linalg.norm(np.asarray(landed - plane), axis=-1)[np.asarray(down)]
        result[k] = tuple(
            float(np.percentile(e, q)) for e in (back_error, receiver_error) for q in (50, 90)
        )
    return result


@eqx.filter_jit
def _estimate(view, buffers, point, inside, ior, iterations):
    """`intersection_errors`' image-space path for one iteration count: the exit
    estimate, the floor estimate, the exact floor hit of the estimated leaving ray, and
    whether that ray goes down."""
    exit_point, out, tir, _, _ = _leave(view, buffers, point, inside, ior, iterations)
    landed = ray_geo(view, buffers.receiver_position, exit_point, out, iterations)
    down = (out[:, 2] < 0) & ~tir
    t = -exit_point[:, 2] / jnp.where(down, out[:, 2], -1.0)
    return exit_point, landed, exit_point + t[:, None] * out, down
