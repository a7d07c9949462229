"""`render`: the one entry point from a scene to an irradiance image."""

from __future__ import annotations

import logging
import warnings
from typing import Any, cast

import equinox as eqx
import jax

from .._checks import check_bool, check_number
from ..scene.ellipsoid import EllipsoidScene
from ..scene.mesh import MeshScene
from ..scene.mirror import MirrorScene
from ..scene.scene import LensScene, WaterScene
from .base import Method, worst
from .choose import DEFAULT_MARGIN, as_mesh_scene, choose_method
from .extended import is_extended, render_over_source
from .refine import DEFAULT_BUDGET_S, refinable_method, refine_to_tolerance
from .registry import as_method, method_class

logger = logging.getLogger("jaxcaustics")


MISSED_FLUX_WARNING = 0.01
"""`render` warns when a method leaves out more than this fraction of the light."""


def _warn_missed(method: Method, missed) -> None:
    """`warnings.warn` when `method` left out more than `MISSED_FLUX_WARNING` of the
    light it models (`Method.missed_advice`; concrete values only: under `jit` the
    fraction is in the result alone)."""
    if method.missed_advice is None or isinstance(missed, jax.core.Tracer):
        return
    largest = worst(missed)
    if largest > MISSED_FLUX_WARNING:
        warnings.warn(
            f"render: method {method.name!r} missed {largest:.1%} of the light (the image is "
            f"that much too dark; `missed_flux_fraction` in the stats): "
            f"{method.missed_advice}",
            stacklevel=3,
        )


def _warn_unsupported(method: Method, scene) -> None:
    """`warnings.warn` when `method` was asked for a scene it does not model
    (`Method.support` says why: an effect it leaves out, a shape it cannot follow);
    concrete scenes only (the checks read the scene's values)."""
    if any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(scene)):
        return
    reason = method.support(scene)
    if reason:
        warnings.warn(
            f"render: method {method.name!r} does not model this scene ({reason}): its "
            "image can be far from the reference (`jc.internal.method_support` says which "
            "methods do; `tolerance=` chooses one)",
            stacklevel=3,
        )


def _warn_limited(limited) -> None:
    """`warnings.warn` when the scene's interface limit dropped more than
    `MISSED_FLUX_WARNING` of the light through the object (concrete values only)."""
    if limited is None or isinstance(limited, jax.core.Tracer):
        return
    largest = worst(limited)
    if largest > MISSED_FLUX_WARNING:
        warnings.warn(
            f"render: the scene's interface limit dropped {largest:.1%} of the light through "
            "the object (photons still inside it, or meeting it again, after "
            "`scene.interfaces` events; `interface_limited_fraction` in the stats): raise "
            "the MeshScene's `interfaces`",
            stacklevel=3,
        )


