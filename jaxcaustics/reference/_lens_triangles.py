"""The caustic of a `LensScene`'s smooth top by triangles: a grid of rest-plane vertices
traced exactly, each triangle of the grid carrying its flux evenly over the triangle its
corners land on (the lens's counterpart of `area_ratio_water`).

A photon grid binned point by point is noisy where light is spread thin and aliases
where the grid beats against the pixels; a triangle's flux spread over its landing
triangle has neither fault: the image is piecewise smooth in the vertices' landing
points, and its error is that of the ray map's linear interpolation over a triangle
(second order in the grid's spacing). The flux is split among the pixels by the exact
areas the landing triangles cover (`_coverage.bin_triangles`). This traces the surface
a height map describes (the bicubic of `_surface.py`), which is what a mill cuts from
the heights; `trace_solid_facets` traces the flat facets of the exported solid instead.

What it leaves out, stated: a triangle with a corner outside the aperture (a blank's
elliptical outline), lost to total internal reflection or not reaching the bottom face
is dropped whole; folds are kept (their flux is spread over each fold's triangle).
"""

from __future__ import annotations

import numbers

import numpy as np

from ._coverage import bin_triangles
from ._lens import LANDED, _field_to_world, _image, _read_lens, _trace_lens
from ._optics import MAX_EMITTED, _check_int

# vertices traced at a time (each with its two triangles binned: a few kB per vertex)
_CHUNK_VERTICES = 1 << 18


def trace_lens_triangles(scene, vertices_per_axis=1025) -> np.ndarray:
    """Irradiance on the screen of a `LensScene` by triangles of traced vertices.

    The aperture (``surface.extent``, in the field's own frame) carries a grid of
    ``rows x cols`` vertices from edge to edge (the far edges a billionth of the side
    inside, as the aperture is half-open); each grid cell is split into two triangles
    along its diagonal. The vertices are traced exactly (`trace_lens_photons`); a triangle whose
    three corners land carries its rest-plane area times the mean of their flux
    densities (Fresnel factors, a point light's ``I |w_z| / r^2``), spread evenly over
    the triangle they land on and split among the pixels by area.

    **Arguments:**

    - `scene`: a `LensScene`, read by duck typing (see the module docstring).
    - `vertices_per_axis`: the vertex grid, an int ``n`` (``n x n``) or ``(rows,
      cols)``, at least 2 per axis; default 1025. The accuracy knob: a few vertices per
      screen pixel side (the error falls as the square of their spacing).

    **Returns:** a float64 `np.ndarray` ``(rows, cols)`` (``(rows, cols, C)`` for ``C``
    indices): irradiance as `trace_lens` gives it.
    """
    lens = _read_lens(scene)
    rows, cols = _vertex_grid(vertices_per_axis)
    e = lens.surface.extent
    inside = 1e-9  # of the extent's side: the far edges' vertices within the aperture
    fx = np.linspace(0.0, 1.0 - inside, cols) * (e[1] - e[0])
    fy = np.linspace(0.0, 1.0 - inside, rows) * (e[3] - e[2])
    area = 0.5 * (fx[1] - fx[0]) * (fy[1] - fy[0])  # each triangle's, on the rest plane
    rec = lens.receiver
    r0, r1, s0, s1 = rec.extent
    scale_u, scale_v = rec.shape[1] / (r1 - r0), rec.shape[0] / (s1 - s0)
    flux = np.zeros((len(lens.iors), rec.shape[0] * rec.shape[1]))
    block = max(2, _CHUNK_VERTICES // cols)
    for top in range(0, rows - 1, block - 1):  # vertex rows top .. bottom (shared edges)
        bottom = min(top + block, rows)
        gx, gy = np.meshgrid(e[0] + fx, e[2] + fy[top:bottom])
        xs, ys = _field_to_world(lens.surface, gx.ravel(), gy.ravel())
        lx, ly, weight, status = _trace_lens(lens, xs, ys)
        corners = _triangles(bottom - top, cols)  # (T, 3) vertex indices
        for k in range(len(lens.iors)):
            landed = status[k][corners] == LANDED
            ok = landed.all(axis=1)
            tri = corners[ok]
            u = (lx[k][tri] - r0) * scale_u
            v = (ly[k][tri] - s0) * scale_v
            flux[k] += bin_triangles(u, v, weight[k][tri].mean(axis=1) * area, rec.shape)
    return _image(rec, flux, lens.multichannel)


def _vertex_grid(vertices_per_axis) -> tuple[int, int]:
    """``n`` -> ``(n, n)``; ``(rows, cols)`` -> itself: ints >= 2, at most `MAX_EMITTED`
    vertices."""
    if isinstance(vertices_per_axis, numbers.Integral) and not isinstance(vertices_per_axis, bool):
        shape: tuple = (vertices_per_axis, vertices_per_axis)
    else:
        try:
            shape = tuple(vertices_per_axis)
        except TypeError:
            shape = ()
        if len(shape) != 2:
            raise ValueError(
                f"`vertices_per_axis` must be an int or a pair (rows, cols), got "
                f"{vertices_per_axis!r}"
            )
    rows, cols = (_check_int(n, "vertices_per_axis", minimum=2) for n in shape)
    if rows * cols > MAX_EMITTED:
        raise ValueError(
            f"`vertices_per_axis` gives {rows * cols} vertices, over the limit {MAX_EMITTED}"
        )
    return rows, cols


def _triangles(rows: int, cols: int) -> np.ndarray:
    """The two triangles of each cell of a ``rows x cols`` vertex grid (row-major
    vertex indices), ``(2 (rows - 1) (cols - 1), 3)``."""
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (i * cols + j).ravel()
    b, c, d = a + 1, a + cols + 1, a + cols
    return np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
