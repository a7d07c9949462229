"""The rays leaving a caustic object: the first step of Liu et al.'s caustic spot lights.

`trace_exit_rays` (Liu, Dong, Bao & Peng 2008, section 3.1) casts a regular grid of
parallel rays at a caustic object (an ellipsoid scene, traced with exact ray/quadric
intersections, or a mesh scene) and keeps the origin, direction and power of every ray
that leaves it. It is jittable, vmappable over the light's direction and differentiable
with respect to the object.
"""

from __future__ import annotations

import numbers

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._checks import check_fits, check_int, check_memory_limit
from ...scene.ellipsoid import Ellipsoid, EllipsoidScene
from ...scene.mesh import MeshScene
from ...scene.scene import (
    DirectionalLight,
    as_float_array,
    is_concrete,
)
from ...trace.optics import fresnel_transmittance, orthonormal_basis, refract_components
from ...trace.photons import emission_frame, trace_mesh_rays


class ExitRays(eqx.Module):
    """The rays leaving a caustic object (Liu et al.'s "caustic object rays").

    - `origin`: ``(R, 3)``, where each ray leaves the object, metres.
    - `direction`: ``(R, 3)``, unit direction of travel after leaving it.
    - `energy`: ``(R,)``, the power the ray carries for a light of unit irradiance
      *perpendicular to its direction*: the emission cell's area ``spacing**2`` (m^2)
      times the Fresnel transmittances met (when the scene has Fresnel on). Exactly 0
      for rays that missed the object, were still inside after the scene's
      ``interfaces`` events, or are otherwise invalid (their origin and direction are
      then meaningless). Multiply by ``1 / |d_z|`` (``d`` the light's unit direction)
      for the library's image units: flux relative to the irradiance the light gives a
      horizontal plane.
    - `spacing`: scalar, the emission grid's spacing perpendicular to the light, metres.
    - `centre`: ``(3,)``, centre of the object's axis-aligned bounding box, metres.
    - `size`: scalar, the largest side of that box, metres.
    """

    origin: Float[Array, "R 3"]
    direction: Float[Array, "R 3"]
    energy: Float[Array, " R"]
    spacing: Float[Array, ""]
    centre: Float[Array, "3"]
    size: Float[Array, ""]

    @property
    def valid(self) -> Array:
        """``(R,)`` bool: the ray left the object (its energy is positive)."""
        return self.energy > 0.0


def _square_grid(centre, half, direction, n: int):
    """Cell centres of an ``n x n`` grid over ``[-half, half]^2`` on the plane through
    `centre` perpendicular to unit `direction` (axes `orthonormal_basis`, columns along
    ``e1``, rows along ``e2``, row-major), and the spacing."""
    e1, e2 = orthonormal_basis(direction)
    spacing = 2.0 * half / n
    s = (jnp.arange(n, dtype=direction.dtype) + 0.5) * spacing - half
    u, v = jnp.meshgrid(s, s)
    plane = centre + u.reshape(-1, 1) * e1 + v.reshape(-1, 1) * e2
    return plane, spacing


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _unit(v):
    return v / jnp.sqrt(_dot(v, v))


def ellipsoid_hit(ellipsoid: Ellipsoid, o, d, inside):
    """Where rays ``o + t d`` ``(R, 3)`` meet the ellipsoid's surface.

    The ray is mapped into the frame where the ellipsoid is the unit sphere
    (``p = D^-1 R^T (o - c)``, ``q = D^-1 R^T d``) and ``|p + t q|^2 = 1`` is solved:
    from outside the near root (``c / (-b + sqrt(b^2 - a c))``, free of cancellation),
    from inside (`inside`, ``(R,)``) the far root.

    **Returns:** ``(t (R,), hit (R,), normal (R, 3))``: the ray parameter, whether there
    is such a hit, and the unit outward normal ``R D^-2 R^T (x - c)`` normalised there.
    ``t`` is 0 where there is no hit (values and gradients stay finite).
    """
    rot, radii = ellipsoid.rotation, ellipsoid.radii
    p = ((o - ellipsoid.center) @ rot) / radii
    q = (d @ rot) / radii
    a, b, c = _dot(q, q), _dot(p, q), _dot(p, p) - 1.0
    disc = b * b - a * c
    real = disc > 0.0
    root = jnp.sqrt(jnp.where(real, disc, 1.0))
    far = -b + root  # a times the far root
    ahead = far > 0.0
    t_out = c / jnp.where(ahead, far, 1.0)
    t_in = far / a
    hit = real & ahead
    t = jnp.where(hit, jnp.where(inside, t_in, t_out), 0.0)
    m = (p + t[:, None] * q) / radii  # D^-1 (unit-frame point)
    normal = m @ rot.T
    length = jnp.sqrt(jnp.where(hit, _dot(normal, normal), 1.0))
    return t, hit, normal / length[:, None]


