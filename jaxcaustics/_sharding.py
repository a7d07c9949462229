"""Spreading work over devices with `jax.sharding`.

One vocabulary for every sharded entry point of the library: `devices` is ``None`` (all
of `jax.devices()`, which after `jax.distributed.initialize` spans every host), an int
``n`` (the first ``n`` of them) or a sequence of `jax.Device`; the devices form a one-axis
`jax.sharding.Mesh` named `MESH_AXIS`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

MESH_AXIS = "batch"


def resolve_devices(devices: Sequence[jax.Device] | int | None = None) -> list[jax.Device]:
    """The devices to shard over: ``None`` -> `jax.devices()`, an int ``n`` -> the first
    ``n`` of them, a sequence -> itself. Raises a `ValueError` naming `devices` when empty
    or when more devices are asked for than exist."""
    available = jax.devices()
    if devices is None:
        return list(available)
    if isinstance(devices, bool):
        raise ValueError(f"`devices` must be None, an int or a list of devices, got {devices!r}")
    if isinstance(devices, int | np.integer):
        if not 1 <= int(devices) <= len(available):
            raise ValueError(
                f"`devices` must be from 1 to the {len(available)} available, got {int(devices)}"
            )
        return list(available[: int(devices)])
    devices = list(devices)
    if not devices:
        raise ValueError("`devices` must not be empty")
    if not all(isinstance(d, jax.Device) for d in devices):
        raise ValueError("`devices` must hold jax.Device objects")
    return devices


def device_mesh(devices: Sequence[jax.Device] | int | None = None) -> Mesh:
    """A one-axis `Mesh` (axis `MESH_AXIS`) over `resolve_devices(devices)`."""
    return Mesh(np.asarray(resolve_devices(devices)), (MESH_AXIS,))


def map_sharded(
    fn: Callable,
    shared,
    batch,
    *,
    devices: Sequence[jax.Device] | int | None = None,
    chunk: int | None = None,
    progress: bool = False,
    desc: str | None = None,
    per_device: str | None = None,
):
    """``fn(shared, item)`` for every item along the leading axis of `batch`, sharded
    across `devices` and run in chunks; results are gathered to the host.

    `per_device` (default ``"vmap"`` on GPU/TPU, ``"map"`` on CPU): ``"vmap"`` vectorises
    a chunk placed with a `NamedSharding` over the devices (XLA splits the work along the
    sharded axis); ``"map"`` gives each device its contiguous share of the chunk and runs
    it item after item with ``jax.lax.map`` (on a CPU the fit runs 2-4x faster per item
    than vmapped, where every while-loop and branch waits for the slowest item).

    The devices form a one-axis `jax.sharding.Mesh` named `MESH_AXIS`; each chunk of
    `batch` is placed with ``NamedSharding(mesh, PartitionSpec(MESH_AXIS))`` (split along
    its leading axis), `shared` is replicated. `chunk` (default: one item per device) is
    rounded up to a multiple of the device count and the batch is padded (with copies of
    its last item) to a multiple of `chunk`, so every chunk has one shape and the function
    compiles once. **Returns** a pytree of NumPy arrays with the batch's leading axis.
    """
    devices = resolve_devices(devices)
    leaves = jax.tree.leaves(batch)
    if not leaves:
        raise ValueError("`batch` must hold arrays")
    n = int(np.shape(leaves[0])[0])
    if n == 0 or any(np.shape(leaf)[0] != n for leaf in leaves):
        raise ValueError("`batch` arrays must share a non-empty leading axis")
    n_dev = len(devices)
    if chunk is None:
        chunk = n_dev
    if isinstance(chunk, bool) or not isinstance(chunk, int | np.integer) or chunk < 1:
        raise ValueError(f"`chunk` must be a positive int, got {chunk!r}")
    chunk = -(-int(chunk) // n_dev) * n_dev
    chunk = min(chunk, -(-n // n_dev) * n_dev)
    padded = -(-n // chunk) * chunk

    def pad(x):
        x = np.asarray(x)
        return np.concatenate([x, np.repeat(x[-1:], padded - n, axis=0)])

    batch = jax.tree.map(pad, batch)
    mesh = Mesh(np.asarray(devices), (MESH_AXIS,))
    split = NamedSharding(mesh, PartitionSpec(MESH_AXIS))
    replicated = NamedSharding(mesh, PartitionSpec())
    shared = jax.tree.map(lambda x: jax.device_put(x, replicated) if eqx.is_array(x) else x, shared)

    if per_device is None:
        per_device = "map" if devices[0].platform == "cpu" else "vmap"
    if per_device not in ("map", "vmap"):
        raise ValueError(f"`per_device` must be 'map' or 'vmap', got {per_device!r}")
    arrays, static = eqx.partition(shared, eqx.is_array)

    @jax.jit
    def run_vmap(arrays, piece):
        out = jax.vmap(fn, in_axes=(None, 0))(eqx.combine(arrays, static), piece)
        return jax.lax.with_sharding_constraint(out, split)

    @jax.jit
    def run_map(arrays, piece):
        return jax.lax.map(lambda item: fn(eqx.combine(arrays, static), item), piece)

    def run(piece):
        if per_device == "vmap":
            return jax.device_get(run_vmap(arrays, jax.device_put(piece, split)))
        # each device maps over its contiguous share of the chunk; the calls are
        # dispatched asynchronously, so the devices work at the same time
        share = chunk // n_dev
        outs = [
            run_map(
                jax.device_put(arrays, device),
                jax.device_put(
                    jax.tree.map(lambda x, k=k: x[k * share : (k + 1) * share], piece), device
                ),
            )
            for k, device in enumerate(devices)
        ]
        return jax.tree.map(lambda *xs: np.concatenate(xs), *jax.device_get(outs))

    from tqdm.auto import tqdm

    outputs = []
    for start in tqdm(range(0, padded, chunk), desc=desc, disable=not progress, unit="chunk"):
        outputs.append(run(jax.tree.map(lambda x, s=start: x[s : s + chunk], batch)))
    return jax.tree.map(lambda *xs: np.concatenate(xs)[:n], *outputs)
