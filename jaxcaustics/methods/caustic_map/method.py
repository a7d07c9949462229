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
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, Literal

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
    check_real_array,
    check_shape,
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

METRICS = ("traversal", "error")
DISCARDS = ("footprint", "samples")
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


class _AdaptiveConfig(eqx.Module):
    """Static knobs of one adaptive traversal step."""

    base: int = eqx.field(static=True)
    max_level: int = eqx.field(static=True)
    check_level: int = eqx.field(static=True)
    metric: str = eqx.field(static=True)
    map_shape: tuple[int, int] = eqx.field(static=True)
    sigma: float = eqx.field(static=True)
    window: int = eqx.field(static=True)
    intersection: str = eqx.field(static=True)
    iterations: int = eqx.field(static=True)
    discard: str = eqx.field(static=True)


_CHILD = np.array([[0, 0], [0, 1], [1, 0], [1, 1]], np.int32)  # (row, col) offsets


@eqx.filter_jit
def _adaptive_step(scene, buffers, cmap, clusters, active, level, cfg: _AdaptiveConfig):
    """Shade the four photons of each 2 x 2 cluster at `level`, splat the clusters that
    stop here, and say which to refine. `clusters`: ``(K, 2)`` (row, col) indices in the
    grid of ``base 2^level / 2`` clusters; `active`: ``(K,)`` (padding is inactive)."""
    view = buffers.view
    dtype = cmap.dtype
    n = cfg.base * 2 ** level.astype(dtype)  # photons per side at this level
    u0, u1, v0, v1 = (view.window[k] for k in range(4))
    cell = (u1 - u0) / n
    index = 2 * clusters[:, None, :] + jnp.asarray(_CHILD)[None]  # (K, 4, 2)
    u = u0 + (index[..., 1].astype(dtype) + 0.5) * cell
    v = v0 + (index[..., 0].astype(dtype) + 0.5) * (v1 - v0) / n
    hits = shade_photons(
        scene,
        buffers,
        u.reshape(-1),
        v.reshape(-1),
        cell * (v1 - v0) / n,
        intersection=cfg.intersection,
        iterations=cfg.iterations,
    )
    channels, count = hits.valid.shape[0], clusters.shape[0]
    valid = hits.valid.reshape(channels, count, 4) & active[None, :, None]
    flux = jnp.where(valid, hits.flux.reshape(channels, count, 4), 0.0)
    position = hits.position.reshape(channels, count, 4, 3)
    any_valid = valid.any(axis=(0, 2))
    if cfg.discard == "footprint":
        any_valid = any_valid | _touches_generator(buffers, clusters, n)
    at_max = level >= cfg.max_level
    if cfg.metric == "error":
        pu, pv = view.project(position)
        x, y = view.to_texels(pu, pv, cfg.map_shape)
        tx, ty = jnp.floor(x), jnp.floor(y)
        one_texel = (tx == tx[..., :1]).all(-1) & (ty == ty[..., :1]).all(-1)
        converged = (valid.all(-1) & one_texel).all(0) & (level >= cfg.check_level)
    else:
        converged = jnp.zeros_like(any_valid)
    merged = active & converged
    each = active & any_valid & at_max & ~converged
    refine = active & any_valid & ~at_max & ~converged
    # the photons that go out: each valid one of a finished cluster, and one per merged
    # cluster at the mean of its landing points, carrying the cluster's flux
    each_valid = valid & each[None, :, None]
    out_position = jnp.concatenate([position, position.mean(axis=2, keepdims=True)], axis=2)
    out_flux = jnp.concatenate(
        [jnp.where(each_valid, flux, 0.0), flux.sum(axis=2, keepdims=True)], axis=2
    )
    out_valid = jnp.concatenate(
        [each_valid, jnp.broadcast_to(merged[None, :, None], (channels, count, 1))], axis=2
    )
    out = type(hits)(
        out_position.reshape(channels, -1, 3),
        jnp.where(out_valid, out_flux, 0.0).reshape(channels, -1),
        out_valid.reshape(channels, -1),
    )
    cmap = cmap + _splat(view, out, cfg.map_shape, cfg.sigma, cfg.window)
    splatted = each_valid.any(axis=0).sum() + merged.sum()
    return cmap, out.flux.sum(axis=1), refine, active.sum() * 4, splatted