def _trace_ellipsoid_paths(ellipsoid: Ellipsoid, o, d, ior, interfaces: int, fresnel: bool):
    """Follow rays ``o + t d`` ``(R, 3)`` (starting outside) through a glass ellipsoid
    of index `ior` for at most `interfaces` events (refraction, or reflection under total
    internal reflection).

    The events are a `jax.lax.scan` (one compiled step, whatever `interfaces`): at the
    first a ray enters if it meets the surface; later only rays still inside move.

    **Returns:** ``(origin (R, 3), direction (R, 3), factor (R,), valid (R,))``: the last
    event's point and the direction after it, the product of the Fresnel transmittances
    (1 without `fresnel`), and whether the ray met the object and left it.
    """

    def event(carry, first):
        o, d, inside, met, factor = carry
        t, hit, normal = ellipsoid_hit(ellipsoid, o, d, inside)
        active = hit & (inside | first)
        eta = jnp.where(inside, ior, 1.0 / ior)
        comps, tir, cos_i = refract_components(tuple(d.T), tuple(normal.T), eta)
        if fresnel:
            step = jnp.where(tir, 1.0, fresnel_transmittance(cos_i, eta))
            factor = factor * jnp.where(active, step, 1.0)
        o = jnp.where(active[:, None], o + t[:, None] * d, o)
        d = jnp.where(active[:, None], jnp.stack(comps, axis=-1), d)
        inside = jnp.where(active, jnp.where(tir, inside, ~inside), inside)
        return (o, d, inside, met | active, factor), None

    none = jnp.zeros(o.shape[:1], bool)
    first = jnp.arange(interfaces) == 0
    carry = (o, d, none, none, jnp.ones(o.shape[:1], o.dtype))
    (o, d, inside, met, factor), _ = jax.lax.scan(event, carry, first)
    return o, d, factor, met & ~inside


@eqx.filter_jit
def _ellipsoid_exit_rays(
    ell: Ellipsoid, direction, n: int, ior: Array, interfaces: int, fresnel: bool
) -> ExitRays:
    """`trace_exit_rays` for an ellipsoid. Compiled for the generator alone (the scene's
    light and receiver play no part) with the index of refraction `ior` traced, so all
    channels and indices share one compilation."""
    dtype = ell.center.dtype
    direction = _unit(direction.astype(dtype))
    ior = ior.astype(dtype)
    half = ell.bounding_radius
    plane, spacing = _square_grid(ell.center, half, direction, n)
    o0 = plane - 3.0 * half * direction
    d0 = jnp.broadcast_to(direction, o0.shape)
    o, d, factor, valid = _trace_ellipsoid_paths(ell, o0, d0, ior, interfaces, fresnel)
    energy = jnp.where(valid, spacing * spacing * factor, 0.0)
    size = 2.0 * jnp.max(ell.half_extents)
    return ExitRays(o, d, energy, spacing, ell.center, size)


@eqx.filter_jit
def _mesh_exit_rays(scene: MeshScene, direction, n: int, channel: int) -> ExitRays:
    """`trace_exit_rays` for a mesh scene."""
    verts = scene.generator.vertices
    dtype = verts.dtype
    direction = _unit(direction.astype(dtype))
    centre, radius = emission_frame(scene, dtype)[:2]
    plane, spacing = _square_grid(centre, radius, direction, n)
    o0 = plane - 3.0 * radius * direction
    d0 = jnp.broadcast_to(direction, o0.shape)
    density = jnp.full(o0.shape[:1], spacing * spacing, dtype)
    refractor = scene.material == "refractor"
    single = MeshScene(  # this channel only, no occluders
        scene.generator,
        scene.light,
        scene.receiver,
        material=scene.material,
        ior=scene.iors[channel] if refractor else scene.ior,
        fresnel=scene.fresnel,
        interfaces=scene.interfaces,
        normals=scene.normals,
    )

    def leave(origin, dirn):  # the rays end where they leave the object
        return origin, jnp.ones(origin.shape[:1], bool)

    ((o, d, energy, _, _),) = trace_mesh_rays(single, o0, d0, density, terminal=leave)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    return ExitRays(o, d, energy, spacing, 0.5 * (lo + hi), jnp.max(hi - lo))


