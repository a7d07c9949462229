"""Extended sources in the reference: a disc of directions (the Sun) or a flat emitter
(an LED's die) sampled, each sample traced as a collimated or a point light, the images
averaged with the samples' weights.

A light with an ``angular_radius`` (radians; `jaxcaustics.SunLight`, or any object with
``direction``, ``angular_radius`` and optionally ``limb_darkening``) is such a disc; one
with a ``position`` and a ``size`` (`jaxcaustics.AreaLight`: ``shape``, ``intensity``,
``lambertian``) such an emitter, its points from `area_points`. Its
directions come from `disc_directions` (a sunflower pattern: even, stratified cover);
the photons per axis are shared out, ``photons_per_axis / sqrt(samples)`` each, so a
trace costs about what one under a point source does.
"""

from __future__ import annotations

import functools
import inspect
import math
import types

import numpy as np

# directions over a disc source by default (the Sun's disc, 2-3 pixels across on the
# usual screens, is then sampled every 0.3-0.4 pixel)
SOURCE_SAMPLES = 64


def disc_directions(
    direction, angular_radius: float, samples: int, limb_darkening: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """`samples` unit directions spread evenly over a disc of `angular_radius` (radians)
    about `direction`, and their weights summing to 1.

    Sample ``k`` lies at ``sqrt((k + 1/2) / samples)`` of the disc's radius, turned by
    ``k`` golden angles (a sunflower pattern); its weight is the disc's radiance there
    under linear limb darkening, ``1 - u (1 - mu)`` with ``mu = sqrt(1 - rho^2)``.

    **Returns:** ``(directions (samples, 3), weights (samples,))``."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    k = np.arange(samples)
    rho = np.sqrt((k + 0.5) / samples)
    turn = k * math.pi * (3.0 - math.sqrt(5.0))
    offset = math.tan(angular_radius) * rho
    out = d + offset[:, None] * (np.cos(turn)[:, None] * e1 + np.sin(turn)[:, None] * e2)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    weights = 1.0 - limb_darkening * (1.0 - np.sqrt(np.clip(1.0 - rho**2, 0.0, 1.0)))
    return out, weights / weights.sum()


def area_points(light, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """About `samples` points over a flat emitter facing down (`light`'s ``position``,
    ``size`` ``(width, height)`` and ``shape``, ``"rectangle"`` or ``"disc"``: an
    `AreaLight`): a rectangle's are the centres of a ``k x k`` grid of equal cells,
    ``k = round(sqrt(samples))``; a disc's a sunflower. Their weights are equal.

    **Returns:** ``(points (n, 3), weights (n,))``."""
    centre = np.asarray(light.position, float)
    width, height = light.size
    if light.shape == "disc":
        k = np.arange(samples)
        rho = 0.5 * width * np.sqrt((k + 0.5) / samples)
        turn = k * math.pi * (3.0 - math.sqrt(5.0))
        dx, dy = rho * np.cos(turn), rho * np.sin(turn)
    else:
        side = max(1, round(math.sqrt(samples)))
        cells = (np.arange(side) + 0.5) / side - 0.5
        dx, dy = (g.ravel() for g in np.meshgrid(cells * width, cells * height))
    points = centre + np.stack([dx, dy, np.zeros_like(dx)], axis=-1)
    return points, np.full(len(points), 1.0 / len(points))


class _Lit:
    """`scene` seen with another `light` (every other attribute read through)."""

    def __init__(self, scene, light):
        self._scene, self.light = scene, light

    def __getattr__(self, name):
        return getattr(self._scene, name)


def over_source(trace):
    """`trace(scene, photons_per_axis, **options)` that integrates a disc light (see the
    module docstring); it takes ``source_samples`` (directions over the disc; default
    `SOURCE_SAMPLES`). Other lights are traced as they are."""

    default = inspect.signature(trace).parameters["photons_per_axis"].default

    @functools.wraps(trace)
    def traced(scene, photons_per_axis=default, *, source_samples=None, **options):
        light = scene.light
        disc = getattr(light, "angular_radius", None) is not None
        area = getattr(light, "size", None) is not None and hasattr(light, "position")
        if not (disc or area):
            return trace(scene, photons_per_axis, **options)
        if options.get("return_stats"):
            raise ValueError("`return_stats` is not given under an extended `scene.light`")
        samples = SOURCE_SAMPLES if source_samples is None else int(source_samples)
        if samples < 1:
            raise ValueError(f"`source_samples` must be >= 1, got {source_samples!r}")
        if disc:
            directions, weights = disc_directions(
                light.direction, light.angular_radius, samples,
                getattr(light, "limb_darkening", 0.0),
            )  # fmt: skip
            lights = [types.SimpleNamespace(direction=d) for d in directions]
        else:
            points, weights = area_points(light, samples)
            lambertian = bool(getattr(light, "lambertian", False))
            lights = [
                types.SimpleNamespace(position=p, intensity=light.intensity, lambertian=lambertian)
                for p in points
            ]
        per_axis = max(2, round(int(photons_per_axis) / math.sqrt(len(lights))))
        image = None
        for one, w in zip(lights, weights, strict=True):
            part = w * trace(_Lit(scene, one), per_axis, **options)
            image = part if image is None else image + part
        return image

    return traced
