"""A method's error on the scene at hand (`estimate_error`), and ``render(scene,
tolerance=t)`` refining until that error meets ``t``.

As an adaptive ODE solver does, a method renders the scene at two settings of its
accuracy knob, one twice as fine as the other along each side (`Method.refined`), and
the difference of the two images (`image_error`) estimates the finer one's error. Only
methods with `Method.estimate_is_reliable` are refined to a tolerance. See the design
notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from .._checks import check_int, check_number
from ..scene.ellipsoid import EllipsoidScene
from .base import Method, RenderResult, worst
from .choose import (
    Choice,
    accuracy_table,
    allowed_rows,
    as_mesh_scene,
    choose_method,
    image_error,
    scene_kind,
)
from .registry import METHODS, method_class

#: seconds `render(scene, tolerance=t)` may spend refining before it stops and warns
DEFAULT_BUDGET_S = 120.0


@dataclasses.dataclass(frozen=True)
class ErrorEstimate:
    """A method's estimated error on one scene (`estimate_error`).

    - `error`: the estimated error of the finer image (relative L1 after a 1-pixel blur
      against an exact render): `difference` plus `missed`.
    - `difference`: `image_error` of the coarser image against the finer.
    - `missed`: the largest per-channel fraction of the light the finer render's model
      left out (0 for methods whose missed flux is light landing off the receiver).
    - `coarse`, `fine`: the two settings rendered.
    - `coarse_subdivisions`, `fine_subdivisions`: for an ellipsoid rendered as a mesh,
      the tessellations (`Ellipsoid.to_mesh`) of the two renders; else ``None``.
    """

    error: float
    difference: float
    missed: float
    coarse: Method
    fine: Method
    coarse_subdivisions: int | None = None
    fine_subdivisions: int | None = None


def _compare(coarse: Method, low: RenderResult, fine: Method, high: RenderResult, meshes=()):
    difference = image_error(np.asarray(low.image), np.asarray(high.image))
    # light the model leaves out at every setting (not light landing off the receiver)
    missed = 0.0 if fine.missed_advice is None else worst(high.missed_flux_fraction)
    return ErrorEstimate(difference + missed, difference, missed, coarse, fine, *meshes)


def estimate_error(
    scene, method: Method, *, subdivisions: int | None = None
) -> tuple[RenderResult, ErrorEstimate]:
    """Render `scene` with `method` and with the next coarser setting of its accuracy
    knob (at the coarsest, with `method` and the next finer one) and estimate the finer
    image's error from their difference.

    `subdivisions`: for an `EllipsoidScene` rendered by a mesh method, the tessellation
    (`Ellipsoid.to_mesh`) of `method`'s render; the coarser render has one subdivision
    fewer (the finer one more), so that the difference sees the tessellation's error.

    **Returns:** ``(result, estimate)``: the finer render (a `RenderResult`) and its
    `ErrorEstimate`. Two renders: about 1.25 to 1.5 times the cost of `method` alone when
    it can be coarsened (the coarser costs a quarter to a half), 3 to 5 times otherwise.
    """
    if not isinstance(method, Method):
        raise ValueError(f"`method` must be a Method, got {type(method).__name__}")
    if subdivisions is not None:
        subdivisions = check_int(subdivisions, "subdivisions", 0)
        if not isinstance(scene, EllipsoidScene):
            raise ValueError(
                f"`subdivisions` is for an EllipsoidScene rendered as a mesh, got a "
                f"{type(scene).__name__}"
            )
    (coarse, coarse_sub), (fine, fine_sub) = _first_pair(method, subdivisions)
    low = _render_level(scene, coarse, coarse_sub)
    high = _render_level(scene, fine, fine_sub)
    return high, _compare(coarse, low, fine, high, (coarse_sub, fine_sub))


def _start(scene, tolerance: float, name: str | None, margin: float) -> Choice | None:
    """The table's guess, or ``None`` when no measured setting is expected to meet
    `tolerance` (then the most accurate one starts, `_most_accurate`)."""
    try:
        return choose_method(scene, tolerance, method=name, margin=margin)
    except ValueError as err:
        if "below what any measured setting reaches" not in str(err):
            raise
        return None


def _most_accurate(scene, tolerance: float, name: str | None, margin: float) -> Choice:
    """The choice for the loosest tolerance the most accurate allowed setting meets."""
    rows = accuracy_table()["kinds"][scene_kind(scene)]["rows"]
    rows = [r for r in rows if r.get("choosable", True) and (name is None or r["method"] == name)]
    allowed, _ = allowed_rows(scene, rows)
    best = min(allowed, key=lambda r: r["error"])
    return choose_method(scene, best["error"] * margin * (1 + 1e-9), method=name, margin=margin)


def refinable_method(scene, name: str | None) -> tuple[str | None, str]:
    """``(method, "")``: `name`, or the first method whose error estimate is reliable
    (`Method.estimate_is_reliable`) that the accuracy table has for `scene`; or
    ``(None, why)`` when there is none (an unreliable estimate would let a refined
    render miss its tolerance unsaid)."""
    reliable = [n for n, cls in METHODS.items() if cls.estimate_is_reliable]
    if name is not None and name not in reliable:
        return None, (
            f"the error estimate of method {name!r} was measured to under-state its error "
            "(it does not see what all its settings share: the caustic maps' splats, the "
            f"spot lights' model); refining is for {reliable}"
        )
    rows = accuracy_table()["kinds"][scene_kind(scene)]["rows"]
    for candidate in [name] if name else reliable:
        ours = [r for r in rows if r["method"] == candidate and r.get("choosable", True)]
        if allowed_rows(scene, ours)[0]:
            return candidate, ""
    return None, (
        f"no method whose error estimate is reliable ({reliable}) renders this "
        f"{scene_kind(scene)} scene"
    )


def _render_level(scene, method: Method, subdivisions: int | None) -> RenderResult:
    """`method` on `scene`, or on its ellipsoid as a mesh of `subdivisions`."""
    return method(scene if subdivisions is None else as_mesh_scene(scene, subdivisions))


def _on_mesh(subdivisions: int | None) -> str:
    return (
        "" if subdivisions is None else f" on the ellipsoid's mesh of {subdivisions} subdivisions"
    )


def _first_pair(guess: Method, subdivisions: int | None):
    """``((coarse, its subdivisions), (fine, its subdivisions))`` around the table's
    guess: the guess and its coarser setting (one tessellation level fewer for an
    ellipsoid's mesh, so that the difference sees the tessellation's error too), or at
    the coarsest the guess and its finer setting."""
    coarse = guess.coarsened()
    if coarse is not None and subdivisions != 0:
        return (coarse, None if subdivisions is None else subdivisions - 1), (guess, subdivisions)
    finer = None if subdivisions is None else subdivisions + 1
    return (guess, subdivisions), (guess.refined(), finer)


def refine_to_tolerance(
    scene,
    tolerance: float,
    *,
    method: str | None = None,
    margin: float = 1.0,
    budget_s: float = DEFAULT_BUDGET_S,
) -> tuple[RenderResult, dict]:
    """What ``render(scene, tolerance=t, refine=True)`` does: start from the accuracy
    table's guess (`choose_method` with `margin`) among the methods whose error estimate
    is reliable (`Method.estimate_is_reliable`: two-pass and caustic triangles; `method`
    must be one),
    estimate its error on this scene (`estimate_error`)
    and refine its accuracy knob until the estimate is within `tolerance`, or the next
    level (about four times the last) would end past `budget_s` seconds, or a finer
    setting does not fit in memory (then `warnings.warn` with the error reached).

    An ellipsoid (rendered through its mesh) refines its tessellation with the knob:
    each level one subdivision more (`Ellipsoid.to_mesh`), so that the estimate sees the
    tessellation's error as well as the photon grid's.

    **Returns:** ``(result, info)``: the finest render and ``{"choice": the table's
    Choice, "method": the Method rendered, "subdivisions": its ellipsoid's tessellation
    (``None`` for other scenes), "error_estimate": its estimated error, "levels":
    [ErrorEstimate, ...] one per comparison, "met": bool}``.
    """
    tolerance = check_number(tolerance, "tolerance", low=0.0, low_open=True)
    budget_s = check_number(budget_s, "budget_s", low=0.0, low_open=True)
    method, why = refinable_method(scene, method)
    if method is None:
        raise ValueError(f"`refine`: {why}; pass `refine=False` (the accuracy table's choice)")
    choice = _start(scene, tolerance, method, margin)
    if choice is None:
        choice = _most_accurate(scene, tolerance, method, margin)
    subdivisions = choice.as_mesh["subdivisions"] if choice.as_mesh else None
    start = time.perf_counter()
    guess = method_class(choice.method).from_knobs(**choice.knobs)
    result, estimate = estimate_error(scene, guess, subdivisions=subdivisions)
    fine_sub = estimate.fine_subdivisions
    levels = [estimate]
    stop = None
    last = time.perf_counter() - start  # the last level's seconds (both renders, first)
    while estimate.error > tolerance:
        # a finer level costs about 4 times the last (twice the samples along each side):
        # not started if it would end past the budget
        elapsed = time.perf_counter() - start
        if elapsed + 4.0 * last > budget_s:
            stop = (
                f"the time budget ({budget_s:g} s) would be spent: {elapsed:.3g} s so far, "
                f"the next level about {4.0 * last:.3g} s"
            )
            break
        finer = estimate.fine.refined()
        finer_sub = None if fine_sub is None else fine_sub + 1
        try:
            higher = _render_level(scene, finer, finer_sub)
        except ValueError as err:  # a finer setting over the memory limit (checked first)
            if "memory_limit" not in str(err):
                raise
            stop = f"a finer setting does not fit in memory ({err})"
            break
        estimate = _compare(estimate.fine, result, finer, higher, (fine_sub, finer_sub))
        last = time.perf_counter() - start - elapsed
        result, fine_sub = higher, finer_sub
        levels.append(estimate)
    met = estimate.error <= tolerance
    if not met:
        warnings.warn(
            f"render: tolerance {tolerance:g} not met: the estimated error is "
            f"{estimate.error:.3g} with {estimate.fine!r}{_on_mesh(fine_sub)} ({stop})",
            stacklevel=3,
        )
    info = {
        "choice": choice,
        "method": estimate.fine,
        "subdivisions": fine_sub,
        "error_estimate": estimate.error,
        "levels": levels,
        "met": met,
    }
    return result, info
