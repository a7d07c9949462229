"""Refraction through the water surface and Fresnel transmittance (plain NumPy, float64)."""

from __future__ import annotations

import numpy as np


def refract(
    direction: np.ndarray, hx: np.ndarray, hy: np.ndarray, ior: float, fresnel: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Refract unit direction `direction` from index 1 into index `ior` at slopes (hx, hy).

    Parameters
    ----------
    direction : np.ndarray, shape (3,)
        Unit direction of travel of the incoming light (``z < 0``).
    hx, hy : np.ndarray, shape (N,)
        Surface slopes at the hit points; the upward normal is ``(-hx, -hy, 1) / |.|``.
    ior : float
        Index of refraction below the surface (above is 1).
    fresnel : bool
        Whether to compute the unpolarised dielectric transmittance (else 1).

    Returns
    -------
    tx, ty, tz : np.ndarray, shape (N,)
        The unit refracted direction (vector Snell, ``eta = 1 / ior``).
    transmittance : np.ndarray, shape (N,)
        ``1 - (Rs + Rp) / 2`` if `fresnel` else 1; 0 where the photon is lost.
    ok : np.ndarray of bool, shape (N,)
        False for total internal reflection (``sin^2 theta_t > 1``) or a refracted ray
        that does not go down (``tz >= 0``).
    """
    d_x, d_y, d_z = (float(c) for c in direction)
    norm = np.sqrt(1.0 + hx * hx + hy * hy)
    n_x, n_y, n_z = -hx / norm, -hy / norm, 1.0 / norm
    cos_i = -(d_x * n_x + d_y * n_y + d_z * n_z)
    eta = 1.0 / ior
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    tir = sin2_t > 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    k = eta * cos_i - cos_t
    tx = eta * d_x + k * n_x
    ty = eta * d_y + k * n_y
    tz = eta * d_z + k * n_z
    ok = ~tir & (tz < 0.0)
    if fresnel:
        with np.errstate(divide="ignore", invalid="ignore"):
            rs = ((cos_i - ior * cos_t) / (cos_i + ior * cos_t)) ** 2
            rp = ((ior * cos_i - cos_t) / (ior * cos_i + cos_t)) ** 2
            transmittance = 1.0 - 0.5 * (rs + rp)
        # 0/0 only at exact grazing incidence with ior == 1: nothing is transmitted there.
        transmittance = np.where(np.isfinite(transmittance), transmittance, 0.0)
    else:
        transmittance = np.ones_like(cos_i)
    transmittance = np.where(ok, transmittance, 0.0)
    return tx, ty, tz, transmittance, ok


# memory of one photon in a chunk of the reference tracers: its arrays and the tracers'
# NumPy temporaries, bytes (an estimate: about 128 float64 numbers)
PHOTON_BYTES = 1024


def chunk_photons(memory_limit, default: int) -> int:
    """Photons traced at a time under `memory_limit` bytes (`PHOTON_BYTES` each);
    ``None``: the tracer's `default`. Raises a `ValueError` naming `memory_limit` unless
    it is ``None`` or an int ``>= 1``."""
    if memory_limit is None:
        return default
    if isinstance(memory_limit, bool) or not isinstance(memory_limit, (int, np.integer)):
        raise ValueError(f"`memory_limit` must be None or an int >= 1, got {memory_limit!r}")
    if memory_limit < 1:
        raise ValueError(f"`memory_limit` must be None or an int >= 1, got {memory_limit!r}")
    return max(1, int(memory_limit) // PHOTON_BYTES)
