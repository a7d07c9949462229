"""Recover a water surface from the caustics it casts (inverse two-pass rendering).

Given a target caustic image and the scene's known parts (rest depth, light, index of
refraction, extents), `recover_surface` finds the height field whose two-pass caustic
(`jaxcaustics.two_pass`) matches the target, as a nonlinear least-squares problem solved
with Optimistix.

**The start.** By default (``start="auto"``, where the target covers the heights'
extent) the heights come from the transport start (`jaxcaustics.inverse.water_start`:
optimal transport, then Gauss-Newton fits of the exact rays), which is the whole
recovery for a caustic without folds; the image-space solve below follows it only
when a `solver` is named. ``start="ripple"`` begins that solve from flat water instead.

**Unknowns.** The heights are solved for in a scaled unit
``u = heights / height_scale`` with ``height_scale = dA / (rest_depth |1 - 1/n|)``
(``dA``: the area of one receiver pixel, ``n``: the index of refraction). For small
slopes the caustic of a surface is ``1 - rest_depth (1 - 1/n) Laplacian(heights)``, so
in this unit the image's contrast is about the Laplacian of ``u`` in receiver pixels:
the unknowns are O(1) for any caustic of O(1) contrast, and the tolerances mean the
same thing at every scale.

**Residuals** (their sum of squares is the objective):

- ``(render(heights) - target) / sqrt(pixels)``: the image misfit (mean square);
- ``sqrt(smoothness) * Laplacian(u) / sqrt(samples)``: a smoothness prior, the discrete
  five-point Laplacian of ``u`` in receiver-pixel units (periodic or clamped like the
  surface), i.e. the image contrast that the curvature would cause. ``smoothness`` is a
  dimensionless weight relative to the image misfit;
- ``mean(u)``: the mean height is (nearly) unobservable, so it is pinned to zero.

**Solvers.** ``"levenberg_marquardt"`` and ``"gauss_newton"`` solve the least-squares
problem matrix-free: each (damped) Gauss-Newton step solves its normal equations by a
truncated conjugate gradient (`lineax.Normal(lineax.CG(...))`, `cg_steps` iterations of
one Jacobian-vector and one vector-Jacobian product each). ``"bfgs"`` minimises the sum
of squares with `optimistix.BFGS`, ``"adam"`` with Optax's Adam through
`optimistix.OptaxMinimiser` (all four stop by Optimistix's Cauchy criterion).

**Coarse to fine.** `coarse_to_fine` lists downsampling factors of the height grid,
ending with 1: each level is solved on a grid ``ceil(shape / factor)``, and its solution,
evaluated through the surface's own bicubic interpolant at the next grid's samples, is
the next level's initial guess. The image is always compared at full resolution.

**The gather window** of the two-pass method must be fixed (integers) inside a solve.
With ``samples_x="auto"`` each level's window is the `auto_window` of that level's
initial surface plus a margin of `WINDOW_MARGIN` pixels on each side, and at least
``N = 5, M = 4``; the result reports the missed-flux fraction of the final surface,
which says whether the window was large enough.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from .._checks import check_bool, check_int, check_number, check_real_array, check_shape
from ..methods.twopass import MAX_AUTO_HALF_WINDOW, auto_window, two_pass
from ..scene.scene import (
    BOUNDARY_MODES,
    DirectionalLight,
    HeightField,
    PlaneReceiver,
    WaterScene,
    check_extent,
    check_ior,
    check_positive_scalar,
)
from .camera import camera_blur, deconvolve
from .driver import iterate, residual_fn
from .numerics import resample_heights, weighted_laplacian
from .recover_result import RecoveryLevel, RecoveryResult
from .solvers import (
    MAX_CG_STEPS,
    SOLVER_NAMES,
    SolverLike,
    check_solver,
    half_squares,
    make_solver,
    solver_name,
)
from .transport import MAX_PIXELS
from .water_refine import FOLD_BLURS, refine_folds
from .water_start import flat_shift, transport_start
from .water_target import check_above_ground, check_target_mean, load_target

SOLVERS = SOLVER_NAMES  # (the names `compare_solvers` runs by default)
WINDOW_MARGIN = 1  # pixels added on each side of the automatic window
MIN_WINDOW = (5, 4)  # the smallest automatic window
# the transport start's irradiance misfit above which it warns (RMS of log irradiance
# per cell; measured on 32^2 reference caustics under 30-degree light: 0.0003-0.008 on
# seas without folds, 0.011 the residual of the true surface at 16^2 photons a pixel,
# 0.033 and 0.061 on folded seas whose heights came out 16% and 49% off)
START_MISFIT = 0.02
# the result's window after the transport start: its reach plus this margin (pixels),
# redone with `auto_window` if more than RESULT_MISSED_FLUX of the light falls outside
RESULT_WINDOW_MARGIN = 0.5
RESULT_MISSED_FLUX = 1e-3
INITIAL_RIPPLE = 0.05  # scaled units: the random ripple of the default initial guess


# ------------------------------------------------------------------ the problem


class _Problem(eqx.Module):
    """The residual function ``u -> (image misfit, smoothness, mean)`` of one level."""

    target: Array
    extent: Array
    light: DirectionalLight
    receiver: PlaneReceiver
    rest_depth: Array
    height_scale: Array
    smooth: Array  # sqrt(smoothness)
    lap_x: Array  # receiver pixel area / dx^2 of the height grid
    lap_y: Array
    ior: Any = eqx.field(static=True)
    boundary: str = eqx.field(static=True)
    samples_x: int = eqx.field(static=True)
    channels_y: int = eqx.field(static=True)
    hit_iterations: int = eqx.field(static=True)
    supersample: int = eqx.field(static=True)
    blur: float = eqx.field(static=True, default=0.0)

    def scene(self, u: Array) -> WaterScene:
        surface = HeightField(u * self.height_scale, self.extent, self.boundary)
        return WaterScene(surface, self.light, self.receiver, self.rest_depth, ior=self.ior)

    def render(self, u: Array) -> Any:
        return two_pass.unchecked(
            self.scene(u),
            samples_x=self.samples_x,
            channels_y=self.channels_y,
            hit_iterations=self.hit_iterations,
            supersample=self.supersample,
        )

    def __call__(self, u: Array, args: Any = None) -> tuple[Array, Array, Array]:
        del args
        image = camera_blur(self.render(u).image, self.blur, self.boundary)
        misfit = (image - self.target) / math.sqrt(self.target.size)
        lap = weighted_laplacian(u, self.boundary, self.lap_x, self.lap_y)
        smooth = self.smooth * lap / math.sqrt(u.size)
        return misfit, smooth, jnp.mean(u)[None]


@eqx.filter_jit
def _loss(problem: _Problem, u: Array) -> Array:
    return half_squares(problem(u))


def _make_solver(solver, rtol: float, atol: float, cg_steps: int, learning_rate: float):
    return make_solver(solver, rtol=rtol, atol=atol, cg_steps=cg_steps, learning_rate=learning_rate)


# ------------------------------------------------------------------ validation


def _result_window(levels, stages, samples_x, channels_y):
    """The two-pass window of the result's image: the last level's; else the given
    one; else (the transport start alone) the transport's reach plus
    `RESULT_WINDOW_MARGIN` pixels, which spares `auto_window` its own trace and
    compilation (measured at 128^2: 2.4 s of a 20 s recovery); else ``"auto"``."""
    if levels:
        return levels[-1].window
    if samples_x != "auto":
        return samples_x, channels_y
    reach = stages[0].get("reach") if stages else None
    if reach is None or len(stages) > 3:  # a warm start, or the fold fit moved the rays
        return "auto", "auto"
    half_x, half_y = (
        min(MAX_AUTO_HALF_WINDOW, max(1, math.ceil(r + RESULT_WINDOW_MARGIN))) for r in reach
    )
    return 2 * half_x + 1, 2 * half_y


def _levels(coarse_to_fine, shape: tuple[int, int]) -> list[tuple[int, int]]:
    if isinstance(coarse_to_fine, (str, bytes)) or not isinstance(
        coarse_to_fine, (Sequence, np.ndarray)
    ):
        raise ValueError(f"`coarse_to_fine` must be a sequence of ints, got {coarse_to_fine!r}")
    factors = [check_int(f, "coarse_to_fine", 1) for f in coarse_to_fine]
    if (
        not factors
        or factors[-1] != 1
        or any(a <= b for a, b in zip(factors, factors[1:], strict=False))
    ):
        raise ValueError(
            f"`coarse_to_fine` must be strictly decreasing factors ending with 1, "
            f"got {coarse_to_fine!r}"
        )
    shapes: list[tuple[int, int]] = []
    for f in factors:
        s = (max(2, -(-shape[0] // f)), max(2, -(-shape[1] // f)))
        if not shapes or shapes[-1] != s:
            shapes.append(s)
    return shapes


# ------------------------------------------------------------------ the solve


def recover_surface(
    target,
    *,
    extent,
    rest_depth,
    light: DirectionalLight,
    ior: float | Sequence[float] = 1.333,
    heights_shape: Sequence[int] | None = None,
    receiver_extent=None,
    boundary: str = "periodic",
    start: Literal["auto", "transport", "ripple"] = "auto",
    solver: SolverLike | None = None,
    smoothness: float = 1e-3,
    coarse_to_fine: Sequence[int] = (1,),
    max_steps: int = 100,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    initial=None,
    throw: bool = True,
    samples_x: int | Literal["auto"] = "auto",
    channels_y: int | None = None,
    hit_iterations: int = 3,
    supersample: int = 1,
    blur: float = 0.0,
    fold_fit: bool | None = None,
    normalize: bool | None = None,
    cg_steps: int = 30,
    learning_rate: float = 0.05,
    callback: Callable[[RecoveryLevel], Any] | None = None,
) -> RecoveryResult:
    """Recover the water height field whose caustic is `target`.

    **Arguments:**

    - `target`: the caustic image: an array ``(rows, cols)`` (``(rows, cols, channels)``
      when `ior` is a sequence) of irradiance relative to flat water, or the path of a
      PNG, EXR, TIFF or JPEG file (read with `read_image`).
    - `extent`: ``(x_min, x_max, y_min, y_max)`` of the height field, metres.
    - `rest_depth`: depth of the flat water above the ground, metres (> 0).
    - `light`: the `DirectionalLight`.
    - `ior`: index of refraction (static), as in `WaterScene`; must not be 1.
    - `heights_shape`: ``(rows, cols)`` of the height grid; default: the target's.
    - `receiver_extent`: extent of the caustic map on the ground; default `extent`.
    - `boundary`: the surface's boundary mode, ``"periodic"`` or ``"clamp"``.
    - `start`: ``"transport"``: the transport start (`jaxcaustics.inverse.water_start`:
      optimal transport, then Gauss-Newton fits of the exact rays' landing points and
      irradiance; for caustics without folds, on the target's pixel grid, which must
      cover `extent`); ``"ripple"``: flat water with a small ripple, for the image-space
      solve below; ``"auto"``: the transport start where the target covers `extent`.
      With an `initial`, the transport start is warm: its irradiance fit alone, from
      `initial` (a sequence's previous frame; `recover_sequence`); the ripple start
      is replaced by `initial`.
    - `solver`: the image-space solve after the start, on the two-pass caustic (the
      options below): ``"levenberg_marquardt"``, ``"gauss_newton"``, ``"bfgs"``,
      ``"lbfgs"``, ``"adam"`` or an Optimistix least-squares solver or minimiser object
      (`jaxcaustics.inverse.solvers`; a minimiser gets ``0.5 * sum(residual^2)``);
      None (default): none after the transport start, Levenberg-Marquardt after the
      ripple start.
    - `smoothness`: weight of the Laplacian prior (dimensionless, see the module).
    - `coarse_to_fine`: strictly decreasing downsampling factors of the height grid,
      ending with 1, e.g. ``(4, 2, 1)``; ``(1,)`` solves on the full grid only.
    - `max_steps`: the most solver steps per level.
    - `rtol`, `atol`: the solvers' tolerances (Optimistix's Cauchy criterion on the
      scaled heights and on the residuals / loss).
    - `initial`: initial heights, metres, any grid over `extent` (resampled to the grid
      solved on); default: none (see `start`).
    - `throw`: raise if a level fails (for example reaches `max_steps`); with False the
      result carries the `optimistix.RESULTS` codes instead.
    - `samples_x`, `channels_y`: the two-pass window ``(N, M)``; ``"auto"`` (see the
      module); an int N with `channels_y` None uses ``M = N - 1``.
    - `hit_iterations`, `supersample`: the two-pass knobs (see `TwoPass`).
    - `blur`: the camera's blur, a Gaussian PSF of this standard deviation in target
      pixels (0: none). The transport start works on the target deconvolved by
      Richardson-Lucy (`deconvolve`); the image-space solve blurs its rendered caustic
      instead (`camera_blur`), and so does the result's `image`.
    - `fold_fit`: after the transport start, fit the images of the exact rays to the
      target, blurred coarse to fine (`jaxcaustics.inverse.water_refine`: follows
      folds, where rays cross; measured at 32^2 on 2 cores: about 50-80 s in all).
      None (default): when the start's irradiance misfit exceeds `START_MISFIT` (the
      caustic folds) and no `solver` is named.
    - `normalize`: scale the target so its mean is 1 (the mean irradiance of flat
      water); default: True for a file path (whose scale is arbitrary), False for an
      array (whose mean must then lie in `water_target.TARGET_MEAN`).
    - `cg_steps`: conjugate-gradient iterations per Gauss-Newton / Levenberg-Marquardt
      step (a truncated, inexact Newton step).
    - `learning_rate`: Adam's step in scaled height units (``"adam"`` only).
    - `callback`: called with each level's `RecoveryLevel` when the level is done.

    **Returns:** a `RecoveryResult`.

    **Raises:** `ValueError`, naming the argument, for invalid inputs, before any
    optimisation; with `throw`, a `RuntimeError` naming the level and its
    `optimistix.RESULTS` message when a level does not converge (after the level's
    steps: each step is one compiled call of the package's iteration driver,
    `jaxcaustics.inverse.driver.iterate`, as the designs' are)."""
    # ---- validate everything before compiling anything
    ior = check_ior(ior)
    iors = ior if isinstance(ior, tuple) else (ior,)
    if any(abs(1.0 - 1.0 / n) < 1e-6 for n in iors):
        raise ValueError(f"`ior` must differ from 1 (no refraction, no caustic), got {ior!r}")
    target_arr = load_target(target, ior)
    ext = np.asarray(check_extent(extent, "extent"), dtype=float)
    rec_ext = (
        ext
        if receiver_extent is None
        else np.asarray(check_extent(receiver_extent, "receiver_extent"), dtype=float)
    )
    depth = float(check_positive_scalar(rest_depth, "rest_depth"))
    if not isinstance(light, DirectionalLight):
        raise ValueError(f"`light` must be a DirectionalLight, got {type(light).__name__}")
    shape = target_arr.shape[:2]
    if heights_shape is not None:
        shape = check_shape(heights_shape, "heights_shape", 2, max_size=MAX_PIXELS)
    if boundary not in BOUNDARY_MODES:
        raise ValueError(f"`boundary` must be one of {BOUNDARY_MODES}, got {boundary!r}")
    if start not in ("auto", "transport", "ripple"):
        raise ValueError(f"`start` must be 'auto', 'transport' or 'ripple', got {start!r}")
    covers = receiver_extent is None or np.allclose(rec_ext, ext)
    if start == "transport" and not covers:
        raise ValueError(
            "`start='transport'` needs the target to cover the heights' `extent`: "
            f"`receiver_extent` {rec_ext.tolist()} differs from it (pass start='ripple')"
        )
    if boundary == "clamp" and not covers:
        # beyond its extent a clamped surface is flat: a caustic cast by the extent
        # (shifted along the refracted light) must reach the receiver
        s = flat_shift(np.asarray(light.direction, float), float(np.mean(iors)), depth)
        if (
            rec_ext[0] >= ext[1] + s[0]
            or rec_ext[1] <= ext[0] + s[0]
            or rec_ext[2] >= ext[3] + s[1]
            or rec_ext[3] <= ext[2] + s[1]
        ):
            raise ValueError(
                f"`receiver_extent` {rec_ext.tolist()} does not meet the light that the "
                f"heights' extent refracts (it lands on {(ext + np.repeat(s, 2)).tolist()}): "
                "the caustic there cannot depend on the heights"
            )
    if start == "auto":
        start = "transport" if covers else "ripple"
    if solver is None and start == "ripple":
        solver = "levenberg_marquardt"
    if solver is not None:
        solver = check_solver(solver)
    smoothness = check_number(smoothness, "smoothness", low=0.0)
    level_shapes = _levels(coarse_to_fine, shape)
    max_steps = check_int(max_steps, "max_steps", 1)
    rtol = check_number(rtol, "rtol", low=0.0)
    atol = check_number(atol, "atol", low=0.0)
    cg_steps = check_int(cg_steps, "cg_steps", 1, MAX_CG_STEPS)
    hit_iterations = check_int(hit_iterations, "hit_iterations", 0)
    supersample = check_int(supersample, "supersample", 1)
    blur = check_number(blur, "blur", low=0.0)
    if blur > min(target_arr.shape[:2]) / 6:
        raise ValueError(
            f"`blur` of {blur} pixels is wider than a sixth of the target "
            f"{target_arr.shape[:2]}: nothing would be left to recover"
        )
    learning_rate = check_number(learning_rate, "learning_rate", low=0.0, low_open=True)
    if samples_x != "auto":
        if (
            isinstance(samples_x, bool)
            or not isinstance(samples_x, int)
            or samples_x < 1
            or samples_x % 2 == 0
        ):
            raise ValueError(f"`samples_x` must be an odd int >= 1 or 'auto', got {samples_x!r}")
        channels_y = samples_x - 1 if channels_y is None else channels_y
        if (
            isinstance(channels_y, bool)
            or not isinstance(channels_y, int)
            or channels_y < 0
            or channels_y % 2
        ):
            raise ValueError(f"`channels_y` must be an even int >= 0, got {channels_y!r}")
        rows, cols = target_arr.shape[:2]  # an explicit window past every pixel is refused
        if samples_x > 2 * cols + 1 or channels_y > 2 * rows:
            raise ValueError(
                f"the window (`samples_x`={samples_x}, `channels_y`={channels_y}) reaches "
                f"past the target's {rows} x {cols} pixels: samples_x <= {2 * cols + 1} and "
                f"channels_y <= {2 * rows} already reach every pixel"
            )
    elif channels_y is not None:
        raise ValueError("`channels_y` is chosen with samples_x='auto'; pass both as ints")
    if fold_fit is not None and not isinstance(fold_fit, bool):
        raise ValueError(f"`fold_fit` must be True, False or None, got {fold_fit!r}")
    throw = check_bool(throw, "throw")
    if normalize is not None:
        normalize = check_bool(normalize, "normalize")
    if callback is not None and not callable(callback):
        raise ValueError(f"`callback` must be callable or None, got {type(callback).__name__}")
    dtype = jnp.result_type(float)
    if initial is not None:
        init_arr = check_real_array(initial, "initial").astype(float)
        if init_arr.ndim != 2 or min(init_arr.shape) < 2:
            raise ValueError(
                f"`initial` must be 2-D with at least 2x2 samples, got {init_arr.shape}"
            )
        if not np.all(np.isfinite(init_arr)):
            raise ValueError("`initial` contains NaN or infinite values")
    if normalize is None:
        normalize = isinstance(target, (str, os.PathLike))
    if normalize:
        target_arr = target_arr / target_arr.mean()
    else:
        check_target_mean(target_arr)

    started = time.perf_counter()
    receiver = PlaneReceiver(jnp.asarray(rec_ext, dtype), target_arr.shape[:2])
    pixel_area = float(
        (rec_ext[1] - rec_ext[0])
        * (rec_ext[3] - rec_ext[2])
        / receiver.shape[0]
        / receiver.shape[1]
    )
    height_scale = pixel_area / (depth * float(np.mean([abs(1.0 - 1.0 / n) for n in iors])))
    light = DirectionalLight(jnp.asarray(light.direction, dtype))
    target_j = jnp.asarray(target_arr, dtype)
    stages: list[dict] = []
    if start == "transport":
        seen = target_arr if target_arr.ndim == 2 else target_arr.mean(axis=2)
        gray = deconvolve(seen, blur, boundary)
        warm = None
        if initial is not None:  # a warm start: the irradiance fit alone, from `initial`
            warm = np.asarray(resample_heights(init_arr, ext, gray.shape, boundary), float)
        geometry: dict[str, Any] = dict(
            extent=ext,
            rest_depth=depth,
            direction=np.asarray(light.direction, float),
            ior=float(np.mean(iors)),
            boundary=boundary,
        )
        found, stages = transport_start(gray, **geometry, initial=warm)
        check_above_ground(found, depth, target_arr, "found by the transport start")
        misfit = stages[-1]["rms"]
        folds = misfit > START_MISFIT
        if fold_fit or (fold_fit is None and folds and solver is None):
            found, fold_stages = refine_folds(seen, found, **geometry, camera_blur_px=blur)
            check_above_ground(found, depth, target_arr, "found by the fold fit")
            stages = [*stages, *fold_stages]
        if folds and solver is None:
            done = (
                f"; the fold fit matched the images to {stages[-1]['rms']:.3g} (RMS per "
                f"pixel after a {FOLD_BLURS[-1]}-pixel blur), but the heights of a folding "
                f"sea are not unique (measured on a sea with peak irradiance 15x the mean: "
                f"its caustic 2% off the target, its heights 48% off the truth)"
                if len(stages) > 3
                else "; pass fold_fit=True to fit the folds"
            )
            warnings.warn(
                f"recover_surface: the transport start explains the target only to "
                f"{misfit:.3g} (RMS of log irradiance per cell, above {START_MISFIT}): the "
                f"caustic folds (rays cross), which the start cannot follow{done}",
                stacklevel=2,
            )
        u = resample_heights(jnp.asarray(found / height_scale, dtype), ext, shape, boundary)
    elif initial is None:
        # Flat water plus a tiny deterministic ripple: at exactly flat water every
        # two-pass sample sits on a kink of its splat kernel, where the renderer is not
        # differentiable; its one-sided gradient there is still a poor first direction
        # (started from exactly flat water, the LM recovery test fails), so start nearby.
        rng = np.random.default_rng(0)
        u = jnp.asarray(INITIAL_RIPPLE * rng.standard_normal(level_shapes[0]), dtype)
    else:
        u = resample_heights(
            jnp.asarray(init_arr, dtype) / height_scale, ext, level_shapes[0], boundary
        )

    def water(u) -> WaterScene:  # the scene of scaled heights u
        surface = HeightField(u * height_scale, jnp.asarray(ext, dtype), boundary)
        return WaterScene(surface, light, receiver, jnp.asarray(depth, dtype), ior=ior)

    levels: list[RecoveryLevel] = []
    for index, level_shape in enumerate(level_shapes if solver is not None else ()):
        assert solver is not None  # (for mypy: levels are solved only with a solver)
        t0 = time.perf_counter()
        u = resample_heights(u, ext, level_shape, boundary)
        hx = (ext[1] - ext[0]) / level_shape[1]
        hy = (ext[3] - ext[2]) / level_shape[0]
        if samples_x == "auto":
            flat_scene = water(u)
            n, m = auto_window(flat_scene, hit_iterations, supersample)
            window = (
                max(n + 2 * WINDOW_MARGIN, MIN_WINDOW[0]),
                max(m + 2 * WINDOW_MARGIN, MIN_WINDOW[1]),
            )
        else:
            assert channels_y is not None  # (for mypy: set with `samples_x` above)
            window = (samples_x, channels_y)
        problem = _Problem(
            target=target_j,
            extent=jnp.asarray(ext, dtype),
            light=light,
            receiver=receiver,
            rest_depth=jnp.asarray(depth, dtype),
            height_scale=jnp.asarray(height_scale, dtype),
            smooth=jnp.asarray(math.sqrt(smoothness), dtype),
            lap_x=jnp.asarray(pixel_area / hx**2, dtype),
            lap_y=jnp.asarray(pixel_area / hy**2, dtype),
            ior=ior,
            boundary=boundary,
            samples_x=window[0],
            channels_y=window[1],
            hit_iterations=hit_iterations,
            supersample=supersample,
            blur=blur,
        )
        initial_loss = float(_loss(problem, u))
        run_start = u
        chosen = _make_solver(solver, rtol, atol, cg_steps, learning_rate)
        run = iterate(
            residual_fn(chosen),
            chosen,
            u,
            problem,
            max_steps=max_steps,
            history=[],
        )
        if throw and run.result != optx.RESULTS.successful:
            # (`optx.RESULTS[...]`: Equinox's enumeration metaclass, unknown to mypy)
            raise RuntimeError(
                f"recover_surface: level {index} ({level_shape[0]} x {level_shape[1]}) "
                f"stopped after {run.steps} steps: {optx.RESULTS[run.result]}"  # type: ignore[misc]
            )
        u, steps, result = run.y, run.steps, run.result
        loss = float(_loss(problem, u))
        if depth + float(jnp.min(u * height_scale)) <= 0:
            what = f"its heights went through the ground, `rest_depth` {depth:g} m below"
        elif run.diverged or not loss <= initial_loss:
            what = f"its loss went from {initial_loss:.3g} to {loss:.3g}"
            if run.diverged:
                what += " and then to NaN or infinity"
        else:
            what = None
        if what is not None:
            # a runaway solver's heights (NaN, or through the ground) were reported as the
            # scene's "`surface` reaches the ground"; the level's start is kept instead
            u, loss, result = run_start, initial_loss, optx.RESULTS.nonlinear_divergence
            warnings.warn(
                f"recover_surface: the {solver_name(solver)} solver diverged at level "
                f"{index} ({level_shape[0]} x {level_shape[1]}) in {steps} steps ({what}); "
                "the level's start is kept: try `solver` levenberg_marquardt (the "
                "steadiest) or fewer `max_steps`",
                stacklevel=2,
            )
        level = RecoveryLevel(
            level=index,
            shape=level_shape,
            heights=np.asarray(u * height_scale),
            initial_loss=initial_loss,
            loss=loss,
            steps=steps,
            result=result,
            window=window,
            time_s=time.perf_counter() - t0,
        )
        levels.append(level)
        if callback is not None:
            callback(level)

    scene = water(u)
    window = _result_window(levels, stages, samples_x, channels_y)
    rendered = two_pass(
        scene,
        samples_x=window[0],
        channels_y=window[1],
        hit_iterations=hit_iterations,
        supersample=supersample,
    )
    if window != ("auto", "auto") and samples_x == "auto" and not levels:
        if float(np.max(rendered.missed_flux_fraction)) > RESULT_MISSED_FLUX:
            rendered = two_pass(  # the transport's reach was too short: trace the window
                scene, hit_iterations=hit_iterations, supersample=supersample
            )
    image = np.asarray(camera_blur(rendered.image, blur, boundary))
    heights = np.asarray(u * height_scale)
    misfit = image - target_arr
    # the target's contrast; a target with almost none (flat water) is its own scale
    # (its contrast, 0, gave 3.7e+294)
    contrast = np.linalg.norm(target_arr - target_arr.mean())
    if not contrast > 1e-3 * np.linalg.norm(target_arr):
        contrast = np.linalg.norm(target_arr)
    return RecoveryResult(
        heights=heights - heights.mean(),
        image=image,
        target=target_arr,
        loss=levels[-1].loss if levels else float(np.mean(misfit**2)),
        image_rmse=float(np.sqrt(np.mean(misfit**2))),
        image_error=float(np.linalg.norm(misfit) / contrast),
        missed_flux_fraction=np.asarray(rendered.missed_flux_fraction),
        levels=tuple(levels),
        solver="none" if solver is None else solver_name(solver),
        time_s=time.perf_counter() - started,
        scene=scene,
        stages=tuple(stages),
    )