EXIT_RAY_FLOATS = 32
"""Numbers one ray takes while `trace_exit_rays` traces it (the exit ray and XLA's
temporaries: 20 measured in float64 for an ellipsoid), for its memory estimate."""


def trace_exit_rays(
    scene: EllipsoidScene | MeshScene,
    rays_per_axis: int,
    *,
    direction=None,
    channel: int = 0,
    memory_limit: int | None = None,
) -> ExitRays:
    """Cast a grid of parallel rays at a caustic object; the rays that leave it.

    A square grid of ``rays_per_axis**2`` parallel rays (one at each cell centre) covers
    the object's bounding sphere, seen along `direction`: for an ellipsoid the sphere
    about its `center` of radius `bounding_radius` (the grid moves and scales with the
    ellipsoid: it is part of the differentiable function), for a mesh the generator's
    bounding sphere rounded outwards (see `emission_frame`; held fixed under
    differentiation). Each ray starts three radii before the grid's plane, refracts into
    the object (index ``scene.iors[channel]``), meets the surface from inside (total
    internal reflection reflects it and it goes on), refracts out and becomes an exit
    ray, with at most ``scene.interfaces`` events; a ray still inside after them is
    dropped. Occluders are ignored (they matter only when rendering). Ellipsoids are
    intersected exactly (ray/quadric roots); meshes by `trace_mesh_rays`.

    **Arguments:**

    - `scene`: an `EllipsoidScene` or a `MeshScene`.
    - `rays_per_axis`: rays along each side of the grid (static int, >= 2).
    - `direction`: shape ``(3,)``, the light's direction of travel (normalised here):
      any direction, up or sideways included. Default: the scene light's
      `unit_direction` (required for a mesh scene with a point light). It may be traced:
      ``jax.vmap`` over directions works.
    - `channel`: which index of refraction of the scene to use (static int).
    - `memory_limit`: bytes the tracing may take (default 1 GiB; `EXIT_RAY_FLOATS`
      numbers a ray): a larger grid raises a `ValueError` before anything is compiled.

    **Returns:** an `ExitRays` with ``R = rays_per_axis**2`` rays (row-major over the
    grid); rays that did not leave the object have energy 0.
    """
    if not isinstance(scene, (EllipsoidScene, MeshScene)):
        raise ValueError(
            f"`scene` must be an EllipsoidScene or a MeshScene, got {type(scene).__name__}"
        )
    rays_per_axis = check_int(rays_per_axis, "rays_per_axis", 2)
    channels = len(scene.iors)
    if (
        isinstance(channel, bool)
        or not isinstance(channel, numbers.Integral)
        or not 0 <= channel < channels
    ):
        raise ValueError(
            f"`channel` must be an integer in [0, {channels - 1}] (the scene has {channels} "
            f"index of refraction channel(s)), got {channel!r}"
        )
    if direction is None:
        if not isinstance(scene.light, DirectionalLight):
            raise ValueError("`direction` is required: the scene's light is not a DirectionalLight")
        direction = scene.light.unit_direction
    if not isinstance(direction, jax.Array):
        direction = as_float_array(direction, "direction")
    if direction.shape != (3,) or not jnp.issubdtype(direction.dtype, jnp.floating):
        raise ValueError(
            f"`direction` must be a float array of shape (3,), got {direction.dtype} "
            f"{direction.shape}"
        )
    if is_concrete(direction):
        d = np.asarray(direction)
        if not np.all(np.isfinite(d)) or not np.any(d):
            raise ValueError(f"`direction` must be finite and non-zero, got {d.tolist()}")
    check_fits(
        rays_per_axis**2 * EXIT_RAY_FLOATS * direction.dtype.itemsize,
        check_memory_limit(memory_limit),
        f"tracing {rays_per_axis}^2 rays",
        "lower `rays_per_axis`",
    )
    n, channel = int(rays_per_axis), int(channel)
    if isinstance(scene, MeshScene):
        return _mesh_exit_rays(scene, direction, n, channel)
    ior = jnp.asarray(scene.iors[channel])
    return _ellipsoid_exit_rays(scene.generator, direction, n, ior, scene.interfaces, scene.fresnel)
