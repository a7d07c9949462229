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

Tracking and matching (Sect. 4.2). Every edge is tracked both ways (``a`` to ``b`` and
``b`` to ``a``; `precompute_spot_lights`), refining the axes slot by slot with the rays of
earlier slots removed, as the fit found them. A pair's distance is the mean of its distance
after tracking forwards and after tracking backwards, so the matching does not depend on the
edge's orientation; greedy by increasing distance, pairs beyond `match_threshold` (default
`DEFAULT_MATCH_FRACTION` of the object's size) skipped. An unmatched light of either end
gets a black partner at the other end, at its own axis tracked there, with its ``alpha``,
``beta`` and half width.

Triples. Let ``P_ij(L)`` be the partner of light ``L`` of vertex ``i`` on the edge ``(i, j)``:
the light of ``j`` it was matched with, or the black CSL created for it at ``j`` (at ``L``'s
axis tracked to ``j``). Every light ``L`` of a face's vertex ``i`` *owns* the triple whose
corner ``i`` is ``L`` and whose other corners are ``P_ij(L)`` and ``P_ik(L)``; only the owner
is painted (its image is added). Identical triples merge, their paints add; where the three
pairwise matches agree (``L0 - L1 - L2`` all matched with each other) the three owners give
one triple with every corner painted: the paper's triple, rule (1). Where they do not (a
light that appears or vanishes, or inconsistent matches), the owners give separate triples
whose unpainted corners are the paper's CSLs "labelled so that their image is not added";
such a triple's corners are matched with the owner but not necessarily with each other
(the deviation from rule (1) that makes the others exact):

- rule (3), exactness at the vertices: at barycentric ``(1, 0, 0)`` only corner 0 counts and
  each light of vertex 0 is painted in exactly one triple of the face (its own);
- rule (2), continuity across edges: on the edge ``(i, j)`` a face gives, for every pair
  ``(L, P)`` of that edge's matching, the CSLs at the geometry blended from ``L`` and ``P``
  with the images ``w_i I_L`` and ``w_j I_P`` (one CSL with both, if merged); the third
  corners weigh 0 and the triples owned by the third vertex's lights are black. This depends
  only on the edge's matching, which both faces share, so the light field (the sum of the
  images at each geometry) is the same from both sides.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..._checks import (
    check_array,
    check_bool,
    check_fits,
    check_int,
    check_memory_limit,
    check_number,
)
from ...devices import check_per_device, map_sharded, resolve_devices
from ...io.files import written_whole
from ...trace.optics import orthonormal_basis
from .exit_rays import EXIT_RAY_FLOATS, trace_exit_rays
from .fit import (
    DISTANCE_THRESHOLD,
    check_fit_knobs,
    check_refine_knobs,
    fit_bytes,
    fit_spot_lights,
    refine_axis,
)
from .lights import SpotLights, sample_light_plane

DEFAULT_MATCH_FRACTION = 0.25
"""Default `match_threshold`, as a fraction of the object's size."""

MAX_SUBDIVISIONS = 6
"""Most subdivisions of the icosahedron of directions (6: 40962 directions)."""

_KARCHER_ITERATIONS = 4
_SAVE_FORMAT = 1
_LIGHT_FIELDS = tuple(f.name for f in dataclasses.fields(SpotLights))


# --------------------------------------------------------------------------------------
# Directions


