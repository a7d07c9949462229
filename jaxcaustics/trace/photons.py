"""Photon tracing for the lens and mesh scenes: the photon hit location image.

Photons leave the light on a regular grid (the light's view of the caustic generator),
follow their path through the generator, and end on the screen ``z = 0``. The result is
a `Photons` image: one photon per grid vertex, with its terminal position, the flux
density it carries and a validity mask. Photons that miss the generator, are stopped by
an occluder, are lost to total internal reflection or need more interfaces than the
scene allows are *invalid*: they stay in the image (fixed shapes, jittable) and are
masked out downstream, never filtered on the Python side.

Flux: a photon's `density` is the flux per unit emission area it carries (the light's
irradiance across the emission plane, times the Fresnel factors along its path), so the
flux of a grid cell is ``cell_area`` times the mean density of its corners.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..scene.mesh import MeshScene
from ..scene.mirror import MirrorScene
from ..scene.outline import inside_outline
from ..scene.scene import DirectionalLight, LensScene, emission
from ..scene.surface import ray_surface_hit
from .intersect import face_normals, hit_on_triangle, nearest_hits, search_tree, vertex_normals
from .optics import fresnel_transmittance, orthonormal_basis, reflect, refract_components


class Photons(eqx.Module):
    """The photon hit location image (one photon per vertex of the emission grid).

    - `position`: ``(channels, rows, cols, 3)``, where each photon ends, metres (on the
      screen ``z = 0`` for the lens and mesh scenes).
    - `direction`: ``(channels, rows, cols, 3)``, unit direction of travel on arrival.
    - `density`: ``(channels, rows, cols)``, flux per unit emission area carried (0 where
      invalid).
    - `valid`: ``(channels, rows, cols)``, the photon reached the screen through the
      generator.
    - `cell_area`: area of one emission-grid cell, m^2 (scalar).
    - `limited`: ``(channels, rows, cols)``, the flux per unit emission area of photons
      the scene's interface limit dropped (mesh scenes: they met the object again after
      ``scene.interfaces`` events, or were still inside it); ``None`` where no limit
      applies (lens slabs).
    """

    position: Float[Array, "channels rows cols 3"]
    direction: Float[Array, "channels rows cols 3"]
    density: Float[Array, "channels rows cols"]
    valid: Bool[Array, "channels rows cols"]
    cell_area: Float[Array, ""]
    limited: Float[Array, "channels rows cols"] | None = None

    @property
    def grid_shape(self) -> tuple[int, int]:
        return tuple(self.valid.shape[1:])  # type: ignore[return-value]

    def flux(self) -> Float[Array, "channels rows cols"]:
        """Flux of each photon taken as a point (its share of the grid: a quarter of each
        adjacent cell), for splatting."""
        rows, cols = self.grid_shape
        wy = jnp.ones(rows, self.density.dtype).at[jnp.array([0, -1])].set(0.5)
        wx = jnp.ones(cols, self.density.dtype).at[jnp.array([0, -1])].set(0.5)
        return self.density * self.cell_area * wy[:, None] * wx[None, :]


def _stack_channels(
    positions, directions, densities, valids, cell_area, dtype, limited=None
) -> Photons:
    """`Photons` from per-channel lists (channels first)."""
    return Photons(
        jnp.stack(positions),
        jnp.stack(directions),
        jnp.stack(densities),
        jnp.stack(valids),
        jnp.asarray(cell_area, dtype),
        None if limited is None else jnp.stack(limited),
    )


def corner_grid(lo_u, hi_u, lo_v, hi_v, shape: tuple[int, int], dtype, band=None):
    """Vertices of a ``rows x cols`` grid spanning the rectangle (edges included).

    `band`: ``(start, count)``: only the grid rows ``start .. start + count - 1``
    (`start` may be traced and the rows may run past the grid: see `band_rows`).
    """
    rows, cols = shape
    u = lo_u + (hi_u - lo_u) * jnp.arange(cols, dtype=dtype) / (cols - 1)
    index = jnp.arange(rows) if band is None else band[0] + jnp.arange(band[1])
    v = lo_v + (hi_v - lo_v) * index.astype(dtype) / (rows - 1)
    uu, vv = jnp.meshgrid(u, v)
    return uu, vv, (hi_u - lo_u) / (cols - 1) * (hi_v - lo_v) / (rows - 1)


def band_rows(grid: tuple[int, int], band) -> Bool[Array, " count"]:
    """Which rows of a band ``(start, count)`` of a ``rows x cols`` grid lie in the grid
    (rows before the first or past the last are padding: their photons are invalid)."""
    index = band[0] + jnp.arange(band[1])
    return (index >= 0) & (index < grid[0])


def _clip_band(photons: Photons, grid, band) -> Photons:
    """Invalidate the photons of a band's rows outside the grid."""
    if band is None:
        return photons
    inside = band_rows(grid, band)[None, :, None]
    valid = photons.valid & inside
    photons = eqx.tree_at(
        lambda p: (p.valid, p.density),
        photons,
        (valid, jnp.where(valid, photons.density, 0.0)),
    )
    if photons.limited is None:
        return photons
    return eqx.tree_at(lambda p: p.limited, photons, jnp.where(inside, photons.limited, 0.0))


