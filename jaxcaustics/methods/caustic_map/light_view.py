"""The light's view of a scene: the projection that caustic maps share with shadow maps.

Caustics mapping (Shah et al.) and adaptive caustic maps (Wyman & Nichols) work in the
light's image space: the geometry buffers of the refractor, the photon grid, the
receiver positions texture and the caustic map are all images "seen from the light".
`LightView` is that projection:

- a `DirectionalLight` gives an orthographic view: ``(u, v)`` are metres across the beam,
  on the plane through `centre` perpendicular to the light's direction `axis`;
- a `PointLight` gives a perspective view: ``(u, v)`` are the tangents of the angle from
  `axis` (an image plane at unit distance from the light, which sits at `centre`).

Its `window` ``(u0, u1, v0, v1)`` covers the receiver and the generator, so every photon
the light sends through the generator starts inside it and every receiver point that can
be lit projects into it. Image ``(rows, cols)`` over the window: column ``j`` covers
``u0 + [j, j + 1] du``, row ``i`` covers ``v0 + [i, i + 1] dv``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ...scene.mesh import Mesh
from ...scene.scene import DirectionalLight, PlaneReceiver, PointLight
from ...trace.optics import orthonormal_basis


class LightView(eqx.Module):
    """The light's projection (see the module docstring). Build it with `light_view`.

    - `centre`: ``(3,)``: a point of the view plane (orthographic), or the light.
    - `axis`, `e1`, `e2`: ``(3,)`` orthonormal: the viewing direction and the ``u`` and
      ``v`` directions.
    - `window`: ``(4,)``: ``(u0, u1, v0, v1)``, a square.
    - `start`: orthographic views: how far before the view plane photons start (m).
    - `intensity`: point light's intensity (W/sr); 1 for a directional light.
    - `perspective`: static: ``True`` for a point light.
    """

    centre: Float[Array, "3"]
    axis: Float[Array, "3"]
    e1: Float[Array, "3"]
    e2: Float[Array, "3"]
    window: Float[Array, "4"]
    start: Float[Array, ""]
    intensity: Float[Array, ""]
    perspective: bool = eqx.field(static=True)

    def rays(self, u: Array, v: Array) -> tuple[Float[Array, "... 3"], Float[Array, "... 3"]]:
        """Origins and unit directions of the light's rays through view points ``(u, v)``."""
        u, v = u[..., None], v[..., None]
        if self.perspective:
            d = self.axis + u * self.e1 + v * self.e2
            d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
            return jnp.broadcast_to(self.centre, d.shape), d
        origin = self.centre + u * self.e1 + v * self.e2 - self.start * self.axis
        return origin, jnp.broadcast_to(self.axis, origin.shape)

    def project(self, points: Float[Array, "... 3"]) -> tuple[Array, Array]:
        """View coordinates ``(u, v)`` of world points (the light's ray through them).
        Perspective views: points must lie in front of the light."""
        rel = points - self.centre
        u, v = rel @ self.e1, rel @ self.e2
        if self.perspective:
            depth = rel @ self.axis
            depth = jnp.where(depth > 0, depth, 1.0)
            return u / depth, v / depth
        return u, v

    def density(self, u: Array, v: Array) -> Array:
        """Flux the light sends per unit view area at ``(u, v)``: ``1 / |axis_z|`` for a
        directional light (so a horizontal plane receives 1), ``I cos^3(alpha)`` for a
        point light (``alpha`` the angle from the axis)."""
        if self.perspective:
            return self.intensity * (1.0 + u * u + v * v) ** -1.5
        return jnp.broadcast_to(1.0 / jnp.abs(self.axis[2]), jnp.shape(u))

    def area_ratio(self, points: Float[Array, "... 3"], normals: Float[Array, "... 3"]) -> Array:
        """View area per unit surface area at `points` with unit `normals` (the shadow-map
        projection's Jacobian): irradiance = (flux per view area) x this. ``|n . axis|``
        for a directional light, ``|n . w| / (r^2 cos^3 alpha)`` for a point light (``w``
        the unit direction from the light, ``r`` the distance)."""
        if not self.perspective:
            return jnp.abs(normals @ self.axis)
        rel = points - self.centre
        r = jnp.linalg.norm(rel, axis=-1)
        w = rel / r[..., None]
        cos_a = jnp.abs(w @ self.axis)
        return jnp.abs(jnp.sum(normals * w, axis=-1)) / (r * r * cos_a**3)

    def texel_area(self, shape: tuple[int, ...]) -> Array:
        """View area of one texel of a ``shape`` image over the window."""
        u0, u1, v0, v1 = (self.window[k] for k in range(4))
        return (u1 - u0) / shape[1] * (v1 - v0) / shape[0]

    def texel_centres(self, shape: tuple[int, int]) -> list[Array]:
        """``(u, v)`` of the texel centres of a ``shape`` image, each ``(rows, cols)``."""
        rows, cols = shape
        u0, u1, v0, v1 = (self.window[k] for k in range(4))
        dtype = self.window.dtype
        u = u0 + (jnp.arange(cols, dtype=dtype) + 0.5) * (u1 - u0) / cols
        v = v0 + (jnp.arange(rows, dtype=dtype) + 0.5) * (v1 - v0) / rows
        return jnp.meshgrid(u, v)

    def to_texels(self, u: Array, v: Array, shape: tuple[int, ...]) -> tuple[Array, Array]:
        """Continuous texel coordinates ``(x, y)`` (columns, rows; a texel centre is at
        ``(j + 0.5, i + 0.5)``) of view points in a ``shape`` image over the window."""
        rows, cols = shape
        u0, u1, v0, v1 = (self.window[k] for k in range(4))
        return (u - u0) * (cols / (u1 - u0)), (v - v0) * (rows / (v1 - v0))


