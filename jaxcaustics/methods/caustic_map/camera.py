"""The final pass of Shah et al.'s caustics mapping seen from a camera: a `PinholeCamera`
and `camera_image` (the receiver shaded with its shadow and caustic maps)."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._checks import (
    check_number,
    check_real_array,
    check_shape,
)
from ...scene.mesh import MeshScene
from ..base import channels_last
from .gbuffer import (
    bilinear,
)
from .method import CausticMapResult, project_caustic_map


class PinholeCamera(eqx.Module):
    """A pinhole camera for `camera_image`.

    - `position`, `look_at`: ``(3,)`` metres; `up`: ``(3,)``, the image's upward
      direction (default ``+y``; any vector not along the view).
    - `fov`: vertical field of view, degrees (static).
    - `shape`: ``(rows, cols)`` of the image (static).
    """

    position: Array
    look_at: Array
    up: Array
    fov: float = eqx.field(static=True)
    shape: tuple[int, int] = eqx.field(static=True)

    def __init__(self, position, look_at, *, fov: float = 45.0, shape=(240, 320), up=(0, 1, 0)):
        for name, value in (("position", position), ("look_at", look_at), ("up", up)):
            arr = check_real_array(value, name)
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"`{name}` must be 3 finite numbers, got {value!r}")
        self.position = jnp.asarray(position, float)
        self.look_at = jnp.asarray(look_at, float)
        self.up = jnp.asarray(up, float)
        self.fov = check_number(fov, "fov", low=0.0, high=180.0, low_open=True, high_open=True)
        self.shape = check_shape(shape, "shape")
        forward = self.look_at - self.position
        if float(jnp.linalg.norm(jnp.cross(forward, self.up))) <= 1e-9 * float(
            jnp.linalg.norm(forward) + 1e-300
        ):
            raise ValueError("`look_at` must differ from `position`, and `up` not be along it")
        if not float(self.position[2]) > 0.0:  # below the screen it sees its underside
            raise ValueError(f"`position` must be above the receiver z = 0, got {position!r}")
        # the image's corner rays span its rays' z components: one must go down
        f, r, u = (np.asarray(a, float) for a in self._frame())
        half = math.tan(math.radians(self.fov) / 2)
        rows, cols = self.shape
        corners = [
            f + sx * half * cols / rows * r + sy * half * u for sx in (-1, 1) for sy in (-1, 1)
        ]
        if not min(c[2] for c in corners) < 0.0:
            raise ValueError(
                f"`look_at` {look_at!r}: the camera looks nowhere (no pixel sees the "
                "receiver plane z = 0 below it)"
            )

    def _frame(self) -> tuple[Array, Array, Array]:
        """Unit forward, right and up vectors of the image."""
        forward = self.look_at - self.position
        forward = forward / jnp.linalg.norm(forward)
        right = jnp.cross(forward, self.up)
        right = right / jnp.linalg.norm(right)
        return forward, right, jnp.cross(right, forward)

    def rays(self) -> tuple[Array, Array]:
        """Unit directions ``(rows, cols, 3)`` through the pixel centres."""
        rows, cols = self.shape
        forward, right, up = self._frame()
        half = math.tan(math.radians(self.fov) / 2)
        y = (1 - 2 * (jnp.arange(rows) + 0.5) / rows) * half
        x = (2 * (jnp.arange(cols) + 0.5) / cols - 1) * half * cols / rows
        d = forward + x[None, :, None] * right + y[:, None, None] * up
        return self.position, d / jnp.linalg.norm(d, axis=-1, keepdims=True)


def camera_image(
    scene: MeshScene, result: CausticMapResult, camera: PinholeCamera, *, albedo: float = 0.8
) -> Array:
    """The paper's final pass, seen from a camera: the receiver (the plane ``z = 0``
    within its extent; black elsewhere) shaded as a Lambertian surface of the given
    `albedo`: radiance ``albedo / pi (E_direct + E_caustic)``, ``E_direct`` the light's
    irradiance where the shadow map (`result.shadow_map`) does not see the generator,
    ``E_caustic`` the caustic map projected as in `project_caustic_map`. The generator
    itself is not drawn (only its shadow and caustic).

    **Arguments:**

    - `scene`: the `MeshScene` that was rendered.
    - `result`: its caustic map, a `CausticMapResult`
      (``CausticsMapping(...).trace(scene)`` or ``AdaptiveCausticMap(...).trace(scene)``).
    - `camera`: a `PinholeCamera` (its `shape` is the image's).
    - `albedo`: the receiver's Lambertian albedo, in ``[0, 1]`` (default 0.8).

    **Returns:** the radiance, in the images' units, ``(rows, cols)`` or ``(rows, cols,
    channels)``.
    """
    for name, value, kind in (
        ("scene", scene, MeshScene),
        ("result", result, CausticMapResult),
        ("camera", camera, PinholeCamera),
    ):
        if not isinstance(value, kind):
            raise ValueError(f"`{name}` must be a {kind.__name__}, got {type(value).__name__}")
    albedo = check_number(albedo, "albedo", low=0.0, high=1.0)
    origin, directions = camera.rays()
    dtype = result.caustic_map.dtype
    origin, directions = origin.astype(dtype), directions.astype(dtype)
    down = directions[..., 2] < 0
    t = -origin[2] / jnp.where(down, directions[..., 2], -1.0)
    points = origin + t[..., None] * directions
    x0, x1, y0, y1 = (scene.receiver.extent[k] for k in range(4))
    seen = down & (points[..., 0] >= x0) & (points[..., 0] <= x1)
    seen = seen & (points[..., 1] >= y0) & (points[..., 1] <= y1)
    normals = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], dtype), points.shape)
    view = result.view
    caustic = project_caustic_map(view, result.caustic_map, points, normals)  # (C, r, c)
    u, v = view.project(points)
    x, y = view.to_texels(u, v, result.shadow_map.shape)
    shadowed = bilinear(result.shadow_map.astype(dtype), x, y) >= 0.5
    direct = jnp.where(shadowed, 0.0, view.density(u, v) * view.area_ratio(points, normals))
    radiance = albedo / jnp.pi * (direct[None] + caustic)
    radiance = jnp.where(seen[None], radiance, 0.0)
    return channels_last(scene, radiance)