def render(
    scene: WaterScene | LensScene | MirrorScene | MeshScene | EllipsoidScene,
    method: str | Method | None = None,
    *,
    tolerance: float | None = None,
    margin: float | None = None,
    refine: bool | None = None,
    budget_s: float | None = None,
    return_stats: bool = False,
    source_samples: int | None = None,
    **knobs: Any,
):
    """Render the caustics of `scene` on its receiver.

    **Arguments:**

    - `scene`: a `WaterScene`, `LensScene`, `MeshScene` or `EllipsoidScene`.
    - `method`: ``"twopass"`` (Yuksel & Keyser; water), ``"triangles"`` (Umenhoffer et
      al.'s caustic triangles; lens and mesh scenes), ``"caustics_mapping"`` (Shah et
      al.'s splatted caustic map; mesh scenes) or ``"adaptive"`` (Wyman & Nichols'
      adaptive caustic map; mesh scenes) or ``"spot_lights"`` (Liu et al.'s caustic spot
      lights; ellipsoid and mesh scenes), or a method with its knobs set: `TwoPass`,
      `CausticTriangles`, `CausticsMapping`, `AdaptiveCausticMap`, `SpotLightMethod`
      (then no `**knobs`). Default: the scene's natural method (``"twopass"`` for water,
      ``"spot_lights"`` for ellipsoids, ``"triangles"`` otherwise).
    - `tolerance`: instead of naming knobs, ask for an error against the reference
      (relative L1 after a 1-pixel Gaussian blur of both images, `image_error`). Where
      a method whose error estimate is reliable renders the scene (two-pass on water,
      caustic triangles on lens, mesh and ellipsoid scenes), the render is *refined* on
      the scene at hand (`refine`); elsewhere (`method` one of the others) the
      fastest method and knobs that the accuracy table expects to meet it are picked
      (`choose_method`, with `margin`, default 2). The choice is logged (logger
      ``"jaxcaustics"``, level INFO) and, with `return_stats`, returned as
      ``stats["choice"]`` (a `Choice`: method, knobs, expected error and time).
    - `refine`: with `tolerance`; ``None`` (the default) refines wherever a reliable
      estimate exists, ``True`` insists (a `ValueError` says why where it cannot),
      ``False`` trusts the table. Refining starts from the table's guess (`margin`
      default 1), renders it and the next coarser setting of its accuracy knob, whose
      difference estimates the error on this scene (`estimate_error`), and refines the
      knob until the estimate is within `tolerance` (`refine_to_tolerance`), or the
      next level would end past `budget_s` seconds (default 120) or not fit in memory
      (then a warning states the error reached). ``stats["error_estimate"]`` and
      ``stats["levels"]`` say what happened. Only methods whose estimate was measured
      reliable are refined (``benchmarks/results/estimate.md``): not the caustic maps
      or spot lights. An ellipsoid (rendered as a mesh) refines its tessellation too.
    - `return_stats`: also return a dict of diagnostics (``missed_flux_fraction`` per
      channel). Whether asked for or not, a two-pass render that leaves out more than
      1% of the light (beyond its window), spot lights that do not carry it, and caustic
      triangles whose scene's interface limit drops more than 1% of the light through
      the object warn (`warnings.warn`, with the fraction and the knob to change).
    - `source_samples`: under an extended light (`SunLight`, `AreaLight`), how many of
      its directions or points are rendered and averaged (stratified; default
      `SOURCE_SAMPLES`, 64: `jaxcaustics.methods.extended`); ``stats["source_samples"]``.
      With a collimated or point light it must be None.
    - `**knobs`: the knobs of the named method (the fields of its class, described
      there: `TwoPass`, `CausticTriangles`, `CausticsMapping`, `AdaptiveCausticMap`,
      `SpotLightMethod`).

    Every argument is checked before anything is compiled: `method` one of the names
    above, `return_stats` and `refine` bools, `tolerance` a positive number, `margin` a
    number >= 1 (only with `tolerance`), `budget_s` a positive number (only with
    `refine`), a knob the method does not take is refused by name, and
    each method checks its knobs' types, ranges and memory (`memory_limit`).

    **Returns:** the irradiance image, relative to the irradiance the light gives a
    horizontal plane: ``(rows, cols)`` for a single index of refraction, ``(rows, cols,
    channels)`` for a sequence of indices. With `return_stats`, ``(image, stats)``.

    **Example:** a sea's caustics on the pool floor (flat water would give 1 everywhere).

    ```pycon
    >>> extent = (0.0, 1.0, 0.0, 1.0)  # metres
    >>> heights = jc.wave_heights((32, 32), extent, amplitude=0.002, depth=0.5)
    >>> scene = jc.WaterScene(
    ...     jc.HeightField(heights, extent),
    ...     jc.DirectionalLight.from_angles(0.0),
    ...     jc.PlaneReceiver(extent, (32, 32)),
    ...     rest_depth=0.5,
    ... )
    >>> image = jc.render(scene)  # water: Yuksel & Keyser's two-pass method
    >>> image.shape
    (32, 32)
    >>> round(float(image.mean()), 3)  # the light is moved about, none lost
    1.0

    ```

    Under `jax.jit` or `jax.vmap`, fix the knobs sized from the scene first
    (`method_for`).
    """
    return_stats = check_bool(return_stats, "return_stats")
    if refine is not None:
        refine = check_bool(refine, "refine")
    if method is not None and not isinstance(method, Method):
        method_class(method)  # the name checked before anything is chosen or compiled
    if tolerance is None:
        for option, value in (("margin", margin), ("budget_s", budget_s), ("refine", refine)):
            if value not in (None, False):
                raise ValueError(f"`{option}` applies only with `tolerance`")
    elif knobs:
        raise ValueError(f"`tolerance` picks the knobs: do not pass {sorted(knobs)} with it")
    elif isinstance(method, Method) and not eqx.tree_equal(method, type(method)()):
        raise ValueError(
            f"`tolerance` picks the knobs: pass the method's name ({method.name!r}) or a "
            f"default {type(method).__name__}(), not {method!r}"
        )
    name = method.name if isinstance(method, Method) else method
    stats: dict[str, Any] = {}
    if is_extended(getattr(scene, "light", None)):
        if tolerance is not None:
            raise ValueError(
                "`tolerance` under an extended `scene.light` (a SunLight or AreaLight) is not "
                "estimated: name a `method` and its knobs (each of `source_samples` renders "
                "uses them)"
            )
        one = as_method(method, knobs, scene)
        _warn_unsupported(one, scene)

        def render_one(lit):
            result = one(lit)
            _warn_missed(one, result.missed_flux_fraction)
            return result.image, {"missed_flux_fraction": result.missed_flux_fraction} | (
                result.stats
            )

        image, stats = render_over_source(render_one, scene, source_samples)
        return (image, stats) if return_stats else image
    if source_samples is not None:
        raise ValueError("`source_samples` applies only under a SunLight or an AreaLight")
    if tolerance is None:
        method = as_method(method, knobs, scene)
        _warn_unsupported(method, scene)
        result = method(scene)
    elif refine or (refine is None and refinable_method(scene, name)[0] is not None):
        margin = check_number(1.0 if margin is None else margin, "margin", low=1.0)
        budget_s = DEFAULT_BUDGET_S if budget_s is None else budget_s
        result, info = refine_to_tolerance(
            scene, tolerance, method=name, margin=margin, budget_s=budget_s
        )
        method = cast(Method, info["method"])  # the method rendered
        logger.info("render: %s, refined to %r", info["choice"], method)
        stats = {k: info[k] for k in ("choice", "subdivisions", "error_estimate", "levels")}
    else:
        if budget_s is not None:
            raise ValueError("`budget_s` applies only when refining (`refine`)")
        margin = DEFAULT_MARGIN if margin is None else margin
        choice = choose_method(scene, tolerance, method=name, margin=margin)
        logger.info("render: %s", choice)
        if choice.as_mesh:  # (an EllipsoidScene's rows only: `choose_method`)
            assert isinstance(scene, EllipsoidScene)  # (for mypy)
            scene = as_mesh_scene(scene, choice.as_mesh["subdivisions"])
        method = method_class(choice.method).from_knobs(**choice.knobs)
        result = method(scene)
        stats = {"choice": choice}
    _warn_missed(method, result.missed_flux_fraction)
    _warn_limited(result.stats.get("interface_limited_fraction"))
    if return_stats:
        return result.image, {"missed_flux_fraction": result.missed_flux_fraction} | (
            result.stats | stats
        )
    return result.image
