"""Argument checks shared by the whole package: one rule for every public argument.

Every public function checks its arguments for type, finiteness, sign, range and
consistency before anything is compiled or traced, and refuses bad values with a
`ValueError` (a wrong kind of object: `TypeError` where the function documents it)
whose message names the argument. The checks here are the shared ones:

- `check_int`: a whole number (``bool``, floats and strings refused) within a range;
- `check_number`: a finite real number (``bool`` and strings refused) within a range;
- `check_choice`: one of a fixed set of strings;
- `check_bool`: ``True`` or ``False`` (not ``"yes"``, ``0.5`` or an array).

Values that exist only under a JAX transformation (tracers) are checked where the
methods start rendering (`jaxcaustics.scene.checks`), with `equinox.error_if`.

This module imports nothing of the package, so every module can use it.
"""

from __future__ import annotations

import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np


def check_int(value, name: str, low: int = 1, high: int | None = None) -> int:
    """`value` as an int, or a `ValueError` naming `name` unless it is an int in
    ``[low, high]`` (``high=None``: no upper bound). Floats (``2.0`` included), bools and
    strings are refused."""
    whole = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
    if not whole or value < low or (high is not None and value > high):
        bound = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"`{name}` must be an int {bound}, got {value!r}")
    return int(value)


def check_number(
    value,
    name: str,
    *,
    low: float = -math.inf,
    high: float = math.inf,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
) -> float:
    """`value` as a finite float, or a `ValueError` naming `name` unless it is a real
    number (a Python or NumPy scalar, or a 0-d array) within ``[low, high]`` (an open end
    with `low_open` / `high_open`). Bools, strings and complex numbers are refused.
    `unit` (e.g. ``"metres"``) is named in the message."""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if (
        hasattr(value, "shape") and getattr(value, "shape", None) == () and hasattr(value, "item")
    ):  # a 0-d JAX array (concrete)
        try:
            value = value.item()
        except Exception:  # noqa: BLE001 - a tracer: refused below with the name
            pass
    real = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    what = f"a finite number{f' ({unit})' if unit else ''}"
    if not real:
        raise ValueError(f"`{name}` must be {what}, got {value!r}")
    try:
        v = float(value)
    except OverflowError:  # an int beyond float range
        v = math.inf
    if not math.isfinite(v):
        raise ValueError(f"`{name}` must be {what}, got {v}")
    too_low = v < low or (low_open and v == low)
    too_high = v > high or (high_open and v == high)
    if too_low or too_high:
        parts = []
        if math.isfinite(low):
            parts.append(f"{'>' if low_open else '>='} {low:g}")
        if math.isfinite(high):
            parts.append(f"{'<' if high_open else '<='} {high:g}")
        raise ValueError(f"`{name}` must be {' and '.join(parts)}, got {v:g}")
    return v


def check_choice(value, name: str, choices) -> str:
    """`value` if it is one of the strings `choices`, else a `ValueError` naming `name`."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"`{name}` must be one of {tuple(choices)}, got {value!r}")
    return value


def check_bool(value, name: str) -> bool:
    """`value` if it is ``True`` or ``False`` (Python or NumPy), else a `ValueError`."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"`{name}` must be True or False, got {value!r}")
    return bool(value)


# Largest number of elements of a (rows, cols) grid that a builder allocates (2**28: a
# GiB of float32); larger grids are refused before any work (see `check_shape`).
MAX_GRID_ELEMENTS = 1 << 28


def check_real_array(value, name: str) -> np.ndarray:
    """`value` as a NumPy array of real numbers (its own int or float dtype), or a
    `ValueError` naming `name`: strings, bools, complex numbers, ``None``, ragged
    sequences and Python ints too large for an int64 are refused."""
    try:
        arr = np.asarray(value)
    except Exception as err:  # noqa: BLE001 - ragged, traced: re-raised with the name
        raise ValueError(f"`{name}` must be real numbers, got {type(value).__name__}") from err
    if arr.dtype.kind not in "iuf":
        shown = repr(value) if arr.size <= 8 else f"an array of shape {arr.shape}"
        raise ValueError(f"`{name}` must be real numbers, got {shown} (dtype {arr.dtype})")
    return arr


def check_shape(value, name: str, low: int = 1, max_size: int = MAX_GRID_ELEMENTS):
    """`value` as ``(rows, cols)``: two ints (no bools, floats or strings), each
    ``>= low``, ``rows * cols <= max_size``; else a `ValueError` naming `name`."""
    pair = isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim == 1)
    if not pair or len(value) != 2:
        raise ValueError(f"`{name}` must be (rows, cols), got {value!r}")
    rows, cols = (check_int(v, name, low) for v in value)
    if rows * cols > max_size:
        raise ValueError(
            f"`{name}` {(rows, cols)} has {rows * cols} elements, over the limit {max_size}"
        )
    return rows, cols


