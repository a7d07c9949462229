"""The caustic triangles of a photon grid, drawn on the screen: the two triangles of
every grid cell (`grid_triangles`), their pixel corners and flux, the paper's vertex
irradiance, and the rasterisation of a whole grid or a band of its rows by tiers of
windows (`_band_image`), finished into irradiance images and missed-flux fractions."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ...reconstruct.raster import (
    pixel_coordinates,
    rasterize_exact,
    rasterize_gouraud,
    signed_area,
    sum_in_tiers,
)
from ...trace.photons import Photons

MAX_AUTO_WINDOW = 32


def grid_triangles(values: Array) -> Array:
    """The two triangles of every grid cell: ``(..., rows, cols, *rest)`` vertex data to
    ``(..., 2 (rows - 1) (cols - 1), 3, *rest)``.

    Cell ``(i, j)`` with corners ``a = (i, j)``, ``b = (i, j + 1)``, ``c = (i + 1, j)``,
    ``d = (i + 1, j + 1)`` gives the triangles ``(a, b, d)`` and ``(a, d, c)``.
    """
    a = values[:, :-1, :-1]
    b = values[:, :-1, 1:]
    c = values[:, 1:, :-1]
    d = values[:, 1:, 1:]
    first = jnp.stack([a, b, d], axis=3)
    second = jnp.stack([a, d, c], axis=3)
    tri = jnp.stack([first, second], axis=3)  # (C, rows-1, cols-1, 2, 3, ...)
    return tri.reshape(tri.shape[0], -1, *tri.shape[4:])


def _scatter_to_vertices(per_triangle: Array, grid: tuple[int, int]) -> Array:
    """Sum ``(C, T, 3)`` per-triangle-corner values onto the grid vertices."""
    rows, cols = grid
    index = jnp.arange(rows * cols).reshape(1, rows, cols)
    corner = grid_triangles(index)[0]  # (T, 3) vertex indices
    out = jnp.zeros((per_triangle.shape[0], rows * cols), per_triangle.dtype)
    out = out.at[:, corner.reshape(-1)].add(per_triangle.reshape(per_triangle.shape[0], -1))
    return out.reshape(-1, rows, cols)


class _Triangles(eqx.Module):
    pixels: Float[Array, "C T 3 2"]
    flux: Float[Array, "C T"]
    valid: Bool[Array, "C T"]
    limited: Float[Array, "C T"]  # flux the interface limit dropped, by its vertices


def _screen_triangles(photons: Photons, extent, shape) -> _Triangles:
    valid = grid_triangles(photons.valid).all(axis=-1)
    density = grid_triangles(photons.density).mean(axis=-1)
    flux = jnp.where(valid, 0.5 * photons.cell_area * density, 0.0)
    pixels = pixel_coordinates(grid_triangles(photons.position[..., :2]), extent, shape)
    if photons.limited is None:
        limited = jnp.zeros_like(flux)
    else:
        limited = 0.5 * photons.cell_area * grid_triangles(photons.limited).mean(axis=-1)
    return _Triangles(pixels, flux, valid, limited)


def _vertex_irradiance(flux: Array, area: Array, valid: Array, grid, mean_area=None) -> Array:
    """The paper's vertex irradiance ``dPhi / dA``: a third of each adjacent triangle's
    flux over a third of its area (on the surface it landed on), per triangle corner
    ``(C, T, 3)``; `flux`, `area` and `valid` are per triangle ``(C, T)``; `mean_area`
    ``(C,)``: the valid area over the number of triangles of the whole grid (default:
    of these triangles)."""
    area = jnp.where(valid, area, 0.0)
    flux = jnp.where(valid, flux, 0.0)
    power = _scatter_to_vertices(jnp.broadcast_to(flux[..., None] / 3, area.shape + (3,)), grid)
    spread = _scatter_to_vertices(jnp.broadcast_to(area[..., None] / 3, area.shape + (3,)), grid)
    # a vertex whose triangles all collapsed (a perfect focus) is given a thousandth of
    # its mean share of area: finite, and far brighter than anything resolvable
    if mean_area is None:
        mean_area = jnp.sum(area, axis=-1) / max(1, area.shape[-1])
    floor = 1e-3 * mean_area[:, None]
    irradiance = power / jnp.maximum(spread, floor[..., None])
    rows, cols = grid
    index = grid_triangles(jnp.arange(rows * cols).reshape(1, rows, cols))[0]
    return irradiance.reshape(irradiance.shape[0], -1)[:, index]


def _pixel_area(extent, shape):
    return (extent[1] - extent[0]) / shape[1] * (extent[3] - extent[2]) / shape[0]


def _band_image(
    photons,
    extent,
    shape,
    reconstruction: str,
    tiers,
    supersample: int,
    draw=None,
    mean_area=None,
):
    """Rasterise the caustic triangles of `photons` (a whole grid or a band of its rows)
    by `tiers` (`sum_in_tiers`: ``((window, capacity, batch), ...)``, the triangles
    parted by `_spans`). `draw` ``(T,)``: which of them to draw (a band's own rows: its
    halo rows only complete the vertex irradiance); `mean_area`: see
    `_vertex_irradiance`.
    **Returns:** the summed rasteriser output ``(C, rows, cols)`` (flux per pixel, or the
    Gouraud image), the drawn valid flux ``(C,)`` and the flux the interface limit
    dropped from the drawn triangles ``(C,)``."""
    tri = _screen_triangles(photons, extent, shape)
    drawn = tri.valid if draw is None else tri.valid & draw[None]
    if reconstruction == "exact":

        def raster(w, v, f, m):
            return rasterize_exact(v, f, m, shape, w)

        values = tri.flux
    else:

        def raster(w, v, e, m):
            return rasterize_gouraud(v, e, m, shape, w, supersample)

        area = jnp.abs(signed_area(tri.pixels)) * _pixel_area(extent, shape)
        values = _vertex_irradiance(tri.flux, area, tri.valid, photons.grid_shape, mean_area)
    size = jnp.where(drawn, _spans(tri), -1.0)
    images = jnp.stack(
        [
            sum_in_tiers(raster, tiers, size[c], tri.pixels[c], values[c], drawn[c])
            for c in range(tri.valid.shape[0])
        ]
    )
    mine = tri.limited if draw is None else jnp.where(draw[None], tri.limited, 0.0)
    return images, jnp.where(drawn, tri.flux, 0.0).sum(axis=-1), mine.sum(axis=-1)


def _finish(images, total, limited, extent, shape, reconstruction):
    """Irradiance images, the missed-flux fraction and the fraction of the light through
    the object the interface limit dropped (``limited / (total + limited)``) from
    `_band_image`'s sums."""
    pixel_area = _pixel_area(extent, shape)
    if reconstruction == "exact":
        # overlap areas are sums of signed edge terms: clear their rounding below zero
        images = jnp.maximum(images / pixel_area, 0.0)
    landed = images.sum(axis=(1, 2)) * pixel_area
    missed = jnp.where(total > 0, 1.0 - landed / jnp.where(total > 0, total, 1.0), 0.0)
    through = total + limited
    dropped = jnp.where(through > 0, limited / jnp.where(through > 0, through, 1.0), 0.0)
    return images, jnp.clip(missed, 0.0, 1.0), dropped


@eqx.filter_jit
def _triangles_image(photons, extent, shape, reconstruction: str, tiers, supersample: int):
    images, total, limited = _band_image(photons, extent, shape, reconstruction, tiers, supersample)
    return _finish(images, total, limited, extent, shape, reconstruction)


def _spans(tri: _Triangles) -> Array:
    """The side of the pixel block that holds each valid triangle whole, ``(C, T)``,
    clipped to ``MAX_AUTO_WINDOW + 1`` (0 for invalid ones)."""
    pix = jnp.where(tri.valid[..., None, None], tri.pixels, 0.0)
    span = jnp.max(jnp.ceil(pix.max(axis=-2)) - jnp.floor(pix.min(axis=-2)), axis=-1)
    return jnp.clip(span, 0, MAX_AUTO_WINDOW + 1)
