"""Liu, Dong, Bao & Peng's caustic spot lights as a rendering method for a scene.

`spot_lights(scene)` traces a grid of rays through the scene's caustic object
(`trace_exit_rays`), fits a set of caustic spot lights to the rays that leave it
(`fit_spot_lights`) and renders them on the receiver (`render_spot_lights`), with the
scene's ellipsoid occluders as analytic shadow tests. Precomputed lights (for example
interpolated for a moving light with `interpolate_spot_lights`) can be given instead of
fitting.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._checks import check_bool, check_fits, check_int, check_memory_limit, check_number
from ...scene.checks import checks_scene_values
from ...scene.ellipsoid import EllipsoidScene
from ...scene.mesh import MeshScene
from ...scene.scene import DirectionalLight
from ..base import Method, channels_last
from .exit_rays import trace_exit_rays
from .fit import FitInfo, fit_spot_lights
from .lights import Glossy, Lambertian, SpotLights, render_spot_lights

_RAY_FLOATS = 64  # per traced ray: the exit ray, tracing and fit temporaries (estimate)
# per rendered point (``samples^2`` per pixel, all at once): XLA's compiled temporaries of
# `render_spot_lights` are 42 numbers per point, whatever the number of lights
_POINT_FLOATS = 64


def ray_bytes(dtype=jnp.float64) -> int:
    """Memory one traced ray takes (its exit ray, the tracing temporaries and the fit's
    per-ray arrays; an estimate: XLA's temporaries of `trace_exit_rays` on an ellipsoid
    are about 20 numbers per ray), bytes."""
    return jnp.dtype(dtype).itemsize * _RAY_FLOATS


def max_rays_per_axis(memory_limit: int, dtype=jnp.float64) -> int:
    """The largest `rays_per_axis` whose rays fit in `memory_limit` bytes (`ray_bytes`
    each)."""
    return math.isqrt(int(memory_limit) // ray_bytes(dtype))


class SpotLightResult(eqx.Module):
    """What `spot_lights` returns.

    - `image`: ``(rows, cols)`` (one index of refraction) or ``(rows, cols, C)``:
      irradiance relative to the irradiance the light gives a horizontal plane (or
      radiance with a `shading` model).
    - `lights`: the `SpotLights` used, one set per channel (a tuple).
    - `fit_info`: the `FitInfo` of each channel's fit (a tuple; empty when `lights` were
      given).
    - `missed_flux_fraction`: ``(C,)`` share of the light leaving the object that the
      fitted lights do not carry (``1 - FitInfo.fraction``; 0 for given lights).
    - `stats`: ``lights`` (active lights per channel), ``traced_rays``, and, as the
      other photon renderers, ``batches`` (traced grids: one per channel fitted),
      ``peak_buffer_photons`` (rays of one grid) and ``peak_buffer_bytes`` (by
      `ray_bytes`).
    """

    image: Float[Array, "..."]
    lights: tuple[SpotLights, ...]
    fit_info: tuple[FitInfo, ...]
    missed_flux_fraction: Float[Array, " C"]
    stats: dict[str, Any]


#: a mesh is sphere-like (caustic spot lights apply) if every vertex lies within this
#: relative distance of the ellipsoid through its principal extents, and that
#: ellipsoid's longest axis is at most `SPHERE_LIKE_ASPECT` times its shortest
SPHERE_LIKE_DEVIATION = 0.1
SPHERE_LIKE_ASPECT = 3.0


def _scene_problem(scene) -> str | None:
    """What `spot_lights` cannot render in `scene` (it refuses it), or ``None``."""
    if not isinstance(scene, (EllipsoidScene, MeshScene)):
        return (
            f"`scene` must be an EllipsoidScene or a MeshScene for caustic spot lights, got "
            f"{type(scene).__name__}"
        )
    if not isinstance(scene.light, DirectionalLight):
        return (
            "`scene.light` must be a DirectionalLight: caustic spot lights are fitted to "
            "parallel light (Liu et al. Sect. 3)"
        )
    if isinstance(scene, MeshScene) and scene.occluders:
        return (
            "`scene.occluders`: caustic spot lights test shadows analytically against "
            "ellipsoids and spheres only; use an EllipsoidScene with Ellipsoid occluders"
        )
    if isinstance(scene, MeshScene) and scene.material != "refractor":
        return "`scene.material` must be 'refractor' for caustic spot lights"
    return None


def _check_scene(scene) -> None:
    problem = _scene_problem(scene)
    if problem:
        raise ValueError(problem)


def _sphere_like(vertices: np.ndarray) -> str | None:
    """``None`` if the points lie on an ellipsoid of moderate aspect (whose refracted rays
    focus near moving points), else why not."""
    # the principal extents of the vertices give the ellipsoid they should lie on
    centre = vertices.mean(axis=0)
    local = vertices - centre
    _, _, axes = np.linalg.svd(local, full_matrices=False)
    coords = local @ axes.T
    radii = 0.5 * (coords.max(axis=0) - coords.min(axis=0))
    if radii.min() <= 0:
        return "the object is flat"
    return _moderate_aspect(radii) or _on_ellipsoid(coords, radii)


def _moderate_aspect(radii: np.ndarray, what: str = "object") -> str | None:
    aspect = radii.max() / radii.min()
    if aspect > SPHERE_LIKE_ASPECT:
        return f"the {what} is elongated (aspect {aspect:.3g} > {SPHERE_LIKE_ASPECT:g})"
    return None


def _on_ellipsoid(coords: np.ndarray, radii: np.ndarray) -> str | None:
    mid = 0.5 * (coords.max(axis=0) + coords.min(axis=0))
    deviation = np.abs(np.linalg.norm((coords - mid) / radii, axis=1) - 1.0).max()
    if deviation > SPHERE_LIKE_DEVIATION:
        return (
            f"the object is not sphere-like (vertices {deviation:.2g} off the ellipsoid "
            "through its extents; caustic spot lights need rays focusing near points, "
            "Liu et al. Sect. 6: a cylinder focuses on a line)"
        )
    return None


class SpotLightMethod(Method):
    """Liu et al.'s caustic spot lights for glass ellipsoids and sphere-like meshes under
    parallel light: ``SpotLightMethod(rays_per_axis=...)(scene)`` or ``render(scene,
    SpotLightMethod(...))``.

    **Arguments:**

    - `rays_per_axis`: rays along each side of the traced grid (default 256; the paper
      traces 1280^2); the accuracy knob of the fit, with the fit's knobs (`fit`).
    - `lights`: precomputed `SpotLights` (one set, used for every channel) instead of
      fitting (default ``None``: fit them); their images must be in the fit's units
      (power for unit irradiance perpendicular to the light).
    - `samples`: points per pixel side averaged (default 2; see `render_spot_lights`).
    - `shading`: ``None`` (the default): the receiver's irradiance; `Lambertian` or
      `Glossy`: the radiance they send (see `shade_points`).
    - `max_gain`: bound on the intensity correction ``1 / sigma`` (> 0; default 1e4;
      see `evaluate_spot_lights`).
    - `intensity_correction`: apply Liu et al.'s Eq. 4 (default ``True``); ``False``
      gives the uncorrected rendering of the paper's Fig. 6 (left; see
      `evaluate_spot_lights`).
    - `memory_limit`: bytes for the traced rays of one channel (default 1 GiB,
      `ray_bytes` per ray). The fit needs all of a grid's rays at once, so they are not
      batched: a grid over the limit raises a `ValueError` before anything is compiled,
      naming the largest `rays_per_axis` that fits (`max_rays_per_axis`). The render
      evaluates every point at once (``samples^2`` per pixel, `_POINT_FLOATS` numbers
      each): over the limit, refused the same way. The same limit is passed on to
      `trace_exit_rays`, `fit_spot_lights` and `render_spot_lights`.
    - `fit`: a dict of the keywords passed on to `fit_spot_lights` (`max_lights`,
      `energy_fraction`, `resolution`, `cells`, thresholds...; default empty: the fit's
      defaults); a name it does not take is refused. `render` (and `from_knobs`) take
      them as knobs of their own: ``render(scene, "spot_lights", max_lights=8)``. The
      main ones: `max_lights` (default 16), the light slots; `energy_fraction` (0.95):
      the fit stops once that fraction of the traced energy is in lights; `resolution`
      (64): light-plane image pixels per side; `angle_threshold_deg` (60) and
      `distance_threshold` (0.1 x the object's size): which rays join a bundle (the
      paper: within 90 degrees; 30 splits a glass ball's marginal rays into many small
      lights, 85 forces them into one law that fits them badly: relative L1 0.17 /
      0.057 / 0.10 at 30 / 60 / 85 on the glass ball of radius 0.3 m under the sun at
      20 degrees of `examples/spot_lights.py`).

    Checked before anything is traced: ints are ints (no bools or floats), `max_gain` a
    positive finite number, `intensity_correction` a bool, `lights` a `SpotLights`;
    with `lights`, `rays_per_axis` and the fit's knobs (unused) are refused.
    """

    rays_per_axis: int = 256
    lights: SpotLights | None = None
    samples: int = 2
    shading: Lambertian | Glossy | None = None
    max_gain: float = 1e4
    intensity_correction: bool = True
    memory_limit: int | None = None
    fit: dict[str, Any] = eqx.field(default_factory=dict)

    name: ClassVar[str] = "spot_lights"
    scene_types: ClassVar[tuple[type, ...]] = (EllipsoidScene, MeshScene)
    missed_advice: ClassVar[str | None] = (
        "the fitted spot lights do not carry it; pass a larger `max_lights` or `rays_per_axis`"
    )

    @classmethod
    def knob_names(cls) -> tuple[str, ...]:
        fit = set(inspect.signature(fit_spot_lights).parameters) - {"rays"}
        return tuple(n for n in super().knob_names() if n != "fit") + tuple(sorted(fit))

    @classmethod
    def from_knobs(cls, **knobs: Any) -> SpotLightMethod:
        cls.check_knob_names(knobs)
        own = {k: v for k, v in knobs.items() if k in cls.__dataclass_fields__}
        return cls(**own, fit={k: v for k, v in knobs.items() if k not in own})

    def knobs(self) -> dict[str, Any]:
        own = super().knobs()
        return {**{k: v for k, v in own.items() if k != "fit"}, **self.fit}

    def support(self, scene) -> str | None:
        """Besides what `spot_lights` refuses: the object must be sphere-like (rays that
        focus near points, Liu et al. Sect. 6), not elongated or flat."""
        problem = _scene_problem(scene)
        if problem:
            return problem
        if isinstance(scene, MeshScene):
            return _sphere_like(np.asarray(scene.generator.vertices, dtype=float))
        return _moderate_aspect(np.asarray(scene.generator.radii, dtype=float), "ellipsoid")

    def refined(self) -> SpotLightMethod:
        """Twice the traced rays along each side (the fit's input; the lights' model error
        is not refined)."""
        return dataclasses.replace(self, rays_per_axis=2 * self.rays_per_axis)

    def coarsened(self) -> SpotLightMethod | None:
        if self.rays_per_axis % 2 or self.rays_per_axis < 8:
            return None
        return dataclasses.replace(self, rays_per_axis=self.rays_per_axis // 2)

    def trace(self, scene) -> SpotLightResult:
        return spot_lights(scene, **self.knobs())


@checks_scene_values
def spot_lights(
    scene: EllipsoidScene | MeshScene,
    *,
    rays_per_axis: int = SpotLightMethod.rays_per_axis,
    lights: SpotLights | None = SpotLightMethod.lights,
    samples: int = SpotLightMethod.samples,
    shading: Lambertian | Glossy | None = SpotLightMethod.shading,
    max_gain: float = SpotLightMethod.max_gain,
    intensity_correction: bool = SpotLightMethod.intensity_correction,
    memory_limit: int | None = SpotLightMethod.memory_limit,
    **fit_knobs: Any,
) -> SpotLightResult:
    """Caustics of a glass object by caustic spot lights (Liu et al. 2008).

    The function form of `SpotLightMethod`: `scene` (an `EllipsoidScene`: glass ellipsoid
    or sphere, ellipsoid occluders; or a `MeshScene`: glass mesh, no occluders; lit by a
    `DirectionalLight`) and the same knobs as keywords, described there, its `fit` as
    keywords of their own (`**fit_knobs`).

    **Returns:** a `SpotLightResult`.
    """
    _check_scene(scene)
    light = scene.light
    assert isinstance(light, DirectionalLight)  # (for mypy: `_check_scene` refuses others)
    if lights is not None and not isinstance(lights, SpotLights):
        raise ValueError(f"`lights` must be SpotLights, got {type(lights).__name__}")
    if lights is not None and fit_knobs:
        raise ValueError(f"`lights` were given: nothing to fit with {sorted(fit_knobs)}")
    fit_names = set(inspect.signature(fit_spot_lights).parameters) - {"rays"}
    unknown = sorted(set(fit_knobs) - fit_names)
    if unknown:
        raise ValueError(
            f"`{unknown[0]}` is not a knob of spot_lights or fit_spot_lights (the fit's: "
            f"{', '.join(sorted(fit_names))})"
        )
    rays_per_axis = check_int(rays_per_axis, "rays_per_axis", 2)
    if lights is not None and rays_per_axis != SpotLightMethod.rays_per_axis:
        raise ValueError(
            f"`lights` were given: nothing is traced with `rays_per_axis` {rays_per_axis}"
        )
    samples = check_int(samples, "samples", 1)
    check_number(max_gain, "max_gain", low=0.0, low_open=True)
    intensity_correction = check_bool(intensity_correction, "intensity_correction")
    memory_limit = check_memory_limit(memory_limit)
    dtype = jnp.result_type(light.direction)
    per_ray = ray_bytes(dtype)
    if lights is None:
        check_fits(
            rays_per_axis**2 * per_ray,
            memory_limit,
            f"`rays_per_axis` {rays_per_axis} ({rays_per_axis}^2 traced rays, {per_ray} bytes "
            "each, all at once for the fit)",
            f"the largest `rays_per_axis` that fits is {max_rays_per_axis(memory_limit, dtype)}",
        )
    rows, cols = scene.receiver.shape
    check_fits(
        samples * samples * rows * cols * _POINT_FLOATS * jnp.dtype(dtype).itemsize,
        memory_limit,
        f"rendering {samples}^2 points in each of {rows} x {cols} pixels at once",
        "lower `samples` or the receiver's pixels",
    )
    occluders = tuple(getattr(scene, "occluders", ())) if isinstance(scene, EllipsoidScene) else ()
    # the fit's units: power for unit irradiance across the light; the library's images
    # are relative to the irradiance on a horizontal plane
    scale = 1.0 / jnp.abs(light.unit_direction[2])
    images, sets, infos, missed = [], [], [], []
    for channel in range(len(scene.iors)):
        if lights is None:
            rays = trace_exit_rays(scene, rays_per_axis, channel=channel, memory_limit=memory_limit)
            fitted, info = fit_spot_lights(rays, memory_limit=memory_limit, **fit_knobs)
            infos.append(info)
            missed.append(1.0 - info.fraction)
        else:
            fitted = lights
            missed.append(jnp.zeros(()))
        sets.append(fitted)
        image = render_spot_lights(
            fitted,
            scene.receiver,
            samples=samples,
            shading=shading,
            occluders=occluders,
            max_gain=max_gain,
            intensity_correction=intensity_correction,
            memory_limit=memory_limit,
        )
        images.append(image * scale)
    image = channels_last(scene, jnp.stack(images))
    stats = {
        "lights": tuple(jnp.sum(s.active) for s in sets),
        "traced_rays": 0 if lights is not None else rays_per_axis**2 * len(sets),
        "batches": 0 if lights is not None else len(sets),
        "peak_buffer_photons": 0 if lights is not None else rays_per_axis**2,
        "peak_buffer_bytes": 0 if lights is not None else rays_per_axis**2 * per_ray,
    }
    return SpotLightResult(image, tuple(sets), tuple(infos), jnp.stack(missed), stats)
