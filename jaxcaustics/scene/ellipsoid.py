"""Analytic glass ellipsoids (and spheres) as caustic objects, and their scene.

An `Ellipsoid` is the set of points ``x`` with ``|D^-1 R^T (x - c)| = 1`` (``c`` the
centre, ``D = diag(radii)`` the semi-axes, the columns of the orthonormal ``R`` its axes
in world coordinates). An `EllipsoidScene` puts a glass ellipsoid (and opaque ellipsoid
occluders) over the screen ``z = 0``, lit by a `DirectionalLight`; it follows the
conventions of `MeshScene` (indices of refraction, Fresnel, interface budget). The rays
leaving it are traced in `jaxcaustics.methods.spot_lights.exit_rays`.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_bool, check_int
from .mesh import MAX_INTERFACES, Mesh
from .scene import (
    DirectionalLight,
    Effects,
    PlaneReceiver,
    PointLight,
    as_float_array,
    check_finite,
    check_ior,
    check_positive_scalar,
    check_sequence_of,
    is_concrete,
)

# Largest |R^T R - I| entry accepted for an orthonormal rotation.
_ORTHO_TOL = 1e-6
# Most subdivisions of `Ellipsoid.to_mesh`: 20 * 4**8 = 1.3 million faces.
MAX_SUBDIVISIONS = 8


def _check_vector3(value, name: str) -> Array:
    arr = as_float_array(value, name)
    if arr.shape != (3,):
        raise ValueError(f"`{name}` must have shape (3,), got {arr.shape}")
    check_finite(arr, name)
    return arr


def _check_rotation(value, name: str = "rotation") -> Array:
    rot = as_float_array(value, name)
    if rot.shape != (3, 3):
        raise ValueError(f"`{name}` must have shape (3, 3), got {rot.shape}")
    check_finite(rot, name)
    if is_concrete(rot):
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
        if is_concrete(r):
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
        r = check_positive_scalar(radius, "radius")
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


def lowest_z(ellipsoid: Ellipsoid) -> Array:
    return ellipsoid.center[2] - ellipsoid.half_extents[2]


def _overlap(a: Ellipsoid, b: Ellipsoid) -> bool:
    """Whether two (concrete) ellipsoids surely intersect: the spheres inscribed in them
    (about their centres, of their smallest semi-axes) overlap by more than rounding
    (1e-6 relative). Touching is allowed."""
    leaves = (a.center, a.radii, b.center, b.radii)
    if not all(is_concrete(x) for x in leaves):
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
        occluders = check_sequence_of(occluders, "occluders", Ellipsoid)
        for name, ell in [("generator", generator)] + [
            (f"occluders[{k}]", o) for k, o in enumerate(occluders)
        ]:
            leaves = (ell.center, ell.radii, ell.rotation)
            if all(is_concrete(x) for x in leaves):
                low = float(lowest_z(ell))
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
        self.ior = check_ior(ior)
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
