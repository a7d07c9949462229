"""Optics core: vector refraction and reflection, exact dielectric Fresnel transmittance.

All functions act on the last axis (``(..., 3)`` directions) and broadcast. They are
safe everywhere: at total internal reflection (TIR) and at grazing incidence the values
*and* gradients are finite (the "double where" pattern: degenerate inputs are replaced
before a singular operation and the output is selected after it).

TIR is traced only where it can happen: with a concrete index ratio ``eta < 1`` (light
going into a denser medium) the refracted ray always exists, and neither the TIR test
nor its guards are traced (`tir_possible`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._checks import check_array, check_broadcast, check_number


def _dot(a: Array, b: Array) -> Array:
    return jnp.sum(a * b, axis=-1)


def _check_vectors(direction, normal) -> tuple[Array, Array]:
    """`direction` and `normal` as ``(..., 3)`` float arrays that broadcast, finite
    (unless traced); else a `ValueError` naming the argument."""
    direction = check_array(direction, "direction", (..., 3))
    normal = check_array(normal, "normal", (..., 3))
    check_broadcast(direction, "direction", normal, "normal")
    return direction, normal


def _check_eta(eta):
    """`eta` unchanged (a Python number stays one: see `tir_possible`), once checked to
    be positive and finite (a number or an array; traced: unchecked)."""
    if isinstance(eta, jax.core.Tracer):
        return eta
    if np.ndim(eta) == 0 or isinstance(eta, str):
        check_number(eta, "eta", low=0.0, low_open=True)
    elif np.any(np.asarray(check_array(eta, "eta")) <= 0):
        raise ValueError("`eta` must be > 0 (a ratio of indices of refraction)")
    return eta


def reflect(direction: Float[Array, "... 3"], normal: Float[Array, "... 3"]) -> Array:
    """Mirror `direction` about the plane with unit `normal`: ``d - 2 (d.n) n``."""
    direction, normal = _check_vectors(direction, normal)
    return direction - 2.0 * _dot(direction, normal)[..., None] * normal


def tir_possible(eta) -> bool:
    """Whether refraction with the index ratio `eta` (``n_incident / n_transmitted``) is
    traced with a total-internal-reflection test: always, unless `eta` is a concrete
    number below 1, where ``1 - eta^2 sin^2 >= 1 - eta^2 > 0`` for every angle."""
    return not (isinstance(eta, (int, float, np.floating)) and eta < 1.0)


def _cos_transmitted(cos_i: Array, eta) -> tuple[Array, Array | None]:
    """``cos`` of the refracted angle and the TIR mask (shape of `cos_i`); the mask is
    ``None`` where TIR cannot happen (`tir_possible`)."""
    k = 1.0 - eta**2 * (1.0 - cos_i**2)
    if not tir_possible(eta):
        return jnp.sqrt(k), None
    tir = k <= 0.0
    k_safe = jnp.where(tir, 1.0, k)
    return jnp.where(tir, 0.0, jnp.sqrt(k_safe)), tir


def refract_components(direction, normal, eta):
    """`refract` on components: `direction` and `normal` are 3-tuples of arrays.

    The kernel behind `refract`. Working on separate ``x, y, z`` arrays (rather than a
    trailing axis of 3) lets XLA fuse whole-image refraction into one loop.

    **Returns:** ``(transmitted, tir, cos_i)``: a 3-tuple of arrays, the TIR mask and
    the cosine of the angle of incidence (``>= 0``). Where TIR is impossible
    (`tir_possible`) the mask is a constant ``False`` and no TIR test is traced.
    """
    dot = sum(d * n for d, n in zip(direction, normal, strict=True))
    flip = dot > 0.0  # normal on the far side: use its opposite
    normal = tuple(jnp.where(flip, -n, n) for n in normal)
    cos_i = jnp.abs(dot)
    cos_t, tir = _cos_transmitted(cos_i, eta)
    scale = eta * cos_i - cos_t
    if tir is None:
        transmitted = tuple(eta * d + scale * n for d, n in zip(direction, normal, strict=True))
        return transmitted, jnp.zeros(jnp.shape(cos_i), bool), cos_i
    two_cos = 2.0 * cos_i
    transmitted = tuple(
        jnp.where(tir, d + two_cos * n, eta * d + scale * n)
        for d, n in zip(direction, normal, strict=True)
    )
    return transmitted, tir, cos_i


def refract(
    direction: Float[Array, "... 3"], normal: Float[Array, "... 3"], eta
) -> tuple[Float[Array, "... 3"], Bool[Array, "..."]]:
    """Refract a unit `direction` at a surface with unit `normal` (vector Snell's law).

    **Arguments:**

    - `direction`: unit direction of travel, shape ``(..., 3)``.
    - `normal`: unit normal, shape ``(..., 3)``, on the side the light comes from
      (``direction . normal <= 0``); it is flipped where it is not.
    - `eta`: ratio ``n_incident / n_transmitted`` of the indices of refraction.

    **Returns:** ``(transmitted, tir)``: the unit refracted direction, shape ``(..., 3)``,
    and the total-internal-reflection mask, shape ``(...)``. Where ``tir`` is true the
    returned direction is the mirror reflection (finite, and with finite gradients).
    """
    direction, normal = _check_vectors(direction, normal)
    eta = _check_eta(eta)
    direction, normal = jnp.broadcast_arrays(direction, normal)
    transmitted, tir, _ = refract_components(
        tuple(jnp.moveaxis(direction, -1, 0)), tuple(jnp.moveaxis(normal, -1, 0)), eta
    )
    return jnp.stack(transmitted, axis=-1), tir


def fresnel_transmittance(cos_i: Float[Array, ...], eta) -> Float[Array, ...]:
    """Exact unpolarised dielectric Fresnel transmittance ``1 - (R_s + R_p) / 2``.

    **Arguments:**

    - `cos_i`: cosine of the angle of incidence (``>= 0``), any shape.
    - `eta`: ``n_incident / n_transmitted``.

    **Returns:** the transmitted fraction of power, in ``[0, 1]``; 0 at total internal
    reflection and at grazing incidence.
    """
    cos_i = check_array(cos_i, "cos_i")
    if not isinstance(cos_i, jax.core.Tracer) and np.any(np.abs(np.asarray(cos_i)) > 1 + 1e-5):
        raise ValueError("`cos_i` must be a cosine, in [0, 1]")
    eta = _check_eta(eta)
    cos_i = jnp.abs(cos_i)
    cos_t, tir = _cos_transmitted(cos_i, eta)
    # R_s and R_p with indices (eta, 1): n1 cos_i vs n2 cos_t, scaled by 1/n2.
    s_num, s_den = eta * cos_i - cos_t, eta * cos_i + cos_t
    p_num, p_den = eta * cos_t - cos_i, eta * cos_t + cos_i
    if tir is None:  # cos_t >= sqrt(1 - eta^2) > 0: both denominators are positive
        return 1.0 - 0.5 * ((s_num / s_den) ** 2 + (p_num / p_den) ** 2)
    # both denominators vanish only when cos_i = cos_t = 0 (grazing, nothing transmitted)
    degenerate = (s_den <= 0.0) | (p_den <= 0.0) | tir
    s_den = jnp.where(degenerate, 1.0, s_den)
    p_den = jnp.where(degenerate, 1.0, p_den)
    r = 0.5 * ((s_num / s_den) ** 2 + (p_num / p_den) ** 2)
    return jnp.where(degenerate, 0.0, 1.0 - r)


def orthonormal_basis(axis: Array) -> tuple[Array, Array]:
    """Two unit vectors ``e1, e2`` that make ``(axis, e1, e2)`` orthonormal."""
    helper = jnp.where(
        jnp.abs(axis[0]) < 0.9,
        jnp.array([1.0, 0.0, 0.0], axis.dtype),
        jnp.array([0.0, 1.0, 0.0], axis.dtype),
    )
    e1 = jnp.cross(axis, helper)
    e1 = e1 / jnp.linalg.norm(e1)
    return e1, jnp.cross(axis, e1)
