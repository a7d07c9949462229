"""Yuksel & Keyser's two-pass caustics for height-field water over a flat ground.

C. Yuksel, J. Keyser, "Fast Real-time Caustics from Height Fields" (2009).

For every caustic-map pixel ``P_G`` the method gathers the light refracted through a
window of the water surface around the pixel's *illumination centre*
``P_C = P_G + h L'`` (``L'``: the light refracted by the flat rest surface, ``h``: the
rest depth). It runs as

- a **pre-pass**: one light sample per caustic-map pixel, spaced by the pixel size on
  the rest plane around the illumination centres; each sample's ray is intersected with
  the moving surface (a few Newton steps, `hit_iterations`), refracted, and landed on
  the ground;
- **pass 1**: for every pixel, the `samples_x` (N) samples along ``x`` around its
  illumination centre deposit pixel-sized squares (tent overlaps; with ``S x S``
  samples per pixel, squares ``1/S`` pixel on a side) into ``M + 1``
  channels, one per neighbouring pixel along ``y``;
- **pass 2**: the sum along ``y`` of the channels that belong to each pixel.

Passes 1 and 2 cost ``N x (M + 1)`` products per pixel; a wide window (``"auto"``
under grazing light) takes the same sums the other way round instead (`splat_window`:
each sample adds its square to the at most 2 x 2 pixels it overlaps, dropping what lands
beyond its window), which costs the same whatever the window. The pre-pass runs in
blocks of rows (`SAMPLES_PER_BLOCK`).

The window only sees light that lands within about ``N/2`` pixels (``x``) and ``M/2``
pixels (``y``) of the illumination centre; what falls outside is reported as the
missed-flux fraction, and ``samples_x="auto"`` picks the window from the largest
displacement so nothing is silently lost.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_fits, check_int, check_memory_limit
from ..scene.checks import checks_scene_values
from ..scene.scene import WaterScene
from ..scene.surface import MAX_HIT_ITERATIONS, PaddedField, ray_surface_hit
from ..trace.optics import fresnel_transmittance, refract, refract_components, tir_possible
from .base import Method, channels_last

# Largest automatic window (pixels on each side); beyond it the method is the wrong tool.
MAX_AUTO_HALF_WINDOW = 32
# memory model, numbers of the scene's dtype per pre-pass sample of the padded grid and
# per gathered partial (XLA's compiled temporaries on CPU: 24-26 per sample for windows
# up to 15 x 15, up to 87 for 63 x 63, which the partials term bounds)
_SAMPLE_FLOATS = 32


def _overlap(u: Array, width: float) -> Array:
    """Fraction of an interval `width` pixels long (at most 1) centred ``u`` pixels from
    a pixel's centre that falls on the pixel: a trapezoid in ``u`` (the tent of two unit
    intervals for ``width = 1``)."""
    return jnp.clip((0.5 * (1.0 + width) - jnp.abs(u)) / width, 0.0, 1.0)


def _window_fraction(u: Array, half: int, width: float) -> Array:
    """Fraction of an interval `width` pixels long centred at ``u`` that falls on the
    ``2 half + 1`` pixels around ``u = 0``."""
    return jnp.clip((half + 0.5 * (1.0 + width) - jnp.abs(u)) / width, 0.0, 1.0)


class PrePass(eqx.Module):
    """Ground hits of the pre-pass samples (``S x S`` per caustic-map pixel, padded).

    Shapes are ``(channels, S * S, rows + M, cols + N - 1)``: for each of the ``S * S``
    sub-pixel phases, the padded grid of one sample per pixel.

    - `shift_x`, `shift_y`: where each sample lands, relative to the centre of the
      pixel it starts from (the pixel it lands on under flat water), in pixels.
    - `flux`: relative flux carried (1 for flat water with Fresnel off; Fresnel
      transmittance when on; 0 where total internal reflection loses it).
    """

    shift_x: Float[Array, "channels phases rows cols"]
    shift_y: Float[Array, "channels phases rows cols"]
    flux: Float[Array, "channels phases rows cols"]


SAMPLES_PER_BLOCK = 1 << 15
"""The pre-pass traces its samples in blocks of about this many (whole rows of the
padded grid, a `lax.map` over the blocks): the temporaries of one block are reused
block after block instead of being allocated (and page-faulted in) anew for the whole
grid on every render. At 800 x 600 pixels with 3 Newton steps one unblocked pre-pass
spent about half its time faulting in fresh memory. Forward / gradient of the pre-pass
and gather, ms, at 800 x 600 pixels: blocks of 2^15 samples 20.7 / 71, 2^17 28 / 80,
unblocked 37 / 105 (before `_bicubic_linear`); at 400 x 300 (124k samples) blocks of
2^15 5.4 / 16, unblocked 4.6 / 25 (with `_bicubic_linear`, whose reverse pass is slower
on large arrays)."""

SPLAT_FROM_WINDOW = 100
"""Windows of at least this many pixels (``N x (M + 1)``) are summed by `splat_window`,
smaller ones by `gather_window` (the same image). Measured at 800 x 600 pixels, forward
/ gradient of the sums, ms: 7 x 7 gather 5.0 / 7.1, splat 4.1 / 21.3; 11 x 11 gather
10.6 / 17.7, splat 3.8 / 18.0; 21 x 19 gather 39 / 200, splat 4.5 / 27."""


def _prepass_rows(
    scene: WaterScene, field: PaddedField, gx: Array, gy: Array, iterations: int, supersample: int
):
    """The pre-pass of the sample rows `gy` (pixel centres, metres, ``(B,)``) and columns
    `gx` (``(W,)``): ``(shift_x, shift_y, flux)``, each ``(channels, S * S, B, W)``;
    `field`: the scene's surface, padded once for all blocks."""
    px, py = scene.receiver.pixel_size
    dtype = scene.surface.heights.dtype
    phase = (jnp.arange(supersample, dtype=dtype) + 0.5) / supersample - 0.5
    phase_y, phase_x = (p.reshape(-1, 1, 1) for p in jnp.meshgrid(phase, phase, indexing="ij"))
    gx, gy = jnp.meshgrid(gx, gy)  # pixel centres (B, W)
    sample_x, sample_y = gx + phase_x * px, gy + phase_y * py  # (S * S, B, W)
    d = scene.light.unit_direction.astype(dtype)
    up = jnp.array([0.0, 0.0, 1.0], dtype=dtype)

    shifts_x, shifts_y, fluxes = [], [], []
    for ior in scene.iors:
        eta = 1.0 / ior
        # illumination centres: where flat water sends light to the pixel centres
        flat_t, _ = refract(d, up, eta)
        offset = scene.rest_depth / flat_t[2]
        cx, cy = sample_x + offset * flat_t[0], sample_y + offset * flat_t[1]

        hit_x, hit_y, hit_z, hx, hy = ray_surface_hit(
            field, scene.rest_depth, cx, cy, (d[0], d[1], d[2]), iterations
        )
        inv_norm = jax.lax.rsqrt(1.0 + hx * hx + hy * hy)
        normal = (-hx * inv_norm, -hy * inv_norm, inv_norm)
        t_dir, tir, cos_i = refract_components((d[0], d[1], d[2]), normal, eta)
        going_down = t_dir[2] < 0.0
        valid = going_down & (hit_z > 0.0)  # a trough below the ground casts nothing
        if tir_possible(eta):  # water of index < 1 (traced only there)
            valid = valid & ~tir
        s = hit_z / -jnp.where(going_down, t_dir[2], -1.0)
        ground_x = hit_x + s * t_dir[0]
        ground_y = hit_y + s * t_dir[1]
        flux = valid.astype(dtype)
        if scene.fresnel:
            flux = flux * fresnel_transmittance(cos_i, eta)
        shifts_x.append(jnp.where(valid, (ground_x - gx) / px, 0.0))
        shifts_y.append(jnp.where(valid, (ground_y - gy) / py, 0.0))
        fluxes.append(flux)
    return jnp.stack(shifts_x), jnp.stack(shifts_y), jnp.stack(fluxes)


