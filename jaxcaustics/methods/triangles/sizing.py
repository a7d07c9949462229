"""How big a caustic-triangles render is: the memory model of a band of photons and of
one triangle in a rasteriser batch (`band_bytes`, `triangle_bytes`), the triangle window
from the extent histogram of the triangles (`_extent_histogram`,
`_window_from_histogram`), and the tiers of windows they are drawn in (`_size_tiers`)."""

from __future__ import annotations

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ...trace.intersect import search_bytes
from ...trace.photons import Photons
from .rasterise import MAX_AUTO_WINDOW, _screen_triangles, _spans

MAX_TIERS = 3  # windows of an "auto" render (`_size_tiers`)

# memory model of one band and one rasteriser batch, in numbers of the scene's dtype
# (about 1.2 to 1.5 times XLA's compiled temporaries on CPU; tests/test_memory.py checks
# the bound)
_BAND_FLOATS = 64  # per photon and channel: photon, its two triangles, tracing temporaries


def triangle_bytes(
    window: int, reconstruction: str = "exact", supersample: int = 2, dtype=jnp.float64
) -> int:
    """Memory one triangle takes in a rasteriser batch, bytes: for `rasterize_exact`
    three numbers per edge term ``3 x window x (window + 1)`` (its overlap areas and the
    scattered block), for `rasterize_gouraud` two per sample ``(window S)^2``, plus 64
    numbers (vertices, values, indices)."""
    size = jnp.dtype(dtype).itemsize
    w = int(window)
    if reconstruction == "exact":
        return size * (9 * w * (w + 1) + 64)
    side = w * int(supersample)
    return size * (2 * side * side + 64)


def band_bytes(photons: int, channels: int, dtype=jnp.float64, faces: int = 0, ray_batch: int = 0):
    """Memory of a band of `photons` photons (per channel: the photon, its two caustic
    triangles and the tracing temporaries, `_BAND_FLOATS` numbers) and, for a mesh scene
    of `faces` generator faces, of one batch of `ray_batch` rays in the triangle search
    (`search_bytes`), bytes."""
    size = jnp.dtype(dtype).itemsize
    return size * photons * channels * _BAND_FLOATS + search_bytes(ray_batch, faces, dtype)


def _extent_histogram(photons: Photons, extent, shape) -> tuple[Array, Array]:
    """By `_spans` (bins ``0 .. MAX_AUTO_WINDOW + 1``): the valid flux of the caustic
    triangles of `photons`, channels pooled ``(bins,)``, and the number of valid
    triangles per channel ``(C, bins)``."""
    tri = _screen_triangles(photons, extent, shape)
    keep = tri.valid & (tri.flux > 0)
    bins = _spans(tri).astype(jnp.int32)
    flux = jnp.where(keep, tri.flux, 0.0)
    by_flux = jnp.zeros(MAX_AUTO_WINDOW + 2, flux.dtype).at[bins.reshape(-1)].add(flux.reshape(-1))
    channel = jnp.broadcast_to(jnp.arange(bins.shape[0])[:, None], bins.shape)
    by_count = jnp.zeros((bins.shape[0], MAX_AUTO_WINDOW + 2), jnp.int32)
    by_count = by_count.at[channel, bins].add(tri.valid.astype(jnp.int32))
    return by_flux, by_count


_extent_histogram_jit = eqx.filter_jit(_extent_histogram)


def _window_from_histogram(histogram, flux_fraction: float) -> int:
    """`triangle_window` from `_extent_histogram`'s flux (summed over bands)."""
    histogram = np.asarray(histogram, np.float64)
    total = histogram.sum()
    if not total > 0:
        return 1
    cumulative = np.cumsum(histogram) / total
    needed = min(int(np.searchsorted(cumulative, flux_fraction)), len(histogram) - 1)
    return int(min(MAX_AUTO_WINDOW, max(1, needed)))


def _power_of_two(n: int) -> int:
    """The least power of two >= `n` (>= 1): tier capacities (and so compilations) from a
    few sizes."""
    return 1 << max(0, int(n) - 1).bit_length()


def _tier_penalty(shape, dtype=jnp.float64) -> int:
    """The fixed work of a tier of `sum_in_tiers` in `triangle_bytes`' units: its image
    (made, added to, summed: about four numbers a pixel) and a little more."""
    return (4 * shape[0] * shape[1] + 4096) * jnp.dtype(dtype).itemsize


def _plain_tier(window: int, batch: int):
    """Every triangle in its place, with one `window` (`sum_in_tiers`)."""
    return ((window, None, batch),)


def _size_tiers(counts, window: int, triangles: int, cost, batch, penalty):
    """The cheapest tiers for `sum_in_tiers`: up to `MAX_TIERS` windows, the widest
    `window`, the others powers of two (few distinct tiers: each new one compiles).

    `counts` ``(..., bins)``: `_extent_histogram`'s numbers of triangles by span, for
    each band and channel; a tier's capacity is the most it holds in any of them,
    rounded up to a power of two (at most `triangles`, the triangles of a band);
    `cost(w)`: the work of one triangle in a ``w x w`` window (`triangle_bytes`);
    `batch(w, n)`: the batch of a tier of `n` triangles; `penalty`: the fixed work of a
    tier (its image), in `cost`'s units. **Returns:** ``((window, capacity, batch),
    ...)``, or one tier of capacity ``None`` (every triangle, in place).

    A tier of window ``w`` followed by one of window ``v < w`` holds the triangles wider
    than ``v`` and at most ``w`` wide, so the cost of a chain of windows is a sum over
    its links, and the cheapest chain is found link by link (dynamic programming).
    """
    counts = np.asarray(counts).reshape(-1, np.shape(counts)[-1])
    at_least = np.cumsum(counts[:, ::-1], axis=1)[:, ::-1]  # [:, s]: spans >= s
    at_least = np.concatenate([at_least, np.zeros_like(at_least[:, :1])], axis=1)

    def wider(v):  # per band and channel: triangles wider than v (v = 0: all of them)
        return at_least[:, 0] if v == 0 else at_least[:, v + 1]

    def capacity(w, v):  # the tier of window w followed by one of window v
        held = wider(v) - (0 if w == window else wider(w))
        return min(triangles, _power_of_two(max(1, int(held.max()))))

    narrower = [1 << k for k in range(6) if 1 << k < window]

    @functools.cache
    def cheapest(w: int, tiers: int) -> tuple[float, tuple]:
        """The cheapest tiers from window `w` on."""
        best = (np.inf, ())
        for v in [0] + ([v for v in narrower if v < w] if tiers > 1 else []):
            rest, chain = cheapest(v, tiers - 1) if v else (0.0, ())
            n = capacity(w, v)
            total = n * cost(w) + penalty + rest
            if total < best[0]:
                best = (total, ((w, n), *chain))
        return best

    best = cheapest(window, MAX_TIERS)[1]
    if len(best) == 1 and best[0][1] == triangles:  # one tier of them all: in place
        return _plain_tier(window, batch(window, triangles))
    return tuple((w, n, batch(w, n)) for w, n in best)
