"""The paper's visibility pipeline of `CausticTriangles` (``visibility="distance_map"``):
its knobs (`CubeMapOptions`), the photons traced in a layered distance map around the
generator, their caustic triangles drawn onto a light cube map, and the camera pass that
projects it onto the screen (`_distance_map_caustics`)."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..._checks import check_bool, check_int, check_number
from ...scene.mesh import MeshScene
from ...scene.scene import PlaneReceiver
from ...trace.photons import Photons, mesh_photons
from .distance_map import (
    build_distance_map,
    light_cube_map,
    project_light_cube_map,
    trace_distance_map,
)
from .rasterise import _vertex_irradiance, grid_triangles


class CubeMapOptions(eqx.Module):
    """Knobs of the paper's visibility pipeline (``visibility="distance_map"``).

    - `resolution`: texels per cube-face edge of the distance and light cube maps.
    - `layers`: surfaces kept per texel of the layered distance map.
    - `linear_steps`, `secant_iterations`: the ray search in the distance map.
    - `shadow_test`: use the light cube map's distances as a shadow map in the camera
      pass (``False``: naive projection, which leaks light behind occluders).
    - `tolerance`: relative distance tolerance of the shadow test.
    - `window`: the rasteriser window on the cube faces, texels; ``None`` takes the
      smallest that holds every triangle (needs concrete values, outside `jit`).
    """

    resolution: int = eqx.field(static=True, default=128)
    layers: int = eqx.field(static=True, default=2)
    linear_steps: int = eqx.field(static=True, default=32)
    secant_iterations: int = eqx.field(static=True, default=4)
    shadow_test: bool = eqx.field(static=True, default=True)
    tolerance: float = eqx.field(static=True, default=0.02)
    window: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        for name, low in (
            ("resolution", 2),
            ("layers", 1),
            ("linear_steps", 1),
            ("secant_iterations", 0),
        ):
            check_int(getattr(self, name), name, low)
        check_bool(self.shadow_test, "shadow_test")
        check_number(self.tolerance, "tolerance", low=0.0)
        if self.window is not None:
            check_int(self.window, "window", 1)


def _cube_centre(scene: MeshScene) -> Array:
    verts = jax.lax.stop_gradient(scene.generator.vertices)
    return 0.5 * (verts.min(axis=0) + verts.max(axis=0))


@eqx.filter_jit
def _distance_map_photons(scene: MeshScene, dmap, grid, batch_size, options: CubeMapOptions):

    def terminal(origins, directions):
        hit = trace_distance_map(
            dmap,
            origins,
            directions,
            linear_steps=options.linear_steps,
            secant_iterations=options.secant_iterations,
        )
        return hit.point, hit.found

    return mesh_photons(scene, grid, batch_size, terminal)


@eqx.filter_jit
def _cube_map_triangles(photons: Photons):
    """Caustic triangles in space: corners ``(C, T, 3, 3)``, vertex irradiance on the
    surface they landed on ``(C, T, 3)``, validity ``(C, T)``."""
    corners = grid_triangles(photons.position)  # (C, T, 3, 3)
    valid = grid_triangles(photons.valid).all(axis=-1)
    flux = 0.5 * photons.cell_area * grid_triangles(photons.density).mean(axis=-1)
    edge1 = corners[..., 1, :] - corners[..., 0, :]
    edge2 = corners[..., 2, :] - corners[..., 0, :]
    area = 0.5 * jnp.linalg.norm(jnp.cross(edge1, edge2), axis=-1)  # on the landing surface
    irradiance = _vertex_irradiance(flux, area, valid, photons.grid_shape)
    return corners, irradiance, valid


def _cube_map_image(photons: Photons, centre, receiver: PlaneReceiver, options: CubeMapOptions):

    corners, irradiance, valid = _cube_map_triangles(photons)
    rows, cols = receiver.shape
    x0, x1, y0, y1 = receiver.extent
    xs = x0 + (jnp.arange(cols) + 0.5) * (x1 - x0) / cols
    ys = y0 + (jnp.arange(rows) + 0.5) * (y1 - y0) / rows
    gx, gy = jnp.meshgrid(xs, ys)
    pixels = jnp.stack([gx, gy, jnp.zeros_like(gx)], axis=-1).reshape(-1, 3)
    images = []
    for c in range(corners.shape[0]):
        lcm = light_cube_map(
            centre, corners[c], irradiance[c], valid[c], options.resolution, options.window
        )
        lit = project_light_cube_map(
            lcm, centre, pixels, shadow_test=options.shadow_test, tolerance=options.tolerance
        )
        images.append(lit.reshape(rows, cols))
    return jnp.stack(images)


def _distance_map_caustics(scene: MeshScene, grid, batch_size, options: CubeMapOptions):

    if not scene.occluders:
        # the screen alone: one layer holds it, and every caustic lands on it (no
        # occlusion work is traced)
        options = dataclasses.replace(options, layers=1, shadow_test=False)
    centre = _cube_centre(scene)
    dmap = build_distance_map(centre, scene.occluders, options.resolution, options.layers)
    ph = _distance_map_photons(scene, dmap, grid, batch_size, options)
    images = _cube_map_image(ph, centre, scene.receiver, options)
    # flux bookkeeping on the screen is not defined here (caustics may land on occluders)
    missed = jnp.full(images.shape[:1], jnp.nan, images.dtype)
    return ph, images, missed
