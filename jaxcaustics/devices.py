"""Spreading work over devices with `jax.sharding`.

One vocabulary for every sharded entry point of the library: `devices` is ``None`` (all
of `jax.devices()`, which after `jax.distributed.initialize` spans every host), an int
``n`` (the first ``n`` of them) or a sequence of `jax.Device`; the devices form a one-axis
`jax.sharding.Mesh` named `MESH_AXIS`.

- `map_sharded`: a function over the items of a batch (CSL fits per light direction, the
  lens design's solves per variant), results gathered to NumPy on every process.
- `stack_scenes`: a batch of scenes, rendered by `render_batch` (`methods/batch.py`: it
  needs the methods, which use this module's meshes, so it lives above both).
- `gather_to_host`: NumPy copies of (possibly multi-host) arrays on every process.

Several hosts: run the same script on every host after `jax.distributed.initialize`;
`jax.devices()` then lists every host's devices, each process computes the shares of the
devices it drives, and results are gathered with `process_allgather` (see
``docs/scaling.md``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._checks import check_bool, check_int

MESH_AXIS = "batch"


def resolve_devices(devices: Sequence[jax.Device] | int | None = None) -> list[jax.Device]:
    """The devices to shard over: ``None`` -> `jax.devices()`, an int ``n`` -> the first
    ``n`` of them, a sequence -> itself. Raises a `ValueError` naming `devices` when empty
    or when more devices are asked for than exist."""
    available = jax.devices()
    if devices is None:
        return list(available)
    if isinstance(devices, bool) or not isinstance(devices, int | np.integer | Iterable):
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
    if len(set(devices)) != len(devices):
        raise ValueError("`devices` must not list a device twice")
    return devices


def device_mesh(devices: Sequence[jax.Device] | int | None = None) -> Mesh:
    """A one-axis `Mesh` (axis `MESH_AXIS`) over `resolve_devices(devices)`."""
    return Mesh(np.asarray(resolve_devices(devices)), (MESH_AXIS,))


# module level, so that a repeated call with the same function (a hashable callable)
# reuses the compiled program; `fn` and the non-array parts of `shared` are static


@eqx.filter_jit
def _vmap_items(fn, shared, piece, split):
    out = jax.vmap(fn, in_axes=(None, 0))(shared, piece)
    return jax.lax.with_sharding_constraint(out, split)


@eqx.filter_jit
def _map_items(fn, shared, piece):
    return jax.lax.map(lambda item: fn(shared, item), piece)


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
    it item after item with ``jax.lax.map``, one host thread per device (on a CPU the fit
    runs 2-4x faster per item than vmapped, where every while-loop and branch waits for
    the slowest item).

    The devices form a one-axis `jax.sharding.Mesh` named `MESH_AXIS`; each chunk of
    `batch` is placed with ``NamedSharding(mesh, PartitionSpec(MESH_AXIS))`` (split along
    its leading axis), `shared` is replicated. `chunk` (default: one item per device) is
    rounded up to a multiple of the device count and the batch is padded (with copies of
    its last item) to a multiple of `chunk`, so every chunk has one shape and the function
    compiles once (once per device with ``"map"``: a single-device program is compiled for
    its device); a later call with the same `fn` (a module-level function or a hashable
    callable, not a new lambda) and shapes reuses the compiled programs.

    **Returns** a pytree of NumPy arrays with the batch's leading axis, on every process.

    Several hosts (after `jax.distributed.initialize`, `devices` spanning them): every
    process must call `map_sharded` with the same arguments (the same script on every
    host); each computes the shares of the devices it drives and the results are gathered
    with `process_allgather` (`gather_to_host`), so every process returns all of them.
    """
    if not callable(fn):
        raise ValueError(f"`fn` must be a function fn(shared, item), got {type(fn).__name__}")
    devices = resolve_devices(devices)
    n = batch_size_of(batch, "batch")
    n_dev = len(devices)
    chunk = check_int(n_dev if chunk is None else chunk, "chunk", 1)
    progress = check_bool(progress, "progress")
    if desc is not None and not isinstance(desc, str):
        raise ValueError(f"`desc` must be None or a string, got {type(desc).__name__}")
    chunk = -(-chunk // n_dev) * n_dev
    chunk = min(chunk, -(-n // n_dev) * n_dev)
    padded = -(-n // chunk) * chunk

    batch = jax.tree.map(lambda x: pad_leading(np.asarray(x), padded), batch)
    mesh = device_mesh(devices)
    split = NamedSharding(mesh, PartitionSpec(MESH_AXIS))
    per_device = check_per_device(per_device, devices)
    arrays, static = eqx.partition(shared, eqx.is_array)
    mine = _addressable(devices)
    if not mine:
        raise ValueError(
            f"`devices` holds none of the devices of process {jax.process_index()}: every "
            "process must drive at least one of them"
        )

    if per_device == "vmap":
        # `shared` replicated over the devices (over every host's, after
        # `jax.distributed.initialize`: `device_put` of host data to a global sharding)
        replicated = NamedSharding(mesh, PartitionSpec())
        arrays = jax.tree.map(lambda x: jax.device_put(x, replicated), arrays)
    else:
        # a copy of `shared` on each device this process drives
        arrays = {device: jax.device_put(arrays, device) for _, device in mine}

    def run(piece):
        if per_device == "vmap":
            out = _vmap_items(fn, eqx.combine(arrays, static), jax.device_put(piece, split), split)
            return gather_to_host(out)
        # each device maps over its contiguous share of the chunk, called from a thread of
        # its own: XLA:CPU runs a call on the calling thread, so calls from one thread
        # would run the (simulated) devices one after the other. On several hosts a
        # process runs the shares of its own devices only; the per-device results form
        # one global array split along the batch, gathered on every process.
        share = chunk // n_dev

        def one(k, device):
            part = jax.tree.map(lambda x: x[k * share : (k + 1) * share], piece)
            out = _map_items(fn, eqx.combine(arrays[device], static), jax.device_put(part, device))
            return jax.block_until_ready(out)

        outs = list(pool.map(lambda kd: one(*kd), mine))
        treedef = jax.tree.structure(outs[0])
        per_leaf = zip(*(jax.tree.leaves(out) for out in outs), strict=True)
        whole = [
            jax.make_array_from_single_device_arrays((chunk,) + xs[0].shape[1:], split, list(xs))
            for xs in per_leaf
        ]
        return gather_to_host(jax.tree.unflatten(treedef, whole))

    from tqdm.auto import tqdm

    outputs = []
    with ThreadPoolExecutor(max_workers=len(mine)) as pool:
        for start in tqdm(range(0, padded, chunk), desc=desc, disable=not progress, unit="chunk"):
            outputs.append(run(jax.tree.map(lambda x, s=start: x[s : s + chunk], batch)))
    return jax.tree.map(lambda *xs: np.concatenate(xs)[:n], *outputs)


def gather_to_host(tree):
    """NumPy copies of the arrays of `tree` (a pytree), whole, on every process.

    A fully addressable array (one process: always) is copied with `jax.device_get`; an
    array spread over several hosts (after `jax.distributed.initialize`) is gathered with
    `jax.experimental.multihost_utils.process_allgather`, so every process gets the whole
    array. This is a collective: on several hosts, every process must call it. Leaves that
    are not arrays are returned as they are."""

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            from jax.experimental import multihost_utils

            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(jax.device_get(x)) if eqx.is_array(x) else x

    return jax.tree.map(one, tree)


def _addressable(devices: Sequence[jax.Device]) -> list[tuple[int, jax.Device]]:
    """``(position, device)`` of the devices this process drives."""
    here = jax.process_index()
    return [(k, d) for k, d in enumerate(devices) if d.process_index == here]


# --------------------------------------------------------------------------- batches of scenes


def _difference(a, b, path: str, static: bool = False) -> str | None:
    """Where scene `b` differs from scene `a` in what a batch must share (types, static
    fields, array shapes and dtypes), as a readable path, or ``None``."""
    if type(a) is not type(b):
        return f"{path} is a {type(b).__name__}, not a {type(a).__name__}"
    if eqx.is_array(a):
        if np.shape(a) != np.shape(b) or a.dtype != b.dtype:
            return f"{path} has shape {np.shape(b)} ({b.dtype}), not {np.shape(a)} ({a.dtype})"
        return None
    if isinstance(a, eqx.Module):
        for field in dataclasses.fields(a):
            found = _difference(
                getattr(a, field.name),
                getattr(b, field.name),
                f"{path}.{field.name}",
                static=bool(field.metadata.get("static", False)),
            )
            if found:
                return found
        return None
    if isinstance(a, list | tuple) and not static:
        if len(a) != len(b):
            return f"{path} has {len(b)} items, not {len(a)}"
        for k, (u, v) in enumerate(zip(a, b, strict=True)):
            if found := _difference(u, v, f"{path}[{k}]"):
                return found
        return None
    if isinstance(a, int | float) and not isinstance(a, bool) and not static:
        return None  # a Python number as an array leaf
    if a != b:
        return f"{path} is {b!r}, not {a!r}"
    return None


def stack_scenes(scenes: Sequence):
    """One scene whose array leaves hold `scenes` along a new leading axis: the batch
    `render_batch` renders.

    **Arguments:** `scenes`, a non-empty sequence of scenes of one type that share every
    static part (indices of refraction, Fresnel, boundary mode, receiver shape, ...) and
    the shapes of their arrays (heights grid, ...); their array values (heights, extents,
    depths, light directions, screen_distances, ...) may differ.

    **Returns:** a scene of the same type with arrays of shape ``(len(scenes), ...)``.
    Raises a `ValueError` naming the first scene (``scenes[i]``) and field that differ.
    """
    if isinstance(scenes, eqx.Module) or not hasattr(scenes, "__iter__"):
        raise ValueError(f"`scenes` must be a sequence of scenes, got {type(scenes).__name__}")
    scenes = list(scenes)
    if not scenes:
        raise ValueError("`scenes` must hold at least one scene")
    first = scenes[0]
    if not isinstance(first, eqx.Module):
        raise ValueError(f"`scenes` must hold scenes, got a {type(first).__name__}")
    for i, scene in enumerate(scenes[1:], start=1):
        found = _difference(first, scene, "scene")
        # jaxlib ships no types for PyTreeDef (mypy sees an unresolved type)
        if found is None and jax.tree.structure(first) != jax.tree.structure(scene):  # type: ignore[operator]
            found = "its pytree structure differs"
        if found:
            raise ValueError(
                f"`scenes[{i}]` does not match `scenes[0]`: {found} (a batch shares the "
                "type, the static parts and the array shapes of its scenes)"
            )

    def stack(*xs):
        if all(isinstance(x, np.ndarray | float | int) for x in xs):
            return np.stack([np.asarray(x) for x in xs])
        return jnp.stack(xs)

    return jax.tree.map(stack, *scenes)


def unstack_scenes(scenes) -> list:
    """The scenes of a batch made by `stack_scenes`, one by one."""
    n = batch_size_of(scenes)
    return [jax.tree.map(lambda x, i=i: x[i], scenes) for i in range(n)]


def batch_size_of(tree, name: str = "scenes") -> int:
    """The common leading (batch) size of the arrays of `tree`, named `name` in errors."""
    leaves = jax.tree.leaves(tree)
    if not leaves or any(np.ndim(x) == 0 for x in leaves):
        raise ValueError(f"`{name}` must hold arrays, each with a leading batch axis")
    n = int(np.shape(leaves[0])[0])
    if n == 0 or any(np.shape(x)[0] != n for x in leaves):
        raise ValueError(
            f"`{name}` arrays must share a non-empty leading batch axis, got leading sizes "
            f"{sorted({int(np.shape(x)[0]) for x in leaves})}"
        )
    return n


def check_per_device(per_device: str | None, devices: list[jax.Device]) -> str:
    """`per_device` checked, or its default: ``"map"`` on CPU, ``"vmap"`` elsewhere."""
    if per_device is None:
        return "map" if devices[0].platform == "cpu" else "vmap"
    if per_device not in ("map", "vmap"):
        raise ValueError(f"`per_device` must be 'map' or 'vmap', got {per_device!r}")
    return per_device


def pad_leading(x, size: int):
    """`x` (NumPy or JAX) padded along its leading axis to `size` with copies of its last
    item."""
    xp = np if isinstance(x, np.ndarray) else jnp
    return xp.concatenate([x, xp.repeat(x[-1:], size - x.shape[0], axis=0)])


__all__ = ["device_mesh", "map_sharded", "stack_scenes", "unstack_scenes", "gather_to_host"]
