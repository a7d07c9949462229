"""A caustic mirror (`MirrorScene`): a reflecting height field and a screen facing the
reflected beam."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .outline import check_outline
from .scene import DirectionalLight, HeightField, PlaneReceiver, PointLight, check_light
from .screen_pose import ScreenPose
from .values import as_float_array, check_finite, is_concrete


class MirrorScene(eqx.Module):
    """A mirror with a height-field face and a screen anywhere in front of it.

    The mirror's face is ``z = H(x, y)`` (``surface.heights``, metres) about its rest
    plane ``z = 0``, lit from above within ``surface.extent`` (the aperture) and the
    `outline` (light elsewhere is stopped by the mount). A photon meets the face at the
    first root along its line, reflects about the face's normal, and lands on the screen
    (`screen_pose`); a photon whose reflected ray does not reach the screen's lit face is
    lost.

    **Arguments:**

    - `surface`: a `HeightField` of the mirror's face.
    - `light`: a `DirectionalLight` or a `PointLight` above the mirror.
    - `receiver`: a `PlaneReceiver`: the screen's pixel grid in its ``(s, t)`` frame.
    - `screen_pose`: a `ScreenPose`, in front of the mirror (``z > 0``) with its lit
      face towards it (``ScreenPose.facing`` across the reflected beam).
    - `reflectance`: the fraction of the light the face reflects, in ``(0, 1]``.
    - `outline`: the blank's outline, as `LensScene`'s.

    Images are irradiance relative to the irradiance the light gives a horizontal plane
    (directional light, as for lenses), or W/m^2 (point light).
    """

    surface: HeightField
    light: DirectionalLight | PointLight
    receiver: PlaneReceiver
    screen_pose: ScreenPose
    reflectance: Float[Array, ""]
    outline: str | tuple = eqx.field(static=True)

    def __init__(
        self,
        surface: HeightField,
        light: DirectionalLight | PointLight,
        receiver: PlaneReceiver,
        screen_pose: ScreenPose,
        *,
        reflectance=1.0,
        outline: str | Sequence = "rectangle",
    ):
        if not isinstance(surface, HeightField):
            raise ValueError(f"`surface` must be a HeightField, got {type(surface).__name__}")
        check_light(light)
        if not isinstance(receiver, PlaneReceiver):
            raise ValueError(f"`receiver` must be a PlaneReceiver, got {type(receiver).__name__}")
        if not isinstance(screen_pose, ScreenPose):
            raise ValueError(
                f"`screen_pose` must be a ScreenPose, got {type(screen_pose).__name__}"
            )
        r = as_float_array(reflectance, "reflectance")
        if r.shape != ():
            raise ValueError(f"`reflectance` must be a scalar, got shape {r.shape}")
        check_finite(r, "reflectance")
        if is_concrete(r) and not 0.0 < float(r) <= 1.0:
            raise ValueError(f"`reflectance` must be in (0, 1], got {float(r)}")
        self.surface = surface
        self.light = light
        self.receiver = receiver
        self.screen_pose = screen_pose
        self.reflectance = r
        self.outline = check_outline(outline)
        if is_concrete(screen_pose.centre) and is_concrete(surface.extent):
            centre = np.asarray(screen_pose.centre, float)
            if not centre[2] > 0.0:
                raise ValueError(
                    "`screen_pose`: the screen must stand in front of the mirror (centre "
                    f"z > 0), got z = {centre[2]}"
                )
            e = np.asarray(surface.extent, float)
            mirror = np.array([0.5 * (e[0] + e[1]), 0.5 * (e[2] + e[3]), 0.0])
            if not float(np.dot(np.asarray(screen_pose.normal, float), mirror - centre)) > 0.0:
                raise ValueError(
                    "`screen_pose`: the screen's lit face (its `normal`) must face the mirror"
                )
        if isinstance(light, PointLight) and is_concrete(light.position):
            top = float(np.max(np.asarray(surface.heights))) if is_concrete(surface.heights) else 0
            if not float(light.position[2]) > top:
                raise ValueError(
                    f"`light` must be above the mirror: position z = {float(light.position[2])}"
                    f" <= top of its face {top}"
                )

    @property
    def top(self) -> Array:
        """Height of the face's rest plane: 0."""
        return jnp.zeros((), self.surface.heights.dtype)
