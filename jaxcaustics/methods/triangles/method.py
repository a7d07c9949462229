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
from collections.abc import Sequence
from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..._checks import (
    check_choice,
    check_fits,
    check_int,
    check_memory_limit,
    check_number,
    check_photon_work,
)
from ...devices import device_mesh
from ...reconstruct.raster import pixel_coordinates, splat_gaussian
from ...scene.checks import checks_scene_values
from ...scene.mesh import MeshScene
from ...scene.mirror import MirrorScene
from ...scene.scene import LensScene, PlaneReceiver
from ...scene.surface import MAX_HIT_ITERATIONS
from ...trace.intersect import search_bytes
from ...trace.photons import Photons
from ..base import Method, channels_last
from .bands import _band_census, _BandConfig, _banded_image
from .rasterise import MAX_AUTO_WINDOW as MAX_AUTO_WINDOW
from .rasterise import _triangles_image
from .rasterise import grid_triangles as grid_triangles
from .sizing import MAX_TIERS as MAX_TIERS
from .sizing import (
    _extent_histogram_jit,
    _plain_tier,
    _size_tiers,
    _tier_penalty,
    _window_from_histogram,
    band_bytes,
    triangle_bytes,
)
from .tracing import (
    _ELEMENTS,
    _check_grid,
    _check_scene,
    _is_auto,
    _refuse_unused,
    _sizes,
    _trace_photons,
    trace_photons,
)
from .visibility import CubeMapOptions, _distance_map_caustics

RECONSTRUCTIONS = ("exact", "gouraud")
VISIBILITIES = ("exact", "distance_map")
# numbers per receiver pixel and channel besides the photons: the image being summed,
# one batch's image, its scatter and the result
_IMAGE_FLOATS = 4


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
