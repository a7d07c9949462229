"""The Poisson levels of lens design: the irradiance residual solved coarse to fine
(`PoissonLevels`).

A photon grid over the aperture is traced exactly (`LensModel.landing`); each cell of the
grid lands on a quadrilateral of the screen whose area times the target irradiance at
its centroid must equal the flux the cell carries: ``r = log E(centroid) + log A_landed -
log flux = 0`` per cell, plus the second boundary condition (the aperture's edge lands on
the screen's edge) and a weak curvature prior (`LensModel.transport_residual`). The
system is solved as a nonlinear least-squares problem by Optimistix (Levenberg-Marquardt
or Gauss-Newton) with matrix-free Lineax normal conjugate gradients (JVPs and VJPs of the
residual), right-preconditioned by the inverse of the weak-lens Laplacian (``h = P u``,
``P = ((n - 1) D Laplacian)^-1`` by a DCT Poisson solve with Neumann boundaries), started
from (half) the weak-lens Poisson solution and run coarse to fine, each level against the
target averaged to its grid (`level_target`). Its logarithm needs light everywhere: a
`floor`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._checks import check_int, check_number
from .design_setup import Setup
from .driver import iterate
from .lens_model import LensModel, level_model, level_shape, residual_count
from .numerics import neumann_laplacian, resample_corners
from .solvers import MAX_CG_STEPS, SolverLike, check_solver, half_squares, is_minimiser, make_solver


def default_levels(shape: Sequence[int]) -> tuple[int, ...]:
    """Coarse-to-fine heights grids for a target of `shape`: powers of two from 32 up to
    twice its longer side (at least one level)."""
    top = 2 * max(int(s) for s in shape)
    levels = [32]
    while levels[-1] * 2 <= top:
        levels.append(levels[-1] * 2)
    return tuple(levels)


def check_levels(levels) -> tuple[int, ...]:
    """`levels` as a tuple of strictly increasing ints >= 4 (coarse to fine), or a
    `ValueError` naming it."""
    if isinstance(levels, (str, bytes)) or not isinstance(levels, (Sequence, np.ndarray)):
        raise ValueError(f"`levels` must be a sequence of ints, got {levels!r}")
    if len(levels) == 0:
        raise ValueError(f"`levels` must be a non-empty sequence of ints >= 4, got {levels!r}")
    checked = tuple(check_int(n, "levels", 4) for n in levels)
    if any(b <= a for a, b in zip(checked, checked[1:], strict=False)):
        raise ValueError(
            f"`levels` must increase, coarse to fine (each finer than the last), got {levels!r}"
        )
    return checked


def _nonnegative(value, name: str) -> float:
    real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (real and math.isfinite(value) and value >= 0):
        raise ValueError(f"`{name}` must be a finite number >= 0, got {value!r}")
    return float(value)


class PoissonLevels(eqx.Module):
    """The weak-lens Poisson start and the irradiance residual, solved coarse to fine.

    **Arguments:**

    - `levels`: heights samples along the aperture's longer side, coarse to fine;
      ``None``: powers of two from 32 up to twice the target's longer side
      (`default_levels`: a photon cell per half pixel).
    - `max_steps`: solver steps per level.
    - `solver`: ``"levenberg_marquardt"`` or ``"gauss_newton"`` (least squares, both
      with Lineax `NormalCG`, matrix-free, `cg_steps` iterations at most), a minimiser
      on ``0.5 * sum(residual^2)``: ``"lbfgs"``, ``"bfgs"`` or ``"adam"``, or an
      Optimistix solver object (`jaxcaustics.inverse.solvers`).
    - `oversample`: photon cells per heights sample along each axis.
    - `floor`: a uniform irradiance added to the unit-mean target, in (0, 1): the
      residual's logarithm needs light everywhere.
    - `boundary_weight`: weight of the boundary condition (pixels of misplacement).
    - `regularization`: weight of a curvature prior on the preconditioned variable.
      Measured while tuning on the camera benchmark's setting (128 x 128): 0.003 gave
      0.14 relative L2, 0.01 0.048, 0.02 0.047 (and 0.1, with 20 steps per level, 0.065).
    - `start_scale`: the weak-lens start is scaled by this (1: the full weak-lens
      solution, which folds where the target is dark).
    - `cg_steps`, `rtol`: the linear solves' iterations and the solver's tolerance.
    """

    levels: tuple[int, ...] | None = None
    max_steps: int = 40
    solver: SolverLike = eqx.field(static=True, default="levenberg_marquardt")
    oversample: int = 1
    floor: float = 0.02
    boundary_weight: float = 1.0
    regularization: float = 0.01
    start_scale: float = 0.5
    cg_steps: int = 30
    rtol: float = 1e-4
    # the surface's boundary: "extrapolate" stalled the edge condition (measured on a
    # 16^2 blob: relative L2 0.13 against 0.044)
    boundary: ClassVar[str] = "clamp"

    def __init__(
        self,
        levels=None,
        max_steps=40,
        solver="levenberg_marquardt",
        oversample=1,
        floor=0.02,
        boundary_weight=1.0,
        regularization=0.01,
        start_scale=0.5,
        cg_steps=30,
        rtol=1e-4,
    ):
        self.levels = None if levels is None else check_levels(levels)
        self.max_steps = check_int(max_steps, "max_steps", 1)
        self.solver = check_solver(solver)
        self.oversample = check_int(oversample, "oversample", 1)
        self.floor = check_number(floor, "floor", low=0.0, high=1.0, high_open=True)
        if self.floor == 0:
            raise ValueError("`floor` must be in (0, 1) with the poisson start, got 0")
        self.regularization = _nonnegative(regularization, "regularization")
        self.start_scale = _nonnegative(start_scale, "start_scale")
        self.boundary_weight = _nonnegative(boundary_weight, "boundary_weight")
        self.cg_steps = check_int(cg_steps, "cg_steps", 1, MAX_CG_STEPS)
        real = isinstance(rtol, (int, float, np.integer, np.floating)) and not isinstance(
            rtol, bool
        )
        if not (real and math.isfinite(rtol) and rtol > 0):
            raise ValueError(f"`rtol` must be a finite number > 0, got {rtol!r}")
        self.rtol = float(rtol)

    def shapes(self, target_shape, width: float, height: float) -> list[tuple[int, int]]:
        """The levels' heights grids for a target of `target_shape`."""
        levels = self.levels or default_levels(target_shape)
        return [level_shape(n, width, height) for n in levels]

    def solve_level(
        self, setup: Setup, k: int, h: np.ndarray | None, history: list, callback, throw: bool
    ):
        """Level `k` from the previous level's heights `h` (``None`` for the first).
        Returns ``(heights, report, result)``: heights ``(rows, cols)`` on the level's
        grid with ``max = 0`` (metres)."""
        shape = setup.shapes[k]
        solver, objective = make_level_solver(self)
        u, model = level_start(setup, self, k, h)
        count = residual_count(model)
        info = {"level": k, "shape": shape, "residuals": count}
        run = iterate(
            objective, solver, u, model, max_steps=self.max_steps, history=history,
            callback=callback, info=info,
        )  # fmt: skip
        h = level_heights(model, run.y, k, shape, run.result, throw)
        loss = history[-1] if history else float("nan")
        report = {
            "stage": "irradiance",
            "shape": shape,
            "steps": run.steps,
            "loss": loss,
            "loss_per_pixel": loss / count,
            "result": run.result,
            "seconds": run.seconds,
            "first_step_seconds": run.compile_seconds,
        }
        return h, report, run.result


