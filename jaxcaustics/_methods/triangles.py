"""Umenhoffer, Patow & Szirmay-Kalos's caustic triangles, for lens and mesh scenes.

T. Umenhoffer, G. Patow, L. Szirmay-Kalos, "Caustic Triangles on the GPU" (2008).

Photons leave the light on a regular grid (`jaxcaustics._photons`); the hits of
neighbouring photons form two *caustic triangles* per grid cell, and each triangle
carries the flux of its half cell onto the screen. Two reconstructions:

- ``"gouraud"`` (the paper's): the irradiance at a vertex is the power of the photon
  over the area it spreads over on the screen, ``I = dPhi / dA``, with ``dA`` a third of
  the total area of the triangles around it (a third, not the paper's half: with linear
  interpolation a vertex owns a third of each adjacent triangle's integral, so this
  choice conserves flux; the paper's half would lose a third of it); triangles are drawn
  with linear (Gouraud) interpolation of the vertex irradiances, point-sampled at pixel
  centres (`supersample` x `supersample` samples per pixel), added up.
- ``"exact"``: constant irradiance per triangle (its flux over its area), with exact
  triangle/pixel overlap areas: exactly flux-conserving at any resolution.

Folds: where neighbouring photons cross (the triangle flips orientation, past a focus),
a flipped triangle still spreads its flux over its absolute area (signed overlap over
signed area), so flux is kept and images stay finite; a triangle collapsed to zero area
(at a focus) drops its flux at its centroid. Invalid photons invalidate the triangles
that use them (masks, never Python-side filtering).
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._mesh import MeshScene
from .._photons import Photons, lens_photons, mesh_photons
from .._raster import (
    pixel_coordinates,
    rasterize_exact,
    rasterize_gouraud,
    signed_area,
    splat_gaussian,
    sum_in_batches,
)
from .._scene import LensScene, PlaneReceiver

RECONSTRUCTIONS = ("exact", "gouraud")
MAX_AUTO_WINDOW = 32


class TrianglesResult(eqx.Module):
    """Output of `caustic_triangles`.

    - `image`: irradiance, ``(rows, cols)`` or ``(rows, cols, channels)``.
    - `missed_flux_fraction`: per channel ``(channels,)``: the fraction of the flux of
      the valid triangles that is not in the image (it lands off the screen, or beyond a
      triangle's `window`).
    - `photons`: the photon hit location image used.
    """

    image: Array
    missed_flux_fraction: Array
    photons: Photons


def grid_triangles(values: Array) -> Array:
    """The two triangles of every grid cell: ``(..., rows, cols, *rest)`` vertex data to
    ``(..., 2 (rows - 1) (cols - 1), 3, *rest)``.

    Cell ``(i, j)`` with corners ``a = (i, j)``, ``b = (i, j + 1)``, ``c = (i + 1, j)``,
    ``d = (i + 1, j + 1)`` gives the triangles ``(a, b, d)`` and ``(a, d, c)``.
    """
    a = values[:, :-1, :-1]
    b = values[:, :-1, 1:]
    c = values[:, 1:, :-1]
    d = values[:, 1:, 1:]
    first = jnp.stack([a, b, d], axis=3)
    second = jnp.stack([a, d, c], axis=3)
    tri = jnp.stack([first, second], axis=3)  # (C, rows-1, cols-1, 2, 3, ...)
    return tri.reshape(tri.shape[0], -1, *tri.shape[4:])


def _scatter_to_vertices(per_triangle: Array, grid: tuple[int, int]) -> Array:
    """Sum ``(C, T, 3)`` per-triangle-corner values onto the grid vertices."""
    rows, cols = grid
    index = jnp.arange(rows * cols).reshape(1, rows, cols)
    corner = grid_triangles(index)[0]  # (T, 3) vertex indices
    out = jnp.zeros((per_triangle.shape[0], rows * cols), per_triangle.dtype)
    out = out.at[:, corner.reshape(-1)].add(per_triangle.reshape(per_triangle.shape[0], -1))
    return out.reshape(-1, rows, cols)


class _Triangles(eqx.Module):
    pixels: Float[Array, "C T 3 2"]
    flux: Float[Array, "C T"]
    valid: Bool[Array, "C T"]


def _screen_triangles(photons: Photons, extent, shape) -> _Triangles:
    valid = grid_triangles(photons.valid).all(axis=-1)
    density = grid_triangles(photons.density).mean(axis=-1)
    flux = jnp.where(valid, 0.5 * photons.cell_area * density, 0.0)
    pixels = pixel_coordinates(grid_triangles(photons.position[..., :2]), extent, shape)
    return _Triangles(pixels, flux, valid)


def _vertex_irradiance(flux: Array, area: Array, valid: Array, grid) -> Array:
    """The paper's vertex irradiance ``dPhi / dA``: a third of each adjacent triangle's
    flux over a third of its area (on the surface it landed on), per triangle corner
    ``(C, T, 3)``; `flux`, `area` and `valid` are per triangle ``(C, T)``."""
    area = jnp.where(valid, area, 0.0)
    flux = jnp.where(valid, flux, 0.0)
    power = _scatter_to_vertices(jnp.broadcast_to(flux[..., None] / 3, area.shape + (3,)), grid)
    spread = _scatter_to_vertices(jnp.broadcast_to(area[..., None] / 3, area.shape + (3,)), grid)
    # a vertex whose triangles all collapsed (a perfect focus) is given a thousandth of
    # its mean share of area: finite, and far brighter than anything resolvable
    floor = 1e-3 * jnp.sum(area, axis=-1, keepdims=True) / jnp.maximum(1, area.shape[-1])
    irradiance = power / jnp.maximum(spread, floor[..., None])
    rows, cols = grid
    index = grid_triangles(jnp.arange(rows * cols).reshape(1, rows, cols))[0]
    return irradiance.reshape(irradiance.shape[0], -1)[:, index]


@eqx.filter_jit
def _triangles_image(
    photons, extent, shape, reconstruction: str, window: int, supersample: int, batch_size: int
):
    tri = _screen_triangles(photons, extent, shape)
    pixel_area = (extent[1] - extent[0]) / shape[1] * (extent[3] - extent[2]) / shape[0]
    if reconstruction == "exact":

        def raster(v, f, m):
            return rasterize_exact(v, f, m, shape, window)

        values = tri.flux
    else:

        def raster(v, e, m):
            return rasterize_gouraud(v, e, m, shape, window, supersample)

        area = jnp.abs(signed_area(tri.pixels)) * pixel_area
        values = _vertex_irradiance(tri.flux, area, tri.valid, photons.grid_shape)
    images = jnp.stack(
        [
            sum_in_batches(raster, batch_size, tri.pixels[c], values[c], tri.valid[c])
            for c in range(tri.valid.shape[0])
        ]
    )
    if reconstruction == "exact":
        # overlap areas are sums of signed edge terms: clear their rounding below zero
        images = jnp.maximum(images / pixel_area, 0.0)
    total = tri.flux.sum(axis=-1)
    landed = images.sum(axis=(1, 2)) * pixel_area
    missed = jnp.where(total > 0, 1.0 - landed / jnp.where(total > 0, total, 1.0), 0.0)
    return images, jnp.clip(missed, 0.0, 1.0)


def triangle_window(photons: Photons, receiver: PlaneReceiver, flux_fraction: float = 0.999) -> int:
    """The smallest triangle window (pixels) that holds whole the triangles carrying
    `flux_fraction` of the valid flux, capped at `MAX_AUTO_WINDOW`.

    Near silhouettes and folds a few triangles stretch over huge areas (neighbouring
    photons that part ways); sizing the window for them would cost ``window^2`` per
    triangle for all triangles. Their flux beyond the window is reported as missed.
    Needs concrete values (call it outside `jit`).
    """
    tri = _screen_triangles(photons, receiver.extent, receiver.shape)
    pix = np.asarray(tri.pixels).reshape(-1, 3, 2)
    flux = np.asarray(tri.flux).reshape(-1)
    valid = np.asarray(tri.valid).reshape(-1) & (flux > 0)
    if not valid.any():
        return 1
    pix, flux = pix[valid], flux[valid]
    low = np.floor(pix.min(axis=1))
    extent = np.max(np.ceil(pix.max(axis=1)) - low, axis=1)
    order = np.argsort(extent)
    cumulative = np.cumsum(flux[order]) / flux.sum()
    needed = extent[order][min(np.searchsorted(cumulative, flux_fraction), len(order) - 1)]
    return int(min(MAX_AUTO_WINDOW, max(1, needed)))


def triangles_image(
    photons: Photons,
    receiver: PlaneReceiver,
    *,
    reconstruction: Literal["exact", "gouraud"] = "exact",
    window: int | Literal["auto"] = "auto",
    supersample: int = 2,
    batch_size: int = 16384,
) -> tuple[Array, Array]:
    """Reconstruct the irradiance on `receiver` from a photon hit location image by
    caustic triangles (the photons' terminal positions are taken on the plane ``z = 0``).

    **Returns:** ``(images, missed_flux_fraction)`` of shapes ``(channels, rows, cols)``
    and ``(channels,)``. See `caustic_triangles` for the knobs.
    """
    if reconstruction not in RECONSTRUCTIONS:
        raise ValueError(
            f"`reconstruction` must be one of {RECONSTRUCTIONS}, got {reconstruction!r}"
        )
    if isinstance(supersample, bool) or not isinstance(supersample, int) or supersample < 1:
        raise ValueError(f"`supersample` must be an int >= 1, got {supersample!r}")
    shape, extent = receiver.shape, receiver.extent
    if window == "auto":
        if isinstance(photons.position, jax.core.Tracer):
            raise ValueError(
                "window='auto' needs concrete scene values; under jit/vmap pass an int"
            )
        window = triangle_window(photons, receiver)
    if isinstance(window, bool) or not isinstance(window, int) or window < 1:
        raise ValueError(f"`window` must be an int >= 1 or 'auto', got {window!r}")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"`batch_size` must be an int >= 1, got {batch_size!r}")
    return _triangles_image(photons, extent, shape, reconstruction, window, supersample, batch_size)


def splat_photons(photons: Photons, receiver: PlaneReceiver, sigma, window: int | None = None):
    """Reconstruct the irradiance on `receiver` by Gaussian photon splatting.

    Each photon carries its share of the grid's flux (`Photons.flux`) and spreads it with
    a normalised Gaussian of standard deviation `sigma` *pixels* (the splat radius: too
    small leaves dots, too large blurs). **Returns:** ``(channels, rows, cols)``.
    """
    shape, extent = receiver.shape, receiver.extent
    pixel_area = (extent[1] - extent[0]) / shape[1] * (extent[3] - extent[2]) / shape[0]
    points = pixel_coordinates(photons.position[..., :2], extent, shape)
    flux = photons.flux()
    channels = [
        splat_gaussian(
            points[c].reshape(-1, 2),
            flux[c].reshape(-1),
            photons.valid[c].reshape(-1),
            shape,
            sigma,
            window,
        )
        for c in range(points.shape[0])
    ]
    return jnp.stack(channels) / pixel_area


@eqx.filter_jit
def trace_photons(scene, grid: tuple[int, int], hit_iterations: int = 3, batch_size: int = 4096):
    """The photon hit location image of a `LensScene` or `MeshScene` (jit-compiled)."""
    if isinstance(scene, LensScene):
        return lens_photons(scene, grid, hit_iterations)
    return mesh_photons(scene, grid, batch_size)


def _check_grid(photons) -> tuple[int, int]:
    if isinstance(photons, (int, np.integer)) and not isinstance(photons, bool):
        photons = (int(photons), int(photons))
    if isinstance(photons, str):
        raise ValueError(f"`photons` must be an int or (rows, cols), got {photons!r}")
    try:
        grid = tuple(int(p) for p in photons)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`photons` must be an int or (rows, cols), got {photons!r}") from err
    if len(grid) != 2 or min(grid) < 2:
        raise ValueError(f"`photons` must give at least 2 x 2 photons, got {photons!r}")
    return grid  # type: ignore[return-value]


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


def _cube_centre(scene: MeshScene) -> Array:
    verts = jax.lax.stop_gradient(scene.generator.vertices)
    return 0.5 * (verts.min(axis=0) + verts.max(axis=0))


@eqx.filter_jit
def _distance_map_photons(scene: MeshScene, dmap, grid, batch_size, options: CubeMapOptions):
    from .._distance_map import trace_distance_map

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
    from .._distance_map import light_cube_map, project_light_cube_map

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
    from .._distance_map import build_distance_map

    centre = _cube_centre(scene)
    dmap = build_distance_map(centre, scene.occluders, options.resolution, options.layers)
    ph = _distance_map_photons(scene, dmap, grid, batch_size, options)
    images = _cube_map_image(ph, centre, scene.receiver, options)
    # flux bookkeeping on the screen is not defined here (caustics may land on occluders)
    missed = jnp.full(images.shape[:1], jnp.nan, images.dtype)
    return ph, images, missed


def caustic_triangles(
    scene: LensScene | MeshScene,
    *,
    photons: int | tuple[int, int] = 257,
    reconstruction: Literal["exact", "gouraud"] = "exact",
    window: int | Literal["auto"] = "auto",
    supersample: int = 2,
    hit_iterations: int = 3,
    batch_size: int = 4096,
    triangle_batch: int = 16384,
    visibility: Literal["exact", "distance_map"] = "exact",
    cube_map: CubeMapOptions | None = None,
) -> TrianglesResult:
    """Caustics of a lens or mesh scene by caustic triangles.

    **Arguments:**

    - `scene`: a `LensScene` or a `MeshScene`.
    - `photons`: the photon grid, ``n`` (``n x n``) or ``(rows, cols)`` photons
      (vertices of the grid); ``2 (rows - 1) (cols - 1)`` triangles.
    - `reconstruction`: ``"exact"`` (flux-conserving, exact overlap areas) or
      ``"gouraud"`` (the paper's vertex irradiance with Gouraud interpolation).
    - `window`: each triangle touches a ``window x window`` block of pixels; ``"auto"``
      takes the smallest window that holds whole the triangles carrying 99.9% of the
      flux (`triangle_window`; needs concrete scene values: inside `jax.jit` pass an int).
      Flux beyond it is reported as missed.
    - `supersample`: ``"gouraud"`` only: ``S x S`` point samples per pixel.
    - `hit_iterations`: lens scenes: Newton steps for the top-surface hit.
    - `batch_size`: mesh scenes: rays per batch in the triangle search (memory
      ``batch_size x faces``).
    - `triangle_batch`: triangles rasterised at a time (memory ``triangle_batch x
      window^2``).
    - `visibility`: mesh scenes: ``"exact"`` (rays leaving the generator are intersected
      exactly with the occluders and the screen; triangles are drawn on the screen) or
      ``"distance_map"`` (the paper's pipeline: rays are traced in a layered distance map
      of the screen and the occluders around the generator, caustic triangles are drawn
      with Gouraud interpolation onto a light cube map, and the camera pass projects it
      onto the screen with a shadow-map distance test, so caustics landing on an
      occluder do not leak onto the screen behind it). Its knobs: `cube_map`
      (`CubeMapOptions`); `reconstruction`, `window` and `supersample` do not apply, and
      the missed-flux fraction is NaN (light may land on occluders).

    **Returns:** a `TrianglesResult` (image, missed-flux fraction, photons).
    Differentiable with respect to the scene's arrays (the lens heights, the mesh
    vertices, the light).
    """
    if not isinstance(scene, (LensScene, MeshScene)):
        raise ValueError(f"`scene` must be a LensScene or a MeshScene, got {type(scene).__name__}")
    grid = _check_grid(photons)
    for name, value, low in (
        ("hit_iterations", hit_iterations, 0),
        ("batch_size", batch_size, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"`{name}` must be an int >= {low}, got {value!r}")
    if visibility not in ("exact", "distance_map"):
        raise ValueError(f"`visibility` must be 'exact' or 'distance_map', got {visibility!r}")
    if visibility == "distance_map":
        if not isinstance(scene, MeshScene):
            raise ValueError("`visibility='distance_map'` needs a MeshScene")
        ph, images, missed = _distance_map_caustics(
            scene, grid, batch_size, cube_map or CubeMapOptions()
        )
        return TrianglesResult(_channels_last(scene, images), missed, ph)
    ph = trace_photons(scene, grid, hit_iterations, batch_size)
    images, missed = triangles_image(
        ph,
        scene.receiver,
        reconstruction=reconstruction,
        window=window,
        supersample=supersample,
        batch_size=triangle_batch,
    )
    return TrianglesResult(_channels_last(scene, images), missed, ph)


def _channels_last(scene, images: Array) -> Array:
    """``(C, rows, cols)`` to the scene's image layout (2-D for a scalar index)."""
    multi = isinstance(scene.ior, tuple) and (
        isinstance(scene, LensScene) or scene.material == "refractor"
    )
    return jnp.moveaxis(images, 0, -1) if multi else images[0]
