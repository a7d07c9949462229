"""Tracing the photon grid of a lens, mirror or mesh scene whole (`trace_photons`), and
the checks of scenes, photon grids and knobs that the caustic-triangles functions share
(`_check_scene`, `_check_grid`, `_sizes`, `_is_auto`, `_refuse_unused`)."""

from __future__ import annotations

import equinox as eqx
import numpy as np

from ..._checks import check_fits, check_int, check_memory_limit, check_photon_work
from ...scene.mesh import MeshScene
from ...scene.mirror import MirrorScene
from ...scene.scene import LensScene
from ...scene.surface import MAX_HIT_ITERATIONS
from ...trace.photons import element_photons, mesh_photons
from .sizing import band_bytes

# the height-field caustic elements (one photon grid over the aperture)
_ELEMENTS = (LensScene, MirrorScene)


@eqx.filter_jit
def _trace_photons(scene, grid: tuple[int, int], hit_iterations: int, batch_size: int):
    if isinstance(scene, _ELEMENTS):
        return element_photons(scene, grid, hit_iterations)
    return mesh_photons(scene, grid, batch_size)


def trace_photons(
    scene,
    grid: tuple[int, int],
    hit_iterations: int = 3,
    batch_size: int = 4096,
    *,
    memory_limit: int | None = None,
):
    """The photon hit location image of a `LensScene` or `MeshScene` (jit-compiled).

    `grid`: ``n`` or ``(rows, cols)`` photons (as `CausticTriangles`' `photons`);
    `hit_iterations`: lens scenes only (Newton steps, ``[0, 100]``); `batch_size`: mesh
    scenes only (rays per batch of the triangle search). The whole grid is traced at
    once: its photons (`band_bytes`) must fit in `memory_limit` (default 1 GiB).
    """
    _check_scene(scene)
    grid = _check_grid(grid, "grid")
    hit_iterations = check_int(hit_iterations, "hit_iterations", 0, MAX_HIT_ITERATIONS)
    batch_size = check_int(batch_size, "batch_size", 1)
    memory_limit = check_memory_limit(memory_limit)
    if isinstance(scene, _ELEMENTS):
        _refuse_unused("batch_size", batch_size, 4096, "mesh scenes")
    else:
        _refuse_unused("hit_iterations", hit_iterations, 3, "lens scenes")
    channels, dtype, faces = _sizes(scene)
    check_photon_work(grid[0] * grid[1], 1, "grid")
    check_fits(
        band_bytes(grid[0] * grid[1], channels, dtype, faces, batch_size if faces else 0),
        memory_limit,
        f"the {grid[0]} x {grid[1]} photon grid, traced at once",
        "pass a smaller `grid`" + (" or `batch_size`" if faces else ""),
    )
    return _trace_photons(scene, grid, hit_iterations, batch_size)


def _check_scene(scene) -> None:
    if not isinstance(scene, (*_ELEMENTS, MeshScene)):
        raise ValueError(
            f"`scene` must be a LensScene, a MirrorScene or a MeshScene, got {type(scene).__name__}"
        )


def _sizes(scene) -> tuple[int, np.dtype, int]:
    """Channels, dtype and (mesh scenes) generator faces of a lens or mesh scene."""
    if isinstance(scene, _ELEMENTS):
        return len(getattr(scene, "iors", (1,))), np.dtype(scene.surface.heights.dtype), 0
    faces = int(scene.generator.faces.shape[0])
    return len(scene.iors), np.dtype(scene.generator.vertices.dtype), faces


def _is_auto(value) -> bool:
    return isinstance(value, str) and value == "auto"


def _refuse_unused(name: str, value, default, applies: str) -> None:
    """A knob set (to anything but its default) where it does not apply: a `ValueError`
    naming it, never silently ignored."""
    if value is not default and value != default:
        raise ValueError(f"`{name}` applies to {applies} only; got {value!r} (leave it out)")


def _check_grid(photons, name: str = "photons") -> tuple[int, int]:
    """``n`` or ``(rows, cols)``, ints >= 2 (no bools or floats), as ``(rows, cols)``."""
    if isinstance(photons, np.ndarray) and photons.ndim == 1:
        photons = tuple(photons)
    if not isinstance(photons, (tuple, list)):
        if isinstance(photons, (int, np.integer)) and not isinstance(photons, (bool, np.bool_)):
            photons = (photons, photons)
        else:
            raise ValueError(f"`{name}` must be an int or (rows, cols), got {photons!r}")
    if len(photons) != 2:
        raise ValueError(f"`{name}` must be an int or (rows, cols), got {photons!r}")
    return check_int(photons[0], name, 2), check_int(photons[1], name, 2)
