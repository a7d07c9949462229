"""Caustic design: from a target picture to the height field of a lens or a mirror
(`design`, and `design_lens`, its keyword form).

A design is a problem stated as data (`jaxcaustics.inverse.problem`: the element, the
blank's outline, the light, the screen), solved by strategies, each a Module of its
settings in a file of its own:

- `TransportStart` (default; `transport_start.py`): the optimal transport from the
  aperture's flux to the target gives every photon's landing point, and the heights are
  fitted to them with the exact optics (under leaning light and off mirrors, the target
  is then corrected by the predicted caustic and solved again: `prediction.py`);
- `PoissonLevels` (`poisson_levels.py`): the weak-lens Poisson start and the irradiance
  residual solved coarse to fine (needs light everywhere: a floor);
- `ImageRefinement` (the finish, `image_refine.py`): a few L-BFGS steps on the image
  misfit where the target has dark regions (and on a photograph whose heights grid has
  fewer than four samples a pixel side).

Every stage steps its Optimistix solver through one driver (`driver.iterate`); the lens's
optics are `lens_model.LensModel`; the checks and the derived set-up are
`lens_setup.prepare`. The result (`LensDesign`) carries the forward model's predicted
caustic of the final heights; judge a design by tracing what was exported with the
reference (`verify_lens`; `verify_heights` for mirrors and posed screens).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
import optimistix as optx

from .._checks import check_bool, check_real_array
from .._warnings import warn_user
from ..scene.mirror import MirrorScene
from ..scene.scene import DirectionalLight, LensScene, PointLight
from .checkpoint import check_checkpoint
from .design_rounds import solve_in_rounds
from .design_setup import Setup, has_dark_regions
from .image_refine import ImageRefinement
from .lens_setup import prepare
from .poisson_levels import PoissonLevels, check_levels
from .prediction import predict_caustic, relative_l2
from .problem import DesignProblem, Lens, Rectangle, Screen, _length
from .solvers import SolverLike
from .source_blur import blur, source_limit
from .transport_start import TransportStart


@dataclasses.dataclass
class LensDesign:
    """Result of `design` (and `design_lens`).

    - `heights`: ``(rows, cols)`` NumPy array, metres: the top surface relative to its
      rest plane, with ``max(heights) = 0`` (``thickness`` is the blank's thickness, the
      design is milled into it; the thinnest point is ``thickness + min(heights)``).
    - `scene`: the `LensScene`, or the `MirrorScene` of a mirror (receiver: the screen's
      pixel grid, the target's shape, in the screen's own frame when it is posed).
    - `predicted`: the forward model's caustic on the screen (caustic triangles, exact
      reconstruction), ``(rows, cols)``, irradiance as `caustic_triangles` gives it.
    - `target`: the target as used (float, scaled to the flux of the lens, masked).
    - `loss_history`: ``0.5 * sum(residual^2)`` after every solver step, all levels.
    - `result`: the Optimistix result of the last level (``optx.RESULTS``).
    - `levels`: a report per stage (``"stage"``: transport, landing fit, irradiance,
      image refinement): its grid, steps, final loss (the refinement also its
      ``"photons"`` per side), ``"result"`` (``optx.RESULTS``;
      a stage marked ``"budget"`` ran a fixed number of steps, so its
      ``max_steps_reached`` is no shortfall), seconds (compilation included) and seconds
      of the first call (compilation).
    - `predicted_error`: relative L2 of `predicted` against `target` (both at unit mean).
    - `dark_flux`: the fraction of the predicted flux that lands on pixels where the
      target is below 5% of its mean.
    - `converged`: every level (and the transport) met its tolerance.
    - `timings`: ``{"total": s, "initial_guess": s, "predict": s}``.
    - `warnings`: what the design warned about (also raised with `warnings.warn`).
    - `problem`: the `DesignProblem` designed for.
    - `source_blur_px`: an extended source's blur on the screen, pixels (the radius of
      its image: `source_blur.blur_radius`); None under a point or collimated light.
      `predicted` is then the caustic as seen under the source, and `target` the target
      as given (the transport aimed at it deconvolved).
    """

    heights: np.ndarray
    scene: LensScene | MirrorScene
    predicted: np.ndarray
    target: np.ndarray
    loss_history: list[float]
    levels: list[dict[str, Any]]
    result: Any
    timings: dict[str, float]
    predicted_error: float = float("nan")
    dark_flux: float = float("nan")
    converged: bool = True
    warnings: list[str] = dataclasses.field(default_factory=list)
    problem: DesignProblem | None = None
    source_blur_px: float | None = None

    @property
    def relief(self) -> float:
        """Depth of the relief, metres (``max(heights) - min(heights)``)."""
        return float(np.max(self.heights) - np.min(self.heights))


def fresnel_zones(heights, depth: float) -> np.ndarray:
    """Fold a relief deeper than `depth` into Fresnel zones: the heights modulo `depth`.

    The slopes, which steer the light, are kept everywhere but on the folds, where the
    surface steps down by `depth` (over one sample of the bicubic surface, which sends the
    light falling on the step astray). Returns heights in ``[-depth, 0]`` (metres, the
    same shape)."""
    h = check_real_array(heights, "heights").astype(float)
    if h.size == 0 or not np.all(np.isfinite(h)):
        raise ValueError(f"`heights` must be finite and not empty, got shape {h.shape}")
    depth = _length(depth, "depth")
    folded = -np.mod(h.max() - h, depth)
    return folded - folded.max()


def design(
    problem: DesignProblem,
    target,
    *,
    start: TransportStart | PoissonLevels | None = None,
    finish: ImageRefinement | None = ImageRefinement(),  # noqa: B008 (immutable)
    mask=None,
    heights_shape: tuple[int, int] | None = None,
    max_relief: float | None = None,
    predict_photons: int | None = None,
    warn_error: float = 0.15,
    initial=None,
    callback: Callable[[dict], None] | None = None,
    throw: bool = True,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    progress: bool = False,
    memory_limit: int | None = None,
) -> LensDesign:
    """Design the element of `problem` whose caustic on the screen matches `target`.

    **Arguments:**

    - `problem`: a `DesignProblem` (element, outline, screen, light).
    - `target`: the image to project, ``(rows, cols)`` (an RGB image is turned into
      luminance), non-negative; its shape is the screen's pixel grid, and only its
      relative brightness matters (the design is invariant to scaling it).
    - `start`: how the heights are found: `TransportStart()` (default) or
      `PoissonLevels()`, each with its settings.
    - `finish`: `ImageRefinement()` (default; it runs where the target has dark regions,
      on a photograph whose heights grid has fewer than four samples a target pixel
      side, and always under leaning light, off a mirror or before a posed screen) or
      ``None``.
    - `mask`: boolean ``(rows, cols)``: pixels that may receive light; outside it the
      target is dark (up to the start's `floor`).
    - `heights_shape`: the final heights grid ``(rows, cols)``; default: the start's.
    - `max_relief`: the deepest relief the blank allows (metres); a deeper design is
      folded into Fresnel zones (`fresnel_zones`). ``None``: no bound.
    - `predict_photons`: photons per side of the predicted caustic (default 4 per pixel
      side up to 2049, at least 2 beyond: `predict_photons_default`; caustic triangles,
      their window at most 16 pixels).
    - `warn_error`: warn when the predicted caustic's relative L2 error exceeds this.
    - `initial`: heights (metres, any grid shape) to start from instead of the start's
      own (flat for the transport start, the weak-lens solution for the levels).
    - `callback`: called after every solver step with a dict (level, shape, step, loss,
      and the number of residuals the loss sums).
    - `throw`: raise if a level's solver fails (otherwise the result says so).
    - `checkpoint`: a file written after every round (each Poisson level, the transport
      start, the finish); ``None``: none.
    - `resume`: continue from `checkpoint` (its rounds are not run again; a checkpoint
      of another target, problem, strategy or option is refused). Ctrl-C raises
      `KeyboardInterrupt` and leaves the last round's checkpoint.
    - `progress`: show a progress bar over the rounds.
    - `memory_limit`: bytes the design may take (``None``: half of this machine's
      memory, `default_memory_limit`). Its peak is estimated before anything is
      compiled (`design_memory`) and a design over the limit is refused, naming the
      knobs that lower it; the predicted caustic's photons are traced in bands within
      it.

    **Returns:** a `LensDesign`. A bad problem or option raises `ValueError` naming it
    before anything is compiled. A design whose predicted error exceeds `warn_error`, or
    whose stages stopped at their step limits, is returned with a `warnings.warn` that
    says so and what to change (also in `LensDesign.warnings`).

    For example::

        problem = jc.DesignProblem(
            jc.Lens(thickness=0.02), jc.Rectangle(0.1, 0.1), jc.Screen(distance=0.5)
        )
        lens = jc.design(problem, target)
    """
    t_start = time.perf_counter()
    throw = check_bool(throw, "throw")
    resume = check_bool(resume, "resume")
    progress = check_bool(progress, "progress")
    check_checkpoint(checkpoint, resume)
    if callback is not None and not callable(callback):
        raise ValueError(f"`callback` must be callable or None, got {type(callback).__name__}")
    setup = prepare(
        problem,
        target,
        TransportStart() if start is None else start,
        finish,
        mask=mask,
        heights_shape=heights_shape,
        max_relief=max_relief,
        predict_photons=predict_photons,
        warn_error=warn_error,
        initial=initial,
        memory_limit=memory_limit,
    )
    history: list[float] = []
    h, reports, result = _solve(setup, history, callback, throw, checkpoint, resume, progress)
    return _finish(setup, h, history, reports, result, t_start)


# the work of a design, after every check (tests replace it to show that checks come first)
_solve = solve_in_rounds


def _required_screen_distance(where: str, screen_distance):
    """`screen_distance`, which has no default (a `ValueError` naming it when missing)."""
    if screen_distance is None:
        raise ValueError(
            f"{where}: `screen_distance` is required (metres from the lens's bottom face to "
            "the screen)"
        )
    return screen_distance


def design_lens(
    target,
    *,
    width: float,
    height: float,
    thickness: float,
    screen_distance: float | None = None,
    ior: float = 1.5,
    light: DirectionalLight | PointLight | None = None,
    mask=None,
    heights_shape: tuple[int, int] | None = None,
    screen_extent: Sequence[float] | None = None,
    levels: Sequence[int] | None = None,
    max_steps: int = 40,
    solver: SolverLike = "levenberg_marquardt",
    oversample: int = 1,
    floor: float | None = None,
    boundary_weight: float = 1.0,
    regularization: float = 0.01,
    start_scale: float = 0.5,
    cg_steps: int = 30,
    rtol: float = 1e-4,
    predict_photons: int | None = None,
    max_relief: float | None = None,
    throw: bool = True,
    callback: Callable[[dict], None] | None = None,
    initial=None,
    start: Literal["transport", "poisson"] = "transport",
    transport_iterations: int = 100,
    warn_error: float = 0.15,
    refine_steps: int | None = None,
    refine_photons: int | None = None,
    memory_limit: int | None = None,
) -> LensDesign:
    """Design the height-field top surface of a caustic lens whose caustic on a screen
    matches `target`: `design` with its problem and strategies given as keywords.

    **Arguments** (lengths in metres):

    - `target`: the image to project, ``(rows, cols)`` (an RGB image is turned into
      luminance), non-negative; only its shape matters for the screen's pixel grid and
      its relative brightness (the design is invariant to scaling it).
    - `width`, `height`: the lens aperture (x and y extents), centred on ``x = y = 0``.
    - `thickness`: the blank's thickness, bottom face to the top surface's highest point.
    - `screen_distance`: distance from the bottom face to the screen.
    - `ior`: index of refraction of the glass.
    - `light`: a `DirectionalLight` or a `PointLight`; default: collimated, straight down.
    - `mask`: boolean ``(rows, cols)``: pixels that may receive light; outside it the
      target is dark (up to the `floor`).
    - `heights_shape`: the final heights grid; default: the last level along the longer
      side of the aperture, the other side in proportion.
    - `screen_extent`: ``(x_min, x_max, y_min, y_max)`` of the screen; default: the
      flat lens's footprint (the aperture traced to the screen).
    - `start`: ``"transport"`` (default): the optimal transport from the aperture's flux
      to the target gives every photon's landing point, and the heights are fitted to
      them with the exact optics (one level, see the module docstring; `solver`,
      `floor`, `regularization`, `start_scale`, `boundary_weight`, `cg_steps`, `rtol`
      and `oversample` belong to the other start). ``"poisson"``: the weak-lens Poisson
      start and the irradiance residual solved coarse to fine by `solver` (needs
      light everywhere: a `floor`).
    - `levels`: heights samples along the longer side, coarse to fine; default: powers
      of two from 32 up to twice the target's longer side (heights finer than the
      pixels: a photon cell per half pixel). With the transport start only the last
      entry counts (the heights grid); default: the target's longer side times 4, at
      most 1024 (`transport_shape`).
    - `max_steps`: solver steps per level (the landing fit's steps).
    - `solver`: ``"levenberg_marquardt"`` or ``"gauss_newton"`` (least squares, both
      with Lineax `NormalCG`, matrix-free, `cg_steps` iterations at most), a minimiser
      on ``0.5 * sum(residual^2)``: ``"lbfgs"``, ``"bfgs"`` or ``"adam"`` (Optax's,
      through `optimistix.OptaxMinimiser`), or an Optimistix solver object (the same
      names and rules as `recover_surface`: `jaxcaustics.inverse.solvers`);
      the Poisson start's.
    - `transport_iterations`: back-and-forth iterations of the transport at most.
    - `refine_steps`: the transport start's finish (`ImageRefinement`; None: 8 under
      vertical light, 4 for a photograph on a coarse grid, 24 under leaning light), for
      targets with dark regions
      (below 5% of the mean on more than 10% of the screen: there the map jumps and the
      fitted surface spreads light across the gaps) and for any under leaning light:
      this many L-BFGS steps on the
      image misfit plus the flux on dark pixels, with the caustic-triangles forward
      model (`refine_photons` photons per side, default 4 per pixel, at most 1025;
      window 4), moving the heights' modes up to two per pixel; kept only if the misfit fell. 0: no
      finish. Measured on the white-lettering target (128 x 128), judged by the
      reference: relative L2 0.049 and 2.6% of the flux on dark pixels after 8 steps
      (0.085 and 3.2% without them, measured in an earlier version).
    - `warn_error`: warn when the predicted caustic's relative L2 error against the
      target exceeds this.
    - `max_relief`: the deepest relief the blank allows (metres), e.g. Mitsuba's
      tutorial bound of +-0.5% of the width; a deeper design is folded into Fresnel
      zones (`fresnel_zones`) after the optimisation. ``None``: no bound.
    - `oversample`: photon cells per heights sample along each axis.
    - `floor`: a uniform irradiance added to the unit-mean target; black regions get
      this much. Default: 0 with the transport start (black stays black), 0.02 with
      the Poisson start (its irradiance equation needs light everywhere).
    - `boundary_weight`: weight of the boundary condition (pixels of misplacement).
    - `regularization`: weight of a curvature prior on the preconditioned variable
      (transport); 0.01 by default. Measured while tuning on the camera benchmark's
      setting (128 x 128): 0.003 gave 0.14 relative L2, 0.01 0.048, 0.02 0.047 (and 0.1,
      with 20 steps per level, 0.065).
    - `start_scale`: the weak-lens start is scaled by this (1: the full weak-lens
      solution, which folds where the target is dark; 0.5 by default).
    - `predict_photons`: photon grid of the predicted caustic (default 4 per pixel side
      up to 2049, at least 2 beyond; caustic triangles, their window at most 16 pixels).
    - `throw`: raise if a level's solver fails (otherwise the result says so).
    - `callback`: called after every solver step with a dict (level, shape, step, loss,
      and the number of residuals the loss sums: ``loss / residuals`` is comparable
      between levels; the transport start's loss is already a mean).
    - `initial`: heights (metres, any grid shape) to start the first level from instead
      of the weak-lens Poisson solution (how a run is continued level by level), or
      the landing fit from instead of flat.
    - `memory_limit`: bytes the design may take (`design`'s; default half of this
      machine's memory).

    `design_lens(target, width=w, height=h, thickness=t, screen_distance=d, ...)` is
    ``design(DesignProblem(Lens(t, ior), Rectangle(w, h), Screen(d, screen_extent),
    light), target, start=TransportStart(...), finish=ImageRefinement(refine_steps,
    refine_photons))`` (or ``start=PoissonLevels(...)``, no finish, with
    ``start="poisson"``); the results are the same.

    **Returns:** a `LensDesign`. Invalid specifications raise `ValueError` naming the
    argument before any optimisation starts. A design whose predicted error exceeds
    `warn_error`, or whose levels stopped at `max_steps`, is returned with a
    `warnings.warn` that says so and what to change (also in `LensDesign.warnings`).
    """
    screen_distance = _required_screen_distance("design_lens", screen_distance)
    problem, start_, finish = lens_problem(
        width=width,
        height=height,
        thickness=thickness,
        screen_distance=screen_distance,
        ior=ior,
        light=light,
        screen_extent=screen_extent,
        start=start,
        levels=levels,
        max_steps=max_steps,
        solver=solver,
        oversample=oversample,
        floor=floor,
        boundary_weight=boundary_weight,
        regularization=regularization,
        start_scale=start_scale,
        cg_steps=cg_steps,
        rtol=rtol,
        transport_iterations=transport_iterations,
        refine_steps=refine_steps,
        refine_photons=refine_photons,
    )
    return design(
        problem,
        target,
        start=start_,
        finish=finish,
        mask=mask,
        heights_shape=heights_shape,
        max_relief=max_relief,
        predict_photons=predict_photons,
        warn_error=warn_error,
        initial=initial,
        callback=callback,
        throw=throw,
        memory_limit=memory_limit,
    )


# the strategies' settings -> `design_lens`'s keywords, for its errors
_KEYWORDS = {
    "`iterations`": "`transport_iterations`",
    "`grid`": "`levels`",
    "`steps`": "`refine_steps`",
    "`photons`": "`refine_photons`",
}


def _with_keywords(build: Callable[[], Any]):
    """`build()`, its `ValueError` naming `design_lens`'s keywords instead of the
    strategies' settings."""
    try:
        return build()
    except ValueError as err:
        message = str(err)
        for setting, keyword in _KEYWORDS.items():
            message = message.replace(setting, keyword)
        raise ValueError(message) from None


def lens_problem(
    *,
    width,
    height,
    thickness,
    screen_distance,
    ior=1.5,
    light=None,
    screen_extent=None,
    start="transport",
    levels=None,
    max_steps=40,
    solver="levenberg_marquardt",
    oversample=1,
    floor=None,
    boundary_weight=1.0,
    regularization=0.01,
    start_scale=0.5,
    cg_steps=30,
    rtol=1e-4,
    transport_iterations=100,
    refine_steps=None,
    refine_photons=None,
) -> tuple[DesignProblem, TransportStart | PoissonLevels, ImageRefinement | None]:
    """`design_lens`'s keywords as a problem and its strategies (`ValueError` naming the
    keyword)."""
    problem = DesignProblem(
        Lens(thickness, ior),
        Rectangle(width, height),
        Screen(screen_distance, screen_extent),
        light,
    )
    if start not in ("transport", "poisson"):
        raise ValueError(f"`start` must be 'transport' or 'poisson', got {start!r}")
    if levels is not None:
        levels = check_levels(levels)
    # built under either start: the transport start's `design_lens` checks them too
    poisson = PoissonLevels(
        levels=levels,
        max_steps=max_steps,
        solver=solver,
        oversample=oversample,
        floor=0.02 if floor is None or start != "poisson" else floor,
        boundary_weight=boundary_weight,
        regularization=regularization,
        start_scale=start_scale,
        cg_steps=cg_steps,
        rtol=rtol,
    )
    if start == "poisson":
        return problem, poisson, None
    transport = _with_keywords(
        lambda: TransportStart(
            grid=None if levels is None else levels[-1],
            iterations=transport_iterations,
            max_steps=max_steps,
            floor=0.0 if floor is None else floor,
            oversample=oversample,
        )
    )
    finish = _with_keywords(lambda: ImageRefinement(refine_steps, refine_photons))
    return problem, transport, finish


def _finish(setup: Setup, h, history, level_reports, result, t_start: float) -> LensDesign:
    """Fold the relief if asked, check the blank, predict the caustic: the `LensDesign`."""
    timings = dict(setup.timings)
    if setup.max_relief is not None and h.max() - h.min() > setup.max_relief:
        h = fresnel_zones(h, setup.max_relief)
    setup.check_thickness(h)
    t0 = time.perf_counter()
    # the image refinement's photons per side (None if it did not run)
    refined = next(
        (r.get("photons") for r in level_reports if r.get("stage") == "image refinement"), None
    )
    predicted, missed, window, final = predict_caustic(setup, h, refined)
    if setup.kernel is not None:  # as seen under the extended source
        predicted = blur(predicted, setup.kernel)
    timings["predict"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    target = setup.seen_goal * setup.flux_scale
    error = relative_l2(predicted, target)
    dark = target < 0.05 * target.mean()
    dark_flux = float(predicted[dark].sum() / max(predicted.sum(), 1e-300))
    notes = _design_warnings(setup, level_reports, error, dark_flux)
    radius = None
    if setup.kernel is not None:
        radius, note = source_limit(setup)
        if note:
            notes.append(note)
    # measured: 0.1% on the dots' design (the 16-pixel window); 11.5% on a 32^2
    # silhouette under a point light, nearly all off the screen (11.5% at a 64-pixel
    # window): the light its bevel throws away
    if missed > 0.01:
        notes.append(
            f"design: {100 * missed:.1f}% of the lens's light is not in the "
            f"prediction: it lands off the screen (an edge bevel under leaning light "
            f"throws some away) or beyond the {window}-pixel triangle window; "
            "`predicted`, `predicted_error` and `dark_flux` leave it out"
        )
    for note in notes:
        warn_user(note)
    converged = not any(_stopped(r) for r in level_reports)
    return LensDesign(
        heights=h,
        scene=final,
        predicted=predicted,
        target=target,
        loss_history=history,
        levels=level_reports,
        result=result,
        timings=timings,
        predicted_error=error,
        dark_flux=dark_flux,
        converged=converged,
        warnings=notes,
        problem=setup.problem,
        source_blur_px=radius,
    )


def _stopped(report: dict) -> bool:
    """A stage stopped at its step limit before converging (a step budget is no
    shortfall), or diverged."""
    if _diverged(report):
        return True
    limit = bool(report["result"] == optx.RESULTS.max_steps_reached)
    return limit and not report.get("budget", False)


def _diverged(report: dict) -> bool:
    return bool(report["result"] == optx.RESULTS.nonlinear_divergence)


def _design_warnings(setup: Setup, reports, error: float, dark_flux: float) -> list[str]:
    """What a design missed, with what to change (the design warns each)."""
    notes = []
    for r in reports:
        if _diverged(r):
            notes.append(
                f"design: the {r.get('stage', 'solve')} of {r['shape']} diverged at step "
                f"{r['steps']} (its loss became NaN or infinite); the heights before that "
                "step are kept: try another `solver` (levenberg_marquardt is the steadiest) "
                "or fewer `max_steps`"
            )
        elif _stopped(r):
            transport = r.get("stage") == "transport"
            what = "transport" if transport else f"level {r['shape']}"
            limit = "transport_iterations" if transport else "max_steps"
            notes.append(
                f"design: the {what} stopped at {limit}={r['steps']} before converging "
                f"(loss {r['loss']:.3g}); raise `{limit}`"
                + (" (the start's `iterations`)" if transport else "")
            )
    side = max(setup.shapes[-1]) / max(setup.target_shape)
    coarse = isinstance(setup.start, TransportStart) and max(setup.target_shape) > 256
    # a photograph's coarse grid is finished by the image refinement (`_fine_detail`)
    enough = 4 if coarse and has_dark_regions(setup.goal) else 2
    if coarse and side < enough:
        notes.append(
            f"design: the heights grid {tuple(setup.shapes[-1])} has {side:.3g} samples per "
            f"target pixel side; below {enough} the transport misplaces edges and fine "
            "detail by a fraction of a pixel (measured, judged by the height map: the "
            "camera at 512 pixels with 2, relative L2 0.019 and 1 - SSIM 0.033; at 1024 "
            "with 1, 0.034 and 0.14, and 0.031 and 0.12 after 12 refinement steps; the "
            "silhouette at 512 with 2, 0.048 against 0.042 at 256 with 4): a smaller "
            "target, or more refinement steps (`ImageRefinement(steps=...)`, slower); a "
            "larger `heights_shape` did not help (the camera at 1024 on 2048^2 heights: "
            "1 - SSIM 0.17 against 0.15)"
        )
    if error > setup.warn_error:
        notes.append(
            f"design: the predicted caustic misses the target by {error:.3f} (relative L2, "
            f"above warn_error={setup.warn_error:g}; {100 * dark_flux:.1f}% of the flux on "
            "dark pixels): try more steps, a longer screen distance or a thicker blank (more "
            "relief), "
            "or a softer target (blur its edges, fewer isolated points)"
        )
    return notes
