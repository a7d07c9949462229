"""Scene types: plain data as pytrees (Equinox modules).

Conventions (the same everywhere in the library):

- lengths are in metres; the ground (receiver) plane is ``z = 0`` and ``z`` points up;
- 2-D arrays are indexed ``[row, col] = [y, x]``;
- an extent is ``(x_min, x_max, y_min, y_max)`` and covers the outer *edges* of the
  pixels, so pixel ``(i, j)`` of an array of shape ``(rows, cols)`` has its centre at
  ``x = x_min + (j + 0.5) * dx``, ``y = y_min + (i + 0.5) * dy``;
- irradiance is relative to the irradiance the light gives a horizontal plane, so flat
  water gives exactly 1.0 at any light angle (Fresnel off).

Array fields are pytree leaves (traced, differentiable); everything that fixes shapes or
control flow (boundary mode, receiver shape, indices of refraction, Fresnel on/off) is
static, so ``jax.jit`` specialises on it and effects a scene does not call for are never
traced. Inputs are checked when a scene is built, before anything is compiled.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import (
    check_bool,
    check_choice,
    check_number,
    check_real_array,
    check_shape,
)
from .outline import check_outline
from .screen_pose import ScreenPose
from .values import (
    as_float_array,
    check_extent,
    check_finite,
    check_positive_scalar,
    is_concrete,
)

BOUNDARY_MODES = ("periodic", "clamp", "extrapolate")


class HeightField(eqx.Module):
    """A height field ``z = base + heights(x, y)``, interpolated bicubically.

    The surface between samples is the Catmull-Rom bicubic interpolant of ``heights``
    (C1: continuous normals); samples sit at pixel centres of ``extent``.

    **Arguments:**

    - `heights`: array of shape ``(rows, cols)``, metres, indexed ``[y, x]``.
    - `extent`: ``(x_min, x_max, y_min, y_max)`` in metres, covering the pixel edges.
    - `boundary`: ``"periodic"`` (the surface tiles the plane with period ``extent``) or
      ``"clamp"`` (edge samples extend outwards, so the surface is flat-ish outside) or
      ``"extrapolate"`` (the samples are continued by odd reflection about the edge
      sample, ``h[-k] = 2 h[0] - h[k]``: the surface keeps its edge slope out to the
      extent's edge and 1.5 samples beyond, then levels off; a lens designed with it has
      no flat collar at its rim, which under ``"clamp"`` bends the light of the
      outermost half sample back towards the screen's edge).
    - `rotation`: angle in radians by which the field (its sample grid and `extent`) is
      rotated about the centre of `extent`, counter-clockwise seen from above (+x
      towards +y). A periodic field then tiles the plane along its own rotated axes. A
      scalar array leaf (differentiable); a Python number is stored in the dtype of
      `heights`.
    """

    heights: Float[Array, "rows cols"]
    extent: Float[Array, 4]
    rotation: Float[Array, ""]
    boundary: str = eqx.field(static=True)

    def __init__(self, heights, extent, boundary: str = "periodic", rotation=0.0):
        h = as_float_array(heights, "heights")
        if h.ndim != 2:
            raise ValueError(f"`heights` must be 2-D (rows, cols), got shape {h.shape}")
        if h.shape[0] < 2 or h.shape[1] < 2:
            raise ValueError(f"`heights` needs at least 2x2 samples, got shape {h.shape}")
        check_finite(h, "heights")
        check_choice(boundary, "boundary", BOUNDARY_MODES)
        self.heights = h
        self.extent = check_extent(extent, "extent")
        rot = as_float_array(rotation, "rotation")
        if isinstance(rotation, (int, float)):  # a Python number: the dtype of the heights
            with np.errstate(over="ignore"):
                rot = jnp.asarray(np.asarray(rotation, dtype=h.dtype))
        if rot.shape != ():
            raise ValueError(f"`rotation` must be a scalar (radians), got shape {rot.shape}")
        check_finite(rot, "rotation")
        self.rotation = rot
        self.boundary = boundary

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.heights.shape)  # type: ignore[return-value]


class DirectionalLight(eqx.Module):
    """Collimated light (the Sun, a distant lamp).

    **Arguments:**

    - `direction`: shape ``(3,)``, the direction the light *travels* (not normalised
      necessarily); its ``z`` component must be negative (light going down). Any angle up
      to grazing is allowed.

    Use `DirectionalLight.from_angles(zenith_deg, azimuth_deg)` to build one from angles.
    """

    direction: Float[Array, 3]

    def __init__(self, direction):
        d = as_float_array(direction, "direction")
        if d.shape != (3,):
            raise ValueError(f"`direction` must have shape (3,), got {d.shape}")
        check_finite(d, "direction")
        if is_concrete(d):
            dn = np.asarray(d, dtype=float)
            norm = float(np.linalg.norm(dn))
            if norm == 0.0:
                raise ValueError("`direction` must be non-zero")
            with np.errstate(over="ignore", under="ignore"):  # `unit_direction`'s dtype
                own = float(np.sqrt(np.sum(np.square(np.asarray(d)))))
            if not (math.isfinite(own) and own > 0.0):
                raise ValueError(
                    f"`direction` {dn.tolist()} has a length that over- or underflows "
                    f"{d.dtype}: scale it towards unit length"
                )
            if not dn[2] / norm < -1e-6:
                raise ValueError(
                    f"`direction` is the direction of travel and must point down (z < 0), "
                    f"got {dn.tolist()}"
                )
        self.direction = d

    @classmethod
    def from_angles(cls, zenith_deg: float, azimuth_deg: float = 0.0) -> DirectionalLight:
        """Light arriving at `zenith_deg` from vertical, travelling towards `azimuth_deg`
        (measured from +x towards +y)."""
        zenith = check_number(zenith_deg, "zenith_deg", low=0.0, high=90.0, high_open=True)
        z = math.radians(zenith)
        a = math.radians(check_number(azimuth_deg, "azimuth_deg"))
        if not -math.cos(z) < -1e-6:  # what `DirectionalLight` accepts as going down
            raise ValueError(f"`zenith_deg` {zenith} is too close to 90 (grazing light)")
        return cls([math.sin(z) * math.cos(a), math.sin(z) * math.sin(a), -math.cos(z)])

    @property
    def unit_direction(self) -> Float[Array, 3]:
        return self.direction / jnp.linalg.norm(self.direction)


class PlaneReceiver(eqx.Module):
    """The ground plane ``z = 0`` with a pixel grid: the caustic map.

    **Arguments:**

    - `extent`: ``(x_min, x_max, y_min, y_max)`` in metres, covering pixel edges.
    - `shape`: ``(rows, cols)`` pixels.
    """

    extent: Float[Array, 4]
    shape: tuple[int, int] = eqx.field(static=True)

    def __init__(self, extent, shape: Sequence[int]):
        self.extent = check_extent(extent, "extent")
        self.shape = check_shape(shape, "shape")

    @property
    def pixel_size(self) -> tuple[Array, Array]:
        """``(dx, dy)`` in metres."""
        return (
            (self.extent[1] - self.extent[0]) / self.shape[1],
            (self.extent[3] - self.extent[2]) / self.shape[0],
        )


@dataclasses.dataclass(frozen=True)
class Effects:
    """What a scene will simulate (static configuration; see `WaterScene.effects`): each
    scene's `effects` property builds one, and the methods read it to tell whether they
    support the scene.

    **Arguments:**

    - `refraction`: light is refracted at the surface (water, glass; ``False`` for a
      mirror mesh).
    - `reflection`: light is reflected (a mirror mesh).
    - `fresnel`: photons are weighted by the Fresnel transmittance of each refraction
      (the scene's `fresnel`; a mirror's reflectance is taken as 1).
    - `total_internal_reflection`: total internal reflection can happen and is traced
      (water of index below 1, the bottom face of a lens, a glass mesh or ellipsoid).
    - `dispersion_channels`: the number of indices of refraction, one image channel each.
    - `occlusion`: the scene has occluders that stop light (a photon path that meets one
      is stopped).
    - `interfaces`: the most interfaces a photon path crosses or reflects from (water 1,
      a lens 2, a mesh or an ellipsoid its scene's `interfaces`).
    """

    refraction: bool
    reflection: bool
    fresnel: bool
    total_internal_reflection: bool
    dispersion_channels: int
    occlusion: bool
    interfaces: int


def _check_surface_above(surface, depth, depth_name: str, failure: str) -> None:
    """Refuse (concrete) heights that reach below their base: ``depth + min(heights)
    <= 0``, `depth` the rest plane's height above what lies beneath."""
    if is_concrete(surface.heights) and is_concrete(depth):
        low = float(np.min(np.asarray(surface.heights)))
        if float(depth) + low <= 0.0:
            raise ValueError(
                f"`surface` {failure}: {depth_name} {float(depth)} + min(heights) {low} <= 0 "
                "(impossible geometry)"
            )


# Indices of refraction accepted (relative indices of real media lie well inside), and
# the most channels (indices) one scene may hold: each is a channel of every image.
IOR_RANGE = (0.01, 100.0)
MAX_CHANNELS = 64


def check_ior(ior) -> float | tuple[float, ...]:
    """A number gives a float, a sequence (list, tuple, 1-D array) a tuple of floats."""
    items = ior if isinstance(ior, (list, tuple)) else [ior]
    if any(isinstance(v, (bool, np.bool_)) for v in items):  # 1.0 in disguise
        raise ValueError(f"`ior` must be a number or a sequence of numbers, got {ior!r}")
    arr = check_real_array(ior, "ior")  # traced values are refused here: `ior` is static
    if arr.ndim > 1 or not 1 <= arr.size <= MAX_CHANNELS:
        raise ValueError(
            f"`ior` must be a number or a sequence of 1 to {MAX_CHANNELS} numbers, got {ior!r}"
        )
    values = tuple(float(v) for v in arr.ravel())
    low, high = IOR_RANGE
    if not all(low <= v <= high for v in values):
        raise ValueError(f"`ior` values must be in [{low}, {high}], got {values}")
    return values[0] if arr.ndim == 0 else values


def check_sequence_of(items, name: str, kind: type) -> tuple:
    """`items` (a list or tuple of `kind` objects) as a tuple, else a `ValueError`."""
    if not isinstance(items, (list, tuple)):
        raise ValueError(
            f"`{name}` must be a list or tuple of {kind.__name__} objects, got "
            f"{type(items).__name__}"
        )
    for k, item in enumerate(items):
        if not isinstance(item, kind):
            raise ValueError(f"`{name}[{k}]` must be a {kind.__name__}, got {type(item).__name__}")
    return tuple(items)


class WaterScene(eqx.Module):
    """Water with a height-field surface over a flat ground, lit from above.

    The ground (receiver) is ``z = 0``; the water surface is
    ``z = rest_depth + surface.heights``. Light refracts once, from the medium above
    (index 1) into the water (index ``ior``), then lands on the ground.

    **Arguments:**

    - `surface`: a `HeightField` (heights in metres).
    - `light`: a `DirectionalLight`.
    - `receiver`: a `PlaneReceiver` (the caustic map's grid on the ground).
    - `rest_depth`: depth of the flat water surface above the ground, metres (> 0); the
      surface must stay above the ground (``rest_depth + min(heights) > 0``).
    - `ior`: relative index of refraction below/above the surface. A number gives a
      single-channel image of shape ``(rows, cols)``; a sequence gives one channel per
      index (dispersion), an image of shape ``(rows, cols, channels)``. Values below 1
      (a denser medium above) allow total internal reflection, whose photons are lost.
    - `fresnel`: multiply each photon by the exact unpolarised dielectric transmittance.
    """

    surface: HeightField
    light: DirectionalLight
    receiver: PlaneReceiver
    rest_depth: Float[Array, ""]
    ior: float | tuple[float, ...] = eqx.field(static=True)
    fresnel: bool = eqx.field(static=True)

    def __init__(
        self,
        surface: HeightField,
        light: DirectionalLight,
        receiver: PlaneReceiver,
        rest_depth=1.0,
        *,
        ior: float | Sequence[float] = 1.333,
        fresnel: bool = False,
    ):
        for name, value, kind in (
            ("surface", surface, HeightField),
            ("light", light, DirectionalLight),
            ("receiver", receiver, PlaneReceiver),
        ):
            if not isinstance(value, kind):
                raise ValueError(f"`{name}` must be a {kind.__name__}, got {type(value).__name__}")
        self.surface = surface
        self.light = light
        self.receiver = receiver
        self.rest_depth = check_positive_scalar(rest_depth, "rest_depth")
        self.ior = check_ior(ior)
        self.fresnel = check_bool(fresnel, "fresnel")
        _check_surface_above(surface, self.rest_depth, "rest_depth", "reaches the ground")

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
            # possible below index 1; at exactly 1 only for grazing light, which the
            # refraction kernel still tests for (`tir_possible`)
            total_internal_reflection=min(self.iors) <= 1.0,
            dispersion_channels=len(self.iors),
            occlusion=False,
            interfaces=1,
        )


class PointLight(eqx.Module):
    """An isotropic point light (a bare lamp, an LED at a finite distance).

    **Arguments:**

    - `position`: shape ``(3,)``, metres. It must lie above everything it lights.
    - `intensity`: radiant intensity, W/sr (> 0). A receiver element at distance ``r``
      whose normal makes the angle ``theta`` with the ray gets the irradiance
      ``intensity cos(theta) / r^2`` (W/m^2) straight from the lamp; images of scenes lit
      by a point light are in these units.
    """

    position: Float[Array, 3]
    intensity: Float[Array, ""]

    def __init__(self, position, intensity=1.0):
        p = as_float_array(position, "position")
        if p.shape != (3,):
            raise ValueError(f"`position` must have shape (3,), got {p.shape}")
        check_finite(p, "position")
        if is_concrete(p) and not float(p[2]) > 0.0:
            raise ValueError(
                f"`position` must be above the receiver plane z = 0, got z = {float(p[2])}"
            )
        self.position = p
        self.intensity = check_positive_scalar(intensity, "intensity")


Light = DirectionalLight | PointLight


def emission(light, dz):
    """A point light's intensity towards directions whose ``z`` components are `dz`,
    relative to its `intensity`: 1 (isotropic), or ``|dz|`` for an emitter facing down
    with ``lambertian`` set (`AreaLight`: Lambert's cosine law). NumPy or JAX."""
    return abs(dz) if getattr(light, "lambertian", False) else 1.0


def check_light(light) -> None:
    if not isinstance(light, (DirectionalLight, PointLight)):
        raise ValueError(
            f"`light` must be a DirectionalLight or a PointLight, got {type(light).__name__}"
        )


def _check_lens_pose(pose, bottom):
    """`pose` if it is None or a `ScreenPose` below the bottom face ``z = bottom`` with its
    lit face up (the light leaves the lens going down)."""
    if pose is None:
        return None
    if not isinstance(pose, ScreenPose):
        raise ValueError(f"`screen_pose` must be a ScreenPose or None, got {type(pose).__name__}")
    if is_concrete(pose.centre) and is_concrete(bottom):
        if not float(pose.normal[2]) > 0.0:
            raise ValueError(
                "`screen_pose`: a lens's screen must face up, towards the lens (normal z > 0), "
                f"got normal {np.asarray(pose.normal).tolist()}"
            )
        if not float(pose.centre[2]) < float(bottom):
            raise ValueError(
                f"`screen_pose`: the screen's centre (z = {float(pose.centre[2])}) must lie "
                f"below the lens's bottom face (z = {float(bottom)})"
            )
    return pose


class LensScene(eqx.Module):
    """A glass slab with a height-field top and a flat bottom over a screen: the scene of
    caustic lens design.

    The receiver (screen) is the plane ``z = 0``; the slab's flat bottom face is the plane
    ``z = screen_distance``; its top surface is ``z = screen_distance + thickness +
    surface.heights(x, y)``.
    Light enters through the top surface within ``surface.extent`` (the aperture: light
    outside it is stopped by the lens holder), refracts into the glass, leaves through the
    bottom face (refracting again, or lost by total internal reflection) and lands on the
    screen. The slab's side walls are not modelled: rays leave through the bottom plane.

    **Arguments:**

    - `surface`: a `HeightField` of the top surface, heights in metres relative to its
      rest plane; ``boundary="clamp"`` is the usual choice for a lens.
    - `light`: a `DirectionalLight` (any direction going down) or a `PointLight` above
      the lens.
    - `receiver`: a `PlaneReceiver` (the screen's pixel grid on ``z = 0``).
    - `thickness`: metres from the bottom face to the top surface's rest plane (> 0); the
      top surface must stay above the bottom face (``thickness + min(heights) > 0``).
    - `screen_distance`: metres from the bottom face to the screen (> 0; default 0.5).
    - `ior`: index of refraction of the glass (static); a sequence gives one image
      channel per index (dispersion), like `WaterScene`.
    - `fresnel`: multiply each photon by the exact unpolarised transmittances of both
      faces.
    - `outline`: the blank's outline (static, `jaxcaustics.scene.outline`):
      ``"rectangle"`` (the aperture, default), ``"ellipse"`` (the ellipse inscribed in
      the aperture: a round lens in a round mount) or a star-shaped polygon's vertices
      in the aperture's normalised frame ``[-1, 1]^2``; light outside it is stopped.
    - `screen_pose`: a `ScreenPose` (`jaxcaustics.scene.screen_pose`) to put the screen
      anywhere below the bottom face (tilted to face a leaning beam, say); the
      receiver's extent is then in the screen's own ``(s, t)`` frame, and
      `screen_distance` only places the bottom face at ``z = screen_distance``.
      ``None`` (default): the screen is the ground ``z = 0``.

    Images are irradiance relative to the irradiance the light gives a horizontal plane
    (directional light), or in W/m^2 for a point light of the given intensity.
    """

    surface: HeightField
    light: DirectionalLight | PointLight
    receiver: PlaneReceiver
    thickness: Float[Array, ""]
    screen_distance: Float[Array, ""]
    ior: float | tuple[float, ...] = eqx.field(static=True)
    fresnel: bool = eqx.field(static=True)
    outline: str | tuple = eqx.field(static=True)
    screen_pose: Any = None  # a `ScreenPose` or None (the ground)

    def __init__(
        self,
        surface: HeightField,
        light: DirectionalLight | PointLight,
        receiver: PlaneReceiver,
        thickness=0.01,
        screen_distance=None,
        *,
        ior: float | Sequence[float] = 1.5,
        fresnel: bool = False,
        outline: str | Sequence = "rectangle",
        screen_pose=None,
    ):
        if not isinstance(surface, HeightField):
            raise ValueError(f"`surface` must be a HeightField, got {type(surface).__name__}")
        check_light(light)
        if not isinstance(receiver, PlaneReceiver):
            raise ValueError(f"`receiver` must be a PlaneReceiver, got {type(receiver).__name__}")
        screen_distance = 0.5 if screen_distance is None else screen_distance
        self.surface = surface
        self.light = light
        self.receiver = receiver
        self.thickness = check_positive_scalar(thickness, "thickness")
        self.screen_distance = check_positive_scalar(screen_distance, "screen_distance")
        self.ior = check_ior(ior)
        self.fresnel = check_bool(fresnel, "fresnel")
        self.outline = check_outline(outline)
        self.screen_pose = _check_lens_pose(screen_pose, self.screen_distance)
        _check_surface_above(surface, self.thickness, "thickness", "dips through the bottom face")
        if isinstance(light, PointLight) and is_concrete(light.position):
            top = float(self.screen_distance) + float(self.thickness)
            if is_concrete(surface.heights):
                top += float(np.max(np.asarray(surface.heights)))
            if not float(light.position[2]) > top:
                raise ValueError(
                    f"`light` must be above the lens: position z = {float(light.position[2])}"
                    f" <= top of the lens {top}"
                )

    @property
    def iors(self) -> tuple[float, ...]:
        """The indices of refraction as a tuple, one per image channel."""
        return self.ior if isinstance(self.ior, tuple) else (self.ior,)

    @property
    def top(self) -> Array:
        """Height of the top surface's rest plane above the screen, metres."""
        return self.screen_distance + self.thickness

    @property
    def effects(self) -> Effects:
        """What rendering this scene will trace (TIR is possible at the bottom face)."""
        return Effects(
            refraction=True,
            reflection=False,
            fresnel=self.fresnel,
            total_internal_reflection=True,
            dispersion_channels=len(self.iors),
            occlusion=False,
            interfaces=2,
        )