def _normalise(v):
    inv = jax.lax.rsqrt(sum(c * c for c in v))
    return tuple(c * inv for c in v)


def _land(point, direction, valid, pose=None):
    """Carry rays to the screen: the ground ``z = 0`` (rays going up are invalid), or the
    plane of a `ScreenPose` (positions in its ``(s, t)`` frame, 0 along its normal)."""
    if pose is not None:
        s, t, reached = pose.land(point, direction)
        return (s, t, jnp.zeros_like(s)), valid & reached
    down = direction[2] < 0.0
    s = -point[2] / jnp.where(down, direction[2], -1.0)
    landed = (point[0] + s * direction[0], point[1] + s * direction[1], jnp.zeros_like(s))
    return landed, valid & down


def _stack(components):
    return jnp.stack(jnp.broadcast_arrays(*components), axis=-1)


def _aperture_rays(scene, grid: tuple[int, int], band):
    """The photon grid over a height-field element's aperture (a lens's top, a mirror's
    face) on its rest plane ``z = scene.top``: the points ``(px, py)`` (rotated with the
    surface), the rays' directions (a 3-tuple), their flux density (0 outside the
    outline) and the grid's cell area."""
    surface = scene.surface
    dtype = surface.heights.dtype
    x0, x1, y0, y1 = surface.extent
    u, v, cell_area = corner_grid(x0, x1, y0, y1, grid, dtype, band)
    # the grid turns with the surface about the extent's centre
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    cos_r, sin_r = jnp.cos(surface.rotation), jnp.sin(surface.rotation)
    px = cx + cos_r * (u - cx) - sin_r * (v - cy)
    py = cy + sin_r * (u - cx) + cos_r * (v - cy)
    if isinstance(scene.light, DirectionalLight):
        d = tuple(c.astype(dtype) for c in scene.light.unit_direction)
        density = jnp.ones_like(px)
    else:
        lp = scene.light.position.astype(dtype)
        offset = (px - lp[0], py - lp[1], scene.top - lp[2])
        r2 = sum(c * c for c in offset)
        d = _normalise(offset)
        density = scene.light.intensity * jnp.abs(d[2]) / r2 * emission(scene.light, d[2])
    if scene.outline != "rectangle":  # the mount stops the light outside the outline
        density = jnp.where(inside_outline(scene.outline, (x0, x1, y0, y1), u, v), density, 0.0)
    return px, py, d, density, cell_area


