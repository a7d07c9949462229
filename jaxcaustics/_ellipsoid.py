"""Analytic glass ellipsoids (and spheres) as caustic objects, and the rays leaving them.

An `Ellipsoid` is the set of points ``x`` with ``|D^-1 R^T (x - c)| = 1`` (``c`` the
centre, ``D = diag(radii)`` the semi-axes, the columns of the orthonormal ``R`` its axes
in world coordinates). An `EllipsoidScene` puts a glass ellipsoid (and opaque ellipsoid
occluders) over the screen ``z = 0``, lit by a `DirectionalLight`; it follows the
conventions of `MeshScene` (indices of refraction, Fresnel, interface budget).

`trace_exit_rays` is the first step of Liu et al.'s caustic spot lights (section 3.1):
cast a regular grid of parallel rays at a caustic object (an ellipsoid scene, traced
with exact ray/quadric intersections, or a mesh scene) and keep the origin, direction
and power of every ray that leaves it. It is jittable, vmappable over the light's
direction and differentiable with respect to the object.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._checks import check_bool, check_int
from ._light_view import orthonormal_basis
from ._mesh import MAX_INTERFACES, Mesh, MeshScene
from ._optics import fresnel_transmittance, refract_components
from ._photons import _emission_frame, trace_mesh_rays
from ._raster import check_fits, check_memory_limit
from ._scene import (
    DirectionalLight,
    Effects,
    PlaneReceiver,
    PointLight,
    _as_float_array,
    _check_finite,
    _check_ior,
    _check_positive_scalar,
    _check_sequence_of,
    _is_concrete,
)

# Largest |R^T R - I| entry accepted for an orthonormal rotation.
_ORTHO_TOL = 1e-6
# Most subdivisions of `Ellipsoid.to_mesh`: 20 * 4**8 = 1.3 million faces.
MAX_SUBDIVISIONS = 8


def _check_vector3(value, name: str) -> Array:
    arr = _as_float_array(value, name)
    if arr.shape != (3,):
        raise ValueError(f"`{name}` must have shape (3,), got {arr.shape}")
    _check_finite(arr, name)
    return arr


def _check_rotation(value, name: str = "rotation") -> Array:
    rot = _as_float_array(value, name)
    if rot.shape != (3, 3):
        raise ValueError(f"`{name}` must have shape (3, 3), got {rot.shape}")
    _check_finite(rot, name)
    if _is_concrete(rot):
        r = np.asarray(rot, dtype=np.float64)
        error = float(np.abs(r.T @ r - np.eye(3)).max())
        if error > _ORTHO_TOL:
            raise ValueError(
                f"`{name}` must be orthonormal (R^T R = I within {_ORTHO_TOL}), "
                f"got an error of {error:.3g}"
            )
    return rot


class Ellipsoid(eqx.Module):
    """A solid ellipsoid: the points ``x`` with ``|D^-1 R^T (x - center)| <= 1``.

    **Arguments:**

    - `center`: shape ``(3,)``, metres.
    - `radii`: shape ``(3,)``, the semi-axes ``D = diag(radii)``, metres (> 0).
    - `rotation`: shape ``(3, 3)``, orthonormal (within 1e-6); its columns are the
      ellipsoid's axes in world coordinates (default: the identity, axes along x, y, z).

    All three are pytree leaves (differentiable). `Ellipsoid.sphere(center, radius)`
    builds a sphere.
    """

    center: Float[Array, "3"]
    radii: Float[Array, "3"]
    rotation: Float[Array, "3 3"]

    def __init__(self, center, radii, rotation=None):
        self.center = _check_vector3(center, "center")
        r = _check_vector3(radii, "radii")
        if _is_concrete(r):
            rn = np.asarray(r)
            if not bool(np.all(rn > 0)):
                raise ValueError(f"`radii` must be positive, got {rn.tolist()}")
            if not bool(np.all(rn * rn >= np.finfo(rn.dtype).tiny)):  # the quadric's 1/r^2
                raise ValueError(f"`radii` are too small for {rn.dtype}: {rn.tolist()}")
        self.radii = r
        if rotation is None:
            rotation = jnp.eye(3, dtype=r.dtype)
        self.rotation = _check_rotation(rotation)

    @classmethod
    def sphere(cls, center, radius) -> Ellipsoid:
        """A sphere of `radius` (scalar, metres, > 0) about `center` ``(3,)``."""
        r = _check_positive_scalar(radius, "radius")
        return cls(center, r * jnp.ones(3, r.dtype))

    @property
    def bounding_radius(self) -> Float[Array, ""]:
        """Radius of the smallest sphere about `center` holding the ellipsoid (the
        largest semi-axis), metres."""
        return jnp.max(self.radii)

    @property
    def half_extents(self) -> Float[Array, "3"]:
        """Half-sides of the axis-aligned bounding box, ``sqrt(sum_j (R_ij r_j)^2)``
        along world axis ``i``, metres."""
        return jnp.sqrt(jnp.sum((self.rotation * self.radii[None, :]) ** 2, axis=1))

    def to_mesh(self, subdivisions: int = 3) -> Mesh:
        """A closed triangle mesh of the surface: trimesh's unit icosphere of
        `subdivisions` levels (``20 * 4**subdivisions`` faces) mapped through
        ``u -> center + R D u`` (vertices on the surface, differentiable; faces
        counter-clockwise seen from outside, also for an improper `rotation`)."""
        import trimesh

        subdivisions = check_int(subdivisions, "subdivisions", 0, MAX_SUBDIVISIONS)
        sphere = trimesh.creation.icosphere(subdivisions)
        unit = jnp.asarray(np.asarray(sphere.vertices), self.radii.dtype)
        # R diag(1, 1, det R) maps the unit sphere onto the same ellipsoid and keeps the
        # orientation of the faces
        sign = jnp.sign(jnp.linalg.det(self.rotation))
        rot = self.rotation * jnp.stack([jnp.ones_like(sign), jnp.ones_like(sign), sign])
        vertices = self.center + (unit * self.radii) @ rot.T
        return Mesh(vertices, np.asarray(sphere.faces))


def _lowest_z(ellipsoid: Ellipsoid) -> Array:
    return ellipsoid.center[2] - ellipsoid.half_extents[2]


def _overlap(a: Ellipsoid, b: Ellipsoid) -> bool:
    """Whether two (concrete) ellipsoids surely intersect: the spheres inscribed in them
    (about their centres, of their smallest semi-axes) overlap by more than rounding
    (1e-6 relative). Touching is allowed."""
    leaves = (a.center, a.radii, b.center, b.radii)
    if not all(_is_concrete(x) for x in leaves):
        return False
    gap = np.linalg.norm(np.asarray(a.center, float) - np.asarray(b.center, float))
    return bool(gap < (float(np.min(a.radii)) + float(np.min(b.radii))) * (1 - 1e-6))


class EllipsoidScene(eqx.Module):
    """A glass ellipsoid over a screen, lit by a directional light.

    The receiver (screen) is the plane ``z = 0``; the generator and the occluders lie
    above it. Light refracts into the glass, may totally reflect inside, refracts out and
    lands on the screen unless an occluder stops it. Only light that went through the
    generator is rendered (no direct light), as in `MeshScene`.

    **Arguments:**

    - `generator`: the glass `Ellipsoid`.
    - `light`: a `DirectionalLight` (point lights are not supported).
    - `receiver`: a `PlaneReceiver` on ``z = 0``.
    - `ior`: index of refraction of the glass (static); a sequence gives one channel per
      index (dispersion).
    - `fresnel`: multiply each ray by the exact unpolarised Fresnel transmittance of
      every refraction (static).
    - `interfaces`: how many interface events (refractions and total internal
      reflections) a path may have at most (static, >= 1); enter and leave make 2, each
      total internal reflection one more. A ray still inside after that many is dropped.
    - `occluders`: opaque `Ellipsoid` objects; a path that meets one is stopped.

    Every ellipsoid must lie above the screen: ``center_z >= sqrt(sum_j (R_zj r_j)^2)``
    (its true lowest point, rotation included).
    """

    generator: Ellipsoid
    light: DirectionalLight
    receiver: PlaneReceiver
    occluders: tuple[Ellipsoid, ...]
    ior: float | tuple[float, ...] = eqx.field(static=True)
    fresnel: bool = eqx.field(static=True)
    interfaces: int = eqx.field(static=True)

    def __init__(
        self,
        generator: Ellipsoid,
        light: DirectionalLight,
        receiver: PlaneReceiver,
        *,
        ior: float | Sequence[float] = 1.5,
        fresnel: bool = False,
        interfaces: int = 2,
        occluders: Sequence[Ellipsoid] = (),
    ):
        if not isinstance(generator, Ellipsoid):
            raise ValueError(f"`generator` must be an Ellipsoid, got {type(generator).__name__}")
        if isinstance(light, PointLight):
            raise ValueError(
                "`light` must be a DirectionalLight: ellipsoid scenes do not support point "
                "lights, got PointLight"
            )
        if not isinstance(light, DirectionalLight):
            raise ValueError(f"`light` must be a DirectionalLight, got {type(light).__name__}")
        if not isinstance(receiver, PlaneReceiver):
            raise ValueError(f"`receiver` must be a PlaneReceiver, got {type(receiver).__name__}")
        interfaces = check_int(interfaces, "interfaces", 1, MAX_INTERFACES)
        occluders = _check_sequence_of(occluders, "occluders", Ellipsoid)
        for name, ell in [("generator", generator)] + [
            (f"occluders[{k}]", o) for k, o in enumerate(occluders)
        ]:
            leaves = (ell.center, ell.radii, ell.rotation)
            if all(_is_concrete(x) for x in leaves):
                low = float(_lowest_z(ell))
                if low < -1e-9 * float(ell.bounding_radius):
                    raise ValueError(
                        f"`{name}` reaches below the screen (z < 0): its lowest point is at "
                        f"z = {low:.6g}"
                    )
        for k, occ in enumerate(occluders):
            if _overlap(generator, occ):
                raise ValueError(
                    f"`occluders[{k}]` intersects the generator: their inscribed spheres "
                    "overlap (two solids cannot share space)"
                )
        self.generator = generator
        self.light = light
        self.receiver = receiver
        self.occluders = occluders
        self.ior = _check_ior(ior)
        self.fresnel = check_bool(fresnel, "fresnel")
        self.interfaces = interfaces

    @property
    def iors(self) -> tuple[float, ...]:
        """The indices of refraction as a tuple, one per image channel."""
        return self.ior if isinstance(self.ior, tuple) else (self.ior,)

    @property
    def effects(self) -> Effects:
        """What rendering this scene will trace."""
        return Effects(
            refraction=True,
            reflection=False,
            fresnel=self.fresnel,
            total_internal_reflection=True,
            dispersion_channels=len(self.iors),
            occlusion=bool(self.occluders),
            interfaces=self.interfaces,
        )


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


def _surface_hit(ellipsoid: Ellipsoid, o, d, inside):
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
        t, hit, normal = _surface_hit(ellipsoid, o, d, inside)
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
    centre, radius = _emission_frame(scene, dtype)[:2]
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

    ((o, d, energy, _),) = trace_mesh_rays(single, o0, d0, density, terminal=leave)
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
    bounding sphere rounded outwards (see `_emission_frame`; held fixed under
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
        direction = _as_float_array(direction, "direction")
    if direction.shape != (3,) or not jnp.issubdtype(direction.dtype, jnp.floating):
        raise ValueError(
            f"`direction` must be a float array of shape (3,), got {direction.dtype} "
            f"{direction.shape}"
        )
    if _is_concrete(direction):
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