def prepass(
    scene: WaterScene, half_x: int, half_y: int, iterations: int, supersample: int = 1
) -> PrePass:
    """Trace ``S x S`` samples per caustic-map pixel (padded by the window) to the ground,
    in blocks of rows (`SAMPLES_PER_BLOCK`)."""
    rows, cols = scene.receiver.shape
    x0, _, y0, _ = scene.receiver.extent
    px, py = scene.receiver.pixel_size
    dtype = scene.surface.heights.dtype
    gx = x0 + (jnp.arange(-half_x, cols + half_x, dtype=dtype) + 0.5) * px
    padded_rows = rows + 2 * half_y
    row_samples = supersample * supersample * gx.shape[0]
    block = max(1, SAMPLES_PER_BLOCK // row_samples)
    blocks = -(-padded_rows // block)
    field = PaddedField.of(scene.surface)
    if blocks == 1:
        gy = y0 + (jnp.arange(-half_y, rows + half_y, dtype=dtype) + 0.5) * py
        return PrePass(*_prepass_rows(scene, field, gx, gy, iterations, supersample))
    # the last block runs on past the grid; its extra rows are dropped
    gy = y0 + (jnp.arange(-half_y, blocks * block - half_y, dtype=dtype) + 0.5) * py
    # checkpointed: the reverse pass traces each block again rather than storing its
    # temporaries (stored, their copies into the stacked residuals cost more than that)
    parts = jax.lax.map(
        jax.checkpoint(lambda g: _prepass_rows(scene, field, gx, g, iterations, supersample)),
        gy.reshape(blocks, block),
    )
    # (blocks, channels, S * S, block, W) -> (channels, S * S, padded rows, W)
    return PrePass(
        *(
            jnp.moveaxis(p, 0, 2).reshape(p.shape[1:3] + (-1, p.shape[-1]))[:, :, :padded_rows]
            for p in parts
        )
    )


def _overlap_slope(u: Array, width: float) -> Array:
    """Derivative of `_overlap` in ``u``; at its kinks (``|u| = (1 - width) / 2`` and
    ``(1 + width) / 2``) the derivative from the right, the same for every sample, so
    that at flat water (every shift a sub-sample's phase) the light one pixel loses
    another gains and the gradient is the directional derivative for increasing shifts
    (a symmetric choice gave a zero gradient there)."""
    inner, outer = 0.5 * (1.0 - width), 0.5 * (1.0 + width)
    slope = 1.0 / width
    falling = (u >= inner) & (u < outer)
    rising = (u >= -outer) & (u < -inner)
    return jnp.where(falling, -slope, jnp.where(rising, slope, 0.0))


def _pass1(
    shift_x: Array, shift_y: Array, flux: Array, half_x: int, half_y: int, width: float
) -> Array:
    """Pass 1 for one channel: ``(M + 1, rows + M, cols)`` partial sums.

    Channel ``k`` of row ``r`` holds the light that the ``N`` samples of row ``r``
    around each column send to the pixel ``k - M/2`` rows away. A rolled loop over the
    window's ``N`` columns, its ``M + 1`` channels at once: unrolled, the 65 x 64
    window of a 48 x 64-pixel sea compiled in 21 s and rendered in 27 ms (rolled: 0.6 s
    and 12 ms); the paper's 7 x 7 on 800 x 600 pixels renders about 10% slower rolled
    (38-39 ms against 34-36 ms, the pre-pass being most of it).
    """
    cols = shift_x.shape[1] - 2 * half_x
    offsets = (jnp.arange(2 * half_y + 1) - half_y).astype(shift_y.dtype)[:, None, None]

    def column(i, out):  # the samples i - N/2 columns from each pixel's
        sx, sy, f = (jax.lax.dynamic_slice_in_dim(a, i, cols, 1) for a in (shift_x, shift_y, flux))
        wx = f * _overlap(sx + (i - half_x).astype(sx.dtype), width)
        return out + wx[None] * _overlap(sy[None] - offsets, width)

    out = jnp.zeros((2 * half_y + 1, shift_x.shape[0], cols), shift_x.dtype)
    return jax.lax.fori_loop(0, 2 * half_x + 1, column, out)


def _pass2(partial: Array, half_y: int) -> Array:
    """Pass 2: each pixel sums its ``M + 1`` channels from the rows they came from."""
    rows = partial.shape[1] - 2 * half_y
    image = jnp.zeros((rows, partial.shape[2]), partial.dtype)
    for k in range(2 * half_y + 1):
        dy = k - half_y
        image = image + partial[k, half_y - dy : half_y - dy + rows]
    return image


@functools.partial(jax.custom_jvp, nondiff_argnums=(3, 4, 5))
def _gather_window(shift_x, shift_y, flux, half_x: int, half_y: int, width: float) -> Array:
    return _pass2(_pass1(shift_x, shift_y, flux, half_x, half_y, width), half_y)


@_gather_window.defjvp
def _gather_window_jvp(half_x, half_y, width, primals, tangents):
    """The same window sums with the tents' slopes, written so that each term is
    *padded* onto a common grid and cropped once: JAX transposes a pad into a slice, so
    the reverse pass gathers from the cotangent image instead of padding 49 arrays."""
    shift_x, shift_y, flux = primals
    t_x, t_y, t_f = tangents
    rows, cols = shift_x.shape[0] - 2 * half_y, shift_x.shape[1] - 2 * half_x
    total = jnp.zeros((rows + 4 * half_y, cols + 4 * half_x), shift_x.dtype)
    for dx in range(-half_x, half_x + 1):
        ux = shift_x + dx
        wx = flux * _overlap(ux, width)
        t_wx = t_f * _overlap(ux, width) + flux * _overlap_slope(ux, width) * t_x
        for dy in range(-half_y, half_y + 1):
            uy = shift_y - dy
            term = t_wx * _overlap(uy, width) + wx * _overlap_slope(uy, width) * t_y
            # sample (r, c) reaches pixel (r - M/2 + dy, c - N/2 - dx)
            pads = ((half_y + dy, half_y - dy), (half_x - dx, half_x + dx))
            total = total + jnp.pad(term, pads)
    tangent = total[2 * half_y : 2 * half_y + rows, 2 * half_x : 2 * half_x + cols]
    return _gather_window(*primals, half_x, half_y, width), tangent


@functools.partial(jax.checkpoint, static_argnums=(3, 4, 5))
def gather_window(shift_x, shift_y, flux, half_x: int, half_y: int, width: float) -> Array:
    """Passes 1 and 2: the irradiance image ``(rows, cols)`` from the pre-pass samples.

    Sample ``(r, c)`` of the padded grid ``(rows + M, cols + N - 1)`` deposits a square
    `width` pixels on a side (the fraction of it on each pixel: `_overlap`) centred
    ``(shift_x, shift_y)`` pixels from the centre of pixel ``(r - M/2, c - N/2)``, onto
    the pixels of its window. Derivatives
    (forward and reverse) are hand-written and recomputed in the reverse pass
    (`jax.checkpoint`) rather than stored, which keeps the gradient cheap.
    """
    return _gather_window(shift_x, shift_y, flux, half_x, half_y, width)


def _splatted(half_x: int, half_y: int) -> bool:
    """Whether a window of half widths ``(N // 2, M // 2)`` is summed by `splat_window`
    (``N x (M + 1)`` at least `SPLAT_FROM_WINDOW`) rather than `gather_window`."""
    return (2 * half_x + 1) * (2 * half_y + 1) >= SPLAT_FROM_WINDOW


def _reach(shift: Array, half: int, width: float):
    """Along one axis, the two pixels a sample's square (`width` pixels wide, centred
    `shift` pixels from its home pixel's centre) can reach: for each, its offset from
    the home pixel (int32), the fraction of the square on it and that fraction's slope
    (`_overlap`, `_overlap_slope`), both 0 beyond the window's ``2 half + 1`` pixels."""
    first = jax.lax.stop_gradient(jnp.floor(shift + 0.5 * (1.0 - width)))
    reach = []
    for k in (0, 1):
        offset = first + k
        inside = jnp.abs(offset) <= half
        u = shift - offset
        reach.append(
            (
                offset.astype(jnp.int32),
                jnp.where(inside, _overlap(u, width), 0.0),
                jnp.where(inside, _overlap_slope(u, width), 0.0),
            )
        )
    return reach


def _splat(shift_x, shift_y, values, half_x: int, half_y: int, width: float) -> Array:
    """``sum`` over the (at most) 2 x 2 pixels each sample reaches of ``values(wx, sx,
    wy, sy)`` (its weight from the overlaps ``w`` and their slopes ``s`` along each axis),
    added into the ``(rows, cols)`` image: four scatter-adds (one scatter of all four
    corners ran 3x slower). The samples may have leading axes (the ``S x S`` phases):
    all of them are added into the one image."""
    rows, cols = shift_x.shape[-2] - 2 * half_y, shift_x.shape[-1] - 2 * half_x
    home_row = jnp.arange(rows + 2 * half_y, dtype=jnp.int32)[:, None] - half_y
    home_col = jnp.arange(cols + 2 * half_x, dtype=jnp.int32)[None, :] - half_x
    image = jnp.zeros((rows, cols), shift_x.dtype)
    for dy, wy, sy in _reach(shift_y, half_y, width):
        row = home_row + dy
        row = jnp.where(row < 0, rows, row)  # dropped (a negative index would wrap round)
        for dx, wx, sx in _reach(shift_x, half_x, width):
            col = home_col + dx
            col = jnp.where(col < 0, cols, col)
            image = image.at[row, col].add(values(wx, sx, wy, sy), mode="drop")
    return image


@functools.partial(jax.custom_jvp, nondiff_argnums=(3, 4, 5))
def splat_window(shift_x, shift_y, flux, half_x: int, half_y: int, width: float) -> Array:
    """`gather_window`'s image, the same sums taken the other way round: each sample adds
    its square to the (at most) 2 x 2 pixels it overlaps, dropping what lands beyond
    its window. Its cost does not grow with the window (``N x (M + 1)`` products per
    pixel for the gather); the derivatives use the same slopes (`_overlap_slope`)."""
    return _splat(shift_x, shift_y, lambda wx, sx, wy, sy: flux * wx * wy, half_x, half_y, width)


@splat_window.defjvp
def _splat_window_jvp(half_x, half_y, width, primals, tangents):
    shift_x, shift_y, flux = primals
    t_x, t_y, t_f = tangents

    def tangent(wx, sx, wy, sy):
        return t_f * wx * wy + flux * (sx * t_x * wy + wx * sy * t_y)

    return splat_window(*primals, half_x, half_y, width), _splat(
        shift_x, shift_y, tangent, half_x, half_y, width
    )


class TwoPassResult(eqx.Module):
    """Output of `two_pass`.

    - `image`: irradiance, ``(rows, cols)`` or ``(rows, cols, channels)``.
    - `missed_flux_fraction`: per channel, shape ``(channels,)``: the fraction of the
      incident flux that lands outside the window and is therefore missing from the
      image.
    """

    image: Array
    missed_flux_fraction: Array


def _window_knob(value, name: str, odd: bool) -> int:
    """`samples_x` (N: odd, >= 1) or `channels_y` (M: even, >= 0) as an int, or a
    `ValueError` naming it."""
    try:
        good = check_int(value, name, 1 if odd else 0) % 2 == int(odd)
    except ValueError:
        good = False
    if not good:
        kind = "(N) must be an odd positive int" if odd else "(M) must be an even int >= 0"
        raise ValueError(f"`{name}` {kind} or 'auto', got {value!r}")
    return int(value)


def _is_auto(value) -> bool:
    return isinstance(value, str) and value == "auto"


def _check_window(samples_x, channels_y) -> tuple[int, int]:
    """The half widths ``(N // 2, M // 2)`` of a checked window."""
    return (
        _window_knob(samples_x, "samples_x", odd=True) // 2,
        _window_knob(channels_y, "channels_y", odd=False) // 2,
    )


def _check_knobs(scene, hit_iterations, supersample, memory_limit) -> tuple[int, int, int]:
    """The knobs `two_pass` and `auto_window` share, checked."""
    if not isinstance(scene, WaterScene):
        raise ValueError(f"`scene` must be a WaterScene, got {type(scene).__name__}")
    return (
        check_int(hit_iterations, "hit_iterations", 0, MAX_HIT_ITERATIONS),
        check_int(supersample, "supersample", 1),
        check_memory_limit(memory_limit),
    )


def two_pass_bytes(scene: WaterScene, samples_x: int, channels_y: int, supersample: int) -> int:
    """Memory of a two-pass render, bytes (an estimate, made before compiling): per
    channel and sub-pixel phase (``S^2``), `_SAMPLE_FLOATS` numbers per pre-pass sample
    of the padded grid ``(rows + M) x (cols + N - 1)`` and the ``N + M + 1`` partial
    sums per pixel row of the gather (a window summed by `splat_window`: 12 numbers per
    sample, a row, a column and a value for each pixel it reaches), plus the image. It
    grows with the receiver's pixels, ``S^2`` and (gathered) the window."""
    rows, cols = scene.receiver.shape
    channels = len(scene.iors)
    n, m = samples_x, channels_y
    samples = (rows + m) * (cols + n - 1)
    sums = 12 * samples if _splatted(n // 2, m // 2) else (n + m + 1) * (rows + m) * cols
    per_phase = _SAMPLE_FLOATS * samples + sums
    floats = channels * (supersample * supersample * per_phase + rows * cols)
    return jnp.dtype(scene.surface.heights.dtype).itemsize * floats


def _check_two_pass_memory(scene, samples_x, channels_y, supersample, memory_limit) -> None:
    rows, cols = scene.receiver.shape
    check_fits(
        two_pass_bytes(scene, samples_x, channels_y, supersample),
        memory_limit,
        f"the two-pass render of {rows} x {cols} pixels ({len(scene.iors)} channel(s), "
        f"samples_x={samples_x}, channels_y={channels_y}, supersample={supersample})",
        "lower `supersample`, `samples_x` / `channels_y` or the receiver's pixels",
    )


@eqx.filter_jit
def _two_pass(
    scene: WaterScene, half_x: int, half_y: int, iterations: int, supersample: int
) -> TwoPassResult:
    pre = prepass(scene, half_x, half_y, iterations, supersample)
    rows, cols = scene.receiver.shape
    # each of the S x S sub-samples covers its own 1/S of the pixel's side
    width = 1.0 / supersample
    if not _splatted(half_x, half_y):
        gather_phases = jax.vmap(gather_window, in_axes=(0, 0, 0, None, None, None))

        def sums(*samples):  # the mean over the S x S phases
            return jnp.mean(gather_phases(*samples, half_x, half_y, width), 0)
    else:

        def sums(*samples):  # every phase splatted into one image
            return splat_window(*samples, half_x, half_y, width) / samples[0].shape[0]

    channels = [sums(pre.shift_x[c], pre.shift_y[c], pre.flux[c]) for c in range(len(scene.iors))]
    image = channels_last(scene, jnp.stack(channels))
    inner = (Ellipsis, slice(half_y, half_y + rows), slice(half_x, half_x + cols))
    in_window = _window_fraction(pre.shift_x[inner], half_x, width) * _window_fraction(
        pre.shift_y[inner], half_y, width
    )
    missed = jnp.mean(pre.flux[inner] * (1.0 - in_window), axis=(1, 2, 3))
    return TwoPassResult(image, missed)


@eqx.filter_jit
def _largest_shift(scene: WaterScene, iterations: int, supersample: int) -> tuple[Array, Array]:
    pre = prepass(scene, 0, 0, iterations, supersample)
    return jnp.max(jnp.abs(pre.shift_x)), jnp.max(jnp.abs(pre.shift_y))


def auto_window(
    scene: WaterScene,
    hit_iterations: int = 3,
    supersample: int = 2,
    *,
    memory_limit: int | None = None,
) -> tuple[int, int]:
    """``(N, M)`` just large enough for the scene's largest ray displacement.

    Traces the pre-pass once (needs concrete scene values: call it outside `jit` and
    `vmap`; under `grad` the window is a constant). The defaults are `TwoPass`'s.
    `hit_iterations`, `supersample` and `memory_limit` as in `TwoPass` (the pre-pass
    of the smallest window must fit in `memory_limit`).
    """
    hit_iterations, supersample, memory_limit = _check_knobs(
        scene, hit_iterations, supersample, memory_limit
    )
    _check_two_pass_memory(scene, 1, 0, supersample, memory_limit)
    shifts = _largest_shift(scene, hit_iterations, supersample)
    try:  # concrete under grad and jvp (the window is a constant there), not under jit
        sx, sy = (float(jax.lax.stop_gradient(v)) for v in shifts)
    except jax.errors.ConcretizationTypeError:
        raise ValueError(
            "samples_x='auto' / channels_y='auto' (the defaults) size the window from the "
            "scene's values, which are not known under jit or vmap: fix them first with "
            "`method = jc.method_for(scene)` and transform `render(scene, method)`, or pass "
            "integers (TwoPass.paper()'s samples_x=7, channels_y=6)"
        ) from None
    half_x, half_y = (min(MAX_AUTO_HALF_WINDOW, max(1, math.ceil(s - 1e-6))) for s in (sx, sy))
    return 2 * half_x + 1, 2 * half_y


class TwoPass(Method):
    """Yuksel & Keyser's two-pass caustics of height-field water: ``TwoPass(samples_x=...,
    ...)(scene)`` or ``render(scene, TwoPass(...))``. Renders `WaterScene` only.

    The defaults (the window sized from the scene, 2 x 2 samples per pixel) are accurate
    rather than the paper's; `TwoPass.paper()` is the paper's method (a 7 x 7 window,
    one sample per pixel).

    **Arguments:**

    - `samples_x`: N, samples along ``x`` per pixel (odd; the paper's 7): light that
      lands within about N/2 pixels along ``x`` is caught. ``"auto"`` (the default)
      sizes the window along ``x`` from the largest ray displacement, up to
      `MAX_AUTO_HALF_WINDOW` = 32 pixels each side. ``"auto"`` traces the pre-pass once
      more and needs concrete scene values: it works under `grad` (the window is a
      constant there) but not under `jit` or `vmap`: fix it first with ``method =
      method_for(scene)`` (which calls `auto_window`), then transform ``render(scene,
      method)``; or pass integers (the paper's 7 and 6: `TwoPass.paper()`).
    - `channels_y`: M, so that ``M + 1`` neighbouring pixels along ``y`` are reached
      (even; the paper's 6): light within about M/2 pixels along ``y``; ``"auto"`` (the
      default) as above, along ``y``.
    - `hit_iterations`: Newton steps to find where each light ray meets the moving
      surface (default 3; 0 uses the rest-plane point; oblique light needs 2-4).
    - `supersample`: S (default 2), so that ``S x S`` samples per pixel are gathered, each
      carrying ``1/S^2`` of the pixel's light and spread over a square ``1/S`` pixel
      on a side (its own part of the pixel: under flat water they tile it). 1 is the
      paper's method (one pixel-sized square per pixel), which blurs the caustic by
      a pixel and leaves a faint pixel-grid ripple where the light is stretched or
      squeezed; as S grows the image converges to the exact irradiance binned into
      pixels (the error falls about 3x per doubling of S on held-out seas), at about
      ``S^2`` times the cost of the gather.
    - `memory_limit`: bytes (default 1 GiB). The render's memory is estimated before
      anything is compiled (`two_pass_bytes`: it grows with the receiver's pixels,
      ``S^2`` and the window ``N x (M + 1)``); over the limit it raises a `ValueError`
      with the estimate (with ``"auto"``, first for the smallest window, then for the
      one chosen).

    Knobs are checked before anything is compiled: ints are ints (no bools or floats),
    `hit_iterations` in ``[0, 100]``; an int beside an ``"auto"`` is kept (and checked
    first).
    """

    samples_x: int | Literal["auto"] = "auto"
    channels_y: int | Literal["auto"] = "auto"
    hit_iterations: int = 3
    supersample: int = 2
    memory_limit: int | None = None

    name: ClassVar[str] = "twopass"
    scene_types: ClassVar[tuple[type, ...]] = (WaterScene,)
    estimate_is_reliable: ClassVar[bool] = True
    missed_advice: ClassVar[str | None] = (
        "it lands beyond the window of samples_x x (channels_y + 1) pixels around its "
        "illumination centre; pass samples_x='auto', channels_y='auto' (the window sized "
        "from the largest ray displacement, up to MAX_AUTO_HALF_WINDOW = "
        f"{MAX_AUTO_HALF_WINDOW} pixels each side) or a wider window"
    )

    @classmethod
    def paper(cls, **knobs) -> TwoPass:
        """Yuksel & Keyser's settings: N = 7 samples along ``x``, M = 6 (7 pixels along
        ``y``), one sample per pixel (a pixel-sized square each, so the caustic is
        blurred by about a pixel); `knobs` replace any of them. Fast; it misses no
        light where the light moves less than 3 pixels, and beyond that `render` warns
        with the fraction missed."""
        return cls(**{"samples_x": 7, "channels_y": 6, "supersample": 1, **knobs})

    def needs_sizing(self) -> bool:
        return _is_auto(self.samples_x) or _is_auto(self.channels_y)

    def sized_for(self, scenes: Sequence) -> TwoPass:
        """Each ``"auto"`` knob of the window becomes the widest `auto_window` of
        `scenes` along its axis."""
        if not self.needs_sizing():
            return self
        windows = np.array(
            [
                auto_window(
                    s, self.hit_iterations, self.supersample, memory_limit=self.memory_limit
                )
                for s in scenes
            ]
        )
        n, m = (int(v) for v in windows.max(axis=0))
        return dataclasses.replace(
            self,
            samples_x=n if _is_auto(self.samples_x) else self.samples_x,
            channels_y=m if _is_auto(self.channels_y) else self.channels_y,
        )

    def refined(self) -> TwoPass:
        """Twice the samples per pixel side (`supersample`) and one more Newton step
        (`hit_iterations`), so that the difference of two settings sees both the
        footprint's error and the hit's."""
        return dataclasses.replace(
            self,
            supersample=2 * self.supersample,
            hit_iterations=min(self.hit_iterations + 1, MAX_HIT_ITERATIONS),
        )

    def coarsened(self) -> TwoPass | None:
        """Half the samples per pixel side and one Newton step less; ``None`` for an
        odd `supersample` or no Newton steps."""
        if self.supersample % 2 or self.hit_iterations == 0:
            return None
        return dataclasses.replace(
            self, supersample=self.supersample // 2, hit_iterations=self.hit_iterations - 1
        )

    def trace(self, scene) -> TwoPassResult:
        return two_pass(scene, **self.knobs())


@checks_scene_values
def two_pass(
    scene: WaterScene,
    *,
    samples_x: int | Literal["auto"] = TwoPass.samples_x,
    channels_y: int | Literal["auto"] = TwoPass.channels_y,
    hit_iterations: int = TwoPass.hit_iterations,
    supersample: int = TwoPass.supersample,
    memory_limit: int | None = TwoPass.memory_limit,
) -> TwoPassResult:
    """Caustics of `scene` by Yuksel & Keyser's two-pass gather.

    The function form of `TwoPass`: `scene` (a `WaterScene`) and the same knobs as
    keywords, described there.

    **Returns:** a `TwoPassResult` with the irradiance image and the missed-flux
    fraction. Jit-compiled; differentiable with respect to every array of the scene
    (heights, extents, rest depth, light direction).
    """
    hit_iterations, supersample, memory_limit = _check_knobs(
        scene, hit_iterations, supersample, memory_limit
    )
    auto_x, auto_y = _is_auto(samples_x), _is_auto(channels_y)
    # an explicit knob beside an "auto" one is checked before the pre-pass is traced
    half_x, half_y = _check_window(1 if auto_x else samples_x, 0 if auto_y else channels_y)
    rows, cols = scene.receiver.shape
    # an explicit window: `samples_x=100001` once compiled for minutes
    if half_x > cols or half_y > rows:
        raise ValueError(
            f"the window (`samples_x` {samples_x}, `channels_y` {channels_y}) reaches past "
            f"the receiver's {rows} x {cols} pixels: samples_x <= {2 * cols + 1} and "
            f"channels_y <= {2 * rows} already reach every pixel"
        )
    if auto_x or auto_y:
        n, m = auto_window(scene, hit_iterations, supersample, memory_limit=memory_limit)
        samples_x, channels_y = (n if auto_x else samples_x), (m if auto_y else channels_y)
        half_x, half_y = _check_window(samples_x, channels_y)
    _check_two_pass_memory(scene, samples_x, channels_y, supersample, memory_limit)
    return _two_pass(scene, half_x, half_y, hit_iterations, supersample)