def lens_photons(
    scene: LensScene, grid: tuple[int, int], hit_iterations: int = 3, band=None
) -> Photons:
    """Trace a ``rows x cols`` grid of photons through a `LensScene`.

    `band` (optional) ``(start, count)``: trace only the grid rows ``start .. start +
    count - 1`` (a ``count x cols`` `Photons`, bitwise the same photons as those rows of
    the whole grid; rows outside the grid are invalid; `start` may be traced).

    The grid's vertices span the aperture (``surface.extent``, rotated with the surface)
    on the top surface's rest plane, edges included (photons outside the scene's
    `outline` carry no flux); each photon's line crosses that
    plane there and meets the top surface at the root found by `hit_iterations` Newton
    steps. It refracts into the glass, refracts out of the flat bottom (total internal
    reflection there makes it invalid) and lands on the screen (the ground, or the
    plane of `scene.screen_pose`: positions in its ``(s, t)`` frame).
    """
    dtype = scene.surface.heights.dtype
    px, py, d, density, cell_area = _aperture_rays(scene, grid, band)
    hit_x, hit_y, hit_z, hx, hy = ray_surface_hit(
        scene.surface, scene.top, px, py, d, hit_iterations
    )
    normal = _normalise((-hx, -hy, jnp.ones_like(hx)))
    up = (jnp.zeros_like(hx), jnp.zeros_like(hx), jnp.ones_like(hx))

    positions, directions, densities, valids = [], [], [], []
    for ior in scene.iors:
        inside, _, cos_in = refract_components(d, normal, 1.0 / ior)
        valid = (inside[2] < 0.0) & (hit_z > scene.screen_distance)
        s = (hit_z - scene.screen_distance) / -jnp.where(valid, inside[2], -1.0)
        bottom = (
            hit_x + s * inside[0],
            hit_y + s * inside[1],
            jnp.broadcast_to(scene.screen_distance, s.shape),
        )
        out, tir, cos_out = refract_components(inside, up, ior)
        landed, valid = _land(bottom, out, valid & ~tir, scene.screen_pose)
        flux = density
        if scene.fresnel:
            flux = (
                flux
                * fresnel_transmittance(cos_in, 1.0 / ior)
                * fresnel_transmittance(cos_out, ior)
            )
        positions.append(_stack(landed))
        directions.append(_stack(out))
        densities.append(jnp.where(valid, flux, 0.0))
        valids.append(valid)
    photons = _stack_channels(positions, directions, densities, valids, cell_area, dtype)
    return _clip_band(photons, grid, band)


def reflect_components(d, normal):
    """`d` reflected about the unit `normal` (3-tuples of arrays)."""
    twice = 2.0 * sum(a * b for a, b in zip(d, normal, strict=True))
    return tuple(a - twice * b for a, b in zip(d, normal, strict=True))


def _on_face(scene: MirrorScene, px, py, hit_x, hit_y, grid):
    """The fraction of each photon's share of the grid (a grid cell about its rest-plane
    point, clipped to the aperture) whose hits lie on the face, taking its own hit's
    offset for the whole cell: along each axis the cell moved by the offset, clipped to
    the extent, over the cell clipped to the extent; times the outline's test of the hit
    for a round or polygonal blank."""
    surface = scene.surface
    x0, x1, y0, y1 = surface.extent
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    cos_r, sin_r = jnp.cos(surface.rotation), jnp.sin(surface.rotation)

    def field(x, y):  # into the surface's own (unrotated) frame
        return (
            cx + cos_r * (x - cx) + sin_r * (y - cy),
            cy - sin_r * (x - cx) + cos_r * (y - cy),
        )

    hu, hv = field(hit_x, hit_y)
    ru, rv = field(px, py)

    def share(hit, rest, lo, hi, half):
        moved = jnp.minimum(hit + half, hi) - jnp.maximum(hit - half, lo)
        own = jnp.minimum(rest + half, hi) - jnp.maximum(rest - half, lo)
        return jnp.clip(moved / own, 0.0, 1.0)

    rows, cols = grid
    fraction = share(hu, ru, x0, x1, 0.5 * (x1 - x0) / (cols - 1)) * share(
        hv, rv, y0, y1, 0.5 * (y1 - y0) / (rows - 1)
    )
    if scene.outline != "rectangle":
        fraction = fraction * inside_outline(scene.outline, (x0, x1, y0, y1), hu, hv)
    return fraction


