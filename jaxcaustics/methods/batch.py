"""`render_batch`: a batch of scenes rendered across devices.

Above `_render` (it renders by method name) and `_sharding` (devices, meshes, stacking):
the one module that needs both, so that neither imports the other.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

from ..devices import (
    MESH_AXIS,
    batch_size_of,
    check_per_device,
    device_mesh,
    pad_leading,
    resolve_devices,
    stack_scenes,
    unstack_scenes,
)
from .render import DEFAULT_METHOD, METHODS, check_knob_names
from .triangles.method import _check_grid, trace_photons, triangle_window
from .twopass import auto_window


def _default(method_fn: Callable, name: str):
    return inspect.signature(method_fn).parameters[name].default


def _is_auto(value) -> bool:
    return isinstance(value, str) and value == "auto"


def _resolve_auto_knobs(scenes, method: str, method_fn: Callable, knobs: dict) -> dict:
    """Knobs that ``"auto"`` sizes from concrete scene values (the two-pass window, the
    triangles' window) become the largest over the batch, so one program renders all."""
    knobs = dict(knobs)
    traced = any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(scenes))
    if method == "twopass":
        names = ("samples_x", "channels_y")
        if any(_is_auto(knobs.get(k, _default(method_fn, k))) for k in names):
            if traced:
                raise ValueError(
                    "samples_x='auto' needs concrete scene values; under jit/grad pass ints"
                )

            hit = knobs.get("hit_iterations", _default(method_fn, "hit_iterations"))
            sup = knobs.get("supersample", _default(method_fn, "supersample"))
            windows = np.array([auto_window(s, hit, sup) for s in unstack_scenes(scenes)])
            knobs["samples_x"], knobs["channels_y"] = (int(v) for v in windows.max(axis=0))
    elif method == "triangles":
        visibility = knobs.get("visibility", _default(method_fn, "visibility"))
        if _is_auto(knobs.get("window", _default(method_fn, "window"))) and visibility == "exact":
            if traced:
                raise ValueError(
                    "window='auto' needs concrete scene values; under jit/grad pass an int"
                )

            grid = _check_grid(knobs.get("photons", _default(method_fn, "photons")))
            hit = knobs.get("hit_iterations", _default(method_fn, "hit_iterations"))
            extra = {
                k: knobs[k] for k in ("batch_size", "memory_limit") if knobs.get(k) is not None
            }
            knobs["window"] = max(
                triangle_window(trace_photons(s, grid, hit, **extra), s.receiver)
                for s in unstack_scenes(scenes)
            )
    return knobs


@eqx.filter_jit
def _render_sharded(arrays, static, knobs, method_fn, mesh, per_device):
    """Each device renders its share of the batch (`jax.shard_map`), vectorised or item
    after item."""
    knob_arrays, knob_static = eqx.partition(knobs, eqx.is_array)

    def local(arrays, knob_arrays):
        kw = eqx.combine(knob_arrays, knob_static)

        def one(a):
            return method_fn(eqx.combine(a, static), **kw).image

        return jax.vmap(one)(arrays) if per_device == "vmap" else jax.lax.map(one, arrays)

    spec = PartitionSpec(MESH_AXIS)
    # check_vma=False: the methods' loops (scans with zero-initialised carries) are not
    # written for shard_map's varying-type checks; nothing here communicates
    return jax.shard_map(
        local, mesh=mesh, in_specs=(spec, PartitionSpec()), out_specs=spec, check_vma=False
    )(arrays, knob_arrays)


def render_batch(
    scenes,
    method: str | None = None,
    *,
    devices: Sequence[jax.Device] | int | None = None,
    per_device: str | None = None,
    **knobs,
) -> jax.Array:
    """Render a batch of scenes (surfaces, lenses, ...), split across `devices`.

    **Arguments:**

    - `scenes`: a batch made by `stack_scenes` (one scene whose arrays carry a leading
      batch axis of size ``n``), or a sequence of scenes (stacked here).
    - `method`: as for `render` (default: the scene type's natural method). The method
      must trace under `jax.vmap`: ``"twopass"`` and ``"triangles"`` do; knobs that
      ``"auto"`` sizes from scene values (the two-pass window ``samples_x`` /
      ``channels_y``, the triangles' ``window``) are sized beforehand, the largest over
      the batch, which needs concrete scenes (under `jax.grad` or `jax.jit` pass ints).
    - `devices`: ``None`` (all of `jax.devices()`), an int ``n`` (the first ``n``) or a
      sequence of devices.
    - `per_device`: ``"vmap"`` (each device renders its share vectorised; the default on
      GPU/TPU) or ``"map"`` (scene after scene with ``jax.lax.map``: less memory; the
      default on CPU). Gradients need ``"map"`` for now: reverse-mode through the
      vectorised ray-surface hit fails inside JAX (a `broadcast_in_dim` error).
    - `**knobs`: the method's knobs (as for `render`), the same for every scene.

    The batch is padded (with copies of its last scene) to a multiple of the device count,
    placed with ``NamedSharding(mesh, PartitionSpec(MESH_AXIS))`` and rendered by
    `jax.shard_map`: each device renders its own contiguous share.

    **Returns:** the images, a `jax.Array` of shape ``(n, rows, cols)`` (``(n, rows,
    cols, channels)`` with several indices of refraction), left on the devices (split
    along the batch); differentiable with respect to the scenes' arrays. `gather_to_host`
    copies it to NumPy (on every process, when the devices span several hosts).
    """

    if method is not None:  # checked before the scenes are stacked (that compiles)
        if not isinstance(method, str) or method not in METHODS:
            raise ValueError(f"`method` must be one of {sorted(METHODS)}, got {method!r}")
        check_knob_names(method, knobs)
    if isinstance(scenes, list | tuple):
        scenes = stack_scenes(scenes)
    if not isinstance(scenes, eqx.Module):
        raise ValueError(f"`scenes` must be a batch of scenes, got {type(scenes).__name__}")
    n = batch_size_of(scenes)
    if method is None:
        method = DEFAULT_METHOD.get(type(scenes).__name__, "twopass")
        check_knob_names(method, knobs)
    devices = resolve_devices(devices)
    per_device = check_per_device(per_device, devices)
    knobs = _resolve_auto_knobs(scenes, method, METHODS[method], knobs)

    mesh = device_mesh(devices)
    padded = -(-n // len(devices)) * len(devices)
    arrays, static = eqx.partition(scenes, eqx.is_array)
    arrays = jax.tree.map(lambda x: pad_leading(x, padded), arrays)
    arrays = jax.device_put(arrays, NamedSharding(mesh, PartitionSpec(MESH_AXIS)))
    images = _render_sharded(arrays, static, knobs, METHODS[method], mesh, per_device)
    return images if padded == n else images[:n]