def icosphere_directions(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Light directions at the vertices of a subdivided icosahedron (trimesh's icosphere).

    **Arguments:**

    - `subdivisions`: number of midpoint subdivisions of the icosahedron (0: 12 vertices,
      1: 42, 2: 162 as in the paper).

    **Returns:** ``(vertices, faces)``: ``(V, 3)`` float64 unit vectors (each the direction
    towards the light; the light travels along ``-vertex``) and ``(F, 3)`` int32 vertex
    indices, counter-clockwise seen from outside (normals point outwards).
    """
    subdivisions = check_int(subdivisions, "subdivisions", 0, MAX_SUBDIVISIONS)
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=1.0)
    vertices = np.asarray(mesh.vertices, np.float64)
    vertices = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    faces = np.asarray(mesh.faces, np.int32).copy()
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.einsum("fk,fk->f", normal, tri.sum(axis=1)) < 0
    faces[inward] = faces[inward][:, ::-1]
    return vertices, faces


def direction_edges(faces) -> np.ndarray:
    """The edges of a triangle mesh of directions, ``(E, 2)`` int32, each sorted
    (``a < b``), in lexicographic order: the edge order of `SpotLightTable`."""
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"`faces` must have shape (F, 3), got {faces.shape}")
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0).astype(np.int32)


def slerp(s0: Float[Array, "3"], s1: Float[Array, "3"], t) -> Float[Array, "3"]:
    """Spherical linear interpolation between unit vectors (not antipodal), ``t`` in [0, 1]."""
    cos = jnp.clip(jnp.dot(s0, s1), -1.0, 1.0)
    angle = jnp.arccos(cos)
    sin = jnp.sin(angle)
    small = sin < 1e-9
    safe = jnp.where(small, 1.0, sin)
    w0 = jnp.where(small, 1.0 - t, jnp.sin((1.0 - t) * angle) / safe)
    w1 = jnp.where(small, t, jnp.sin(t * angle) / safe)
    s = w0 * s0 + w1 * s1
    return s / jnp.linalg.norm(s)


# --------------------------------------------------------------------------------------
# The table


class SpotLightTable(eqx.Module):
    """Per-scene CSL precomputation for a moving directional light (Sect. 4).

    ``V`` directions, ``F`` faces, ``E`` edges, ``K`` light slots per direction, ``T``
    triple slots per face, ``N`` image side. Lengths in metres.

    - `directions`: ``(V, 3)`` unit vectors towards the light (the light travels along
      ``-directions[v]``).
    - `faces`: ``(F, 3)`` int vertex indices, outward.
    - `edges`: ``(E, 2)`` int sorted vertex pairs (`direction_edges`).
    - `lights`: `SpotLights` with leading axes ``(V, K)``: the CSL set of every direction,
      frames canonical (``frame_u = orthonormal_basis(axis)[0]``).
    - `edge_match`: ``(E, 2K, 2)`` int: the matching of each edge ``(a, b)``: rows
      ``(slot of a, slot of b)``; ``-1`` for a black partner; ``(-2, -2)`` pads.
    - `triple_active`: ``(F, T)`` bool, which triple slots of a face are used.
    - `triple_slot`: ``(F, T, 3)`` int: corner ``i`` is light slot ``triple_slot[f, t, i]``
      of vertex ``faces[f, i]``, or ``-1`` for a black CSL.
    - `corner_origin`, `corner_axis`: ``(F, T, 3, 3)`` each corner's light-plane origin and
      unit axis (a black CSL: the tracked axis of the light it partners, with its origin
      slid along the axis).
    - `corner_alpha`, `corner_beta`, `corner_half_width`: ``(F, T, 3)`` each corner's
      ``alpha`` (m, may be inf), ``beta`` (1/m) and image half width (m); a black CSL takes
      those of the light it partners.
    - `corner_paint`: ``(F, T, 3)`` 1.0 where the corner's image is added, 0.0 for a black
      CSL or a light painted by another triple of the face ("not added", Sect. 4.3).
    - `centre`: ``(3,)`` the object's centre; `size`: ``()`` its size (largest side of its
      bounding box); `match_threshold`: ``()`` the axis distance beyond which no pair was
      matched (m).
    """

    directions: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]
    edges: Int[Array, "E 2"]
    lights: SpotLights
    edge_match: Int[Array, "E M 2"]
    triple_active: Bool[Array, "F T"]
    triple_slot: Int[Array, "F T 3"]
    corner_origin: Float[Array, "F T 3 3"]
    corner_axis: Float[Array, "F T 3 3"]
    corner_alpha: Float[Array, "F T 3"]
    corner_beta: Float[Array, "F T 3"]
    corner_half_width: Float[Array, "F T 3"]
    corner_paint: Float[Array, "F T 3"]
    centre: Float[Array, "3"]
    size: Float[Array, ""]
    match_threshold: Float[Array, ""]

    def __check_init__(self):
        v = self.directions.shape[0]
        f, t = self.triple_active.shape
        if self.lights.origin.shape[:1] != (v,) or self.lights.origin.ndim != 3:
            raise ValueError(f"`lights` must have leading axes (V={v}, K)")
        for name in (
            "triple_slot",
            "corner_alpha",
            "corner_beta",
            "corner_half_width",
            "corner_paint",
        ):
            if getattr(self, name).shape != (f, t, 3):
                raise ValueError(f"`{name}` must have shape ({f}, {t}, 3)")
        for name in ("corner_origin", "corner_axis"):
            if getattr(self, name).shape != (f, t, 3, 3):
                raise ValueError(f"`{name}` must have shape ({f}, {t}, 3, 3)")

    @property
    def max_lights(self) -> int:
        """``K``, the light slots per direction."""
        return self.lights.origin.shape[1]

    @property
    def max_triples(self) -> int:
        """``T``, the triple slots per face (the most triples any face has)."""
        return self.triple_active.shape[1]

    @property
    def resolution(self) -> int:
        """``N``, the side of the light images in pixels."""
        return self.lights.image.shape[-1]

    def interpolate(self, direction) -> SpotLights:
        """`interpolate_spot_lights` of this table."""
        return interpolate_spot_lights(self, direction)

    def save(self, path: str | os.PathLike) -> None:
        """Write the table to an ``.npz`` file (numpy adds the suffix if `path` lacks it)."""
        path = _check_path(path)
        # (Any: mypy would take `**arrays` for `savez_compressed`'s `allow_pickle` too)
        arrays: dict[str, Any] = {"format": np.asarray(_SAVE_FORMAT)}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name == "lights":
                for name in _LIGHT_FIELDS:
                    arrays[f"lights.{name}"] = np.asarray(getattr(value, name))
            else:
                arrays[field.name] = np.asarray(value)
        if Path(path).suffix != ".npz":  # numpy would add it
            path = Path(path).with_name(Path(path).name + ".npz")
        try:
            with written_whole(path) as tmp:
                np.savez_compressed(tmp, **arrays)
        except OSError as err:
            raise ValueError(f"`path` cannot be written: {err}") from err

    @classmethod
    def load(cls, path: str | os.PathLike) -> SpotLightTable:
        """Read a table written by `save`."""
        path = _check_path(path)
        try:
            data = np.load(path)
        except (OSError, ValueError) as err:
            raise ValueError(f"`path` is not a readable .npz file: {path}") from err
        with data:
            if "format" not in data or int(data["format"]) != _SAVE_FORMAT:
                raise ValueError(f"`path` is not a SpotLightTable file (format {_SAVE_FORMAT})")
            lights = _stacked_spot_lights({name: data[f"lights.{name}"] for name in _LIGHT_FIELDS})
            kwargs = {
                f.name: jnp.asarray(data[f.name])
                for f in dataclasses.fields(cls)
                if f.name != "lights"
            }
        return cls(lights=lights, **kwargs)


def _check_path(path):
    """`path` if it is a file name (a string or an `os.PathLike`), else a `ValueError`."""
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"`path` must be a file name, got {type(path).__name__}")
    return path


def _stacked_spot_lights(fields: dict) -> SpotLights:
    """A `SpotLights` with any leading axes from arrays named as its fields (the
    constructor only takes one leading axis)."""
    treedef = jax.tree.structure(
        SpotLights(
            np.zeros((1, 3)),
            [[0.0, 0.0, 1.0]],
            [[1.0, 0.0, 0.0]],
            [1.0],
            [0.0],
            [1.0],
            np.zeros((1, 1, 1)),
        )
    )
    return jax.tree.unflatten(treedef, [jnp.asarray(fields[name]) for name in _LIGHT_FIELDS])


# --------------------------------------------------------------------------------------
# Geometry helpers (JAX)


def _normalise(x: Array) -> Array:
    return x / jnp.linalg.norm(x, axis=-1, keepdims=True)


def _canonical_frame(axis: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """``orthonormal_basis(axis)[0]`` for any leading axes."""
    flat = axis.reshape(-1, 3)
    return jax.vmap(lambda a: orthonormal_basis(a)[0])(flat).reshape(axis.shape)


def _rotate_onto(x: Float[Array, "... 3"], y: Float[Array, "... 3"], v: Float[Array, "... 3"]):
    """Apply to `v` the rotation about ``x cross y`` that takes unit `x` to unit `y`
    (Rodrigues: ``v + c x v + c x (c x v) / (1 + x.y)``, ``c = x cross y``; x, y not
    antipodal)."""
    c = jnp.cross(x, y)
    d = jnp.maximum(1.0 + jnp.sum(x * y, axis=-1, keepdims=True), 1e-12)
    cv = jnp.cross(c, v)
    return v + cv + jnp.cross(c, cv) / d


def _resample_images(
    source: SpotLights,
    axis: Float[Array, "M 3"],
    frame_u: Float[Array, "M 3"],
    half_width: Float[Array, " M"],
) -> Float[Array, "M N N"]:
    """Resample each of ``M`` source light images into a target light plane.

    The target plane of light ``m`` has unit normal ``axis[m]``, column direction
    ``frame_u[m]`` and half width ``half_width[m]`` (``N`` pixels, the source's). The source
    plane is rotated onto it by the rotation about ``axis_src x axis`` taking ``axis_src``
    to ``axis`` (Liu et al. Sect. 4.1), origins coinciding; each target pixel centre is
    looked up bilinearly in the source image (intensity, 0 outside it).
    """
    n = source.resolution
    m = axis.shape[0]
    frame_v = jnp.cross(axis, frame_u)
    ticks = (jnp.arange(n, dtype=axis.dtype) + 0.5) / n * 2.0 - 1.0  # in units of w
    u = ticks[None, None, :, None] * half_width[None, None, None, :]  # (1, 1, N, M) cols
    v = ticks[None, :, None, None] * half_width[None, None, None, :]  # (1, N, 1, M) rows
    q = u * frame_u.T[:, None, None, :] + v * frame_v.T[:, None, None, :]  # (3, N, N, M)
    q = jnp.moveaxis(q, 0, -1)  # (N, N, M, 3)
    q_src = _rotate_onto(axis, source.axis, q)
    us = jnp.sum(q_src * source.frame_u, axis=-1)
    vs = jnp.sum(q_src * source.frame_v, axis=-1)
    image = sample_light_plane(source, us, vs)  # (N, N, M)
    assert image.shape == (n, n, m)
    return jnp.moveaxis(image, -1, 0)


@jax.jit
def _canonicalise(lights: SpotLights) -> SpotLights:
    """The same lights (any leading axes) with ``frame_u = orthonormal_basis(axis)[0]``:
    images whose frame differs (by more than sqrt(eps) of the dtype) are resampled (rotated
    in their plane), others kept as they are."""
    lead = lights.origin.shape[:-1]
    flat = jax.tree.map(lambda a: a.reshape((-1,) + a.shape[len(lead) :]), lights)
    canonical = _canonical_frame(flat.axis)
    rotated = _resample_images(flat, flat.axis, canonical, flat.half_width)
    tolerance = jnp.sqrt(jnp.finfo(canonical.dtype).eps)  # a negligible in-plane turn
    same = jnp.all(jnp.abs(flat.frame_u - canonical) < tolerance, axis=-1)
    image = jnp.where(same[:, None, None], flat.image, rotated)
    flat = eqx.tree_at(lambda x: (x.frame_u, x.image), flat, (canonical, image))
    return jax.tree.map(lambda a: a.reshape(lead + a.shape[1:]), flat)


def _spherical_mean(axes: Float[Array, "n 3"], weights: Float[Array, " n"]) -> Float[Array, "3"]:
    """Weighted spherical (Karcher) mean of unit vectors: a few fixed-point steps
    ``m <- exp_m(sum_i w_i log_m(a_i))`` from the normalised weighted sum. Exact for a
    single non-zero weight; the slerp of two vectors when one weight is 0."""
    mean = _normalise(weights @ axes)
    for _ in range(_KARCHER_ITERATIONS):
        cos = axes @ mean
        tangent = axes - cos[:, None] * mean
        sin = jnp.linalg.norm(tangent, axis=-1)
        ok = sin > 1e-12
        scale = jnp.where(ok, jnp.arctan2(sin, cos) / jnp.where(ok, sin, 1.0), 1.0)
        step = weights @ (scale[:, None] * tangent)
        length = jnp.linalg.norm(step)
        ok = length > 1e-15
        safe = jnp.where(ok, length, 1.0)
        moved = jnp.cos(length) * mean + jnp.where(ok, jnp.sin(safe) / safe, 1.0) * step
        mean = _normalise(moved)
    return mean


def _locate(
    directions: Float[Array, "V 3"], faces: Int[Array, "F 3"], s: Float[Array, "3"]
) -> tuple[Int[Array, ""], Float[Array, "3"]]:
    """The face hit by the ray from the origin along unit `s` and the planar barycentric
    coordinates of the hit (clipped to >= 0, values below a few ulp set to 0, renormalised).
    """
    tri = directions[faces]  # (F, 3 vertices, 3 coords)
    rhs = jnp.broadcast_to(s, (tri.shape[0], 3))[..., None]
    b = jnp.linalg.solve(jnp.swapaxes(tri, -1, -2), rhs)[..., 0]  # s = sum_i b_i v_i
    total = jnp.sum(b, axis=-1)
    score = jnp.where(total > 0, jnp.min(b, axis=-1) / jnp.where(total > 0, total, 1.0), -jnp.inf)
    face = jnp.argmax(score)
    w = jnp.clip(b[face] / total[face], 0.0, None)
    w = jnp.where(w < 64 * jnp.finfo(w.dtype).eps, 0.0, w)
    return face, w / jnp.sum(w)


def _blend_alpha(alpha: Float[Array, "... 3"], w: Float[Array, "3"]) -> Float[Array, "..."]:
    """``sum_i w_i alpha_i`` over corners with ``w_i > 0``; inf if any of those is inf."""
    used = w > 0
    finite = jnp.where(jnp.isinf(alpha), 0.0, alpha)
    total = jnp.sum(jnp.where(used, w * finite, 0.0), axis=-1)
    return jnp.where(jnp.any(used & jnp.isinf(alpha), axis=-1), jnp.inf, total)


# --------------------------------------------------------------------------------------
# Per-frame interpolation


def interpolate_spot_lights(table: SpotLightTable, direction) -> SpotLights:
    """The CSL set for a light travelling along `direction`, interpolated from `table`.

    The face of the icosphere hit by ``-direction`` and the barycentric weights ``w`` of the
    hit (on the face's plane) select and blend the face's triples (Sect. 4.1): the axis is
    the weighted spherical (Karcher) mean of the corners' axes; origin, ``alpha``, ``beta``
    and half width are weighted linear blends; the image is ``sum_i w_i paint_i`` times
    corner ``i``'s image rotated into the interpolated light's plane (frame
    ``orthonormal_basis(axis)[0]``) and resampled bilinearly.

    **Arguments:**

    - `table`: a `SpotLightTable`.
    - `direction`: ``(3,)`` direction of travel of the light (normalised here); may be
      traced (jit, vmap, no recompilation per direction).

    **Returns:** `SpotLights` with ``T`` slots (one per triple slot of the face); a slot is
    active if its triple is and some painted corner has a non-zero weight (so at a vertex
    exactly that vertex's lights are active).
    """
    if not isinstance(table, SpotLightTable):
        raise ValueError(f"`table` must be a SpotLightTable, got {type(table).__name__}")
    direction = check_array(direction, "direction", (3,))
    if not isinstance(direction, jax.core.Tracer) and not np.any(np.asarray(direction)):
        raise ValueError("`direction` must be finite and non-zero")
    return _interpolate(table, direction.astype(table.directions.dtype))


@jax.jit
def _interpolate(table: SpotLightTable, direction: Float[Array, "3"]) -> SpotLights:
    s = -direction / jnp.linalg.norm(direction)
    face, w = _locate(table.directions, table.faces, s)
    return interpolate_in_face(table, face, w)


@jax.jit
def interpolate_in_face(
    table: SpotLightTable, face: Int[Array, ""], weights: Float[Array, "3"]
) -> SpotLights:
    """Blend the triples of `face` (an index) with barycentric `weights` ``(3,)`` (>= 0,
    summing to 1, in the order of ``table.faces[face]``). See `interpolate_spot_lights`."""
    w = weights
    vertex = table.faces[face]  # (3,)
    slot = table.triple_slot[face]  # (T, 3)
    corner_axis = table.corner_axis[face]  # (T, 3, 3)
    t = slot.shape[0]
    paint = table.corner_paint[face] * (slot >= 0)
    wp = w[None, :] * paint  # (T, 3)
    axis = jax.vmap(_spherical_mean, in_axes=(0, None))(corner_axis, w)  # (T, 3)
    frame_u = _canonical_frame(axis)
    origin = jnp.einsum("i,tik->tk", w, table.corner_origin[face])
    alpha = _blend_alpha(table.corner_alpha[face], w)
    beta = table.corner_beta[face] @ w
    half_width = table.corner_half_width[face] @ w

    source = jax.tree.map(
        lambda a: a[vertex[None, :], jnp.maximum(slot, 0)].reshape((3 * t,) + a.shape[2:]),
        table.lights,
    )
    images = _resample_images(
        source,
        jnp.repeat(axis, 3, axis=0),
        jnp.repeat(frame_u, 3, axis=0),
        jnp.repeat(half_width, 3, axis=0),
    ).reshape((t, 3) + source.image.shape[1:])
    image = jnp.einsum("ti,tinm->tnm", wp, images)

    lit = table.triple_active[face] & (jnp.sum(wp, axis=-1) > 0)
    one = jnp.ones_like(alpha)
    fallback_axis = jnp.zeros_like(axis).at[:, 2].set(1.0)
    axis = jnp.where(lit[:, None], axis, fallback_axis)
    return SpotLights(
        jnp.where(lit[:, None], origin, 0.0),
        axis,
        jnp.where(lit[:, None], frame_u, _canonical_frame(fallback_axis)),
        jnp.where(lit, alpha, one),
        jnp.where(lit, beta, 0.0),
        jnp.where(lit, half_width, one),
        jnp.where(lit[:, None, None], image, 0.0),
        lit,
    )


# --------------------------------------------------------------------------------------
# Matching and triples (host, NumPy)


def axis_distance(point0, axis0, point1, axis1, centre, size) -> np.ndarray:
    """Axis distance of Sect. 4.2: ``sqrt(|b0 - b1|^2 + size^2 |a0 - a1|^2)``.

    `point*`: ``(..., 3)`` any points of the axes (m); `axis*`: ``(..., 3)`` unit directions;
    ``b`` is the point of each axis nearest to `centre` ``(3,)``; `size`: the object's size
    (m, the paper's bounding sphere size ``sqrt(B)``). Broadcasts; returns metres.
    """

    def nearest(p, a):
        return p + np.sum((centre - p) * a, axis=-1, keepdims=True) * a

    b0, b1 = nearest(point0, axis0), nearest(point1, axis1)
    return np.sqrt(np.sum((b0 - b1) ** 2, -1) + size**2 * np.sum((axis0 - axis1) ** 2, -1))


def greedy_match(distance: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Greedy matching by increasing distance (Sect. 4.2).

    `distance`: ``(K0, K1)``, ``inf`` (or NaN) for pairs that must not match. Pairs are
    taken in order of increasing distance; a pair beyond `threshold` or with a light
    already matched is skipped. **Returns** ``(partner0 (K0,), partner1 (K1,))``: the
    matched index on the other side, ``-1`` where unmatched.
    """
    k0, k1 = distance.shape
    partner0 = np.full(k0, -1, np.int64)
    partner1 = np.full(k1, -1, np.int64)
    for flat in np.argsort(distance, axis=None, kind="stable"):
        i, j = divmod(int(flat), k1)
        if not distance[i, j] <= threshold:
            break  # sorted: every later pair is farther (NaN sorts last)
        if partner0[i] < 0 and partner1[j] < 0:
            partner0[i], partner1[j] = j, i
    return partner0, partner1


def _match_edges(lights, edges, moved_origin, moved_axis, centre, size, threshold):
    """Pairwise matching on every edge. The distance of a pair is the mean of the distance
    after tracking ``a``'s light to ``b`` and that after tracking ``b``'s light to ``a``
    (symmetric in the edge's orientation). **Returns** ``(partners (E, 2, K), match
    (E, 2K, 2))``: ``partners[e, 0, i]`` the slot of ``b`` matched with slot ``i`` of
    ``a`` (-1: black partner, -2: inactive slot), ``partners[e, 1]`` the reverse."""
    k = lights["active"].shape[1]
    partners = np.full((len(edges), 2, k), -2, np.int64)
    match = np.full((len(edges), 2 * k, 2), -2, np.int32)
    for e, (a, b) in enumerate(edges):
        act_a, act_b = lights["active"][a], lights["active"][b]
        forward = axis_distance(
            moved_origin[e, 0][:, None],
            moved_axis[e, 0][:, None],
            lights["origin"][b][None],
            lights["axis"][b][None],
            centre,
            size,
        )
        backward = axis_distance(
            lights["origin"][a][:, None],
            lights["axis"][a][:, None],
            moved_origin[e, 1][None],
            moved_axis[e, 1][None],
            centre,
            size,
        )
        distance = 0.5 * (forward + backward)
        distance[~act_a, :] = np.inf
        distance[:, ~act_b] = np.inf
        p0, p1 = greedy_match(distance, threshold)
        partners[e, 0] = np.where(act_a, p0, -2)
        partners[e, 1] = np.where(act_b, p1, -2)
        rows = [(i, p0[i]) for i in np.flatnonzero(act_a)]
        rows += [(-1, j) for j in np.flatnonzero(act_b & (p1 < 0))]
        if rows:
            match[e, : len(rows)] = rows
    return partners, match


def _face_triples(face, edge_of, edges, partners, active) -> dict:
    """Owner triples of one face, merged (see the module docstring). Keys: three corner
    nodes, ``("L", vertex, slot)`` a light or ``("B", edge, side, slot)`` the black CSL at
    ``edges[edge, side]`` that partners slot ``slot`` of the other end; values: paints."""
    triples: dict = {}
    for i in range(3):
        v = int(face[i])
        for s in np.flatnonzero(active[v]):
            corners: list = [None, None, None]
            corners[i] = ("L", v, int(s))
            for j in ((i + 1) % 3, (i + 2) % 3):
                u = int(face[j])
                e = edge_of[(min(v, u), max(v, u))]
                side = 0 if edges[e, 0] == v else 1
                partner = int(partners[e, side, s])
                corners[j] = ("L", u, partner) if partner >= 0 else ("B", e, 1 - side, int(s))
            paint = triples.setdefault(tuple(corners), [0.0, 0.0, 0.0])
            assert paint[i] == 0.0  # each light owns one triple
            paint[i] = 1.0
    return triples


def _node_geometry(node, lights, edges, moved_origin, moved_axis):
    """``(slot, origin, axis, alpha, beta, half_width)`` of a triple corner node."""
    if node[0] == "L":
        _, v, s = node
        origin, axis, slot = lights["origin"][v, s], lights["axis"][v, s], s
    else:
        _, e, side, s = node
        source = 1 - side
        v = edges[e, source]
        origin, axis, slot = moved_origin[e, source, s], moved_axis[e, source, s], -1
    return (
        slot,
        origin,
        axis,
        lights["alpha"][v, s],
        lights["beta"][v, s],
        lights["half_width"][v, s],
    )


def build_spot_light_table(
    directions,
    faces,
    lights: SpotLights,
    moved_origin,
    moved_axis,
    *,
    centre,
    size,
    match_threshold: float | None = None,
) -> SpotLightTable:
    """Match the CSL sets of neighbouring directions and build the triples of every face.

    **Arguments:**

    - `directions`: ``(V, 3)`` unit vectors towards the light; `faces`: ``(F, 3)`` int.
    - `lights`: `SpotLights` with leading axes ``(V, K)``, the set of every direction.
    - `moved_origin`, `moved_axis`: ``(E, 2, K, 3)``, edges as `direction_edges(faces)`:
      ``[e, 0]`` the lights of ``edges[e, 0]`` with their axes tracked to ``edges[e, 1]``
      (an axis point, m, and a unit direction), ``[e, 1]`` the reverse. Non-finite entries
      fall back to the light's own axis.
    - `centre`: ``(3,)`` the object's centre (m); `size`: its size (m).
    - `match_threshold`: the largest axis distance of a matched pair (m); default
      `DEFAULT_MATCH_FRACTION` times `size`.

    **Returns:** a `SpotLightTable` (``T`` = the most triples of any face).
    """
    directions = np.asarray(directions, np.float64)
    if directions.ndim != 2 or directions.shape[1] != 3:
        raise ValueError(f"`directions` must have shape (V, 3), got {directions.shape}")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"`faces` must be an int array of shape (F, 3), got {faces.shape}")
    v_count = directions.shape[0]
    if faces.min() < 0 or faces.max() >= v_count:
        raise ValueError(f"`faces` must index the {v_count} directions")
    if (
        not isinstance(lights, SpotLights)
        or lights.origin.shape[:1] != (v_count,)
        or (lights.origin.ndim != 3)
    ):
        raise ValueError(f"`lights` must be a SpotLights with leading axes ({v_count}, K)")
    k = lights.origin.shape[1]
    edges = direction_edges(faces)
    moved_origin = np.asarray(moved_origin, np.float64)
    moved_axis = np.asarray(moved_axis, np.float64)
    for name, arr in (("moved_origin", moved_origin), ("moved_axis", moved_axis)):
        if arr.shape != (len(edges), 2, k, 3):
            raise ValueError(f"`{name}` must have shape ({len(edges)}, 2, {k}, 3), got {arr.shape}")
    centre = np.asarray(centre, np.float64)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise ValueError(f"`centre` must be a finite (3,) point, got shape {centre.shape}")
    size = float(size)
    if not size > 0 or not np.isfinite(size):
        raise ValueError(f"`size` must be positive and finite, got {size}")
    threshold = DEFAULT_MATCH_FRACTION * size if match_threshold is None else match_threshold
    threshold = float(threshold)
    if not threshold >= 0:
        raise ValueError(f"`match_threshold` must be >= 0, got {match_threshold}")

    lights = _canonicalise(lights)
    host = {name: np.asarray(getattr(lights, name)) for name in _LIGHT_FIELDS}
    # Tracking that failed (non-finite) falls back to the light's own axis.
    ends = edges.T  # (2, E): source vertex of [e, 0] and [e, 1]
    own_origin = np.stack([host["origin"][ends[0]], host["origin"][ends[1]]], axis=1)
    own_axis = np.stack([host["axis"][ends[0]], host["axis"][ends[1]]], axis=1)
    bad = ~(np.all(np.isfinite(moved_origin), -1) & np.all(np.isfinite(moved_axis), -1))
    moved_origin = np.where(bad[..., None], own_origin, moved_origin)
    moved_axis = np.where(bad[..., None], own_axis, moved_axis)
    moved_axis = moved_axis / np.linalg.norm(moved_axis, axis=-1, keepdims=True)

    partners, edge_match = _match_edges(
        host, edges, moved_origin, moved_axis, centre, size, threshold
    )
    edge_of = {(int(a), int(b)): e for e, (a, b) in enumerate(edges)}
    per_face = [_face_triples(f, edge_of, edges, partners, host["active"]) for f in faces]
    t = max([1] + [len(triples) for triples in per_face])

    f_count = len(faces)
    active = np.zeros((f_count, t), bool)
    slot = np.full((f_count, t, 3), -1, np.int32)
    origin = np.zeros((f_count, t, 3, 3))
    axis = np.zeros((f_count, t, 3, 3))
    axis[..., 2] = 1.0
    alpha = np.ones((f_count, t, 3))
    beta = np.zeros((f_count, t, 3))
    half_width = np.ones((f_count, t, 3))
    paint = np.zeros((f_count, t, 3))
    for f, triples in enumerate(per_face):
        for j, (corners, paints) in enumerate(triples.items()):
            active[f, j] = True
            paint[f, j] = paints
            for i, node in enumerate(corners):
                geometry = _node_geometry(node, host, edges, moved_origin, moved_axis)
                (
                    slot[f, j, i],
                    origin[f, j, i],
                    axis[f, j, i],
                    alpha[f, j, i],
                    beta[f, j, i],
                    half_width[f, j, i],
                ) = geometry

    dtype = lights.origin.dtype
    as_float = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return SpotLightTable(
        directions=as_float(directions),
        faces=jnp.asarray(faces, jnp.int32),
        edges=jnp.asarray(edges),
        lights=lights,
        edge_match=jnp.asarray(edge_match),
        triple_active=jnp.asarray(active),
        triple_slot=jnp.asarray(slot),
        corner_origin=as_float(origin),
        corner_axis=as_float(axis),
        corner_alpha=as_float(alpha),
        corner_beta=as_float(beta),
        corner_half_width=as_float(half_width),
        corner_paint=as_float(paint),
        centre=as_float(centre),
        size=as_float(size),
        match_threshold=as_float(threshold),
    )


# --------------------------------------------------------------------------------------
# Sharded batches


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
