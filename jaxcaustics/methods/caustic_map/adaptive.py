"""Wyman & Nichols' adaptive caustic maps: photons refined as a tree only where the
object is (`AdaptiveCausticMap`), on the caustic map of `method.py`."""

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
    check_choice,
    check_int,
    check_photon_work,
)
from ...scene.checks import checks_scene_values
from ...scene.mesh import MeshScene
from ..base import channels_last
from .gbuffer import (
    GeometryBuffers,
    shade_photons,
)
from .method import (
    CausticMapResult,
    _CausticMapMethod,
    _check_common,
    _check_memory,
    _check_sigma,
    _receiver_image,
    _splat,
    _view_and_buffers,
    photon_bytes,
)

METRICS = ("traversal", "error")
DISCARDS = ("footprint", "samples")


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
