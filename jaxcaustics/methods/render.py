"""`render`: the one entry point from a scene to an irradiance image."""

from __future__ import annotations

import inspect
import logging
import warnings
from typing import Any

import jax
import numpy as np
from jaxtyping import Array

from .._checks import check_bool, check_choice, check_number
from ..scene.scene import WaterScene
from .caustic_map.method import adaptive_caustic_map, caustics_mapping
from .choose import DEFAULT_MARGIN, as_mesh_scene, choose_method
from .spot_lights.method import spot_lights
from .triangles.method import caustic_triangles
from .twopass import two_pass

logger = logging.getLogger("jaxcaustics")

METHODS = {
    "twopass": two_pass,
    "triangles": caustic_triangles,
    "caustics_mapping": caustics_mapping,
    "adaptive": adaptive_caustic_map,
    "spot_lights": spot_lights,
}
# the method each scene type gets when none is named
DEFAULT_METHOD = {
    "WaterScene": "twopass",
    "LensScene": "triangles",
    "MeshScene": "triangles",
    "EllipsoidScene": "spot_lights",
}


MISSED_FLUX_WARNING = 0.01
"""`render` warns when a method leaves out more than this fraction of the light."""

# the methods whose missed flux is light their model leaves out (not light that lands
# off the receiver: caustic triangles and caustic maps count that too, and a scene may
# well light more than its receiver), and what to change
_MISSED_ADVICE = {
    "twopass": "it lands beyond the window of samples_x x (channels_y + 1) pixels around "
    "its illumination centre; pass samples_x='auto', channels_y='auto' (the window sized "
    "from the largest ray displacement) or a wider window",
    "spot_lights": "the fitted spot lights do not carry it; pass a larger `max_lights` or "
    "`rays_per_axis`",
}


def _warn_missed(method: str, missed) -> None:
    """`warnings.warn` when `method` left out more than `MISSED_FLUX_WARNING` of the
    light (concrete values only: under `jit` the fraction is in the result alone)."""
    if method not in _MISSED_ADVICE or isinstance(missed, jax.core.Tracer):
        return
    worst = float(np.nanmax(np.asarray(missed, float), initial=0.0))
    if worst > MISSED_FLUX_WARNING:
        warnings.warn(
            f"render: method {method!r} missed {worst:.1%} of the light (the image is that "
            f"much too dark; `missed_flux_fraction` in the stats): {_MISSED_ADVICE[method]}",
            stacklevel=3,
        )


def check_knob_names(method: str, knobs: dict) -> None:
    """A `ValueError` naming the first of `knobs` that is not a keyword of `method`'s
    function (a knob of another method, a typo): never silently ignored. A method that
    takes ``**knobs`` of its own (spot lights: the fit's) checks those itself."""
    parameters = inspect.signature(METHODS[method]).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
        return
    names = sorted(n for n, p in parameters.items() if p.kind is inspect.Parameter.KEYWORD_ONLY)
    unknown = sorted(set(knobs) - set(names))
    if unknown:
        raise ValueError(
            f"`{unknown[0]}` is not a knob of method {method!r} (its knobs: {', '.join(names)})"
        )


def render(
    scene: WaterScene,
    method: str | None = None,
    *,
    tolerance: float | None = None,
    margin: float = DEFAULT_MARGIN,
    return_stats: bool = False,
    **knobs: Any,
):
    """Render the caustics of `scene` on its receiver.

    **Arguments:**

    - `scene`: a `WaterScene`, `LensScene`, `MeshScene` or `EllipsoidScene`.
    - `method`: ``"twopass"`` (Yuksel & Keyser; water), ``"triangles"`` (Umenhoffer et
      al.'s caustic triangles; lens and mesh scenes), ``"caustics_mapping"`` (Shah et
      al.'s splatted caustic map; mesh scenes) or ``"adaptive"`` (Wyman & Nichols'
      adaptive caustic map; mesh scenes) or ``"spot_lights"`` (Liu et al.'s caustic spot
      lights; ellipsoid and mesh scenes). Default: the scene's natural method
      (``"twopass"`` for water, ``"spot_lights"`` for ellipsoids, ``"triangles"``
      otherwise).
    - `tolerance`: instead of naming knobs, ask for an error against the reference
      (relative L1 after a 1-pixel Gaussian blur of both images): the fastest measured
      method and knobs expected to meet it are picked (`choose_method`; with `method`
      given, that method's knobs). The choice is logged (logger ``"jaxcaustics"``, level
      INFO) and, with `return_stats`, returned as ``stats["choice"]`` (a `Choice`: method,
      knobs, expected error and time). `margin`: see `choose_method`.
    - `return_stats`: also return a dict of diagnostics (``missed_flux_fraction`` per
      channel). Whether asked for or not, a two-pass render that leaves out more than
      1% of the light (beyond its window) or spot lights that do not carry it warn
      (`warnings.warn`, with the fraction and the knob to change).
    - `**knobs`: the method's quality knobs (see `two_pass`, `caustic_triangles`,
      `caustics_mapping`, `adaptive_caustic_map`, `spot_lights`).

    Every argument is checked before anything is compiled: `method` one of the names
    above, `return_stats` a bool, `tolerance` a positive number, `margin` a number >= 1
    (and only with `tolerance`), a knob the method does not take is refused by name, and
    each method checks its knobs' types, ranges and memory (`memory_limit`).

    **Returns:** the irradiance image, relative to the irradiance the light gives a
    horizontal plane: ``(rows, cols)`` for a single index of refraction, ``(rows, cols,
    channels)`` for a sequence of indices. With `return_stats`, ``(image, stats)``.
    """
    return_stats = check_bool(return_stats, "return_stats")
    check_number(margin, "margin", low=1.0)
    if method is not None:
        check_choice(method, "method", sorted(METHODS))
    choice = None
    if tolerance is not None:
        if knobs:
            raise ValueError(f"`tolerance` picks the knobs: do not pass {sorted(knobs)} with it")
        choice = choose_method(scene, tolerance, method=method, margin=margin)
        logger.info("render: %s", choice)
        method, knobs = choice.method, dict(choice.knobs)
        if choice.as_mesh:
            scene = as_mesh_scene(scene, choice.as_mesh["subdivisions"])
    elif margin != DEFAULT_MARGIN:
        raise ValueError("`margin` applies only with `tolerance`")
    if method is None:
        method = DEFAULT_METHOD.get(type(scene).__name__, "twopass")
    check_knob_names(method, knobs)
    result = METHODS[method](scene, **knobs)
    _warn_missed(method, result.missed_flux_fraction)
    if return_stats:
        stats: dict[str, Array] = {"missed_flux_fraction": result.missed_flux_fraction}
        stats.update(getattr(result, "stats", {}))
        if choice is not None:
            stats["choice"] = choice
        return result.image, stats
    return result.image