def _touches_generator(buffers: GeometryBuffers, clusters: Array, n: Array) -> Array:
    """Whether the geometry buffers see the generator anywhere in each cluster's
    footprint (``2 x 2`` cells of an ``n x n`` grid), grown by one texel (the reach of
    the bilinear lookup): a summed-area table of the hit mask, four taps per cluster."""
    rows, cols = buffers.shape
    table = jnp.cumsum(jnp.cumsum(buffers.hit.astype(jnp.int32), axis=0), axis=1)
    table = jnp.pad(table, ((1, 0), (1, 0)))
    per_cell = jnp.array([rows, cols], n.dtype) / n
    low = jnp.floor(2 * clusters * per_cell).astype(jnp.int32) - 1
    high = jnp.ceil((2 * clusters + 2) * per_cell).astype(jnp.int32) + 1
    r0, c0 = jnp.clip(low[:, 0], 0, rows), jnp.clip(low[:, 1], 0, cols)
    r1, c1 = jnp.clip(high[:, 0], 0, rows), jnp.clip(high[:, 1], 0, cols)
    count = table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0]
    return count > 0


def _bucket(count: int, cap: int) -> int:
    """Static buffer size for `count` clusters: the next power of two (at least 64), at
    most `cap` (fewer distinct sizes, fewer compilations)."""
    return min(cap, max(64, 1 << max(0, count - 1).bit_length()))


def _first_clusters(base: int) -> np.ndarray:
    half = base // 2
    rows, cols = np.meshgrid(np.arange(half), np.arange(half), indexing="ij")
    return np.stack([rows.ravel(), cols.ravel()], axis=1).astype(np.int32)


def _traverse_on_host(scene, buffers, cfg: _AdaptiveConfig, cap: int):
    """The photon tree, level by level, decided on the host between jit-compiled steps:
    each step's buffer is sized to its clusters (`_bucket`, at most `cap`); children
    beyond `cap` go in further batches, refined to the end before the next (a stack)."""
    channels = len(scene.iors)
    dtype = scene.generator.vertices.dtype
    rows, cols = cfg.map_shape
    cmap = jnp.zeros((channels, rows, cols), dtype)
    total = jnp.zeros((channels,), dtype)
    levels = cfg.max_level + 1
    stats: dict[str, Any] = {
        "generated_per_level": [0] * levels,
        "splatted_per_level": [0] * levels,
        "refined_per_level": [0] * levels,
        "batches": 0,
        "peak_buffer_photons": 0,
    }
    start = _first_clusters(cfg.base)
    stack = [(0, start[k : k + cap]) for k in range(0, len(start), cap)][::-1]
    while stack:
        level, chunk = stack.pop()
        size = _bucket(len(chunk), cap)
        clusters = np.zeros((size, 2), np.int32)
        clusters[: len(chunk)] = chunk
        active = np.arange(size) < len(chunk)
        cmap, flux, refine, generated, splatted = _adaptive_step(
            scene,
            buffers,
            cmap,
            jnp.asarray(clusters),
            jnp.asarray(active),
            jnp.asarray(level, jnp.int32),
            cfg,
        )
        total = total + flux
        if isinstance(refine, jax.core.Tracer):  # under jit: no concrete choices
            raise ValueError(
                "adaptive_caustic_map decides its photon tree on the host: call it outside "
                "jax.jit (jax.grad works), or pass `capacity` to run it all under jit"
            )
        refine = np.asarray(refine)[: len(chunk)]
        stats["generated_per_level"][level] += int(generated)
        stats["splatted_per_level"][level] += int(splatted)
        stats["refined_per_level"][level] += int(refine.sum())
        stats["batches"] += 1
        stats["peak_buffer_photons"] = max(stats["peak_buffer_photons"], 4 * size)
        kept = chunk[refine]
        if len(kept):
            children = (2 * kept[:, None, :] + _CHILD[None]).reshape(-1, 2)
            parts = [children[k : k + cap] for k in range(0, len(children), cap)]
            stack.extend((level + 1, part) for part in parts[::-1])
    return cmap, total, stats