def mirror_photons(
    scene: MirrorScene, grid: tuple[int, int], hit_iterations: int = 3, band=None
) -> Photons:
    """Trace a ``rows x cols`` grid of photons off a `MirrorScene`: the grid over the
    aperture on the face's rest plane as in `lens_photons` (`band` likewise), the hit
    by `hit_iterations` Newton steps, the reflection about the face's normal, the
    landing on the screen (positions in its ``(s, t)`` frame). A photon whose hit lies
    beyond the blank's edge (its line crosses the rest plane inside the aperture, but
    the face there lies lower and the ray passes the edge: the light leaning out over
    a low edge) misses the mirror: it carries no flux; one that misses the screen's lit
    face is invalid. Flux densities carry the face's reflectance."""
    dtype = scene.surface.heights.dtype
    px, py, d, density, cell_area = _aperture_rays(scene, grid, band)
    hit_x, hit_y, hit_z, hx, hy = ray_surface_hit(
        scene.surface, scene.top, px, py, d, hit_iterations
    )
    normal = _normalise((-hx, -hy, jnp.ones_like(hx)))
    out = reflect_components(d, normal)
    facing = sum(a * b for a, b in zip(d, normal, strict=True)) < 0.0
    # a ray whose hit lies beyond the blank's edge misses the mirror (lost): each
    # photon carries the part of its share of the grid whose hits stay on the face
    # (`_on_face`), and stays valid, as one outside the outline does (measured on a 24^2
    # mirror design: its edge column predicted at 0.53 of the reference's when such
    # photons were invalid, the triangles about them dropped whole)
    on_face = _on_face(scene, px, py, hit_x, hit_y, grid)
    landed, valid = _land((hit_x, hit_y, hit_z), out, facing, scene.screen_pose)
    flux = jnp.where(valid, density * on_face * scene.reflectance.astype(dtype), 0.0)
    photons = _stack_channels([_stack(landed)], [_stack(out)], [flux], [valid], cell_area, dtype)
    return _clip_band(photons, grid, band)


def element_photons(scene, grid: tuple[int, int], hit_iterations: int = 3, band=None):
    """`lens_photons` or `mirror_photons`, by the scene's type."""
    if isinstance(scene, MirrorScene):
        return mirror_photons(scene, grid, hit_iterations, band)
    return lens_photons(scene, grid, hit_iterations, band)


def emission_frame(scene: MeshScene, dtype):
    """Centre, half-width and unit axes of the emission square that covers the generator.

    The centre and half-width are rounded outwards to a coarse grid (a sixteenth of the
    power of two below the bounding radius), so that small changes of the vertices (an
    optimisation step, a finite difference) leave the photon grid where it is.
    """
    sg = jax.lax.stop_gradient
    verts = sg(scene.generator.vertices).astype(dtype)
    centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    radius = jnp.max(jnp.linalg.norm(verts - centre, axis=-1))
    step = 2.0 ** jnp.floor(jnp.log2(radius)) / 16
    centre = jnp.round(centre / step) * step
    # rounding boundaries sit half a step off the grid, away from "round" sizes
    radius = (jnp.ceil(jnp.max(jnp.linalg.norm(verts - centre, axis=-1)) / step + 0.5) + 1) * step
    if isinstance(scene.light, DirectionalLight):
        axis = scene.light.unit_direction.astype(dtype)
    else:
        axis = centre - sg(scene.light.position).astype(dtype)
        axis = axis / jnp.linalg.norm(axis)
    e1, e2 = orthonormal_basis(axis)
    return centre, radius, axis, e1, e2


