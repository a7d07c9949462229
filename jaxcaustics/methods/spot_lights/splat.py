"""EWA splatting of a bundle's ray energies into a light-plane intensity image (step 5
of the spot-light fit, `fit.py`): the image's half width (`splat_half_width`) and the
splatting (`splat_intensity`, Zwicker et al. 2002)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .fit_common import _floats, _plane_hits, _safe_norm

LOWPASS_VARIANCE = 1.0
"""EWA screen-space low-pass filter variance, pixels^2 (Zwicker et al. 2002: ``V^h = I``)."""

SPLAT_MARGIN_PIXELS = 3
"""Pixels kept free around the outermost splat centre (with three footprint radii)."""


def splat_half_width(origin, direction, energy, plane_origin, axis, *, radius, resolution: int):
    """Half-width ``w`` (metres) of a light-plane image holding every ray with energy > 0:
    the largest ``r = |p - c|`` plus three major footprint radii ``radius / |d . a|``,
    widened so that ``SPLAT_MARGIN_PIXELS`` pixels stay free at the border. Shapes as in
    `splat_intensity`; at least ``3 radius`` when no ray has energy."""
    origin, direction, energy, plane_origin, axis, radius = _floats(
        origin, direction, energy, plane_origin, axis, radius
    )
    p, _, cos = _plane_hits(origin, direction, plane_origin, axis)
    used = energy > 0
    r_max = jnp.max(jnp.where(used, _safe_norm(p - plane_origin), 0.0))
    stretch = jnp.max(jnp.where(used, 1 / jnp.maximum(jnp.abs(cos), 0.5), 1.0))
    return (r_max + 3 * radius * stretch) * resolution / (resolution - 2 * SPLAT_MARGIN_PIXELS)


def splat_intensity(
    origin,
    direction,
    energy,
    plane_origin,
    axis,
    frame_u,
    half_width,
    *,
    radius,
    resolution: int,
    window: int = 8,
    chunk: int = 8192,
):
    """EWA-splat ray energies into a light-plane intensity image (Zwicker et al. 2002).

    Each ray is a cylinder of radius `radius` around its line; it meets the plane (normal
    `axis`, through `plane_origin`) at ``p`` in an ellipse with semi-axes
    ``radius / |d . a|`` along the ray's in-plane direction and `radius` across it (for a
    ray of the CSL that direction is along ``p - c``, as in the paper; this form is also
    defined at ``p = c``). Its reconstruction kernel is the Gaussian with that ellipse's
    second moments (a uniform disc of radius ``R`` has variance ``R^2 / 4`` per axis):
    covariance ``(radius / 2)^2 (I + g g^T)``, ``g = d_perp / (d . a)``; the EWA
    resampling filter adds the low-pass ``LOWPASS_VARIANCE`` pixel^2. Each splat is
    evaluated on the ``window x window`` pixels nearest ``p`` (those inside the image),
    normalised to sum 1 and scaled by ``energy / pixel area``, so the image integrates to
    the total energy of the rays whose window meets the image (all, when
    `half_width` comes from `splat_half_width`). Rays are processed `chunk` at a time.

    - `origin`, `direction`: ``(R, 3)`` rays (metres; unit directions);
      `energy`: ``(R,)`` (0: not splatted).
    - `plane_origin` ``c``, `axis` ``a``, `frame_u`: ``(3,)`` the light plane and its
      image columns' direction (see `SpotLights`); `half_width`: ``()`` metres.
    - `radius`: ``()`` cylinder radius, metres. `resolution`, `window`, `chunk`: static.

    **Returns** ``(resolution, resolution)`` intensity (energy per m^2), rows along ``v``.
    """
    origin, direction, energy, plane_origin, axis, frame_u, half_width, radius = _floats(
        origin, direction, energy, plane_origin, axis, frame_u, half_width, radius
    )
    n = resolution
    dtype = origin.dtype
    pixel = 2 * half_width / n
    frame_v = jnp.cross(axis, frame_u)
    basis = jnp.stack([frame_u, frame_v])  # (2, 3)
    offsets = jnp.arange(window)
    base_var = (radius / 2) ** 2
    low_var = LOWPASS_VARIANCE * pixel**2

    def splat_chunk(image, rays):
        o, d, e = rays
        p, _, cos = _plane_hits(o, d, plane_origin, axis)
        uv = (p - plane_origin) @ basis.T  # (C, 2)
        g = (d @ basis.T) / jnp.where(cos != 0, cos, 1.0)[:, None]
        cov = base_var * (jnp.eye(2, dtype=dtype) + g[:, :, None] * g[:, None, :])
        cov = cov + low_var * jnp.eye(2, dtype=dtype)
        det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
        # continuous pixel coordinates: pixel j's centre at j
        xy = (uv + half_width) / pixel - 0.5
        start = jnp.ceil(xy - window / 2).astype(jnp.int32)  # (C, 2)
        cols = start[:, 0:1] + offsets  # (C, W)
        rows = start[:, 1:2] + offsets
        du = (xy[:, 0:1] - cols) * pixel  # (C, W) metres
        dv = (xy[:, 1:2] - rows) * pixel
        q = (
            cov[:, 1, 1, None, None] * du[:, None, :] ** 2
            - 2 * cov[:, 0, 1, None, None] * du[:, None, :] * dv[:, :, None]
            + cov[:, 0, 0, None, None] * dv[:, :, None] ** 2
        ) / det[:, None, None]  # (C, W rows, W cols)
        inside = ((rows >= 0) & (rows < n))[:, :, None] & ((cols >= 0) & (cols < n))[:, None, :]
        wgt = jnp.where(inside, jnp.exp(-0.5 * q), 0.0)
        total = jnp.sum(wgt, axis=(1, 2), keepdims=True)
        scale = jnp.where(e > 0, e, 0.0)[:, None, None] / pixel**2
        wgt = wgt * scale / jnp.where(total > 0, total, 1.0)
        flat = jnp.where(inside, rows[:, :, None] * n + cols[:, None, :], n * n)
        return image.at[flat.reshape(-1)].add(wgt.reshape(-1), mode="drop"), None

    count = origin.shape[0]
    chunk = max(1, min(chunk, count))
    pad = -count % chunk
    rays = (origin, direction, energy)
    rays = jax.tree.map(lambda a: jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)), rays)
    rays = jax.tree.map(lambda a: a.reshape(-1, chunk, *a.shape[1:]), rays)
    image, _ = jax.lax.scan(splat_chunk, jnp.zeros(n * n, dtype), rays)
    return image.reshape(n, n)
