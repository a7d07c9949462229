"""`render_batch`: a batch of scenes rendered across devices.

Above the methods (`registry`: a method by name, `Method.sized_for`: its ``"auto"``
knobs sized for a batch) and `jaxcaustics.devices` (devices, meshes, stacking).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
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
from .base import Method
from .registry import as_method


def _sized(method: Method, scenes) -> Method:
    """`method` with its ``"auto"`` knobs sized for every scene of the batch (the largest
    size any needs, `Method.sized_for`), so that one program renders them all."""
    if not method.needs_sizing():
        return method
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(scenes)):
        raise ValueError(
            f"the 'auto' knobs of {method!r} need concrete scene values; under jit/grad pass ints"
        )
    return method.sized_for(unstack_scenes(scenes))


@eqx.filter_jit
def _render_sharded(arrays, static, method: Method, mesh, per_device):
    """Each device renders its share of the batch (`jax.shard_map`), vectorised or item
    after item."""
    method_arrays, method_static = eqx.partition(method, eqx.is_array)

    def local(arrays, method_arrays):
        method = eqx.combine(method_arrays, method_static)

        def one(a):
            return method(eqx.combine(a, static)).image

        return jax.vmap(one)(arrays) if per_device == "vmap" else jax.lax.map(one, arrays)

    spec = PartitionSpec(MESH_AXIS)
    # check_vma=False: the methods' loops (scans with zero-initialised carries) are not
    # written for shard_map's varying-type checks; nothing here communicates
    return jax.shard_map(
        local, mesh=mesh, in_specs=(spec, PartitionSpec()), out_specs=spec, check_vma=False
    )(arrays, method_arrays)


def render_batch(
    scenes,
    method: str | Method | None = None,
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
    - `**knobs`: the named method's knobs (as for `render`), the same for every scene.

    The batch is padded (with copies of its last scene) to a multiple of the device count,
    placed with ``NamedSharding(mesh, PartitionSpec(MESH_AXIS))`` and rendered by
    `jax.shard_map`: each device renders its own contiguous share.

    **Returns:** the images, a `jax.Array` of shape ``(n, rows, cols)`` (``(n, rows,
    cols, channels)`` with several indices of refraction), left on the devices (split
    along the batch); differentiable with respect to the scenes' arrays. `gather_to_host`
    copies it to NumPy (on every process, when the devices span several hosts).
    """

    # the method and its knobs checked before the scenes are stacked (that compiles)
    first = scenes[0] if isinstance(scenes, list | tuple) and scenes else scenes
    method = as_method(method, knobs, first)
    if isinstance(scenes, list | tuple):
        scenes = stack_scenes(scenes)
    if not isinstance(scenes, eqx.Module):
        raise ValueError(f"`scenes` must be a batch of scenes, got {type(scenes).__name__}")
    n = batch_size_of(scenes)
    devices = resolve_devices(devices)
    per_device = check_per_device(per_device, devices)
    method = _sized(method, scenes)

    mesh = device_mesh(devices)
    padded = -(-n // len(devices)) * len(devices)
    arrays, static = eqx.partition(scenes, eqx.is_array)
    arrays = jax.tree.map(lambda x: pad_leading(x, padded), arrays)
    arrays = jax.device_put(arrays, NamedSharding(mesh, PartitionSpec(MESH_AXIS)))
    images = _render_sharded(arrays, static, method, mesh, per_device)
    return images if padded == n else images[:n]