def level_start(
    setup: Setup, levels: PoissonLevels, k: int, h: np.ndarray | None
) -> tuple[jax.Array, LensModel]:
    """Level `k`'s start (the preconditioned variable ``u``) and its `LensModel`; `h`: the
    previous level's heights (``None`` for the first level)."""
    shape = setup.shapes[k]
    rows, cols = shape
    dx, dy = setup.width / cols, setup.height / rows
    if k == 0 and setup.initial is not None:  # continue from given heights
        h = np.asarray(setup.initial, float)
    if h is not None:
        # carry the heights to this grid, then to the preconditioned variable
        h_fine = resample_corners(h, shape, setup.boundary)
        u = neumann_laplacian(jnp.asarray(h_fine), dx, dy) * setup.weak
    else:
        u = jnp.asarray(-levels.start_scale * np.log(setup.goal0), jnp.result_type(float))
    model = level_model(
        setup, shape, levels.oversample, levels.boundary_weight, levels.regularization
    )
    return u, model


def level_heights(model: LensModel, u, k: int, shape, result, throw: bool) -> np.ndarray:
    """The heights of a solved level (``max = 0``); raises if the solver failed."""
    h = np.asarray(model.heights(jnp.asarray(u)))
    h = h - h.max()
    if throw and result not in (
        optx.RESULTS.successful,
        optx.RESULTS.max_steps_reached,
    ):
        raise RuntimeError(f"level {k} ({shape}): the solver failed: {result}")
    if not np.all(np.isfinite(h)):
        raise RuntimeError(f"level {k} ({shape}): the heights are not finite")
    return h


def _irradiance_residual(u, model: LensModel):
    return model.transport_residual(u)


def _half_squares(u, model: LensModel):
    """The least-squares loss ``0.5 * sum(residual^2)`` (for the minimisers)."""
    return half_squares(model.transport_residual(u))


def make_level_solver(levels: PoissonLevels):
    """The built solver and the objective it takes (the residual, or its loss)."""
    built = make_solver(
        levels.solver,
        rtol=levels.rtol,
        atol=1e-9,
        cg_steps=levels.cg_steps,
        cg_rtol=1e-3,
        cg_atol=1e-8,
    )
    return built, (_half_squares if is_minimiser(built) else _irradiance_residual)