def _shading_normal(scene: MeshScene, face, bary, vnormals, fnormal):
    if scene.normals == "flat":
        return fnormal
    n = jnp.einsum("pk,pkc->pc", bary, vnormals[scene.generator.faces[face]])
    return n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def mesh_photons(
    scene: MeshScene,
    grid: tuple[int, int],
    batch_size: int = 4096,
    terminal=None,
    band=None,
) -> Photons:
    """Trace a ``rows x cols`` grid of photons through a `MeshScene`.

    The grid spans the square ``[-r, r]^2`` (``r``: the generator's bounding radius,
    rounded up; see `emission_frame`) on the plane through the generator's bounding-box
    centre, perpendicular to the light (a point light's axis points at that centre). Each photon
    follows up to ``scene.interfaces`` interface events (see `MeshScene`); which triangle
    it meets is found among the triangles (`nearest_hits`: brute force for a few, a
    bounding volume hierarchy for more; no derivative),
    and the hit is recomputed from that triangle's vertices so the result is
    differentiable with respect to them.

    `terminal` (optional) replaces the exact last step (occluder test and landing on the
    screen): a function ``(origins (P, 3), directions (P, 3)) -> (points (P, 3), found
    (P,))`` giving where the rays leaving the generator end, for example by tracing them
    in a layered distance map. Terminal points may then lie on occluders.

    `band` (optional) ``(start, count)``: only those grid rows, as in `lens_photons`.
    """
    dtype = scene.generator.vertices.dtype
    centre, radius, axis, e1, e2 = emission_frame(scene, dtype)
    u, v, cell_area = corner_grid(-radius, radius, -radius, radius, grid, dtype, band)
    plane = centre + u[..., None] * e1 + v[..., None] * e2  # (rows, cols, 3)
    plane = plane.reshape(-1, 3)
    if isinstance(scene.light, DirectionalLight):
        d0 = jnp.broadcast_to(axis, plane.shape)
        o0 = plane - 3.0 * radius * axis
        density = jnp.full(plane.shape[:1], 1.0 / jnp.abs(axis[2]), dtype)
    else:
        lp = scene.light.position.astype(dtype)
        o0 = jnp.broadcast_to(lp, plane.shape)
        offset = plane - lp
        r2 = jnp.sum(offset**2, axis=-1)
        d0 = offset / jnp.sqrt(r2)[:, None]
        density = scene.light.intensity * jnp.abs(d0 @ axis) / r2 * emission(scene.light, d0[:, 2])

    rows, cols = u.shape
    positions, directions, densities, valids, limited = [], [], [], [], []
    paths = trace_mesh_rays(scene, o0, d0, density, batch_size, terminal)
    for landed, d, flux, alive, dropped in paths:
        positions.append(landed.reshape(rows, cols, 3))
        directions.append(d.reshape(rows, cols, 3))
        densities.append(flux.reshape(rows, cols))
        valids.append(alive.reshape(rows, cols))
        limited.append(dropped.reshape(rows, cols))
    photons = _stack_channels(positions, directions, densities, valids, cell_area, dtype, limited)
    return _clip_band(photons, grid, band)


