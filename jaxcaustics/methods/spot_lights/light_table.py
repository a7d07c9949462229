"""The table of caustic spot lights for a moving directional light (Liu et al. 2008,
Sect. 4; built by `table.py`): `SpotLightTable`, its ``.npz`` file form (`save`, `load`)
and the per-frame phase, `interpolate_spot_lights` (Sect. 4.1): the face the light
direction falls in, its triples blended with the barycentric weights."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..._checks import check_array
from ...io.files import written_whole
from .frames import _canonical_frame, _normalise, _resample_images
from .lights import SpotLights

_KARCHER_ITERATIONS = 4
_SAVE_FORMAT = 1
_LIGHT_FIELDS = tuple(f.name for f in dataclasses.fields(SpotLights))


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
# Per-frame interpolation


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