@eqx.filter_jit
def _traverse_in_jit(scene, buffers, cfg: _AdaptiveConfig, capacity: int, batch: int):
    """The photon tree under jit: every level holds `capacity` clusters (masks), shaded
    in batches of `batch` (a scan); the refined clusters' children are compacted into
    the next level's buffer (`jnp.nonzero` with a fixed size). **Returns:** the map, the
    flux per channel, and per-level counts with an overflow flag."""
    channels = len(scene.iors)
    dtype = scene.generator.vertices.dtype
    cmap = jnp.zeros((channels,) + cfg.map_shape, dtype)
    total = jnp.zeros((channels,), dtype)
    start = _first_clusters(cfg.base)
    if len(start) > capacity:
        raise ValueError(f"`capacity` must hold the first level's {len(start)} clusters")
    clusters = jnp.zeros((capacity, 2), jnp.int32).at[: len(start)].set(jnp.asarray(start))
    active = jnp.arange(capacity) < len(start)
    counts: list[list[Array]] = [[], [], []]
    overflow = jnp.zeros((), bool)

    @jax.checkpoint
    def step(carry, chunk):
        cmap, total, level = carry
        cmap, flux, refine, generated, splatted = _adaptive_step(
            scene, buffers, cmap, chunk[0], chunk[1], level, cfg
        )
        return (cmap, total + flux, level), (refine, generated, splatted)

    for level in range(cfg.max_level + 1):
        chunks = (clusters.reshape(-1, batch, 2), active.reshape(-1, batch))
        level_index = jnp.asarray(level, jnp.int32)
        (cmap, total, _), (refine, generated, splatted) = jax.lax.scan(
            step, (cmap, total, level_index), chunks
        )
        refine = refine.reshape(-1)
        counts[0].append(generated.sum())
        counts[1].append(splatted.sum())
        counts[2].append(refine.sum())
        children = (2 * clusters[:, None, :] + jnp.asarray(_CHILD)[None]).reshape(-1, 2)
        keep = jnp.repeat(refine, 4)
        overflow = overflow | (keep.sum() > capacity)
        (index,) = jnp.nonzero(keep, size=capacity, fill_value=0)
        clusters = children[index]
        active = jnp.arange(capacity) < keep.sum()
    return cmap, total, tuple(jnp.stack(c) for c in counts) + (overflow,)


class AdaptiveCausticMap(_CausticMapMethod):
    """Wyman & Nichols' adaptive caustic maps for refracting meshes:
    ``AdaptiveCausticMap(photons=...)(scene)`` or ``render(scene, AdaptiveCausticMap(...))``.

    Photons start on a ``base x base`` grid over the light's view and are grouped in
    2 x 2 clusters. A cluster whose photons all miss the generator is discarded; the
    others are refined (each photon becomes a cluster of four on the grid twice as fine)
    until a stopping metric says stop:

    - ``"traversal"`` (maximal traversal level): at the level of the equivalent dense
      grid, ``photons x photons``, all photons of the cluster are splatted.
    - ``"error"`` (maximal caustic-map error): from the level of a ``check_from`` grid
      on, a cluster whose four photons all land in one texel of the caustic map is
      splatted as one photon carrying their flux; the rest go on down to the traversal
      level, where they are all splatted.

    The traversal runs level by level (breadth first) in fixed-size buffers with masks.
    By default the tree is decided on the host between jit-compiled steps (one per
    buffer size, each sized to the level's clusters): when a level's photons would take
    more than `memory_limit` bytes (`photon_bytes` each), its clusters are split into
    batches, each refined and splatted to the end before the next (depth first). With
    `capacity` (clusters per level) the whole traversal runs under one `jit`: every
    level is a buffer of `capacity` clusters shaded in batches under the memory limit,
    and the refined clusters' children are compacted into the next level's buffer
    (``jnp.nonzero`` with a fixed size; a level that would overflow raises, or under an
    outer `jit` sets ``stats["overflow"]``). Same image either way.

    **Arguments:**

    - `photons`: the equivalent dense grid (default 2048); ``photons / base`` must be a
      power of two.
    - `base`: the coarse grid (the paper's 64, the default), even.
    - `metric`, `check_from`: as above (defaults ``"traversal"`` and 512: the paper
      checks convergence from 512^2 on).
    - `discard`: when a cluster "misses the refractor": ``"samples"`` (the paper's test:
      its four photons all miss; a sliver of the object between coarse photons is lost
      for good) or ``"footprint"`` (the default; also none of the geometry-buffer texels
      under the cluster's area sees the object: nothing is lost that the dense grid would
      find).
    - `gbuffer_resolution`: default ``min(photons, 1024)``, as `CausticsMapping`, so
      that both give the same image at the same `photons` (the paper samples the
      buffers at a quarter of the caustic map's resolution: coarser buffers smooth the
      object's normals, which costs accuracy on thin objects: on the benchmark's torus
      at 1024^2 photons 0.131 with 256^2 buffers against 0.116 with 1024^2).
    - `map_resolution`, `sigma`, `intersection`, `iterations`: as for `CausticsMapping`
      (same defaults).
    - `memory_limit`: bytes of photon buffer per batch (default 1 GiB, `photon_bytes`
      per photon), as for `CausticsMapping`; a level over it is split into batches as
      above.
    - `capacity`: clusters per level for the all-jit traversal (``None``, the default:
      host-driven), from the first level's ``(base / 2)^2`` to the finest level's
      ``(photons / 2)^2``.

    Checked before anything is compiled, as `CausticsMapping` (memory, at most 2^31
    photons in the equivalent grid, at most 2^20 batches of `memory_limit` at the
    worst, every cluster refined; one cluster of four photons must fit). `check_from`
    is unused with ``metric="traversal"`` but accepted (the benchmarks pass one value
    to both metrics).
    """

    photons: int = 2048
    base: int = 64
    metric: Literal["traversal", "error"] = "traversal"
    check_from: int = 512
    map_resolution: int | None = None
    sigma: float | Literal["auto"] = "auto"
    gbuffer_resolution: int | None = None
    intersection: Literal["image_space", "exact"] = "image_space"
    iterations: int = 4
    memory_limit: int | None = None
    discard: Literal["footprint", "samples"] = "footprint"
    capacity: int | None = None

    name: ClassVar[str] = "adaptive"

    def _fewest_photons(self) -> int:
        return self.base

    def rounded(self) -> AdaptiveCausticMap:
        """`photons` rounded up to `base` times a power of two (the grids the traversal
        refines to)."""
        levels = max(0, math.ceil(math.log2(self.photons / self.base)))
        return dataclasses.replace(self, photons=self.base * 2**levels)

    def trace(self, scene) -> CausticMapResult:
        return adaptive_caustic_map(scene, **self.knobs())