def trace_mesh_rays(
    scene: MeshScene,
    o0: Float[Array, "P 3"],
    d0: Float[Array, "P 3"],
    density: Float[Array, " P"],
    batch_size: int = 4096,
    terminal=None,
) -> list[tuple[Array, Array, Array, Array, Array]]:
    """Trace rays from the light exactly through a `MeshScene` to the screen.

    Rays start at `o0` (before the generator) going along unit `d0`, carrying `density`
    (flux, or flux per emission area). See `mesh_photons` for the path rules and for
    `terminal`. **Returns:** one ``(landed (P, 3), direction (P, 3), flux (P,),
    valid (P,), limited (P,))`` per index of refraction; ``flux`` is 0 where not valid;
    ``limited`` is the flux of the rays the interface limit dropped (they met the
    generator again after ``scene.interfaces`` events, or were still inside it), else 0.
    """
    dtype = o0.dtype
    radius = emission_frame(scene, dtype)[1]
    verts = scene.generator.vertices
    triangles = verts[scene.generator.faces]
    fnormals = face_normals(verts, scene.generator.faces)
    fnormals = fnormals / jnp.linalg.norm(fnormals, axis=-1, keepdims=True)
    vnormals = vertex_normals(verts, scene.generator.faces) if scene.normals == "smooth" else None
    occluders = (
        jnp.concatenate([o.vertices[o.faces] for o in scene.occluders]).astype(dtype)
        if scene.occluders
        else None
    )
    # one search tree each (None for a few triangles), built once for every search
    tree = search_tree(triangles)
    occluder_tree = None if occluders is None else search_tree(occluders)
    # rays restart on the triangle they hit (excluded from their next search); `eps`
    # only guards against re-hitting a neighbour through a shared edge by rounding
    eps = 16 * jnp.finfo(dtype).eps * radius

    def blocked(o, d, t_limit):
        if occluders is None:
            return jnp.zeros(o.shape[:1], bool)
        t_occ, _ = nearest_hits(o, d, occluders, eps, batch_size, tree=occluder_tree)
        return t_occ < t_limit

    def interface(ior, event, carry):
        """One interface: the ray meets the generator (refracted or reflected there),
        or leaves it for good."""
        o, d, alive, inside, left, flux, last = carry
        t_near, face = nearest_hits(o, d, triangles, eps, batch_size, last, tree)
        hit = jnp.isfinite(t_near) & ~left
        alive = alive & ~(blocked(o, d, t_near) & hit)  # an occluder before the next hit
        alive = jnp.where(event == 0, alive & hit, alive)  # only light through the generator
        left = left | ~hit
        t, bary = hit_on_triangle(o, d, triangles[face])
        point = o + t[:, None] * d
        nf = fnormals[face]
        normal = _shading_normal(scene, face, bary, vnormals, nf)
        entering = jnp.sum(d * nf, axis=-1) < 0.0
        if scene.material == "mirror":
            new_d = reflect(d, normal)
            factor = jnp.ones_like(t)
        else:
            eta = jnp.where(entering, 1.0 / ior, ior)
            comps, tir, cos_i = refract_components(tuple(d.T), tuple(normal.T), eta)
            new_d = jnp.stack(comps, axis=-1)
            inside_now = jnp.where(tir, ~entering, entering)
            inside = jnp.where(hit, inside_now, inside)
            factor = (
                jnp.where(tir, 1.0, fresnel_transmittance(cos_i, eta))
                if scene.fresnel
                else jnp.ones_like(t)
            )
        last = jnp.where(hit, face, last)
        o = jnp.where(hit[:, None], point, o)
        d = jnp.where(hit[:, None], new_d, d)
        flux = flux * jnp.where(hit, factor, 1.0)
        return o, d, alive, inside, left, flux, last

    paths = []
    for ior in scene.iors:
        false = jnp.zeros(o0.shape[:1], bool)
        carry = (o0, d0, ~false, false, false, density, jnp.full(o0.shape[:1], -1, jnp.int32))
        # the interfaces in a loop, not unrolled: each unrolled one added about 2 s to the
        # compilation of a differentiated render (measured: a sphere's caustic
        # triangles, 2 to 6 interfaces, 8.1 to 17.1 s)
        step = functools.partial(interface, ior)
        with jax.named_scope("interfaces"):  # (the tests find the loop by this name)
            carry = jax.lax.fori_loop(0, scene.interfaces, step, carry)
        o, d, alive, inside, left, flux, last = carry
        # the path needs more interfaces than allowed if it meets the generator again
        t_near, _ = nearest_hits(o, d, triangles, eps, batch_size, last, tree)
        hit = jnp.isfinite(t_near) & ~left
        limited = jnp.where(alive & (hit | inside), flux, 0.0)
        alive = alive & ~hit
        alive = alive & ~inside
        if terminal is None:
            down = d[:, 2] < 0.0
            t_floor = -o[:, 2] / jnp.where(down, d[:, 2], -1.0)
            alive = alive & down & ~blocked(o, d, t_floor)
            landed = o + t_floor[:, None] * d
            landed = landed.at[:, 2].set(0.0)
        else:
            landed, found = terminal(o, d)
            alive = alive & found
        paths.append((landed, d, jnp.where(alive, flux, 0.0), alive, limited))
    return paths