def check_array(value, name: str, shape: tuple | None = None, *, finite: bool = True):
    """`value` as a floating JAX array (ints are converted to the default float type), or
    a `ValueError` naming `name`: strings, bools, complex numbers and ``None`` are
    refused; `shape` is a pattern, ``None`` an axis of any length and a leading ``...``
    any number of leading axes (``(None, 3)``: ``(P, 3)``; ``(..., 3)``: ``(..., 3)``);
    with `finite` NaN and infinities are refused. A traced value (under `jax.jit`,
    `jax.grad`, `jax.vmap`) is checked for its kind and shape only."""
    arr: jax.Array | np.ndarray
    if isinstance(value, jax.Array):  # concrete or traced
        if value.dtype.kind not in "iuf":
            raise ValueError(f"`{name}` must be real numbers, got dtype {value.dtype}")
        arr = value
    else:
        arr = check_real_array(value, name)
    if shape is not None:
        fixed = shape[1:] if shape[:1] == (...,) else shape
        lead = arr.ndim - len(fixed)
        fits = (lead >= 0 if shape[:1] == (...,) else lead == 0) and all(
            want is None or got == want for got, want in zip(arr.shape[lead:], fixed, strict=False)
        )
        if not fits:
            pattern = ", ".join("..." if s is ... else "n" if s is None else str(s) for s in shape)
            raise ValueError(f"`{name}` must have shape ({pattern}), got {tuple(arr.shape)}")
    if finite and not isinstance(arr, jax.core.Tracer) and not np.all(np.isfinite(arr)):
        raise ValueError(f"`{name}` must be finite, got NaN or infinite values")
    if arr.dtype.kind != "f":
        arr = arr.astype(jnp.result_type(float))
    return jnp.asarray(arr)


def check_broadcast(a, name_a: str, b, name_b: str) -> None:
    """A `ValueError` naming `name_b` unless the shapes of `a` and `b` broadcast."""
    try:
        np.broadcast_shapes(a.shape, b.shape)
    except ValueError as err:
        raise ValueError(f"`{name_b}` {b.shape} must broadcast with `{name_a}` {a.shape}") from err


# --------------------------------------------------------------------------- memory and work

DEFAULT_MEMORY_LIMIT = 1 << 30  # bytes: the photon renderers' default buffer budget (1 GiB)
#: the most photons (rays, samples) one render traces: 2^31, a 46340^2 grid. At the rates
#: measured on a CPU (8192^2 caustic-triangle photons in about 3 minutes) that is hours of
#: work; more is refused before anything is compiled, naming the knob that asks for them
MAX_PHOTONS = 1 << 31
#: the most batches (loop steps, host round trips) one render splits its photons into:
#: more means a `memory_limit` far too small for the photon count
MAX_BATCHES = 1 << 20


def check_memory_limit(memory_limit) -> int:
    """`memory_limit` in bytes (``None``: `DEFAULT_MEMORY_LIMIT`), checked."""
    if memory_limit is None:
        return DEFAULT_MEMORY_LIMIT
    return check_int(memory_limit, "memory_limit", 1)


def check_fits(needed: int, memory_limit: int, what: str, change: str, share: int = 1) -> None:
    """The renderers' memory rule: `needed` bytes (their estimate of `what`, made before
    anything is compiled) must be within ``memory_limit / share`` (the part of the limit
    that goes to it), else a `ValueError` with the estimate, the limit and `change` (the
    knobs that lower it)."""
    if needed * share > memory_limit:
        part = "" if share == 1 else f"1/{share} of "
        raise ValueError(
            f"{what}: an estimated {needed / 2**20:.4g} MiB ({needed} bytes), over {part}"
            f"`memory_limit` ({memory_limit} bytes): {change}, or raise `memory_limit`"
        )


def check_photon_work(photons: int, batches: int, knob: str) -> None:
    """The renderers' work rule: at most `MAX_PHOTONS` photons in at most `MAX_BATCHES`
    batches, else a `ValueError` naming `knob` (the photon count) and, for the batches,
    `memory_limit`."""
    if photons > MAX_PHOTONS:
        raise ValueError(
            f"`{knob}` asks for {photons} photons, over the {MAX_PHOTONS} (2^31, a 46340^2 "
            f"grid) one render traces: pass fewer `{knob}`"
        )
    if batches > MAX_BATCHES:
        raise ValueError(
            f"{photons} photons in batches under `memory_limit` take {batches} batches, over "
            f"{MAX_BATCHES} (2^20): raise `memory_limit` or pass fewer `{knob}`"
        )


# --------------------------------------------------------------------------- renamed keywords
