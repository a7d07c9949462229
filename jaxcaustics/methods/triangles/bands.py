"""The banded loop of `CausticTriangles`: a photon grid too large for the memory limit is
traced and drawn in bands of photon rows, one after the other or across devices
(`sum_over_batches`): their layout (`_BandConfig`), a first pass that counts their
triangles for the window and tiers (`_band_census`), and the banded image
(`_banded_image`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from ...reconstruct.raster import signed_area, sum_over_batches
from ...trace.photons import element_photons, mesh_photons
from .rasterise import _band_image, _finish, _pixel_area, _screen_triangles
from .sizing import _extent_histogram
from .tracing import _ELEMENTS

_COUNT_ROWS = 256  # bands counted apart for the tiers (`_band_census`)


class _BandConfig(eqx.Module):
    """Static layout of a banded render: `rows` photon rows per band (`rows - 1`
    triangle rows drawn), `halo` extra photon rows on each side (Gouraud: the vertex
    irradiance of the band's edge rows needs their other triangles), `bands` bands."""

    grid: tuple[int, int] = eqx.field(static=True)
    rows: int = eqx.field(static=True)
    halo: int = eqx.field(static=True)
    bands: int = eqx.field(static=True)
    hit_iterations: int = eqx.field(static=True)
    ray_batch: int = eqx.field(static=True)

    def photons(self, scene, k, halo: int):
        """The photons of band `k` (photon rows ``k (rows - 1) - halo`` on, ``rows + 2
        halo`` of them)."""
        band = (k * (self.rows - 1) - halo, self.rows + 2 * halo)
        if isinstance(scene, _ELEMENTS):
            return element_photons(scene, self.grid, self.hit_iterations, band)
        return mesh_photons(scene, self.grid, self.ray_batch, band=band)

    def drawn(self, halo: int):
        """Which of a band's triangles are its own (not the halo's): ``(T,)``."""
        per_row = 2 * (self.grid[1] - 1)
        row = jnp.arange((self.rows + 2 * halo - 1) * per_row) // per_row
        return (row >= halo) & (row < halo + self.rows - 1)


@eqx.filter_jit
def _band_census(scene, cfg: _BandConfig, mesh):
    """Over all bands: the extent histograms (`_extent_histogram`: the flux summed, the
    counts by band ``(bands, C, bins)``, at most `_COUNT_ROWS` rows) and the valid screen
    area of the triangles per channel ``(C,)``."""

    def census(scene, k):
        ph = cfg.photons(scene, k, 0)
        extent, shape = scene.receiver.extent, scene.receiver.shape
        tri = _screen_triangles(ph, extent, shape)
        area = jnp.abs(signed_area(tri.pixels)) * _pixel_area(extent, shape)
        area = jnp.where(tri.valid, area, 0.0).sum(axis=-1)
        by_flux, by_count = _extent_histogram(ph, extent, shape)
        # each band's counts in a row of their own (the tiers need the most of any band);
        # past _COUNT_ROWS bands a row adds up several: more than any one band, never less
        rows = min(cfg.bands, _COUNT_ROWS)
        stacked = jnp.zeros((rows,) + by_count.shape, by_count.dtype)
        return by_flux, stacked.at[k % rows].add(by_count), area

    return sum_over_batches(census, scene, cfg.bands, mesh=mesh)


@eqx.filter_jit
def _banded_image(scene, cfg: _BandConfig, mean_area, reconstruction, tiers, supersample, mesh):
    """The images and missed-flux fractions of a grid traced and drawn band by band
    (`sum_over_batches`: a scan, or split across the `mesh`'s devices)."""
    extent, shape = scene.receiver.extent, scene.receiver.shape

    def band(operands, k):
        scene, mean_area = operands
        ph = cfg.photons(scene, k, cfg.halo)
        return _band_image(
            ph,
            scene.receiver.extent,
            shape,
            reconstruction,
            tiers,
            supersample,
            draw=cfg.drawn(cfg.halo),
            mean_area=mean_area,
        )

    images, total, limited = sum_over_batches(band, (scene, mean_area), cfg.bands, mesh=mesh)
    return _finish(images, total, limited, extent, shape, reconstruction)
