"""Procedural water surfaces: animated periodic seas and small test surfaces.

All builders sample at pixel centres of ``extent = (x_min, x_max, y_min, y_max)``
(metres, covering the pixel edges) and return a ``(rows, cols)`` array indexed
``[y, x]`` of heights in metres, ready for `HeightField(heights, extent)`.

- `wave_heights`: a sum of travelling gravity waves, exactly periodic over the extent
  (use ``boundary="periodic"``), animated by `time` with the water-wave dispersion
  relation. Jittable, differentiable in `time` (and `amplitude`, `depth`), vmappable
  over `time`.
- `gaussian_bump`, `sine_sum`: small analytic surfaces for tests and benchmarks.
"""

from __future__ import annotations

import functools
import math
import numbers
import warnings
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_number, check_real_array, check_shape
from .scene import check_extent, is_concrete

__all__ = ["GRAVITY", "gaussian_bump", "sine_sum", "wave_heights"]

GRAVITY = 9.81
"""Standard gravity, m/s^2, used by the dispersion relation of `wave_heights`."""

# Above this many candidate wave vectors `wavelength_range` is too wide for the extent.
_MAX_CANDIDATES = 4_000_000


def _concrete_extent(extent) -> tuple[float, float, float, float]:
    """The extent as Python floats; it fixes the wave vectors, so it cannot be traced."""
    if isinstance(extent, jax.core.Tracer):
        raise ValueError(
            "`extent` must be concrete (not traced): it fixes the wave numbers; close over "
            "it or mark it static instead of passing it through jax.jit / jax.vmap"
        )
    ext = check_real_array(extent, "extent").astype(np.float64)
    if ext.shape != (4,):
        raise ValueError(f"`extent` must be (x_min, x_max, y_min, y_max), got shape {ext.shape}")
    if not np.all(np.isfinite(ext)):
        raise ValueError(f"`extent` contains NaN or infinite values: {ext.tolist()}")
    if not (ext[1] > ext[0] and ext[3] > ext[2]):
        raise ValueError(f"`extent` must have x_max > x_min and y_max > y_min, got {ext.tolist()}")
    return tuple(float(v) for v in ext)  # type: ignore[return-value]


def _pixel_centres_unit(n: int) -> np.ndarray:
    """Pixel-centre positions as fractions of the extent, float64, shape (n,)."""
    return (np.arange(n, dtype=np.float64) + 0.5) / n


def _cycles(lo: float, hi: float, n: int, waves: np.ndarray) -> np.ndarray:
    """``waves * x / L`` modulo 1 at the pixel centres x of ``[lo, hi]`` (``L = hi - lo``),
    in float64: the spatial phase of waves with integer numbers of periods over ``L``, in
    turns, shape (n, len(waves)). Absolute coordinates, so the pattern tiles the plane."""
    frac = lo / (hi - lo) + _pixel_centres_unit(n)
    return np.mod(np.outer(frac, waves), 1.0)


def _scalar(
    value, name: str, *, minimum: float | None = None, strict: bool = False, allow_inf: bool = False
) -> Array:
    """A float scalar (possibly traced); checked when concrete, also for fitting the
    float dtype it is computed in."""
    if not is_concrete(value):
        if jnp.ndim(value) != 0:
            raise ValueError(f"`{name}` must be a scalar, got shape {jnp.shape(value)}")
        return jnp.asarray(value, dtype=jnp.result_type(float, value))
    arr = check_real_array(value, name)
    if arr.ndim != 0:
        raise ValueError(f"`{name}` must be a scalar, got shape {arr.shape}")
    v = float(arr)
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ValueError(f"`{name}` must be finite, got {v}")
    if minimum is not None and (v <= minimum if strict else v < minimum):
        op = ">" if strict else ">="
        raise ValueError(f"`{name}` must be {op} {minimum}, got {v}")
    dtype = jnp.result_type(float, value)
    with np.errstate(over="ignore"):
        if math.isfinite(v) and not np.isfinite(np.asarray(v, dtype)):
            raise ValueError(f"`{name}` {v} overflows {dtype}")
    return jnp.asarray(value, dtype=dtype)


def _float_dtype(*values) -> np.dtype:
    return jnp.result_type(float, *values)


# --------------------------------------------------------------------------- waves


