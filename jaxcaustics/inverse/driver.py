"""The iteration driver of the inverse problems: an Optimistix solver stepped from Python
(init, step, terminate), a loss after every step, a callback, the best iterate kept.

Optimistix's own `optimistix.least_squares` / `minimise` run the whole loop inside one
compiled call; the designs need a loss after each step (progress, a callback, a stall
test that keeps the best iterate), so the loop runs here, each step one compiled call
(`eqx.filter_jit` at module level: designs of one shape reuse it). `iterate_traced` is the
same step as one `jax.lax.while_loop`, for batches spread over devices.

Conventions:

- least-squares solvers take ``fn(y, args)``, the residual (a pytree); minimisers the
  scalar loss; the loss reported is ``0.5 * sum(residual^2)`` or the minimiser's loss;
- a fixed-point solver (`optimistix.AbstractFixedPointSolver`) takes ``fn(y, args) ->
  (next y, misfit)``: the misfit (a scalar, of the `y` it was given) is what the driver
  reports (as ``0.5 misfit^2``) and keeps the best iterate by.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx


@dataclasses.dataclass
class Run:
    """What `iterate` returns.

    - `y`: the final iterate (the best one when a stall ended the run).
    - `steps`: solver steps taken.
    - `result`: ``optx.RESULTS`` (``max_steps_reached`` when the budget ended it).
    - `compile_seconds`: the first step's wall time (compilation included).
    - `seconds`: the whole run's wall time.
    - `stalled`: the misfit stopped falling for `patience` steps (fixed point only).
    - `misfit`: the best misfit (fixed point only; NaN otherwise).
    - `diverged`: a step's loss was NaN or infinite; `y` is the iterate before it and
      `result` is ``optx.RESULTS.nonlinear_divergence``.
    """

    y: Any
    steps: int
    result: Any
    compile_seconds: float
    seconds: float
    stalled: bool = False
    misfit: float = float("nan")
    diverged: bool = False


class _CallArgs(eqx.Module):
    """``fn(y, problem) = problem(y)``: a callable problem Module as the driver's `fn`,
    with the Module itself passed as `args` (its arrays traced, not folded)."""

    def __call__(self, y, problem):
        return problem(y)


class _HalfSquares(eqx.Module):
    """``0.5 * sum(problem(y)^2)``: a residual as a minimiser's loss, as
    `optimistix.least_squares` does when given a minimiser."""

    def __call__(self, y, problem):
        return 0.5 * sum(jnp.sum(c**2) for c in jax.tree_util.tree_leaves(problem(y)))


def residual_fn(solver) -> Callable:
    """The driver's `fn` for a problem Module whose call gives residuals, with the
    problem as `args`: the residuals for a least-squares solver, half their sum of
    squares for a minimiser."""
    return _HalfSquares() if isinstance(solver, optx.AbstractMinimiser) else _CallArgs()


def _fixed_point(solver) -> bool:
    return isinstance(solver, optx.AbstractFixedPointSolver)


class _WithAux(eqx.Module):
    fn: Callable = eqx.field(static=True)

    def __call__(self, y, args):
        return self.fn(y, args), None


def _wrapped(fn, solver):
    return fn if _fixed_point(solver) else _WithAux(fn)


@eqx.filter_jit
def _init(fn, solver, y, args):
    wrapped = _wrapped(fn, solver)
    f_struct, aux_struct = jax.eval_shape(wrapped, y, args)
    return solver.init(wrapped, y, args, {}, f_struct, aux_struct, frozenset())


@eqx.filter_jit
def _step(fn, solver, y, state, args):
    """One solver step: ``(y, state, done, result, value)``; `value` is the loss at the
    new `y`, or for a fixed-point solver the misfit of the `y` it started from."""
    wrapped = _wrapped(fn, solver)
    y, state, aux = solver.step(wrapped, y, args, {}, state, frozenset())
    done, result = solver.terminate(wrapped, y, args, {}, state, frozenset())
    if _fixed_point(solver):
        return y, state, done, result, aux
    f_info = getattr(state, "f_info", None)
    if isinstance(getattr(f_info, "f", None), jax.Array) and f_info.f.ndim == 0:
        loss = f_info.f  # a quasi-Newton minimiser's loss at `y` (the accepted point)
    elif isinstance(f_info, optx.FunctionInfo.ResidualJac):  # Gauss-Newton: at `y` too
        loss = 0.5 * sum(jnp.sum(c**2) for c in jax.tree_util.tree_leaves(f_info.residual))
    else:
        r = fn(y, args)
        if isinstance(r, jax.Array) and r.ndim == 0:  # a minimiser's loss
            loss = r
        else:
            loss = 0.5 * sum(jnp.sum(c**2) for c in jax.tree_util.tree_leaves(r))
    return y, state, done, result, loss


def iterate(
    fn,
    solver,
    y0,
    args,
    *,
    max_steps: int,
    history: list[float],
    callback: Callable[[dict], None] | None = None,
    info: dict | None = None,
    patience: int | None = None,
) -> Run:
    """Step `solver` on `fn` from `y0`, at most `max_steps` steps.

    After every step the loss is appended to `history` and `callback` (if any) gets
    ``{**info, "step": k, "loss": loss}`` (a fixed point adds ``"rms_pixels"``, its
    misfit). `args` (the problem's arrays) goes through `filter_jit` as an argument, not
    closed over, so that XLA does not constant-fold it.

    With `patience` (fixed-point solvers): the best iterate is kept, and a run whose
    misfit has not fallen by 0.1% for `patience` steps ends as stalled (what is left is
    what the iterate cannot follow).

    A step whose loss is NaN or infinite ends the run as diverged (`Run.diverged`): that
    loss is neither recorded nor passed to `callback`, and the iterate before the step is
    returned (a fixed point's: the best one before it); the NaN heights of such a run were
    reported downstream as impossible geometry."""
    info = info or {}
    fixed = _fixed_point(solver)
    t0 = time.perf_counter()
    state = _init(fn, solver, y0, args)
    y, best_y, best, worse = y0, y0, np.inf, 0
    result, compile_s, stalled, steps = optx.RESULTS.successful, None, False, 0
    diverged = False
    for steps in range(1, max_steps + 1):
        y_new, state, done, result, value = _step(fn, solver, y, state, args)
        value = float(value)
        if compile_s is None:
            compile_s = time.perf_counter() - t0
        if not np.isfinite(value):
            diverged, result = True, optx.RESULTS.nonlinear_divergence
            break
        loss = 0.5 * value**2 if fixed else value
        history.append(loss)
        if callback is not None:
            extra = {"rms_pixels": value} if fixed else {}
            callback({**info, "step": steps, "loss": loss, **extra})
        if fixed:  # `value` is the misfit of `y`, the iterate before the step
            if value < best * (1 - 1e-3):
                best, best_y, worse = value, y, 0
            else:
                worse += 1
        y = y_new
        if bool(done):
            best_y, best = y, value
            break
        if patience is not None and worse >= patience:
            stalled = True
            break
    else:
        result = optx.RESULTS.max_steps_reached
    return Run(
        y=best_y if fixed else y,
        steps=steps,
        result=result,
        compile_seconds=compile_s or 0.0,
        seconds=time.perf_counter() - t0,
        stalled=stalled,
        misfit=float(best) if fixed else float("nan"),
        diverged=diverged,
    )


def iterate_traced(fn, solver, y0, args, max_steps: int):
    """`iterate`'s steps as one traceable loop (`jax.lax.while_loop`), for batches spread
    over devices: the same step, termination test and loss, ``max_steps`` at most (least
    squares and minimisers).

    **Returns:** ``(y, steps, result, losses)``; ``losses``: ``(max_steps,)``, the loss
    after each step, NaN after the last."""
    state = _init(fn, solver, y0, args)
    dynamic, static = eqx.partition(state, eqx.is_array)

    def cond(carry):
        _, _, step, done, _, _ = carry
        return jnp.logical_and(jnp.logical_not(done), step < max_steps)

    def body(carry):
        y, dynamic, step, _, _, losses = carry
        y, state, done, result, loss = _step(fn, solver, y, eqx.combine(dynamic, static), args)
        dynamic = eqx.partition(state, eqx.is_array)[0]
        return y, dynamic, step + 1, done, result, losses.at[step].set(loss)

    losses = jnp.full((max_steps,), jnp.nan, dtype=jnp.result_type(y0))
    carry = (y0, dynamic, jnp.array(0), jnp.array(False), optx.RESULTS.successful, losses)
    y, _, steps, done, result, losses = jax.lax.while_loop(cond, body, carry)
    result = optx.RESULTS.where(done, result, optx.RESULTS.max_steps_reached)
    return y, steps, result, losses