def _round_out(low: Array, high: Array) -> tuple[Array, Array]:
    """Widen ``[low, high]`` to a square-ish interval on a coarse grid (a sixteenth of the
    power of two below its size), so a small change of the scene (an optimisation step, a
    finite difference) leaves the window, and every image over it, where it is."""
    size = jnp.max(high - low)
    step = 2.0 ** jnp.floor(jnp.log2(size)) / 16
    centre = jnp.round(0.5 * (low + high) / step) * step
    half = (jnp.ceil(0.5 * size / step + 0.5) + 1) * step
    return centre - half, centre + half


def light_view(scene) -> LightView:
    """The light's view of a `MeshScene` (or any scene with a `generator` mesh, a `light`
    and a plane `receiver`): its window covers the receiver's extent on ``z = 0`` and the
    generator's bounding box. The window is held fixed under differentiation (it is where
    images are sampled, not physics); the light's direction, position and intensity carry
    their derivatives into the photons. A point light that does not see the whole scene
    from one side (inside or below its bounding box) has no view: a `ValueError`."""

    if not (
        isinstance(getattr(scene, "generator", None), Mesh)
        and isinstance(getattr(scene, "light", None), DirectionalLight | PointLight)
        and isinstance(getattr(scene, "receiver", None), PlaneReceiver)
    ):
        raise ValueError(
            "`scene` must be a MeshScene (a `generator` Mesh, a DirectionalLight or "
            f"PointLight and a PlaneReceiver), got {type(scene).__name__}"
        )
    view = _light_view(scene)
    if not isinstance(view.window, jax.core.Tracer) and not bool(
        jnp.all(jnp.isfinite(view.window))
    ):
        raise ValueError(
            "`scene`: the light must see the whole scene from one side; a point light "
            "inside or below the bounding box of the receiver and the generator has no view"
        )
    return view


def _light_view(scene) -> LightView:
    """`light_view` once `scene` is checked."""
    sg = jax.lax.stop_gradient
    verts = sg(scene.generator.vertices)
    dtype = verts.dtype
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    box = jnp.stack(
        [
            jnp.stack([x, y, z])
            for x in (lo[0], hi[0])
            for y in (lo[1], hi[1])
            for z in (lo[2], hi[2])
        ]
    )
    x0, x1, y0, y1 = (sg(scene.receiver.extent[k]).astype(dtype) for k in range(4))
    zero = jnp.zeros((), dtype)
    corners = jnp.stack([jnp.stack([x, y, zero]) for x in (x0, x1) for y in (y0, y1)])
    points = jnp.concatenate([box, corners])
    mid = 0.5 * (points.min(axis=0) + points.max(axis=0))
    if isinstance(scene.light, DirectionalLight):
        axis = scene.light.unit_direction.astype(dtype)
        centre = 0.5 * (lo + hi)
        intensity = jnp.ones((), dtype)
        perspective = False
    else:
        centre = scene.light.position.astype(dtype)
        axis = mid - centre
        axis = axis / jnp.linalg.norm(axis)
        intensity = jnp.asarray(scene.light.intensity, dtype)
        perspective = True
    e1, e2 = orthonormal_basis(axis)
    rel = points - centre
    depth = rel @ axis
    if perspective:
        # every point must be in front of the light (a view of less than a half space)
        depth = jnp.where(depth > 0, depth, jnp.inf)
        u, v = (rel @ e1) / depth, (rel @ e2) / depth
    else:
        u, v = rel @ e1, rel @ e2
    low = jnp.stack([u.min(), v.min()])
    high = jnp.stack([u.max(), v.max()])
    low, high = _round_out(sg(low), sg(high))
    window = jnp.stack([low[0], high[0], low[1], high[1]])
    start = jnp.maximum(0.0, -sg(depth).min()) + 1e-3 * jnp.max(points.max(0) - points.min(0))
    return LightView(centre, axis, e1, e2, window, start, intensity, perspective)
