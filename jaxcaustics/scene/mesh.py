"""Triangle meshes and the mesh scene: a refracting or mirroring object over a screen.

A `Mesh` holds vertex positions (a differentiable leaf, metres) and triangle indices.
Meshes come from trimesh (`Mesh.from_trimesh`, `Mesh.load` for OBJ/STL/PLY files, or any
`trimesh.creation` primitive). Which triangle a ray hits is a non-differentiable choice;
the hit point and normal are then recomputed from that triangle's vertices, so images are
differentiable with respect to vertex positions.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._checks import check_bool, check_choice, check_int, check_real_array
from .scene import (
    DirectionalLight,
    Effects,
    PlaneReceiver,
    PointLight,
    as_float_array,
    check_finite,
    check_ior,
    check_light,
    check_sequence_of,
    is_concrete,
)

MATERIALS = ("refractor", "mirror")
NORMALS = ("smooth", "flat")
# Most interfaces a photon path may meet: the tracers loop this many times per photon.
MAX_INTERFACES = 1000


class Mesh(eqx.Module):
    """A triangle mesh.

    **Arguments:**

    - `vertices`: shape ``(V, 3)``, metres (a pytree leaf: differentiable).
    - `faces`: shape ``(F, 3)`` integer vertex indices, counter-clockwise seen from
      outside (outward normals), as trimesh stores them.
    """

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]

    def __init__(self, vertices, faces):
        v = as_float_array(vertices, "vertices")
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"`vertices` must have shape (V, 3), got {v.shape}")
        check_finite(v, "vertices")
        f = check_real_array(faces, "faces") if is_concrete(faces) else faces
        if f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"`faces` must have shape (F, 3), got {f.shape}")
        if f.shape[0] == 0:
            raise ValueError("`faces` is empty: the mesh has no triangles")
        if is_concrete(f):
            if not np.issubdtype(f.dtype, np.integer):
                raise ValueError(f"`faces` must hold integer indices, got dtype {f.dtype}")
            if f.min() < 0 or f.max() >= v.shape[0]:
                raise ValueError(
                    f"`faces` indices must lie in [0, {v.shape[0] - 1}] (`vertices` has "
                    f"{v.shape[0]} rows), got [{int(f.min())}, {int(f.max())}]"
                )
        self.vertices = v
        self.faces = jnp.asarray(f, dtype=jnp.int32)

    @classmethod
    def from_trimesh(cls, mesh) -> Mesh:
        """From a `trimesh.Trimesh` (for example ``trimesh.creation.icosphere()``)."""
        faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
        if faces.size == 0:
            raise ValueError("`mesh` has no faces")
        if not hasattr(mesh, "vertices"):
            raise ValueError(f"`mesh` has no vertices: a {type(mesh).__name__}")
        try:
            return cls(np.asarray(mesh.vertices), faces)
        except ValueError as err:
            raise ValueError(f"`mesh` is not a valid mesh: {err}") from err

    @classmethod
    def load(cls, path: str | os.PathLike) -> Mesh:
        """Read an OBJ, STL, PLY (any format trimesh reads) file as one mesh."""
        import trimesh

        if not isinstance(path, (str, os.PathLike)):
            raise ValueError(f"`path` must be a str or os.PathLike, got {type(path).__name__}")
        path = os.fspath(path)
        if not isinstance(path, str) or not os.path.isfile(path):
            raise ValueError(f"`path` {path!r} does not exist or is not a file")
        try:
            loaded = trimesh.load(path, force="mesh")
        except Exception as err:  # noqa: BLE001 - re-raised with the argument's name
            raise ValueError(f"`path` {path!r} could not be read as a mesh: {err}") from err
        if not hasattr(loaded, "faces") or len(loaded.faces) == 0:
            raise ValueError(f"`path` {path!r} holds no triangles")
        return cls.from_trimesh(loaded)

    def to_trimesh(self):
        """A `trimesh.Trimesh` copy (NumPy arrays; not differentiable)."""
        import trimesh

        return trimesh.Trimesh(np.asarray(self.vertices), np.asarray(self.faces), process=False)

    @property
    def triangles(self) -> Float[Array, "F 3 3"]:
        """Vertex positions per face, ``(F, 3 vertices, 3 coordinates)``."""
        return self.vertices[self.faces]

    def is_watertight(self) -> bool:
        """Every edge is shared by exactly two faces with opposite orientations."""
        f = np.asarray(self.faces)
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        directed, counts = np.unique(edges, axis=0, return_counts=True)
        if np.any(counts != 1):
            return False
        reverse = {tuple(e) for e in directed[:, ::-1].tolist()}
        return all(tuple(e) in reverse for e in directed.tolist())

    def signed_volume(self) -> float:
        """The enclosed volume by the divergence theorem (m^3): positive when the faces
        are wound counter-clockwise seen from outside (outward normals), negative when
        the mesh is inside out. Meaningful for a closed mesh."""
        v = np.asarray(self.vertices, dtype=float)
        a, b, c = (v[np.asarray(self.faces)[:, k]] for k in range(3))
        return float(np.sum(a * np.cross(b, c)) / 6.0)


class MeshScene(eqx.Module):
    """A mesh caustic generator (glass object or mirror) over a screen, lit from above.

    The receiver (screen) is the plane ``z = 0``; the generator and the occluders lie
    above it. Photons leave the light, hit the generator, refract into it (or reflect off
    a mirror), may totally reflect inside, and after leaving it land on the screen unless
    an occluder stops them. Only light that went through (or off) the generator is
    rendered: the caustic, without the direct light around it.

    **Arguments:**

    - `generator`: a closed (watertight) `Mesh` for a refractor; any `Mesh` for a mirror.
    - `light`: a `DirectionalLight` or a `PointLight`.
    - `receiver`: a `PlaneReceiver` on ``z = 0``.
    - `material`: ``"refractor"`` (glass, index `ior`) or ``"mirror"`` (static).
    - `ior`: index of refraction inside the refractor (static); a sequence gives one
      channel per index. Ignored by mirrors.
    - `fresnel`: multiply photons by the exact unpolarised Fresnel factor at every
      interface (transmittance when refracting, reflectance at a mirror is taken as 1).
    - `interfaces`: how many interfaces a photon path may cross or reflect from at most
      (static, >= 1); a photon still inside the object after that many is dropped.
      Two is enough for convex glass (enter, leave); more follows internal reflections.
    - `occluders`: opaque `Mesh` objects; a photon path that meets one is stopped.
    - `normals`: ``"smooth"`` (vertex normals interpolated across each triangle, the
      object the mesh approximates) or ``"flat"`` (face normals: the faceted object).
    """

    generator: Mesh
    light: DirectionalLight | PointLight
    receiver: PlaneReceiver
    occluders: tuple[Mesh, ...]
    material: str = eqx.field(static=True)
    ior: float | tuple[float, ...] = eqx.field(static=True)
    fresnel: bool = eqx.field(static=True)
    interfaces: int = eqx.field(static=True)
    normals: str = eqx.field(static=True)

    def __init__(
        self,
        generator: Mesh,
        light: DirectionalLight | PointLight,
        receiver: PlaneReceiver,
        *,
        material: str = "refractor",
        ior: float | Sequence[float] = 1.5,
        fresnel: bool = False,
        interfaces: int = 2,
        occluders: Sequence[Mesh] = (),
        normals: str = "smooth",
    ):
        if not isinstance(generator, Mesh):
            raise ValueError(f"`generator` must be a Mesh, got {type(generator).__name__}")
        check_light(light)
        if not isinstance(receiver, PlaneReceiver):
            raise ValueError(f"`receiver` must be a PlaneReceiver, got {type(receiver).__name__}")
        check_choice(material, "material", MATERIALS)
        check_choice(normals, "normals", NORMALS)
        interfaces = check_int(interfaces, "interfaces", 1, MAX_INTERFACES)
        occluders = check_sequence_of(occluders, "occluders", Mesh)
        if (
            material == "refractor"
            and is_concrete(generator.faces)
            and not generator.is_watertight()
        ):
            raise ValueError(
                "`generator` must be a closed (watertight) mesh for a refractor: some edges"
                " are not shared by exactly two consistently oriented faces"
            )
        if (
            material == "refractor"
            and is_concrete(generator.vertices)
            and is_concrete(generator.faces)
            and generator.signed_volume() <= 0.0
        ):  # it passes the watertight check, and rendered an all-zero image
            raise ValueError(
                "`generator` is inside out: its faces are wound inwards (signed volume "
                f"{generator.signed_volume():.3g} m^3 <= 0); reverse them (faces[:, ::-1])"
            )
        if (
            isinstance(light, PointLight)
            and is_concrete(light.position)
            and is_concrete(generator.vertices)
        ):
            lo = np.asarray(generator.vertices).min(axis=0)
            hi = np.asarray(generator.vertices).max(axis=0)
            p = np.asarray(light.position, dtype=float)
            if p[2] < lo[2] or bool(np.all((p >= lo) & (p <= hi))):
                where = "below" if p[2] < lo[2] else "inside the bounding box of"
                raise ValueError(
                    f"`light` at {p.tolist()} is {where} the generator (z from {lo[2]:.4g} "
                    f"to {hi[2]:.4g}): it must light the object from outside its bounding "
                    "box, not from below"
                )
        for name, mesh in [("generator", generator)] + [
            (f"occluders[{k}]", o) for k, o in enumerate(occluders)
        ]:
            if is_concrete(mesh.vertices) and float(np.min(np.asarray(mesh.vertices)[:, 2])) < 0:
                raise ValueError(f"`{name}` reaches below the screen (z < 0)")
        self.generator = generator
        self.light = light
        self.receiver = receiver
        self.occluders = occluders
        self.material = material
        self.ior = check_ior(ior)
        self.fresnel = check_bool(fresnel, "fresnel")
        self.interfaces = interfaces
        self.normals = normals

    @property
    def iors(self) -> tuple[float, ...]:
        """The indices of refraction as a tuple, one per image channel (mirror: one)."""
        if self.material == "mirror":
            return (1.0,)
        return self.ior if isinstance(self.ior, tuple) else (self.ior,)

    @property
    def effects(self) -> Effects:
        """What rendering this scene will trace."""
        refractor = self.material == "refractor"
        return Effects(
            refraction=refractor,
            reflection=not refractor,
            fresnel=self.fresnel and refractor,  # a mirror's reflectance is taken as 1
            total_internal_reflection=refractor,
            dispersion_channels=len(self.iors),
            occlusion=bool(self.occluders),
            interfaces=self.interfaces,
        )
