"""A scene's values checked where they are built: real, finite arrays (possibly traced,
under `jit`: then only what the shapes say is checked)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import check_real_array


def is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def as_float_array(value, name: str) -> Array:
    """`value` (possibly traced) as a float array; strings, bools and complex numbers
    (which would lose their imaginary part) are refused."""
    arr: Any
    if isinstance(value, jax.Array):
        arr = value
        if not any(jnp.issubdtype(arr.dtype, k) for k in (jnp.integer, jnp.floating)):
            raise ValueError(f"`{name}` must be real numbers, got dtype {arr.dtype}")
    else:
        arr = check_real_array(value, name)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = jnp.asarray(arr, dtype=jnp.result_type(float))
    return jnp.asarray(arr)


def check_finite(arr, name: str) -> None:
    if is_concrete(arr) and not bool(np.all(np.isfinite(np.asarray(arr)))):
        raise ValueError(f"`{name}` contains NaN or infinite values")


def check_extent(extent, name: str) -> Array:
    ext = as_float_array(extent, name)
    if ext.shape != (4,):
        raise ValueError(f"`{name}` must be (x_min, x_max, y_min, y_max), got shape {ext.shape}")
    check_finite(ext, name)
    if is_concrete(ext):
        e = np.asarray(ext)
        if not (e[1] > e[0] and e[3] > e[2]):
            raise ValueError(
                f"`{name}` must have x_max > x_min and y_max > y_min, got {e.tolist()}"
            )
        with np.errstate(over="ignore"):
            if not np.all(np.isfinite(e[1::2] - e[0::2])):  # in the extent's own dtype
                raise ValueError(f"`{name}` is too wide for {e.dtype}: {e.tolist()}")
    return ext


def check_positive_scalar(value, name: str) -> Array:
    arr = as_float_array(value, name)
    if arr.shape != ():
        raise ValueError(f"`{name}` must be a scalar, got shape {arr.shape}")
    check_finite(arr, name)
    if is_concrete(arr) and not float(arr) > 0:
        raise ValueError(f"`{name}` must be positive, got {float(arr)}")
    return arr
