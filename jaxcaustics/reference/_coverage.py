"""Triangles of evenly spread flux binned into pixels exactly: each pixel receives the
flux times the fraction of the triangle's area that lies in it.

The area of a triangle inside a pixel follows from Green's theorem: for a
counter-clockwise polygon the area is ``-(contour integral of y dx)``; with ``y``
clamped to the pixel's rows and ``x`` cut to its columns the same integral is the area
inside the pixel. Each edge contributes the integral of a clamped linear function, in
closed form. Triangles are grouped by the size of their pixel bounding box, so that a
group is one set of arrays (triangles x candidate pixels x 3 edges), in chunks.

scikit-image's `polygon` and matplotlib's `Path` rasterise by pixel centres (a triangle
a tenth of a pixel wide falls in one pixel or none); no maintained NumPy library gives
the area of a polygon inside each pixel, so it is written here (60 lines).
"""

from __future__ import annotations

import numpy as np

# candidate (triangle, pixel) pairs per array chunk: 24 float64 arrays of this size
_CHUNK = 1 << 20
# below this slope (pixels per pixel) an edge is integrated by its midpoint: exact for a
# level edge, and the closed form divides by the slope
_LEVEL = 1e-9


def _ramp(u: np.ndarray) -> np.ndarray:
    """``F(u) = integral from 0 to u of clamp(t, 0, 1) dt``."""
    c = np.clip(u, 0.0, 1.0)
    return 0.5 * c * c + np.maximum(u - 1.0, 0.0)


def _edge_area(xa, ya, xb, yb) -> np.ndarray:
    """``-integral of clamp(y, 0, 1) dx`` along the edges ``(xa, ya) -> (xb, yb)`` (pixel
    units, the pixel ``[0, 1]^2``), ``x`` cut to ``[0, 1]``."""
    lo = np.clip(np.minimum(xa, xb), 0.0, 1.0)
    hi = np.clip(np.maximum(xa, xb), 0.0, 1.0)
    dx = xb - xa
    level = np.abs(dx) <= _LEVEL * np.maximum(np.abs(yb - ya), 1.0)
    slope = np.where(level, 0.0, (yb - ya) / np.where(level, 1.0, dx))
    y_lo = ya + (lo - xa) * slope
    y_hi = ya + (hi - xa) * slope
    steep = np.abs(slope) > _LEVEL
    closed = (_ramp(y_hi) - _ramp(y_lo)) / np.where(steep, slope, 1.0)
    mid = np.clip(0.5 * (y_lo + y_hi), 0.0, 1.0) * (hi - lo)
    integral = np.where(steep, closed, mid)
    return np.where(level, 0.0, -np.sign(dx) * integral)


def bin_triangles(u: np.ndarray, v: np.ndarray, flux: np.ndarray, shape) -> np.ndarray:
    """Flux per pixel (flat, ``rows * cols``) of triangles with corners ``(u, v)``
    ``(T, 3)`` in pixel units (pixel ``(i, j)`` covers ``[j, j + 1] x [i, i + 1]``), each
    carrying `flux` ``(T,)`` evenly over its area. Flux that falls outside the grid is
    lost; a triangle of no area puts its flux in the pixel of its centroid."""
    rows, cols = shape
    out = np.zeros(rows * cols)
    u, v, flux = (np.asarray(a, dtype=np.float64) for a in (u, v, flux))
    area2 = (u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0]) - (u[:, 2] - u[:, 0]) * (v[:, 1] - v[:, 0])
    flat = np.abs(area2) < 1e-12
    if np.any(flat):  # by its centroid
        cu, cv = u[flat].mean(axis=1), v[flat].mean(axis=1)
        inside = (cu >= 0) & (cu < cols) & (cv >= 0) & (cv < rows)
        pix = np.floor(cv[inside]).astype(np.int64) * cols + np.floor(cu[inside]).astype(np.int64)
        out += np.bincount(pix, flux[flat][inside], minlength=rows * cols)
    keep = ~flat & (flux != 0)
    u, v, flux, area2 = u[keep], v[keep], flux[keep], area2[keep]
    if len(flux) == 0:
        return out
    clockwise = area2 < 0  # made counter-clockwise: the contour integral is +area
    u[clockwise] = u[clockwise][:, ::-1]
    v[clockwise] = v[clockwise][:, ::-1]
    density = flux / (0.5 * np.abs(area2))  # flux per pixel area
    j0 = np.floor(u.min(axis=1)).astype(np.int64)
    i0 = np.floor(v.min(axis=1)).astype(np.int64)
    width = np.floor(u.max(axis=1)).astype(np.int64) - j0 + 1
    height = np.floor(v.max(axis=1)).astype(np.int64) - i0 + 1
    # inside one pixel: all of its flux there
    one = (width == 1) & (height == 1)
    inside = one & (j0 >= 0) & (j0 < cols) & (i0 >= 0) & (i0 < rows)
    out += np.bincount(i0[inside] * cols + j0[inside], flux[inside], minlength=rows * cols)
    rest = np.flatnonzero(~one)
    key = width[rest] * (height.max() + 1) + height[rest]
    order = rest[np.argsort(key, kind="stable")]
    key = key[np.argsort(key, kind="stable")]
    bounds = np.flatnonzero(np.diff(key)) + 1
    for group in np.split(order, bounds) if len(order) else []:
        w, h = int(width[group[0]]), int(height[group[0]])
        grid_j, grid_i = np.meshgrid(np.arange(w), np.arange(h))
        dj, di = grid_j.ravel(), grid_i.ravel()  # (P,) the candidate pixels' offsets
        step = max(1, _CHUNK // len(dj))
        for lo in range(0, len(group), step):
            t = group[lo : lo + step]
            jj = j0[t, None] + dj[None, :]  # (n, P)
            ii = i0[t, None] + di[None, :]
            x = u[t][:, None, :] - jj[..., None]  # (n, P, 3): corners in the pixel's frame
            y = v[t][:, None, :] - ii[..., None]
            inside_area = sum(
                _edge_area(x[..., a], y[..., a], x[..., b], y[..., b])
                for a, b in ((0, 1), (1, 2), (2, 0))
            )
            ok = (jj >= 0) & (jj < cols) & (ii >= 0) & (ii < rows) & (inside_area > 0)
            pix = np.where(ok, ii * cols + jj, 0)
            out += np.bincount(
                pix.ravel(), np.where(ok, inside_area * density[t, None], 0.0).ravel(),
                minlength=rows * cols,
            )  # fmt: skip
    return out
