"""Caustic maps: Shah et al.'s caustics mapping and Wyman & Nichols' adaptive caustic maps.

M. Shah, J. Konttinen, S. Pattanaik, "Caustics Mapping: An Image-Space Technique for
Real-Time Caustics" (2007), and C. Wyman, G. Nichols, "Adaptive Caustic Maps Using
Deferred Shading" (2009).

Both build a *caustic map*: an image in the light's view (`LightView`) into which every
photon that went through the generator adds its flux as a normalised Gaussian splat, at
the light's projection of where it landed. The final pass projects the map onto the
receiver as a shadow map would: a receiver point looks up the map (bilinear) at its own
projection; the map holds flux per unit view area, and the Lambertian factor of the
papers' shader (``n . l`` for a directional light) is exactly the view area per unit
surface area (`LightView.area_ratio`), so the result is the irradiance. Images follow
the library's convention: relative to the light's irradiance on a horizontal plane
(directional light) or W/m^2 (point light), caustic light only (the light that went
through the generator).

- `caustics_mapping` (Shah et al.): photons on a dense ``N x N`` grid over the light's
  view (the refractive vertex grid), shaded from the geometry buffers, all splatted,
  in batches of bounded memory.
- `adaptive_caustic_map` (Wyman & Nichols): photons from a coarse grid (64^2), 2 x 2
  clusters that miss the generator discarded, the others refined down to the level of
  the equivalent dense grid (``"traversal"`` metric) or until the cluster's photons land
  in one texel of the caustic map and go out as one photon carrying the cluster's flux
  (``"error"`` metric, checked from a given level on); batches under a memory limit.

This module holds what both share and caustics mapping itself; `adaptive.py` holds the
adaptive traversal, `camera.py` the final pass seen from a camera.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._checks import (
    DEFAULT_MEMORY_LIMIT,
    check_array,
    check_choice,
    check_fits,
    check_int,
    check_memory_limit,
    check_number,
    check_photon_work,
)
from ...devices import device_mesh
from ...reconstruct.raster import splat_gaussian, sum_over_batches
from ...scene.checks import checks_scene_values
from ...scene.mesh import MeshScene
from ..base import Method, channels_last
from .gbuffer import (
    INTERSECTIONS,
    GeometryBuffers,
    bilinear,
    geometry_buffers,
    raster_window,
    shade_photons,
)
from .light_view import LightView, light_view

# most image-space intersection steps (`ray_geo` unrolls them: 100000 compiled for ever)
MAX_ITERATIONS = 64
# memory model of what does not grow with the photons, numbers of the scene's dtype: per
# geometry-buffer texel (XLA's compiled temporaries and outputs: 64) and per caustic-map
# texel and channel (the map, a batch's map, the receiver's lookups: 12 measured)
_GBUFFER_FLOATS = 64
_MAP_FLOATS = 16


class CausticMapResult(eqx.Module):
    """Output of `caustics_mapping` and `adaptive_caustic_map`.

    - `image`: irradiance on the receiver, ``(rows, cols)`` or ``(rows, cols, channels)``.
    - `caustic_map`: flux per texel in the light's view, ``(channels, R, R)``.
    - `view`: the `LightView` the map is in.
    - `shadow_map`: ``(G, G)`` bool, the geometry buffers' hit mask: where the light's
      view sees the generator (what a shadow map holds; `camera_image` uses it).
    - `missed_flux_fraction`: ``(channels,)``: the fraction of the splatted flux that is
      not in the image (it landed off the receiver).
    - `stats`: dict of counts (Python ints): ``generated`` (photons shaded, all levels),
      ``splatted`` (photons added to the map: valid ones, a merged cluster counting once),
      ``batches`` (kernel calls), ``peak_buffer_photons`` and ``peak_buffer_bytes`` (the
      largest photon buffer of one call, see `photon_bytes`); `caustics_mapping` adds
      ``devices`` (those the batches were split across); the adaptive renderer adds
      per level lists ``generated_per_level``, ``splatted_per_level``,
      ``refined_per_level``.
    """

    image: Array
    caustic_map: Array
    view: LightView
    shadow_map: Array
    missed_flux_fraction: Array
    stats: dict


def photon_bytes(channels: int, window: int, dtype) -> int:
    """Memory one photon takes in a batch, bytes: a model of XLA's compiled temporaries
    for shading and splatting it, per channel ``size (2 w^2 + 8) + 8 w^2`` (``size``
    the dtype's bytes, ``w`` the splat window): per texel of its ``w x w`` splat, its
    weight, a partial and two int32 scatter indices. On a CPU in float64 the measured
    cost is 65-85% of it for windows 5 to 13, both intersections, one or three
    channels (``tests/test_memory.py`` checks the bound)."""
    channels = check_int(channels, "channels", 1)
    window = check_int(window, "window", 1)
    try:
        size = jnp.dtype(dtype).itemsize
    except TypeError as err:
        raise ValueError(f"`dtype` must be a NumPy dtype, got {dtype!r}") from err
    w2 = window * window
    return channels * (size * (2 * w2 + 8) + 8 * w2)


def _check_common(scene, map_resolution, intersection, iterations, memory_limit):
    if not isinstance(scene, MeshScene):
        raise ValueError(
            f"`scene` must be a MeshScene, got {type(scene).__name__} (lens slabs: use "
            "caustic_triangles)"
        )
    if scene.occluders:
        raise ValueError(
            "caustic maps do not test occlusion: the scene has occluders (use "
            "caustic_triangles, whose visibility='distance_map' handles them)"
        )
    check_choice(intersection, "intersection", INTERSECTIONS)
    check_int(iterations, "iterations", 0, MAX_ITERATIONS)
    if map_resolution is None:
        map_resolution = 2 * max(scene.receiver.shape)
    map_resolution = check_int(map_resolution, "map_resolution", 2)
    return map_resolution, check_memory_limit(memory_limit)


def _check_sigma(sigma, map_resolution: int, photons: int) -> float:
    """A splat from a thousandth of a texel (narrower underflowed to NaN) to the map's
    side (wider covers nothing more), or ``"auto"``."""
    if isinstance(sigma, str) and sigma == "auto":
        return max(0.5, map_resolution / photons)
    if isinstance(sigma, str):
        raise ValueError(f"`sigma` must be a positive number or 'auto', got {sigma!r}")
    return check_number(sigma, "sigma", low=1e-3, high=map_resolution)


def _check_memory(scene, photons: int, map_resolution, gbuffer_resolution, per_photon, limit):
    """What does not grow with the photons (the geometry buffers, the caustic map and
    the receiver's lookups) and one photon (or cluster of `photons`) must fit; refused,
    with the estimate, before anything is compiled. `limit` bounds the photon batches
    (its documented meaning: a small one means more batches); the fixed buffers, which
    batching cannot shrink, are held to the larger of it and the 1 GiB default."""
    channels, size = len(scene.iors), jnp.dtype(scene.generator.vertices.dtype).itemsize
    fixed = size * (
        _GBUFFER_FLOATS * gbuffer_resolution**2 + _MAP_FLOATS * channels * map_resolution**2
    )
    check_fits(
        fixed,
        max(limit, DEFAULT_MEMORY_LIMIT),
        f"the {gbuffer_resolution}^2 geometry buffers and the {map_resolution}^2 caustic map",
        "lower `gbuffer_resolution` or `map_resolution`",
    )
    check_fits(
        photons * per_photon,
        limit,
        f"{'one photon' if photons == 1 else f'a cluster of {photons} photons'} "
        f"({per_photon} bytes each: its splat window, from `sigma`)",
        "pass a smaller `sigma`",
    )


def _view_and_buffers(
    scene, gbuffer_resolution: int, memory_limit: int | None = None
) -> GeometryBuffers:
    """The light's view and its geometry buffers; `memory_limit` is the photon batches'
    budget, so the buffers (which batching cannot shrink) get at least the default."""
    memory_limit = max(memory_limit or 0, DEFAULT_MEMORY_LIMIT)
    view = light_view(scene)
    if not isinstance(view.window, jax.core.Tracer):
        if not np.all(np.isfinite(np.asarray(view.window))):
            raise ValueError(
                "the light must see the whole scene from one side: a point light inside "
                "or below the receiver/generator's bounding box has no light view"
            )
    traced = any(
        isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves((scene.generator, view))
    )
    if traced:  # under jit or grad: no concrete footprints
        window = gbuffer_resolution  # every face may cover the whole view
    else:
        window = raster_window(scene, view, gbuffer_resolution)
    return _buffers(scene, view, gbuffer_resolution, window, memory_limit)


@eqx.filter_jit
def _buffers(scene, view, resolution, window, memory_limit):
    return geometry_buffers(scene, view, resolution, window, memory_limit=memory_limit)


def _splat(view: LightView, hits, shape, sigma, window) -> Array:
    """Splat photon hits ``(C, P)`` into a caustic map ``(C, R, R)`` (flux per texel)."""
    u, v = view.project(hits.position)
    x, y = view.to_texels(u, v, shape)
    points = jnp.stack([x, y], axis=-1)
    return jnp.stack(
        [
            splat_gaussian(points[c], hits.flux[c], hits.valid[c], shape, sigma, window)
            for c in range(points.shape[0])
        ]
    )


def project_caustic_map(
    view: LightView, caustic_map: Array, points: Array, normals: Array
) -> Array:
    """The final pass: irradiance ``(C, ...)`` at receiver `points` ``(..., 3)`` with unit
    `normals`, from a caustic map ``(C, R, R)`` (flux per texel), looked up bilinearly at
    the points' projection in the light's view (no shadow test)."""
    if not isinstance(view, LightView):
        raise ValueError(f"`view` must be a LightView, got {type(view).__name__}")
    caustic_map = check_array(caustic_map, "caustic_map", (None, None, None))
    points = check_array(points, "points", (..., 3))
    normals = check_array(normals, "normals", tuple(points.shape))
    shape = caustic_map.shape[1:]
    u, v = view.project(points)
    x, y = view.to_texels(u, v, shape)
    per_area = jnp.moveaxis(caustic_map, 0, -1) / view.texel_area(shape)
    looked_up = bilinear(per_area, x, y)
    # outside the map: nothing (the window covers the receiver, but not every point)
    rows, cols = shape
    inside = (x >= 0) & (x <= cols) & (y >= 0) & (y <= rows)
    irradiance = (
        jnp.where(inside[..., None], looked_up, 0.0) * view.area_ratio(points, normals)[..., None]
    )
    return jnp.moveaxis(irradiance, -1, 0)


def _receiver_image(scene: MeshScene, view: LightView, caustic_map: Array, total_flux: Array):
    """Project the map onto the receiver: each pixel averages ``S x S`` lookups at its
    sub-pixel centres, ``S`` the map's texels per pixel (rounded up), so that a caustic
    finer than a pixel is integrated over it rather than point-sampled (the reference
    bins flux per pixel). Also the missed-flux fraction."""
    receiver = scene.receiver
    rows, cols = receiver.shape
    s = max(1, -(-caustic_map.shape[1] // max(rows, cols)))
    x0, x1, y0, y1 = (receiver.extent[k] for k in range(4))
    dtype = caustic_map.dtype
    xs = x0 + (jnp.arange(cols * s, dtype=dtype) + 0.5) * (x1 - x0) / (cols * s)
    ys = y0 + (jnp.arange(rows * s, dtype=dtype) + 0.5) * (y1 - y0) / (rows * s)
    gx, gy = jnp.meshgrid(xs, ys)
    points = jnp.stack([gx, gy, jnp.zeros_like(gx)], axis=-1)
    normals = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], dtype), points.shape)
    fine = project_caustic_map(view, caustic_map, points, normals)
    images = fine.reshape(-1, rows, s, cols, s).mean(axis=(2, 4))
    dx, dy = receiver.pixel_size
    landed = images.sum(axis=(1, 2)) * dx * dy
    ok = total_flux > 0
    missed = jnp.where(ok, 1.0 - landed / jnp.where(ok, total_flux, 1.0), 0.0)
    return images, jnp.clip(missed, 0.0, 1.0)


def _photon_batch(view: LightView, photons: int, batch: int, k) -> tuple[Array, Array, Array]:
    """Batch `k` of the cell-centred ``photons x photons`` grid over the view, in
    row-major order: ``u, v`` ``(batch,)`` and whether each is a photon of the grid
    (the last batch is padded); the grid itself is never built."""
    index = k * batch + jnp.arange(batch, dtype=jnp.int32)
    row, col = index // photons, index % photons
    u0, u1, v0, v1 = (view.window[i] for i in range(4))
    dtype = view.window.dtype
    u = u0 + (col.astype(dtype) + 0.5) * (u1 - u0) / photons
    v = v0 + (row.astype(dtype) + 0.5) * (v1 - v0) / photons
    return u, v, index < photons * photons


@eqx.filter_jit
def _dense_map(
    scene, buffers, photons, map_shape, sigma, window, batch, intersection, iterations, mesh
):
    batches = -(-photons * photons // batch)

    def raster(operands, k):
        scene, buffers = operands
        view = buffers.view
        u, v, live = _photon_batch(view, photons, batch, k)
        cell_area = view.texel_area((photons, photons))
        hits = shade_photons(
            scene, buffers, u, v, cell_area, intersection=intersection, iterations=iterations
        )
        hits = eqx.tree_at(lambda h: h.valid, hits, hits.valid & live[None])
        flux = jnp.where(hits.valid, hits.flux, 0.0)
        cmap = _splat(view, hits, map_shape, sigma, window)
        return cmap, flux.sum(axis=1), hits.valid.any(axis=0).sum()

    cmap, total, splatted = sum_over_batches(raster, (scene, buffers), batches, mesh=mesh)
    images, missed = _receiver_image(scene, buffers.view, cmap, total)
    return cmap, images, missed, splatted


class _CausticMapMethod(Method):
    """What both caustic maps support: refracting meshes without occluders."""

    photons: eqx.AbstractVar[int]  # each subclass's first knob
    scene_types: ClassVar[tuple[type, ...]] = (MeshScene,)
    resolution_knobs: ClassVar[tuple[str, ...]] = ("photons",)

    def refined(self) -> _CausticMapMethod:
        """Twice the photons along each side of the light's view."""
        return dataclasses.replace(self, photons=2 * self.photons)

    def coarsened(self) -> _CausticMapMethod | None:
        if self.photons % 2 or self.photons // 2 < self._fewest_photons():
            return None
        return dataclasses.replace(self, photons=self.photons // 2)

    def _fewest_photons(self) -> int:
        return 2

    def support(self, scene) -> str | None:
        if not isinstance(scene, MeshScene):
            return "caustic maps take meshes"
        if scene.effects.occlusion:
            return "caustic maps do not test occlusion (the scene has occluders)"
        if scene.effects.reflection:
            return "caustic maps refract only (the mesh is a mirror)"
        return None


class CausticsMapping(_CausticMapMethod):
    """Shah et al.'s caustics mapping (dense photon splats) for refracting meshes:
    ``CausticsMapping(photons=...)(scene)`` or ``render(scene, CausticsMapping(...))``.

    **Arguments:**

    - `photons`: ``N``: the refractive vertex grid, ``N x N`` photons at the cell centres
      of the light's view (`LightView`: it covers the receiver and the generator);
      default 512.
    - `map_resolution`: ``R``: the caustic map is ``R x R`` texels over the same view;
      default twice the receiver's larger side.
    - `sigma`: the splat's standard deviation in map texels (the splat radius);
      ``"auto"`` (the default): ``max(0.5, R / N)``, about one photon spacing.
    - `gbuffer_resolution`: texels per side of the geometry buffers (refractor front and
      back, receiver positions texture); default ``min(N, 1024)`` (Shah et al.: one
      texel per photon; above 1024 photons are interpolated between texels; Wyman &
      Nichols sample them at a quarter of the caustic map's resolution).
    - `intersection`: ``"image_space"`` (the default; the paper's estimate: `ray_geo` on
      the positions textures, two interfaces) or ``"exact"`` (ray tracing through the
      mesh and onto the plane; `gbuffer_resolution` unused).
    - `iterations`: steps of the image-space intersection estimate (rayGeo), one texture
      lookup each. The paper uses 1; the default is 4. On the glass ball of
      `paper_figures/raygeo_iterations.py` (radius 0.5 m, light 10 degrees from vertical)
      the median landing error on the floor is 15 mm after 1 step and 0.6 mm after 4 (the
      exit through the back surface: 24 mm and 0.13 mm); near the rim the update
      converges slowly whatever the count (`jaxcaustics.internal.intersection_errors`).
    - `memory_limit`: bytes of photon buffer per batch (`photon_bytes` per photon);
      photons beyond it are shaded and splatted in further batches, for the same image
      (a loop: each batch makes its own photons from its index, so the ``N x N`` grid
      never exists and the compiled graph does not grow with ``N``). Default 1 GiB.
      Refused before anything is compiled, with the estimate: geometry buffers and
      caustic map over the limit (``64 G^2 + 16 C R^2`` numbers), one photon over it (a
      huge `sigma`), over 2^31 photons (``N`` above 46340) or over 2^20 batches
      (`jaxcaustics.reconstruct.raster`'s `MAX_PHOTONS`, `MAX_BATCHES`).
    - `devices`: ``None`` (the default): the default device only. An int ``n`` (the first
      ``n`` of `jax.devices()`) or a list of devices: the batches are split across them
      (`jax.shard_map` over `jaxcaustics.devices.device_mesh(devices)`, at least one
      batch per device) and the partial maps summed (``psum``); same map to rounding.
    """

    photons: int = 512
    map_resolution: int | None = None
    sigma: float | Literal["auto"] = "auto"
    gbuffer_resolution: int | None = None
    intersection: Literal["image_space", "exact"] = "image_space"
    iterations: int = 4
    memory_limit: int | None = None
    devices: object = None

    name: ClassVar[str] = "caustics_mapping"

    def trace(self, scene) -> CausticMapResult:
        return caustics_mapping(scene, **self.knobs())


@checks_scene_values
def caustics_mapping(
    scene: MeshScene,
    *,
    photons: int = CausticsMapping.photons,
    map_resolution: int | None = CausticsMapping.map_resolution,
    sigma: float | Literal["auto"] = CausticsMapping.sigma,
    gbuffer_resolution: int | None = CausticsMapping.gbuffer_resolution,
    intersection: Literal["image_space", "exact"] = CausticsMapping.intersection,
    iterations: int = CausticsMapping.iterations,
    memory_limit: int | None = CausticsMapping.memory_limit,
    devices=CausticsMapping.devices,
) -> CausticMapResult:
    """Caustics of a mesh scene by Shah et al.'s caustics mapping (dense photon splats).

    The function form of `CausticsMapping`: `scene` (a `MeshScene` without occluders) and
    the same knobs as keywords, described there.

    **Returns:** a `CausticMapResult`. Jit-compiled; differentiable with respect to the
    generator's vertices (and the light), through the geometry buffers and the photons.
    """
    map_resolution, memory_limit = _check_common(
        scene, map_resolution, intersection, iterations, memory_limit
    )
    photons = check_int(photons, "photons", 2)
    sigma = _check_sigma(sigma, map_resolution, photons)
    if gbuffer_resolution is None:
        gbuffer_resolution = min(photons, 1024)
    gbuffer_resolution = check_int(gbuffer_resolution, "gbuffer_resolution", 2)
    window = 2 * math.ceil(3.0 * sigma) + 1
    dtype = scene.generator.vertices.dtype
    per_photon = photon_bytes(len(scene.iors), window, dtype)
    check_photon_work(photons * photons, 1, "photons")
    _check_memory(scene, 1, map_resolution, gbuffer_resolution, per_photon, memory_limit)
    mesh = None if devices is None else device_mesh(devices)
    n_devices = 1 if mesh is None else mesh.size
    batch = max(1, min(-(-photons * photons // n_devices), memory_limit // per_photon))
    # photon indices are int32, up to the last batch of the last device's padded share
    batches = math.ceil(photons * photons / batch)
    check_photon_work(photons * photons, batches, "photons")
    if math.ceil(batches / n_devices) * n_devices * batch > 2**31:
        raise ValueError(
            f"`photons` {photons}: its batches of {batch} photons index past int32 (at most "
            "about 46000 per axis; a smaller `memory_limit` leaves more room)"
        )
    buffers = _view_and_buffers(scene, gbuffer_resolution, memory_limit)
    map_shape = (map_resolution, map_resolution)
    cmap, images, missed, splatted = _dense_map(
        scene, buffers, photons, map_shape, sigma, window, batch, intersection, iterations, mesh
    )
    stats = {
        "generated": photons * photons,
        "splatted": splatted,
        "batches": -(-photons * photons // batch),
        "devices": n_devices,
        "peak_buffer_photons": batch,
        "peak_buffer_bytes": batch * per_photon,
    }
    if not isinstance(splatted, jax.core.Tracer):
        stats["splatted"] = int(splatted)
    return CausticMapResult(
        channels_last(scene, images), cmap, buffers.view, buffers.hit, missed, stats
    )
