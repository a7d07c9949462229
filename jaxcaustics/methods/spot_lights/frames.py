"""Light-plane frames of caustic spot lights (Liu et al. 2008, Sect. 4.1), for the
moving-light table (`table.py`): the canonical frame of an axis, the rotation of one light
plane onto another and the resampling of light images into another plane
(`_resample_images`), which gives every light of a table its canonical frame
(`_canonicalise`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ...trace.optics import orthonormal_basis
from .lights import SpotLights, sample_light_plane


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
