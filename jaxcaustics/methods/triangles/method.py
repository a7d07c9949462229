"""Umenhoffer, Patow & Szirmay-Kalos's caustic triangles, for lens and mesh scenes.

T. Umenhoffer, G. Patow, L. Szirmay-Kalos, "Caustic Triangles on the GPU" (2008).

Photons leave the light on a regular grid (`jaxcaustics.trace.photons`); the hits of
neighbouring photons form two *caustic triangles* per grid cell, and each triangle
carries the flux of its half cell onto the screen. Two reconstructions:

- ``"gouraud"`` (the paper's): the irradiance at a vertex is the power of the photon
  over the area it spreads over on the screen, ``I = dPhi / dA``, with ``dA`` a third of
  the total area of the triangles around it (a third, not the paper's half: with linear
  interpolation a vertex owns a third of each adjacent triangle's integral, so this
  choice conserves flux; the paper's half would lose a third of it); triangles are drawn
  with linear (Gouraud) interpolation of the vertex irradiances, point-sampled at pixel
  centres (`supersample` x `supersample` samples per pixel), added up.
- ``"exact"``: constant irradiance per triangle (its flux over its area), with exact
  triangle/pixel overlap areas: exactly flux-conserving at any resolution.

Folds: where neighbouring photons cross (the triangle flips orientation, past a focus),
a flipped triangle still spreads its flux over its absolute area (signed overlap over
signed area), so flux is kept and images stay finite; a triangle collapsed to zero area
(at a focus) drops its flux at its centroid. Invalid photons invalidate the triangles
that use them (masks, never Python-side filtering).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..._checks import (
    check_bool,
    check_choice,
    check_fits,
    check_int,
    check_memory_limit,
    check_number,
    check_photon_work,
)
from ...devices import device_mesh
from ...reconstruct.raster import (
    pixel_coordinates,
    rasterize_exact,
    rasterize_gouraud,
    signed_area,
    splat_gaussian,
    sum_in_tiers,
    sum_over_batches,
)
from ...scene.checks import checks_scene_values
from ...scene.mesh import MeshScene
from ...scene.mirror import MirrorScene
from ...scene.scene import LensScene, PlaneReceiver
from ...scene.surface import MAX_HIT_ITERATIONS
from ...trace.intersect import search_bytes
from ...trace.photons import Photons, element_photons, mesh_photons
from ..base import Method, channels_last
from .distance_map import (
    build_distance_map,
    light_cube_map,
    project_light_cube_map,
    trace_distance_map,
)

RECONSTRUCTIONS = ("exact", "gouraud")
VISIBILITIES = ("exact", "distance_map")
MAX_AUTO_WINDOW = 32
MAX_TIERS = 3  # windows of an "auto" render (`_size_tiers`)
# numbers per receiver pixel and channel besides the photons: the image being summed,
# one batch's image, its scatter and the result
_IMAGE_FLOATS = 4
# the height-field caustic elements (one photon grid over the aperture)
_ELEMENTS = (LensScene, MirrorScene)


class TrianglesResult(eqx.Module):
    """Output of `caustic_triangles`.

    - `image`: irradiance, ``(rows, cols)`` or ``(rows, cols, channels)``.
    - `missed_flux_fraction`: per channel ``(channels,)``: the fraction of the flux of
      the valid triangles that is not in the image (it lands off the screen, or beyond a
      triangle's `window`).
    - `photons`: the photon hit location image used; ``None`` when the grid was traced
      in bands (it never existed whole: see `CausticTriangles`' `memory_limit`).
    - `stats`: dict of Python ints: ``bands`` (row bands of the photon grid, traced one
      after the other), ``batches`` (rasteriser calls, all bands), ``triangle_batch``
      (triangles per call, in the widest tier), ``tiers`` (``(window, capacity,
      batch)`` per tier of each band, widest first: see `CausticTriangles`' `window`),
      ``ray_batch`` (mesh scenes: rays per triangle search),
      ``devices``, ``peak_buffer_photons`` (photons of one band) and
      ``peak_buffer_bytes`` (one band's photon and triangle buffers plus the largest
      rasteriser batch, by `band_bytes` and `triangle_bytes`).
    """

    image: Array
    missed_flux_fraction: Array
    photons: Photons | None
    stats: dict = eqx.field(default_factory=dict)


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


def _extent_histogram(photons: Photons, extent, shape) -> tuple[Array, Array]:
    """By `_spans` (bins ``0 .. MAX_AUTO_WINDOW + 1``): the valid flux of the caustic
    triangles of `photons`, channels pooled ``(bins,)``, and the number of valid
    triangles per channel ``(C, bins)``."""
    tri = _screen_triangles(photons, extent, shape)
    keep = tri.valid & (tri.flux > 0)
    bins = _spans(tri).astype(jnp.int32)
    flux = jnp.where(keep, tri.flux, 0.0)
    by_flux = jnp.zeros(MAX_AUTO_WINDOW + 2, flux.dtype).at[bins.reshape(-1)].add(flux.reshape(-1))
    channel = jnp.broadcast_to(jnp.arange(bins.shape[0])[:, None], bins.shape)
    by_count = jnp.zeros((bins.shape[0], MAX_AUTO_WINDOW + 2), jnp.int32)
    by_count = by_count.at[channel, bins].add(tri.valid.astype(jnp.int32))
    return by_flux, by_count


_extent_histogram_jit = eqx.filter_jit(_extent_histogram)


def _window_from_histogram(histogram, flux_fraction: float) -> int:
    """`triangle_window` from `_extent_histogram`'s flux (summed over bands)."""
    histogram = np.asarray(histogram, np.float64)
    total = histogram.sum()
    if not total > 0:
        return 1
    cumulative = np.cumsum(histogram) / total
    needed = min(int(np.searchsorted(cumulative, flux_fraction)), len(histogram) - 1)
    return int(min(MAX_AUTO_WINDOW, max(1, needed)))


def _power_of_two(n: int) -> int:
    """The least power of two >= `n` (>= 1): tier capacities (and so compilations) from a
    few sizes."""
    return 1 << max(0, int(n) - 1).bit_length()


def _tier_penalty(shape, dtype=jnp.float64) -> int:
    """The fixed work of a tier of `sum_in_tiers` in `triangle_bytes`' units: its image
    (made, added to, summed: about four numbers a pixel) and a little more."""
    return (4 * shape[0] * shape[1] + 4096) * jnp.dtype(dtype).itemsize


def _plain_tier(window: int, batch: int):
    """Every triangle in its place, with one `window` (`sum_in_tiers`)."""
    return ((window, None, batch),)


def _size_tiers(counts, window: int, triangles: int, cost, batch, penalty):
    """The cheapest tiers for `sum_in_tiers`: up to `MAX_TIERS` windows, the widest
    `window`, the others powers of two (few distinct tiers: each new one compiles).

    `counts` ``(..., bins)``: `_extent_histogram`'s numbers of triangles by span, for
    each band and channel; a tier's capacity is the most it holds in any of them,
    rounded up to a power of two (at most `triangles`, the triangles of a band);
    `cost(w)`: the work of one triangle in a ``w x w`` window (`triangle_bytes`);
    `batch(w, n)`: the batch of a tier of `n` triangles; `penalty`: the fixed work of a
    tier (its image), in `cost`'s units. **Returns:** ``((window, capacity, batch),
    ...)``, or one tier of capacity ``None`` (every triangle, in place).

    A tier of window ``w`` followed by one of window ``v < w`` holds the triangles wider
    than ``v`` and at most ``w`` wide, so the cost of a chain of windows is a sum over
    its links, and the cheapest chain is found link by link (dynamic programming).
    """
    counts = np.asarray(counts).reshape(-1, np.shape(counts)[-1])
    at_least = np.cumsum(counts[:, ::-1], axis=1)[:, ::-1]  # [:, s]: spans >= s
    at_least = np.concatenate([at_least, np.zeros_like(at_least[:, :1])], axis=1)

    def wider(v):  # per band and channel: triangles wider than v (v = 0: all of them)
        return at_least[:, 0] if v == 0 else at_least[:, v + 1]

    def capacity(w, v):  # the tier of window w followed by one of window v
        held = wider(v) - (0 if w == window else wider(w))
        return min(triangles, _power_of_two(max(1, int(held.max()))))

    narrower = [1 << k for k in range(6) if 1 << k < window]

    @functools.cache
    def cheapest(w: int, tiers: int) -> tuple[float, tuple]:
        """The cheapest tiers from window `w` on."""
        best = (np.inf, ())
        for v in [0] + ([v for v in narrower if v < w] if tiers > 1 else []):
            rest, chain = cheapest(v, tiers - 1) if v else (0.0, ())
            n = capacity(w, v)
            total = n * cost(w) + penalty + rest
            if total < best[0]:
                best = (total, ((w, n), *chain))
        return best

    best = cheapest(window, MAX_TIERS)[1]
    if len(best) == 1 and best[0][1] == triangles:  # one tier of them all: in place
        return _plain_tier(window, batch(window, triangles))
    return tuple((w, n, batch(w, n)) for w, n in best)


def _check_photons_receiver(photons, receiver) -> None:
    if not isinstance(photons, Photons):
        raise ValueError(f"`photons` must be a Photons image, got {type(photons).__name__}")
    if not isinstance(receiver, PlaneReceiver):
        raise ValueError(f"`receiver` must be a PlaneReceiver, got {type(receiver).__name__}")


def _check_window(window, receiver: PlaneReceiver) -> int:
    """An int window: at least 1, at most one past the receiver's larger side (a larger
    block reaches no more pixels; `window=100000` asked for terabytes)."""
    return check_int(window, "window", 1, max(receiver.shape) + 1)


def triangle_window(photons: Photons, receiver: PlaneReceiver, flux_fraction: float = 0.999) -> int:
    """The smallest triangle window (pixels) that holds whole the triangles carrying
    `flux_fraction` of the valid flux, capped at `MAX_AUTO_WINDOW` and at one past the
    receiver's larger side (a wider window reaches no more pixels, and `triangles_image`
    takes no wider one: an 8 x 8 design under 85-degree light asked for 16).

    Near silhouettes and folds a few triangles stretch over huge areas (neighbouring
    photons that part ways); sizing the window for them would cost ``window^2`` per
    triangle for all triangles. Their flux beyond the window is reported as missed.
    Needs concrete values (call it outside `jit`). `flux_fraction` in ``(0, 1]``.
    """
    _check_photons_receiver(photons, receiver)
    flux_fraction = check_number(flux_fraction, "flux_fraction", low=0.0, high=1.0, low_open=True)
    by_flux, _ = _extent_histogram_jit(photons, receiver.extent, receiver.shape)
    return min(_window_from_histogram(by_flux, flux_fraction), max(receiver.shape) + 1)


def triangles_image(
    photons: Photons,
    receiver: PlaneReceiver,
    *,
    reconstruction: Literal["exact", "gouraud"] = "exact",
    window: int | Literal["auto"] = "auto",
    supersample: int = 2,
    batch_size: int = 16384,
) -> tuple[Array, Array]:
    """Reconstruct the irradiance on `receiver` from a photon hit location image by
    caustic triangles (the photons' terminal positions are taken on the plane ``z = 0``).

    **Returns:** ``(images, missed_flux_fraction)`` of shapes ``(channels, rows, cols)``
    and ``(channels,)``. See `CausticTriangles` for the knobs (`window`: ``"auto"`` or
    an int up to one past the receiver's larger side; `batch_size`: triangles per
    rasteriser call).
    """
    _check_photons_receiver(photons, receiver)
    check_choice(reconstruction, "reconstruction", RECONSTRUCTIONS)
    supersample = check_int(supersample, "supersample", 1)
    batch_size = check_int(batch_size, "batch_size", 1)
    shape, extent = receiver.shape, receiver.extent
    if not _is_auto(window):
        tiers = _plain_tier(_check_window(window, receiver), batch_size)
    elif isinstance(photons.position, jax.core.Tracer):
        raise ValueError(
            "window='auto' needs concrete scene values: fix it first with "
            "`method = jc.method_for(scene)` and transform `render(scene, method)`, or pass "
            "an int"
        )
    else:
        by_flux, by_count = _extent_histogram_jit(photons, extent, shape)
        rows, cols = photons.grid_shape
        tiers = _size_tiers(
            by_count,
            _window_from_histogram(by_flux, 0.999),
            2 * (rows - 1) * (cols - 1),
            lambda w: triangle_bytes(w, reconstruction, supersample),
            lambda w, n: min(n, batch_size),
            _tier_penalty(shape),
        )
    images, missed, _ = _triangles_image(photons, extent, shape, reconstruction, tiers, supersample)
    return images, missed


def splat_photons(photons: Photons, receiver: PlaneReceiver, sigma, window: int | None = None):
    """Reconstruct the irradiance on `receiver` by Gaussian photon splatting.

    Each photon carries its share of the grid's flux (`Photons.flux`) and spreads it with
    a normalised Gaussian of standard deviation `sigma` *pixels* (the splat radius: too
    small leaves dots, too large blurs): a number from 1e-3 to the receiver's larger
    side (a traced `sigma` needs `window`). `window`: ``None`` (``2 ceil(3 sigma) + 1``)
    or an int up to ``2 max(rows, cols) + 1``. **Returns:** ``(channels, rows, cols)``.
    """
    _check_photons_receiver(photons, receiver)
    if window is not None:
        window = check_int(window, "window", 1, 2 * max(receiver.shape) + 1)
    if not isinstance(sigma, jax.core.Tracer):
        check_number(sigma, "sigma", low=1e-3, high=max(receiver.shape))
    elif window is None:
        raise ValueError("`sigma` is traced: pass `window` (an int)")
    shape, extent = receiver.shape, receiver.extent
    pixel_area = (extent[1] - extent[0]) / shape[1] * (extent[3] - extent[2]) / shape[0]
    points = pixel_coordinates(photons.position[..., :2], extent, shape)
    flux = photons.flux()
    channels = [
        splat_gaussian(
            points[c].reshape(-1, 2),
            flux[c].reshape(-1),
            photons.valid[c].reshape(-1),
            shape,
            sigma,
            window,
        )
        for c in range(points.shape[0])
    ]
    return jnp.stack(channels) / pixel_area


@eqx.filter_jit
def _trace_photons(scene, grid: tuple[int, int], hit_iterations: int, batch_size: int):
    if isinstance(scene, _ELEMENTS):
        return element_photons(scene, grid, hit_iterations)
    return mesh_photons(scene, grid, batch_size)


def trace_photons(
    scene,
    grid: tuple[int, int],
    hit_iterations: int = 3,
    batch_size: int = 4096,
    *,
    memory_limit: int | None = None,
):
    """The photon hit location image of a `LensScene` or `MeshScene` (jit-compiled).

    `grid`: ``n`` or ``(rows, cols)`` photons (as `CausticTriangles`' `photons`);
    `hit_iterations`: lens scenes only (Newton steps, ``[0, 100]``); `batch_size`: mesh
    scenes only (rays per batch of the triangle search). The whole grid is traced at
    once: its photons (`band_bytes`) must fit in `memory_limit` (default 1 GiB).
    """
    _check_scene(scene)
    grid = _check_grid(grid, "grid")
    hit_iterations = check_int(hit_iterations, "hit_iterations", 0, MAX_HIT_ITERATIONS)
    batch_size = check_int(batch_size, "batch_size", 1)
    memory_limit = check_memory_limit(memory_limit)
    if isinstance(scene, _ELEMENTS):
        _refuse_unused("batch_size", batch_size, 4096, "mesh scenes")
    else:
        _refuse_unused("hit_iterations", hit_iterations, 3, "lens scenes")
    channels, dtype, faces = _sizes(scene)
    check_photon_work(grid[0] * grid[1], 1, "grid")
    check_fits(
        band_bytes(grid[0] * grid[1], channels, dtype, faces, batch_size if faces else 0),
        memory_limit,
        f"the {grid[0]} x {grid[1]} photon grid, traced at once",
        "pass a smaller `grid`" + (" or `batch_size`" if faces else ""),
    )
    return _trace_photons(scene, grid, hit_iterations, batch_size)


def _check_scene(scene) -> None:
    if not isinstance(scene, (*_ELEMENTS, MeshScene)):
        raise ValueError(
            f"`scene` must be a LensScene, a MirrorScene or a MeshScene, got {type(scene).__name__}"
        )


def _sizes(scene) -> tuple[int, np.dtype, int]:
    """Channels, dtype and (mesh scenes) generator faces of a lens or mesh scene."""
    if isinstance(scene, _ELEMENTS):
        return len(getattr(scene, "iors", (1,))), np.dtype(scene.surface.heights.dtype), 0
    faces = int(scene.generator.faces.shape[0])
    return len(scene.iors), np.dtype(scene.generator.vertices.dtype), faces


def _is_auto(value) -> bool:
    return isinstance(value, str) and value == "auto"


def _refuse_unused(name: str, value, default, applies: str) -> None:
    """A knob set (to anything but its default) where it does not apply: a `ValueError`
    naming it, never silently ignored."""
    if value is not default and value != default:
        raise ValueError(f"`{name}` applies to {applies} only; got {value!r} (leave it out)")


def _check_grid(photons, name: str = "photons") -> tuple[int, int]:
    """``n`` or ``(rows, cols)``, ints >= 2 (no bools or floats), as ``(rows, cols)``."""
    if isinstance(photons, np.ndarray) and photons.ndim == 1:
        photons = tuple(photons)
    if not isinstance(photons, (tuple, list)):
        if isinstance(photons, (int, np.integer)) and not isinstance(photons, (bool, np.bool_)):
            photons = (photons, photons)
        else:
            raise ValueError(f"`{name}` must be an int or (rows, cols), got {photons!r}")
    if len(photons) != 2:
        raise ValueError(f"`{name}` must be an int or (rows, cols), got {photons!r}")
    return check_int(photons[0], name, 2), check_int(photons[1], name, 2)


class CubeMapOptions(eqx.Module):
    """Knobs of the paper's visibility pipeline (``visibility="distance_map"``).

    - `resolution`: texels per cube-face edge of the distance and light cube maps.
    - `layers`: surfaces kept per texel of the layered distance map.
    - `linear_steps`, `secant_iterations`: the ray search in the distance map.
    - `shadow_test`: use the light cube map's distances as a shadow map in the camera
      pass (``False``: naive projection, which leaks light behind occluders).
    - `tolerance`: relative distance tolerance of the shadow test.
    - `window`: the rasteriser window on the cube faces, texels; ``None`` takes the
      smallest that holds every triangle (needs concrete values, outside `jit`).
    """

    resolution: int = eqx.field(static=True, default=128)
    layers: int = eqx.field(static=True, default=2)
    linear_steps: int = eqx.field(static=True, default=32)
    secant_iterations: int = eqx.field(static=True, default=4)
    shadow_test: bool = eqx.field(static=True, default=True)
    tolerance: float = eqx.field(static=True, default=0.02)
    window: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        for name, low in (
            ("resolution", 2),
            ("layers", 1),
            ("linear_steps", 1),
            ("secant_iterations", 0),
        ):
            check_int(getattr(self, name), name, low)
        check_bool(self.shadow_test, "shadow_test")
        check_number(self.tolerance, "tolerance", low=0.0)
        if self.window is not None:
            check_int(self.window, "window", 1)


def _cube_centre(scene: MeshScene) -> Array:
    verts = jax.lax.stop_gradient(scene.generator.vertices)
    return 0.5 * (verts.min(axis=0) + verts.max(axis=0))


@eqx.filter_jit
def _distance_map_photons(scene: MeshScene, dmap, grid, batch_size, options: CubeMapOptions):

    def terminal(origins, directions):
        hit = trace_distance_map(
            dmap,
            origins,
            directions,
            linear_steps=options.linear_steps,
            secant_iterations=options.secant_iterations,
        )
        return hit.point, hit.found

    return mesh_photons(scene, grid, batch_size, terminal)


@eqx.filter_jit
def _cube_map_triangles(photons: Photons):
    """Caustic triangles in space: corners ``(C, T, 3, 3)``, vertex irradiance on the
    surface they landed on ``(C, T, 3)``, validity ``(C, T)``."""
    corners = grid_triangles(photons.position)  # (C, T, 3, 3)
    valid = grid_triangles(photons.valid).all(axis=-1)
    flux = 0.5 * photons.cell_area * grid_triangles(photons.density).mean(axis=-1)
    edge1 = corners[..., 1, :] - corners[..., 0, :]
    edge2 = corners[..., 2, :] - corners[..., 0, :]
    area = 0.5 * jnp.linalg.norm(jnp.cross(edge1, edge2), axis=-1)  # on the landing surface
    irradiance = _vertex_irradiance(flux, area, valid, photons.grid_shape)
    return corners, irradiance, valid


def _cube_map_image(photons: Photons, centre, receiver: PlaneReceiver, options: CubeMapOptions):

    corners, irradiance, valid = _cube_map_triangles(photons)
    rows, cols = receiver.shape
    x0, x1, y0, y1 = receiver.extent
    xs = x0 + (jnp.arange(cols) + 0.5) * (x1 - x0) / cols
    ys = y0 + (jnp.arange(rows) + 0.5) * (y1 - y0) / rows
    gx, gy = jnp.meshgrid(xs, ys)
    pixels = jnp.stack([gx, gy, jnp.zeros_like(gx)], axis=-1).reshape(-1, 3)
    images = []
    for c in range(corners.shape[0]):
        lcm = light_cube_map(
            centre, corners[c], irradiance[c], valid[c], options.resolution, options.window
        )
        lit = project_light_cube_map(
            lcm, centre, pixels, shadow_test=options.shadow_test, tolerance=options.tolerance
        )
        images.append(lit.reshape(rows, cols))
    return jnp.stack(images)


def _distance_map_caustics(scene: MeshScene, grid, batch_size, options: CubeMapOptions):

    if not scene.occluders:
        # the screen alone: one layer holds it, and every caustic lands on it (no
        # occlusion work is traced)
        options = dataclasses.replace(options, layers=1, shadow_test=False)
    centre = _cube_centre(scene)
    dmap = build_distance_map(centre, scene.occluders, options.resolution, options.layers)
    ph = _distance_map_photons(scene, dmap, grid, batch_size, options)
    images = _cube_map_image(ph, centre, scene.receiver, options)
    # flux bookkeeping on the screen is not defined here (caustics may land on occluders)
    missed = jnp.full(images.shape[:1], jnp.nan, images.dtype)
    return ph, images, missed


# memory model of one band and one rasteriser batch, in numbers of the scene's dtype
# (about 1.2 to 1.5 times XLA's compiled temporaries on CPU; tests/test_memory.py checks
# the bound)
_COUNT_ROWS = 256  # bands counted apart for the tiers (`_band_census`)
_BAND_FLOATS = 64  # per photon and channel: photon, its two triangles, tracing temporaries


def triangle_bytes(
    window: int, reconstruction: str = "exact", supersample: int = 2, dtype=jnp.float64
) -> int:
    """Memory one triangle takes in a rasteriser batch, bytes: for `rasterize_exact`
    three numbers per edge term ``3 x window x (window + 1)`` (its overlap areas and the
    scattered block), for `rasterize_gouraud` two per sample ``(window S)^2``, plus 64
    numbers (vertices, values, indices)."""
    size = jnp.dtype(dtype).itemsize
    w = int(window)
    if reconstruction == "exact":
        return size * (9 * w * (w + 1) + 64)
    side = w * int(supersample)
    return size * (2 * side * side + 64)


def band_bytes(photons: int, channels: int, dtype=jnp.float64, faces: int = 0, ray_batch: int = 0):
    """Memory of a band of `photons` photons (per channel: the photon, its two caustic
    triangles and the tracing temporaries, `_BAND_FLOATS` numbers) and, for a mesh scene
    of `faces` generator faces, of one batch of `ray_batch` rays in the triangle search
    (`search_bytes`), bytes."""
    size = jnp.dtype(dtype).itemsize
    return size * photons * channels * _BAND_FLOATS + search_bytes(ray_batch, faces, dtype)


class _BandConfig(eqx.Module):
    """Static layout of a banded render: `rows` photon rows per band (`rows - 1`
    triangle rows drawn), `halo` extra photon rows on each side (Gouraud: the vertex
    irradiance of the band's edge rows needs their other triangles), `bands` bands."""

    grid: tuple[int, int] = eqx.field(static=True)
    rows: int = eqx.field(static=True)
    halo: int = eqx.field(static=True)
    bands: int = eqx.field(static=True)
    hit_iterations: int = eqx.field(static=True)
    ray_batch: int = eqx.field(static=True)

    def photons(self, scene, k, halo: int):
        """The photons of band `k` (photon rows ``k (rows - 1) - halo`` on, ``rows + 2
        halo`` of them)."""
        band = (k * (self.rows - 1) - halo, self.rows + 2 * halo)
        if isinstance(scene, _ELEMENTS):
            return element_photons(scene, self.grid, self.hit_iterations, band)
        return mesh_photons(scene, self.grid, self.ray_batch, band=band)

    def drawn(self, halo: int):
        """Which of a band's triangles are its own (not the halo's): ``(T,)``."""
        per_row = 2 * (self.grid[1] - 1)
        row = jnp.arange((self.rows + 2 * halo - 1) * per_row) // per_row
        return (row >= halo) & (row < halo + self.rows - 1)


@eqx.filter_jit
def _band_census(scene, cfg: _BandConfig, mesh):
    """Over all bands: the extent histograms (`_extent_histogram`: the flux summed, the
    counts by band ``(bands, C, bins)``, at most `_COUNT_ROWS` rows) and the valid screen
    area of the triangles per channel ``(C,)``."""

    def census(scene, k):
        ph = cfg.photons(scene, k, 0)
        extent, shape = scene.receiver.extent, scene.receiver.shape
        tri = _screen_triangles(ph, extent, shape)
        area = jnp.abs(signed_area(tri.pixels)) * _pixel_area(extent, shape)
        area = jnp.where(tri.valid, area, 0.0).sum(axis=-1)
        by_flux, by_count = _extent_histogram(ph, extent, shape)
        # each band's counts in a row of their own (the tiers need the most of any band);
        # past _COUNT_ROWS bands a row adds up several: more than any one band, never less
        rows = min(cfg.bands, _COUNT_ROWS)
        stacked = jnp.zeros((rows,) + by_count.shape, by_count.dtype)
        return by_flux, stacked.at[k % rows].add(by_count), area

    return sum_over_batches(census, scene, cfg.bands, mesh=mesh)


@eqx.filter_jit
def _banded_image(scene, cfg: _BandConfig, mean_area, reconstruction, tiers, supersample, mesh):
    """The images and missed-flux fractions of a grid traced and drawn band by band
    (`sum_over_batches`: a scan, or split across the `mesh`'s devices)."""
    extent, shape = scene.receiver.extent, scene.receiver.shape

    def band(operands, k):
        scene, mean_area = operands
        ph = cfg.photons(scene, k, cfg.halo)
        return _band_image(
            ph,
            scene.receiver.extent,
            shape,
            reconstruction,
            tiers,
            supersample,
            draw=cfg.drawn(cfg.halo),
            mean_area=mean_area,
        )

    images, total, limited = sum_over_batches(band, (scene, mean_area), cfg.bands, mesh=mesh)
    return _finish(images, total, limited, extent, shape, reconstruction)


class CausticTriangles(Method):
    """Umenhoffer et al.'s caustic triangles for lens slabs and meshes (refractors,
    mirrors, occluders): ``CausticTriangles(photons=...)(scene)`` or ``render(scene,
    CausticTriangles(...))``.

    **Arguments:**

    - `photons`: the photon grid, ``n`` (``n x n``) or ``(rows, cols)`` photons
      (vertices of the grid; default 257); ``2 (rows - 1) (cols - 1)`` triangles.
    - `reconstruction`: ``"exact"`` (constant irradiance per triangle, exact
      triangle/pixel overlap areas, flux conserved to rounding) or ``"gouraud"`` (the
      paper's vertex irradiance, each vertex's power over a third of its adjacent
      triangles' area, interpolated and point-sampled); default ``"exact"``.
    - `window`: each triangle touches a ``window x window`` block of pixels; ``"auto"``
      (the default) takes the smallest window that holds whole the triangles carrying
      99.9% of the flux, capped at `MAX_AUTO_WINDOW` = 32 (`triangle_window`; needs
      concrete scene values: under `jax.jit` or `jax.vmap` fix it first with ``method =
      method_for(scene)``, then transform ``render(scene, method)``, or pass an int: one
      window for all triangles). Flux beyond it is reported as missed. With ``"auto"``
      the triangles are also drawn in *tiers* (`jaxcaustics.reconstruct.raster.sum_in_tiers`):
      by the pixels they span, the few wide ones with that window, the many narrow ones
      with up to `MAX_TIERS` - 1 = 2 narrower windows (powers of two), and invalid ones
      not at all; the tiers are the cheapest by `triangle_bytes` (`stats["tiers"]`), their
      capacities powers of two, so that a new scene seldom compiles anew. Same image, to
      rounding: on the 320-face blob of the accuracy report (97^2 photons, 64^2 pixels,
      window 32) the rasterisation took 6 ms against 150 ms with one window.
    - `supersample`: ``"gouraud"`` only: ``S x S`` point samples per pixel (default 2).
    - `hit_iterations`: lens scenes: Newton steps for the top-surface hit (default 3).
    - `memory_limit`: bytes for the photon and triangle buffers (default 1 GiB). Half
      goes to photons: when the grid's photons (`band_bytes`) exceed it, the grid is
      traced and drawn in *bands* of photon rows, one after the other (a loop: the
      compiled graph does not grow with the grid), consecutive bands sharing one row
      so that every triangle is drawn exactly once (Gouraud bands also trace one halo
      row on each side for the vertex irradiance); the whole grid then never exists,
      `TrianglesResult.photons` is ``None``, and ``window="auto"`` or Gouraud costs a
      first pass over the bands (the window's histogram, the mean triangle area). A
      quarter goes to each rasteriser batch (`triangle_bytes` per triangle) and, for
      mesh scenes, a quarter to the rays of one triangle-search batch. Same image
      (to rounding) whatever the limit.
    - `batch_size`: mesh scenes: rays per batch in the triangle search (memory
      ``batch_size x faces``); default from `memory_limit`, at most 4096.
    - `triangle_batch`: triangles rasterised at a time; default from `memory_limit`.
    - `devices`: ``None`` (the default): the default device only. An int ``n`` (the first
      ``n`` of `jax.devices()`) or a list of devices: the bands are split across them
      (`jax.shard_map` over `jaxcaustics.devices.device_mesh(devices)`, at least one
      band per device) and the partial images summed (``psum``); same image to
      rounding.
    - `visibility`: mesh scenes: ``"exact"`` (the default; rays leaving the generator are
      intersected exactly with the occluders and the screen; triangles are drawn on the
      screen) or ``"distance_map"`` (the paper's pipeline: rays are traced in a layered
      distance map of the screen and the occluders around the generator, by a linear
      then a secant search; caustic triangles are drawn with Gouraud interpolation onto
      a light cube map, and the camera pass projects it onto the screen with a
      shadow-map distance test, so caustics landing on an occluder do not leak onto the
      screen behind it). Its knobs: `cube_map` (`jaxcaustics.internal.CubeMapOptions`;
      ``None``, the default: its defaults); `reconstruction`, `window` and `supersample`
      do not apply, and the missed-flux fraction is NaN (light may land on occluders).
      It traces the whole grid at once: a grid over half the `memory_limit` raises a
      `ValueError`, and `devices` must be ``None``.

    Checks, before anything is compiled: ints are ints (no bools or floats), `window` at
    most one past the receiver's larger side, `hit_iterations` in ``[0, 100]``; a knob
    set where it does not apply (`hit_iterations` on a mesh, `batch_size` on a lens,
    `supersample` with ``"exact"``, `cube_map` without ``"distance_map"``, and
    `reconstruction`, `window`, `supersample`, `triangle_batch` with it) is refused by
    name. Memory and work (`memory_limit`): the receiver's images, the smallest band
    (2 photon rows, with a halo for Gouraud, and one ray batch) in half the limit and
    one triangle (`triangle_bytes` at the window; for ``"auto"``, once the window is
    known, before the rasteriser is compiled) in a quarter must fit, else a
    `ValueError` with the estimate and the knob to change. An absurd photon count is
    refused, not run for days: at most 2^31 photons (a 46340^2 grid,
    `jaxcaustics._checks.MAX_PHOTONS`) in at most 2^20 batches (bands times rasteriser
    batches, `MAX_BATCHES`: more means a `memory_limit` far too small for `photons`).
    An explicit `triangle_batch` is taken as given (at most a band's triangles).
    """

    photons: int | tuple[int, int] = 257
    reconstruction: Literal["exact", "gouraud"] = "exact"
    window: int | Literal["auto"] = "auto"
    supersample: int = 2
    hit_iterations: int = 3
    memory_limit: int | None = None
    batch_size: int | None = None
    triangle_batch: int | None = None
    devices: object = None
    visibility: Literal["exact", "distance_map"] = "exact"
    cube_map: CubeMapOptions | None = None

    name: ClassVar[str] = "triangles"
    resolution_knobs: ClassVar[tuple[str, ...]] = ("photons",)
    estimate_is_reliable: ClassVar[bool] = True
    scene_types: ClassVar[tuple[type, ...]] = (LensScene, MirrorScene, MeshScene)

    def needs_sizing(self) -> bool:
        return _is_auto(self.window) and self.visibility == "exact"

    def sized_for(self, scenes: Sequence) -> CausticTriangles:
        """An ``"auto"`` window (exact visibility) becomes the largest `triangle_window`
        of `scenes`' photons."""
        if not self.needs_sizing():
            return self
        grid = _check_grid(self.photons)
        extra = {
            k: v
            for k, v in (("batch_size", self.batch_size), ("memory_limit", self.memory_limit))
            if v is not None
        }
        window = max(
            triangle_window(trace_photons(s, grid, self.hit_iterations, **extra), s.receiver)
            for s in scenes
        )
        return dataclasses.replace(self, window=window)

    def refined(self) -> CausticTriangles:
        """Twice the photon grid's cells along each side (``n`` vertices: ``2n - 1``)."""
        rows, cols = _check_grid(self.photons)
        return dataclasses.replace(self, photons=(2 * rows - 1, 2 * cols - 1))

    def coarsened(self) -> CausticTriangles | None:
        rows, cols = _check_grid(self.photons)
        if rows % 2 == 0 or cols % 2 == 0 or min(rows, cols) < 5:
            return None
        return dataclasses.replace(self, photons=((rows + 1) // 2, (cols + 1) // 2))

    def trace(self, scene) -> TrianglesResult:
        return caustic_triangles(scene, **self.knobs())


@checks_scene_values
def caustic_triangles(
    scene: LensScene | MirrorScene | MeshScene,
    *,
    photons: int | tuple[int, int] = CausticTriangles.photons,
    reconstruction: Literal["exact", "gouraud"] = CausticTriangles.reconstruction,
    window: int | Literal["auto"] = CausticTriangles.window,
    supersample: int = CausticTriangles.supersample,
    hit_iterations: int = CausticTriangles.hit_iterations,
    memory_limit: int | None = CausticTriangles.memory_limit,
    batch_size: int | None = CausticTriangles.batch_size,
    triangle_batch: int | None = CausticTriangles.triangle_batch,
    devices=CausticTriangles.devices,
    visibility: Literal["exact", "distance_map"] = CausticTriangles.visibility,
    cube_map: CubeMapOptions | None = CausticTriangles.cube_map,
) -> TrianglesResult:
    """Caustics of a lens or mesh scene by caustic triangles.

    The function form of `CausticTriangles`: `scene` (a `LensScene`, a `MirrorScene` or a
    `MeshScene`) and the same knobs as keywords, described there.

    **Returns:** a `TrianglesResult` (image, missed-flux fraction, photons, stats).
    Differentiable with respect to the scene's arrays (the lens heights, the mesh
    vertices, the light), banded and sharded too.
    """
    _check_scene(scene)
    grid = _check_grid(photons)
    check_choice(reconstruction, "reconstruction", RECONSTRUCTIONS)
    check_choice(visibility, "visibility", VISIBILITIES)
    hit_iterations = check_int(hit_iterations, "hit_iterations", 0, MAX_HIT_ITERATIONS)
    supersample = check_int(supersample, "supersample", 1)
    memory_limit = check_memory_limit(memory_limit)
    if not _is_auto(window):
        window = _check_window(window, scene.receiver)
    if batch_size is not None:
        batch_size = check_int(batch_size, "batch_size", 1)
    if triangle_batch is not None:
        triangle_batch = check_int(triangle_batch, "triangle_batch", 1)
    if cube_map is not None and not isinstance(cube_map, CubeMapOptions):
        raise ValueError(f"`cube_map` must be a CubeMapOptions, got {type(cube_map).__name__}")
    # knobs where they do not apply: refused by name unless at their defaults
    if isinstance(scene, _ELEMENTS):
        _refuse_unused("batch_size", batch_size, None, "mesh scenes")
    else:
        _refuse_unused("hit_iterations", hit_iterations, 3, "lens scenes")
    if visibility == "distance_map":
        for name, value, default in (
            ("reconstruction", reconstruction, "exact"),
            ("window", window, "auto"),
            ("supersample", supersample, 2),
            ("triangle_batch", triangle_batch, None),
        ):
            _refuse_unused(name, value, default, "visibility='exact'")
    else:
        _refuse_unused("cube_map", cube_map, None, "visibility='distance_map'")
        if reconstruction == "exact":
            _refuse_unused("supersample", supersample, 2, "reconstruction='gouraud'")
    channels, dtype, faces = _sizes(scene)
    rows_px, cols_px = scene.receiver.shape
    check_fits(
        _IMAGE_FLOATS * channels * rows_px * cols_px * dtype.itemsize,
        memory_limit,
        f"the {rows_px} x {cols_px} receiver's images ({channels} channel(s))",
        "use fewer receiver pixels",
    )
    if batch_size is None:
        fixed = search_bytes(0, faces, dtype) if faces else 0
        per_ray = search_bytes(1, faces, dtype) - fixed if faces else 1
        batch_size = max(1, min(4096, (memory_limit // 4 - fixed) // per_ray))
    ray_batch = batch_size if faces else 0
    mesh = None if devices is None else device_mesh(devices)
    n_devices = 1 if mesh is None else mesh.size

    # photon rows per band: half the limit, less one ray-search batch
    row_bytes = band_bytes(grid[1], channels, dtype)
    budget = memory_limit // 2 - band_bytes(0, 0, dtype, faces, ray_batch)
    halo = 1 if reconstruction == "gouraud" else 0
    check_photon_work(grid[0] * grid[1], 1, "photons")
    check_fits(
        band_bytes((2 + 2 * halo) * grid[1], channels, dtype, faces, ray_batch),
        memory_limit,
        f"the smallest band of the photon grid ({2 + 2 * halo} rows of {grid[1]} photons"
        + (f", and a ray batch of {ray_batch} rays over {faces} faces)" if faces else ")"),
        "pass fewer `photons` per row" + (" or a smaller `batch_size`" if faces else ""),
        share=2,
    )
    rows = max(2, budget // row_bytes - 2 * halo)
    if mesh is not None:  # at least one band per device
        rows = min(rows, -(-(grid[0] - 1) // n_devices) + 1)
    banded = rows < grid[0] or mesh is not None
    if not banded:
        rows, halo = grid[0], 0
    bands = -(-(grid[0] - 1) // (rows - 1))
    band_photons = (rows + 2 * halo) * grid[1]
    check_photon_work(grid[0] * grid[1], bands, "photons")

    def check_triangle(window: int) -> None:
        check_fits(
            triangle_bytes(window, reconstruction, supersample, dtype),
            memory_limit,
            f"one caustic triangle in a {window} x {window} pixel window"
            + (f" ({supersample}^2 samples per pixel)" if reconstruction == "gouraud" else ""),
            "pass a smaller `window`"
            + (" or `supersample`" if reconstruction == "gouraud" else ""),
            share=4,
        )

    check_triangle(1 if window == "auto" else window)  # "auto": at least one pixel

    if visibility == "distance_map":
        if not isinstance(scene, MeshScene):
            raise ValueError("`visibility='distance_map'` needs a MeshScene")
        if banded:
            raise ValueError(
                f"`visibility='distance_map'` traces the whole grid at once: {grid} photons "
                f"need {band_bytes(grid[0] * grid[1], channels, dtype)} bytes, over half the "
                f"`memory_limit` {memory_limit}, or `devices` was given (pass fewer "
                "`photons`, a larger `memory_limit`, devices=None)"
            )
        ph, images, missed = _distance_map_caustics(
            scene, grid, batch_size, cube_map or CubeMapOptions()
        )
        stats = {
            "bands": 1,
            "batches": 1,
            "triangle_batch": 2 * (grid[0] - 1) * (grid[1] - 1),
            "ray_batch": batch_size,
            "devices": 1,
            "peak_buffer_photons": grid[0] * grid[1],
            "peak_buffer_bytes": band_bytes(grid[0] * grid[1], channels, dtype, faces, batch_size),
        }
        return TrianglesResult(channels_last(scene, images), missed, ph, stats)

    receiver = scene.receiver
    cfg = _BandConfig(grid, rows, halo, bands, hit_iterations, ray_batch)
    traced = any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(scene))
    if window == "auto" and traced:
        raise ValueError(
            "window='auto' needs concrete scene values: fix it first with "
            "`method = jc.method_for(scene)` and transform `render(scene, method)`, or pass "
            "an int"
        )
    ph, mean_area, by_count = None, None, None
    if not banded:
        ph = _trace_photons(scene, grid, hit_iterations, batch_size)
        if window == "auto":
            by_flux, by_count = _extent_histogram_jit(ph, receiver.extent, receiver.shape)
    elif window == "auto" or reconstruction == "gouraud":
        by_flux, by_count, area = _band_census(scene, cfg, mesh)
        mean_area = area / (2 * (grid[0] - 1) * (grid[1] - 1))
    if window == "auto":
        window = _window_from_histogram(by_flux, 0.999)
    else:
        by_count = None  # a window given: one tier
    check_triangle(window)  # "auto": now that the window is known

    def cost(w):
        return triangle_bytes(w, reconstruction, supersample, dtype)

    def batch(w, n):
        size = min(n, triangle_batch or max(1, memory_limit // 4 // cost(w)))
        # batches of even size: 295k triangles in two of 275k would pad a second,
        # near-empty one to full size (and twice the work)
        return -(-n // -(-n // size))

    band_triangles = 2 * (rows + 2 * halo - 1) * (grid[1] - 1)
    if by_count is None:
        tiers = _plain_tier(window, batch(window, band_triangles))
    else:
        penalty = _tier_penalty(receiver.shape, dtype)
        tiers = _size_tiers(by_count, window, band_triangles, cost, batch, penalty)
    sizes = [band_triangles if n is None else n for _, n, _ in tiers]
    batches = bands * sum(-(-n // size) for n, (_, _, size) in zip(sizes, tiers, strict=True))
    check_photon_work(grid[0] * grid[1], batches, "photons")
    if not banded:
        images, missed, limited = _triangles_image(
            ph, receiver.extent, receiver.shape, reconstruction, tiers, supersample
        )
    else:
        images, missed, limited = _banded_image(
            scene, cfg, mean_area, reconstruction, tiers, supersample, mesh
        )
    stats = {
        "interface_limited_fraction": limited,
        "bands": bands,
        "batches": batches,
        "triangle_batch": tiers[0][2],
        "tiers": tuple((w, n, size) for n, (w, _, size) in zip(sizes, tiers, strict=True)),
        "ray_batch": ray_batch,
        "devices": n_devices,
        "peak_buffer_photons": band_photons,
        "peak_buffer_bytes": band_bytes(band_photons, channels, dtype, faces, ray_batch)
        + max(size * cost(w) for w, _, size in tiers),
    }
    return TrianglesResult(channels_last(scene, images), missed, ph, stats)