@checks_scene_values
def adaptive_caustic_map(
    scene: MeshScene,
    *,
    photons: int = AdaptiveCausticMap.photons,
    base: int = AdaptiveCausticMap.base,
    metric: Literal["traversal", "error"] = AdaptiveCausticMap.metric,
    check_from: int = AdaptiveCausticMap.check_from,
    map_resolution: int | None = AdaptiveCausticMap.map_resolution,
    sigma: float | Literal["auto"] = AdaptiveCausticMap.sigma,
    gbuffer_resolution: int | None = AdaptiveCausticMap.gbuffer_resolution,
    intersection: Literal["image_space", "exact"] = AdaptiveCausticMap.intersection,
    iterations: int = AdaptiveCausticMap.iterations,
    memory_limit: int | None = AdaptiveCausticMap.memory_limit,
    discard: Literal["footprint", "samples"] = AdaptiveCausticMap.discard,
    capacity: int | None = AdaptiveCausticMap.capacity,
) -> CausticMapResult:
    """Caustics of a mesh scene by Wyman & Nichols' adaptive caustic maps.

    The function form of `AdaptiveCausticMap`: `scene` (a `MeshScene` without occluders)
    and the same knobs as keywords, described there.

    **Returns:** a `CausticMapResult` with per-level counts in `stats`. Differentiable
    with respect to the scene through the photons' landing points (the traversal's
    choices are piecewise constant). The host-driven traversal runs outside `jax.jit`
    (``jax.grad`` works); with `capacity` it also runs inside.
    """
    map_resolution, memory_limit = _check_common(
        scene, map_resolution, intersection, iterations, memory_limit
    )
    photons = check_int(photons, "photons", 2)
    base = check_int(base, "base", 2)
    if base % 2:
        raise ValueError(f"`base` must be even (2 x 2 clusters), got {base}")
    ratio = photons // base
    if photons % base or ratio & (ratio - 1):
        raise ValueError(
            f"`photons` must be `base` times a power of two, got photons={photons}, base={base}"
        )
    check_photon_work(photons * photons, 1, "photons")
    check_choice(metric, "metric", METRICS)
    check_choice(discard, "discard", DISCARDS)
    check_from = check_int(check_from, "check_from", 1)
    if capacity is not None:  # at most every cluster of the finest level
        capacity = check_int(capacity, "capacity", (base // 2) ** 2, (photons // 2) ** 2)
    sigma = _check_sigma(sigma, map_resolution, photons)
    if gbuffer_resolution is None:
        gbuffer_resolution = min(photons, 1024)
    gbuffer_resolution = check_int(gbuffer_resolution, "gbuffer_resolution", 2)
    max_level = ratio.bit_length() - 1
    check_level = max(0, math.ceil(math.log2(max(check_from, base) / base)))
    window = 2 * math.ceil(3.0 * sigma) + 1
    channels = len(scene.iors)
    dtype = scene.generator.vertices.dtype
    per_photon = photon_bytes(channels, window, dtype)
    _check_memory(scene, 4, map_resolution, gbuffer_resolution, per_photon, memory_limit)
    cap = max(1, memory_limit // (4 * per_photon))  # clusters per batch
    # at most every cluster of every level, `cap` at a time
    check_photon_work(photons * photons, -(-(photons * photons // 3) // cap), "photons")
    cfg = _AdaptiveConfig(
        base,
        max_level,
        check_level,
        metric,
        (map_resolution,) * 2,
        sigma,
        window,
        intersection,
        iterations,
        discard,
    )
    buffers = _view_and_buffers(scene, gbuffer_resolution, memory_limit)
    if capacity is None:
        cmap, total, stats = _traverse_on_host(scene, buffers, cfg, cap)
    else:
        batch = min(cap, capacity)
        capacity = -(-capacity // batch) * batch  # whole batches
        cmap, total, counts = _traverse_in_jit(scene, buffers, cfg, capacity, batch)
        stats = {
            "generated_per_level": counts[0],
            "splatted_per_level": counts[1],
            "refined_per_level": counts[2],
            "overflow": counts[3],
            "batches": (max_level + 1) * (capacity // batch),
            "peak_buffer_photons": 4 * batch,
        }
        if not isinstance(counts[3], jax.core.Tracer):
            if bool(counts[3]):
                raise ValueError(
                    f"`capacity` {capacity} is too small: a level refines more clusters "
                    "(run once without it to see `refined_per_level`, and pass at least "
                    "four times the largest)"
                )
            for key in ("generated_per_level", "splatted_per_level", "refined_per_level"):
                stats[key] = [int(k) for k in np.asarray(stats[key])]
            stats["overflow"] = False
    images, missed = _receiver_image(scene, buffers.view, cmap, total)
    stats["generated"] = sum(stats["generated_per_level"])
    stats["splatted"] = sum(stats["splatted_per_level"])
    stats["peak_buffer_bytes"] = stats["peak_buffer_photons"] * per_photon
    return CausticMapResult(
        channels_last(scene, images), cmap, buffers.view, buffers.hit, missed, stats
    )


class PinholeCamera(eqx.Module):
    """A pinhole camera for `camera_image`.

    - `position`, `look_at`: ``(3,)`` metres; `up`: ``(3,)``, the image's upward
      direction (default ``+y``; any vector not along the view).
    - `fov`: vertical field of view, degrees (static).
    - `shape`: ``(rows, cols)`` of the image (static).
    """

    position: Array
    look_at: Array
    up: Array
    fov: float = eqx.field(static=True)
    shape: tuple[int, int] = eqx.field(static=True)

    def __init__(self, position, look_at, *, fov: float = 45.0, shape=(240, 320), up=(0, 1, 0)):
        for name, value in (("position", position), ("look_at", look_at), ("up", up)):
            arr = check_real_array(value, name)
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"`{name}` must be 3 finite numbers, got {value!r}")
        self.position = jnp.asarray(position, float)
        self.look_at = jnp.asarray(look_at, float)
        self.up = jnp.asarray(up, float)
        self.fov = check_number(fov, "fov", low=0.0, high=180.0, low_open=True, high_open=True)
        self.shape = check_shape(shape, "shape")
        forward = self.look_at - self.position
        if float(jnp.linalg.norm(jnp.cross(forward, self.up))) <= 1e-9 * float(
            jnp.linalg.norm(forward) + 1e-300
        ):
            raise ValueError("`look_at` must differ from `position`, and `up` not be along it")
        if not float(self.position[2]) > 0.0:  # below the screen it sees its underside
            raise ValueError(f"`position` must be above the receiver z = 0, got {position!r}")
        # the image's corner rays span its rays' z components: one must go down
        f, r, u = (np.asarray(a, float) for a in self._frame())
        half = math.tan(math.radians(self.fov) / 2)
        rows, cols = self.shape
        corners = [
            f + sx * half * cols / rows * r + sy * half * u for sx in (-1, 1) for sy in (-1, 1)
        ]
        if not min(c[2] for c in corners) < 0.0:
            raise ValueError(
                f"`look_at` {look_at!r}: the camera looks nowhere (no pixel sees the "
                "receiver plane z = 0 below it)"
            )

    def _frame(self) -> tuple[Array, Array, Array]:
        """Unit forward, right and up vectors of the image."""
        forward = self.look_at - self.position
        forward = forward / jnp.linalg.norm(forward)
        right = jnp.cross(forward, self.up)
        right = right / jnp.linalg.norm(right)
        return forward, right, jnp.cross(right, forward)

    def rays(self) -> tuple[Array, Array]:
        """Unit directions ``(rows, cols, 3)`` through the pixel centres."""
        rows, cols = self.shape
        forward, right, up = self._frame()
        half = math.tan(math.radians(self.fov) / 2)
        y = (1 - 2 * (jnp.arange(rows) + 0.5) / rows) * half
        x = (2 * (jnp.arange(cols) + 0.5) / cols - 1) * half * cols / rows
        d = forward + x[None, :, None] * right + y[:, None, None] * up
        return self.position, d / jnp.linalg.norm(d, axis=-1, keepdims=True)


def camera_image(
    scene: MeshScene, result: CausticMapResult, camera: PinholeCamera, *, albedo: float = 0.8
) -> Array:
    """The paper's final pass, seen from a camera: the receiver (the plane ``z = 0``
    within its extent; black elsewhere) shaded as a Lambertian surface of the given
    `albedo`: radiance ``albedo / pi (E_direct + E_caustic)``, ``E_direct`` the light's
    irradiance where the shadow map (`result.shadow_map`) does not see the generator,
    ``E_caustic`` the caustic map projected as in `project_caustic_map`. The generator
    itself is not drawn (only its shadow and caustic).

    **Arguments:**

    - `scene`: the `MeshScene` that was rendered.
    - `result`: its caustic map, a `CausticMapResult`
      (``CausticsMapping(...).trace(scene)`` or ``AdaptiveCausticMap(...).trace(scene)``).
    - `camera`: a `PinholeCamera` (its `shape` is the image's).
    - `albedo`: the receiver's Lambertian albedo, in ``[0, 1]`` (default 0.8).

    **Returns:** the radiance, in the images' units, ``(rows, cols)`` or ``(rows, cols,
    channels)``.
    """
    for name, value, kind in (
        ("scene", scene, MeshScene),
        ("result", result, CausticMapResult),
        ("camera", camera, PinholeCamera),
    ):
        if not isinstance(value, kind):
            raise ValueError(f"`{name}` must be a {kind.__name__}, got {type(value).__name__}")
    albedo = check_number(albedo, "albedo", low=0.0, high=1.0)
    origin, directions = camera.rays()
    dtype = result.caustic_map.dtype
    origin, directions = origin.astype(dtype), directions.astype(dtype)
    down = directions[..., 2] < 0
    t = -origin[2] / jnp.where(down, directions[..., 2], -1.0)
    points = origin + t[..., None] * directions
    x0, x1, y0, y1 = (scene.receiver.extent[k] for k in range(4))
    seen = down & (points[..., 0] >= x0) & (points[..., 0] <= x1)
    seen = seen & (points[..., 1] >= y0) & (points[..., 1] <= y1)
    normals = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], dtype), points.shape)
    view = result.view
    caustic = project_caustic_map(view, result.caustic_map, points, normals)  # (C, r, c)
    u, v = view.project(points)
    x, y = view.to_texels(u, v, result.shadow_map.shape)
    shadowed = bilinear(result.shadow_map.astype(dtype), x, y) >= 0.5
    direct = jnp.where(shadowed, 0.0, view.density(u, v) * view.area_ratio(points, normals))
    radiance = albedo / jnp.pi * (direct[None] + caustic)
    radiance = jnp.where(seen[None], radiance, 0.0)
    return channels_last(scene, radiance)
