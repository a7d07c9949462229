"""The solvers of `design_lens` and `recover_surface`: one set of names, one builder,
one loss.

A solver is named by a string or given as an Optimistix solver object:

- least-squares solvers (`optimistix.AbstractLeastSquaresSolver`: ``"gauss_newton"``,
  ``"levenberg_marquardt"``, matrix-free: each step's normal equations by a truncated
  conjugate gradient) take the residual;
- minimisers (`optimistix.AbstractMinimiser`: ``"bfgs"``, ``"lbfgs"``, and ``"adam"``,
  Optax's Adam through `optimistix.OptaxMinimiser`) take the loss.

The loss is Optimistix's own: ``0.5 * sum(residual^2)`` (`half_squares`), and both
inverse problems report it.
"""

from __future__ import annotations

from typing import Literal, cast, get_args

import jax
import jax.numpy as jnp
import lineax as lx
import optax
import optimistix as optx

SolverName = Literal["levenberg_marquardt", "gauss_newton", "bfgs", "lbfgs", "adam"]
SOLVER_NAMES: tuple[SolverName, ...] = get_args(SolverName)

SolverLike = SolverName | optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser

# conjugate-gradient steps per linear solve: far beyond what any solve here needs (a few
# hundred at most); a larger request is runaway work, refused before anything runs
MAX_CG_STEPS = 10_000


def check_solver(solver, name: str = "solver") -> SolverLike:
    """`solver` if it is one of `SOLVER_NAMES` or an Optimistix least-squares solver or
    minimiser, else a `ValueError` naming `name`."""
    if isinstance(solver, (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)):
        return solver
    if not isinstance(solver, str) or solver not in SOLVER_NAMES:
        raise ValueError(
            f"`{name}` must be one of {SOLVER_NAMES} or an Optimistix least-squares "
            f"solver or minimiser, got {solver!r}"
        )
    return cast(SolverName, solver)  # one of the names, checked above


def solver_name(solver: SolverLike) -> str:
    """The name a result reports: the string, or the solver object's class name."""
    return solver if isinstance(solver, str) else type(solver).__name__


def make_solver(
    solver: SolverLike,
    *,
    rtol: float,
    atol: float,
    cg_steps: int,
    cg_rtol: float = 0.0,
    cg_atol: float = 0.0,
    learning_rate: float = 0.05,
):
    """The Optimistix solver for `solver` (an object is returned as it is): tolerances
    `rtol`, `atol` (Optimistix's Cauchy criterion); least-squares steps by `cg_steps`
    conjugate-gradient iterations (tolerances `cg_rtol`, `cg_atol`); Adam's
    `learning_rate`."""
    if not isinstance(solver, str):
        return solver
    if solver == "bfgs":
        return optx.BFGS(rtol, atol)
    if solver == "lbfgs":
        return optx.LBFGS(rtol, atol)
    if solver == "adam":
        return optx.OptaxMinimiser(optax.adam(learning_rate), rtol, atol)
    linear = lx.Normal(lx.CG(rtol=cg_rtol, atol=cg_atol, max_steps=cg_steps))
    if solver == "gauss_newton":
        return optx.GaussNewton(rtol, atol, linear_solver=linear)
    return optx.LevenbergMarquardt(rtol, atol, linear_solver=linear)


def is_minimiser(solver) -> bool:
    """Whether the built `solver` takes the loss (else the residual)."""
    return isinstance(solver, optx.AbstractMinimiser)


def half_squares(residual) -> jax.Array:
    """The loss ``0.5 * sum(r^2)`` over the arrays of a residual pytree."""
    total = sum(jnp.sum(leaf * leaf) for leaf in jax.tree_util.tree_leaves(residual))
    return 0.5 * cast(jax.Array, total)  # a residual has leaves: never `sum`'s start, 0