@functools.lru_cache(maxsize=64)  # eager animation loops redraw the same waves per frame
def _draw_waves(
    extent: tuple[float, float, float, float],
    num_waves: int,
    wavelength_range: tuple[float, float],
    direction: float,
    direction_spread: float,
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Integer wave vectors (m, n), their |k| (rad/m), amplitudes and phases (NumPy;
    cached, so the arrays must not be modified)."""
    lx, ly = extent[1] - extent[0], extent[3] - extent[2]
    lam_min, lam_max = wavelength_range
    # (1 + 1e-9): a wavelength equal to the minimum up to rounding is a candidate.
    m_max = math.floor(lx / lam_min * (1 + 1e-9))
    n_max = math.floor(ly / lam_min * (1 + 1e-9))
    if (2 * m_max + 1) * (n_max + 1) > _MAX_CANDIDATES:
        raise ValueError(
            f"`wavelength_range` minimum {lam_min} m is too short for the `extent` "
            f"{lx} x {ly} m (over {_MAX_CANDIDATES} candidate wave vectors)"
        )
    # One representative of each pair {k, -k} (the upper half-plane), so that no two
    # waves share a spatial frequency: they stay orthogonal and the RMS is exact.
    m_grid, n_grid = np.meshgrid(
        np.arange(-m_max, m_max + 1), np.arange(0, n_max + 1), indexing="ij"
    )
    m, n = m_grid.ravel(), n_grid.ravel()
    keep = (n > 0) | (m > 0)
    m, n = m[keep], n[keep]
    kx, ky = 2 * np.pi * m / lx, 2 * np.pi * n / ly
    k = np.hypot(kx, ky)
    wavelength = 2 * np.pi / k
    # Tolerances: wavelengths that equal a range end up to rounding are inside.
    in_range = (wavelength >= lam_min * (1 - 1e-9)) & (wavelength <= lam_max * (1 + 1e-9))
    # Which of the two travel directions, +k or -k, lie within the spread.
    angle = np.arctan2(ky, kx)
    d_plus = np.abs((angle - direction + np.pi) % (2 * np.pi) - np.pi)
    d_minus = np.pi - d_plus
    tol = 1e-12
    plus_ok = d_plus <= direction_spread + tol
    minus_ok = d_minus <= direction_spread + tol
    n_dirs = plus_ok.astype(np.int64) + minus_ok.astype(np.int64)
    ok = in_range & (n_dirs > 0)
    if ok.sum() < num_waves:
        raise ValueError(
            f"`num_waves` = {num_waves} exceeds the {int(ok.sum())} periodic wave vectors "
            f"with wavelengths in {tuple(wavelength_range)} m travelling within "
            f"{direction_spread:.3g} rad of the direction {direction:.3g} rad over this "
            "extent; widen `wavelength_range` or `direction_spread`, or use fewer waves"
        )
    idx = np.flatnonzero(ok)
    rng = np.random.default_rng(seed)
    # Sampling weight k^-2 per lattice point (log-uniform in |k|) times the number of
    # allowed directions; amplitudes ~ 1/k: the expected height spectrum falls as k^-4
    # (the tail of the Phillips spectrum), so long, smooth waves dominate.
    weight = n_dirs[idx] / k[idx] ** 2
    chosen = rng.choice(idx, size=num_waves, replace=False, p=weight / weight.sum())
    # Travel direction: +k or -k, at random among those inside the spread.
    flip = np.where(
        plus_ok[chosen] & minus_ok[chosen],
        rng.random(num_waves) < 0.5,
        ~plus_ok[chosen],
    )
    sign = np.where(flip, -1, 1)
    mn = np.stack([sign * m[chosen], sign * n[chosen]], axis=-1)
    amp = rng.rayleigh(scale=1.0, size=num_waves) / k[chosen]
    phase = rng.uniform(0.0, 2 * np.pi, size=num_waves)
    return mn, k[chosen], amp, phase


def wave_heights(
    shape: Sequence[int],
    extent,
    time=0.0,
    *,
    amplitude=0.02,
    num_waves: int = 24,
    wavelength_range: tuple[float, float] | None = None,
    depth=1.0,
    direction: float = 0.0,
    direction_spread: float = math.pi / 3,
    seed: int = 0,
) -> Float[Array, "rows cols"]:
    """An animated, periodic sea: a sum of travelling sinusoidal gravity waves.

    ``h(x, y, t) = sum_i a_i cos(k_i . (x, y) - omega_i t + phi_i)``, sampled at
    pixel centres. Each wave vector is an integer multiple of
    ``(2 pi / Lx, 2 pi / Ly)`` (``Lx, Ly`` the extent's size), so the surface tiles the
    plane with period ``extent`` at every time: use it with ``boundary="periodic"``.
    Angular frequencies follow the dispersion relation of gravity waves on water of
    depth `depth`, ``omega^2 = g |k| tanh(|k| depth)`` (``g = 9.81 m/s^2``), so animating
    `time` gives a plausible moving sea (long waves travel faster).

    The waves are drawn from `seed` with NumPy (the same seed always gives the same
    sea, at any resolution): distinct wave vectors, no two of them opposite, with
    wavelengths in `wavelength_range` and travel directions within `direction_spread`
    of `direction`; long waves are favoured (expected height spectrum falling as
    ``|k|^-4``), amplitudes are Rayleigh-distributed and phases uniform. The heights are
    scaled so that their RMS (over a period) is exactly `amplitude`; on the pixel grid
    too, as long as every wave is below the grid's Nyquist frequency.

    Jittable and differentiable with respect to `time`, `amplitude` and `depth`, and
    vmappable over `time`; everything else fixes the wave set and must be concrete
    (``shape``, ``num_waves``, ``seed``, ... are static; close over `extent`).

    **Arguments:**

    - `shape`: ``(rows, cols)`` of the output, two ints.
    - `extent`: ``(x_min, x_max, y_min, y_max)``, metres, covering the pixel edges; also
      the period of the surface.
    - `time`: seconds, a float or scalar array; default 0.0. A scalar: use `jax.vmap` for
      several times.
    - `amplitude`: RMS height, metres (a float, >= 0); default 0.02.
    - `num_waves`: number of waves (an int, >= 1); default 24.
    - `wavelength_range`: optional ``(min, max)`` wavelengths in metres, two floats.
      Default ``(min(Lx, Ly) / 8, max(Lx, Ly))``; on a square extent, 32 pixels a side then
      give at least 4 samples per wavelength.
    - `depth`: water depth for the dispersion relation, metres (a float, > 0; ``inf`` for
      deep water); default 1.0. Match the scene's ``rest_depth``.
    - `direction`: mean direction of travel, radians from +x towards +y (a float); default
      0.0.
    - `direction_spread`: largest angle between a wave's direction of travel and
      `direction`, radians (a float), in ``(0, pi]``: small for a swell, ``pi`` for waves
      in every direction; default ``pi / 3``.
    - `seed`: non-negative int seed for the wave set; default 0.

    **Returns:** a `jax.Array` of shape ``(rows, cols)``: heights in metres about the rest
    level (zero mean), indexed ``[y, x]``; float32, or float64 when x64 is enabled.

    **Raises:** `ValueError` for a bad argument (named in the message), or when fewer than
    `num_waves` periodic wave vectors fit `wavelength_range` and `direction_spread`.

    **Warns:** `UserWarning` when a wave is at or above the grid's Nyquist frequency (it
    aliases).

    ```pycon
    >>> extent = (0.0, 2.0, 0.0, 1.5)  # metres
    >>> h = jc.wave_heights((150, 200), extent, amplitude=0.002, depth=0.5)
    >>> h.shape
    (150, 200)
    >>> round(float(h.std()), 4), abs(float(h.mean())) < 1e-6  # RMS 2 mm, zero mean
    (0.002, True)
    >>> frames = jax.vmap(lambda t: jc.wave_heights((32, 32), extent, time=t))(
    ...     jnp.linspace(0.0, 1.0, 5)
    ... )
    >>> frames.shape  # five moments of the same sea
    (5, 32, 32)

    ```
    """
    rows, cols = check_shape(shape, "shape")
    ext = _concrete_extent(extent)
    lx, ly = ext[1] - ext[0], ext[3] - ext[2]
    if isinstance(num_waves, bool) or not isinstance(num_waves, numbers.Integral):
        raise ValueError(f"`num_waves` must be an int, got {num_waves!r}")
    if num_waves < 1:
        raise ValueError(f"`num_waves` must be >= 1, got {num_waves}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"`seed` must be a non-negative int, got {seed!r}")
    if wavelength_range is None:
        lam = (min(lx, ly) / 8.0, max(lx, ly))
    else:
        lam_arr = check_real_array(wavelength_range, "wavelength_range")
        lam = tuple(float(v) for v in lam_arr.ravel())
        if lam_arr.shape != (2,) or not all(math.isfinite(v) and v > 0 for v in lam):
            raise ValueError(
                f"`wavelength_range` must be two finite positive lengths, got {wavelength_range!r}"
            )
        if lam[0] > lam[1]:
            raise ValueError(f"`wavelength_range` must be (min, max) with min <= max, got {lam}")
    direction = check_number(direction, "direction")
    direction_spread = check_number(
        direction_spread, "direction_spread", low=0.0, high=math.pi, low_open=True
    )
    amplitude = _scalar(amplitude, "amplitude", minimum=0.0)
    depth = _scalar(depth, "depth", minimum=0.0, strict=True, allow_inf=True)
    time = _scalar(time, "time")

    mn, k, amp, phase = _draw_waves(
        ext, int(num_waves), lam, direction, direction_spread, int(seed)
    )
    if np.any(2 * np.abs(mn[:, 0]) >= cols) or np.any(2 * np.abs(mn[:, 1]) >= rows):
        warnings.warn(
            f"wave_heights: some waves (the shortest is {2 * np.pi / k.max():.3g} m) are "
            f"not resolved by shape {(rows, cols)} over the extent (aliasing); use more "
            "pixels or a larger `wavelength_range` minimum",
            stacklevel=2,
        )
    amp = amp / math.sqrt(0.5 * float(np.sum(amp**2)))  # unit RMS

    dtype = _float_dtype(time, amplitude, depth)
    # Spatial phases, exact in float64 (mod 2 pi) from integer wave numbers, then split
    # cos(px + py + theta) = cos(py) cos(px + theta) - sin(py) sin(px + theta).
    px = 2 * np.pi * _cycles(ext[0], ext[1], cols, mn[:, 0])  # (cols, W)
    py = 2 * np.pi * _cycles(ext[2], ext[3], rows, mn[:, 1])  # (rows, W)
    cx, sx = jnp.asarray(np.cos(px), dtype), jnp.asarray(np.sin(px), dtype)
    cy_a = jnp.asarray(np.cos(py) * amp, dtype)
    sy_a = jnp.asarray(np.sin(py) * amp, dtype)

    deep = is_concrete(depth) and math.isinf(float(depth))
    return _sum_waves(
        cx,
        sx,
        cy_a,
        sy_a,
        jnp.asarray(k, dtype),
        jnp.asarray(phase, dtype),
        amplitude.astype(dtype),
        depth.astype(dtype),
        time.astype(dtype),
        deep=deep,
    )


@functools.partial(jax.jit, static_argnames=("deep",))
def _sum_waves(cx, sx, cy_a, sy_a, k, phase, amplitude, depth, time, *, deep: bool):
    """The traced part of `wave_heights` (jitted so that eager calls compile once)."""
    tanh_kd = jnp.ones_like(k) if deep else jnp.tanh(k * depth)
    omega = jnp.sqrt(GRAVITY * k * tanh_kd)
    theta = phase - omega * time  # (W,)
    c_t, s_t = jnp.cos(theta), jnp.sin(theta)
    u = cx * c_t - sx * s_t  # cos(px + theta), (cols, W)
    v = sx * c_t + cx * s_t  # sin(px + theta)
    hp = jax.lax.Precision.HIGHEST  # no TF32 / bf16 passes on GPUs
    heights = jnp.matmul(cy_a, u.T, precision=hp) - jnp.matmul(sy_a, v.T, precision=hp)
    return amplitude * heights


# --------------------------------------------------------------------------- test surfaces


def _extent_array(extent) -> Array:
    """The extent as a float array, possibly traced (checked fully when concrete)."""
    return check_extent(extent, "extent")


def gaussian_bump(
    shape: Sequence[int],
    extent,
    *,
    center=None,
    sigma,
    amplitude,
) -> Float[Array, "rows cols"]:
    """A Gaussian bump ``amplitude * exp(-|p - center|^2 / (2 sigma^2))``.

    **Arguments:**

    - `shape`: ``(rows, cols)`` of the output, two ints.
    - `extent`: ``(x_min, x_max, y_min, y_max)``, metres, covering the pixel edges.
    - `center`: optional ``(x, y)`` of the peak, two floats, metres; default the centre of
      the extent.
    - `sigma`: standard deviation, metres (a float, > 0).
    - `amplitude`: peak height, metres (a float; negative for a dip).

    **Returns:** a `jax.Array` of shape ``(rows, cols)``: heights in metres at pixel
    centres, indexed ``[y, x]``. Differentiable with respect to `center`, `sigma`,
    `amplitude` and `extent`.
    """
    shape = check_shape(shape, "shape")
    ext = _extent_array(extent)
    sigma = _scalar(sigma, "sigma", minimum=0.0, strict=True)
    amplitude = _scalar(amplitude, "amplitude")
    if center is None:
        c = 0.5 * (ext[0::2] + ext[1::2])  # (x, y) of the extent's centre
    else:
        if not isinstance(center, jax.Array):  # a tracer is checked for shape only
            center = check_real_array(center, "center")
        c = jnp.asarray(center)
        if c.shape != (2,):
            raise ValueError(f"`center` must be (x, y), got shape {c.shape}")
        if is_concrete(c) and not bool(np.all(np.isfinite(np.asarray(c)))):
            raise ValueError(f"`center` must be finite, got {np.asarray(c).tolist()}")
    dtype = _float_dtype(ext, c, sigma, amplitude)
    return _gaussian(ext.astype(dtype), c.astype(dtype), sigma, amplitude, shape=shape)


@functools.partial(jax.jit, static_argnames=("shape",))
def _gaussian(ext, center, sigma, amplitude, *, shape):
    rows, cols = shape
    ux = jnp.asarray(_pixel_centres_unit(cols), ext.dtype)[None, :]
    uy = jnp.asarray(_pixel_centres_unit(rows), ext.dtype)[:, None]
    x = ext[0] + ux * (ext[1] - ext[0])
    y = ext[2] + uy * (ext[3] - ext[2])
    r2 = (x - center[0]) ** 2 + (y - center[1]) ** 2
    return amplitude * jnp.exp(-r2 / (2 * sigma**2))


def sine_sum(
    shape: Sequence[int],
    extent,
    *,
    terms: Sequence[tuple[int, int, float, float]],
) -> Float[Array, "rows cols"]:
    """A sum of plane sine waves, periodic over the extent.

    ``h(x, y) = sum a * sin(2 pi (kx x / Lx + ky y / Ly) + phase)`` at the pixel centres
    ``(x, y)`` (absolute coordinates, metres), ``Lx, Ly`` the size of the extent: the
    surface tiles the plane with period ``extent``.

    **Arguments:**

    - `shape`: ``(rows, cols)`` of the output (two ints).
    - `extent`: ``(x_min, x_max, y_min, y_max)``, metres, covering the pixel edges; the
      period of the surface. Concrete (static).
    - `terms`: a sequence of ``(kx, ky, amplitude, phase)``, at least one: `kx`, `ky`:
      integer numbers of periods across the extent in x and y (static); `amplitude`:
      metres; `phase`: radians (these two may be traced).

    **Returns:** the heights, metres, a ``(rows, cols)`` array indexed ``[y, x]``.
    """
    rows, cols = check_shape(shape, "shape")
    ext = _concrete_extent(extent)
    try:
        terms = [tuple(t) for t in terms]  # type: ignore[misc]
    except TypeError as err:
        raise ValueError(
            f"`terms` must be a sequence of (kx, ky, amplitude, phase), got {terms!r}"
        ) from err
    if not terms:
        raise ValueError("`terms` must hold at least one (kx, ky, amplitude, phase)")
    parsed: list[tuple[Any, ...]] = []
    for i, t in enumerate(terms):
        if len(t) != 4:
            raise ValueError(f"`terms[{i}]` must be (kx, ky, amplitude, phase), got {t!r}")
        kx, ky, a, ph = t
        ints = []
        for name, kval in (("kx", kx), ("ky", ky)):
            if not is_concrete(kval):
                raise ValueError(f"`terms[{i}]` {name} must be a concrete int, not traced")
            try:
                kf = float(check_real_array(kval, "terms"))  # no strings, bools, arrays
            except (ValueError, TypeError):
                kf = math.nan
            if not (math.isfinite(kf) and kf == round(kf) and abs(kf) <= 2**31):
                raise ValueError(
                    f"`terms[{i}]` {name} must be an integer number of periods, got {kval!r}"
                )
            ints.append(int(round(kf)))
        parsed.append(
            (*ints, _scalar(a, f"terms[{i}] amplitude"), _scalar(ph, f"terms[{i}] phase"))
        )
    dtype = _float_dtype(*(p[2] for p in parsed), *(p[3] for p in parsed))
    out = jnp.zeros((rows, cols), dtype)
    for kx, ky, a, ph in parsed:
        # Exact spatial phase in float64 (turns, modulo 1), then the traced part.
        turns = np.mod(
            _cycles(ext[2], ext[3], rows, np.array([ky]))
            + _cycles(ext[0], ext[1], cols, np.array([kx])).T,
            1.0,
        )
        out = out + a * jnp.sin(jnp.asarray(2 * np.pi * turns, dtype) + ph)
    return out
