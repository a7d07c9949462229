"""Designs of one lens for several screen distances, spread over devices
(`design_lens_variants`): the Poisson levels' solves as one traced loop per level
(`driver.iterate_traced`) for every variant at once.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._checks import check_bool, check_number
from ..devices import check_per_device, map_sharded, resolve_devices
from .design import LensDesign, _finish, design_lens, lens_problem
from .driver import iterate_traced
from .lens_setup import prepare
from .poisson_levels import level_heights, level_start, make_level_solver


class _LevelSolve(eqx.Module):
    """``(shared, (u0, model)) -> iterate_traced(...)`` for `map_sharded`: a hashable
    callable, so that designs with the same settings reuse the compiled solve."""

    objective: Callable = eqx.field(static=True)
    solver: Any = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)

    def __call__(self, shared, item):
        u0, problem = item
        return iterate_traced(self.objective, self.solver, u0, problem, self.max_steps)


def design_lens_variants(
    target,
    *,
    screen_distances: Sequence[float] | None = None,
    devices: Sequence[jax.Device] | int | None = None,
    per_device: Literal["map", "vmap"] | None = None,
    throw: bool = True,
    **design_kwargs,
) -> list[LensDesign]:
    """Design one lens per screen distance of `screen_distances` (the same target, blank and light),
    the designs spread over `devices`.

    `design_lens` steps its solver from Python (a loss after every step, a callback, a
    progress report), so it cannot itself run inside a sharded program; here each level's
    solve runs as one traced loop (the same solver steps, `jax.lax.while_loop`) for every
    variant at once, the variants split across the devices by `map_sharded` (each device
    solves its share one after the other with ``jax.lax.map`` on CPU, vectorised on
    GPU/TPU; on several hosts each process solves its own devices' shares and the results
    are gathered on every process). The set-up between levels (resampling, the next
    level's start) and the final predicted caustics run on the host.

    **Arguments:**

    - `target`: as for `design_lens`.
    - `screen_distances`: distances from the bottom face to the screen, metres, one design each.
    - `devices`: ``None`` (all of `jax.devices()`), an int ``n`` (the first ``n``) or a
      sequence of devices.
    - `per_device`: ``"map"`` or ``"vmap"``; see `map_sharded`.
    - `throw`: raise if a variant's solver fails at some level.
    - `**design_kwargs`: the keyword arguments of `design_lens` (``width``, ``height``,
      ``thickness`` required), except ``screen_distance`` and ``callback`` (no per-step calls from
      inside the sharded loop).

    **Returns:** a list of `LensDesign`, one per screen distance, in order; each one's
    ``loss_history`` holds its own steps, its ``levels`` report the steps and final loss
    of each level, and their ``seconds`` the wall time of the level's sharded solve (all
    variants together; ``first_step_seconds`` is NaN). Invalid specifications raise
    `ValueError` before any optimisation starts.
    """

    t_start = time.perf_counter()
    where = "design_lens_variants"
    if screen_distances is None:
        raise ValueError(f"{where}: `screen_distances` is required (metres, one design each)")
    for name in ("screen_distance", "callback"):
        if name in design_kwargs:
            raise ValueError(
                f"`{name}` is not an argument of design_lens_variants"
                + (
                    " (give `screen_distances`)"
                    if name == "screen_distance"
                    else " (no per-step calls)"
                )
            )
    if isinstance(screen_distances, (str, bytes)) or not isinstance(
        screen_distances, (Sequence, np.ndarray)
    ):
        raise ValueError(
            f"`screen_distances` must be a sequence of numbers, got {screen_distances!r}"
        )
    if len(screen_distances) == 0:
        raise ValueError("`screen_distances` must hold at least one screen distance")
    screen_distances = [
        check_number(t, f"screen_distances[{i}]") for i, t in enumerate(screen_distances)
    ]  # > 0: `_prepare`
    throw = check_bool(throw, "throw")
    # bad `devices` or `per_device` fail before the set-up
    check_per_device(per_device, resolve_devices(devices))
    unknown = set(design_kwargs) - set(inspect.signature(design_lens).parameters)
    if unknown:
        raise ValueError(f"unknown arguments of design_lens: {sorted(unknown)}")
    defaults = {
        k: p.default
        for k, p in inspect.signature(design_lens).parameters.items()
        if p.default is not inspect.Parameter.empty
        and k not in ("throw", "callback", "screen_distance")
    }
    spec = {**defaults, "start": "poisson", **design_kwargs}
    if spec["start"] != "poisson":
        raise ValueError(
            "design_lens_variants runs the Poisson start's levels (start='poisson'); "
            "design transport-start variants with design_lens, one screen distance at a time"
        )
    for name in ("width", "height", "thickness"):
        if name not in spec:
            raise ValueError(f"`{name}` is required (metres)")
    keywords = set(inspect.signature(lens_problem).parameters)
    options = {k: v for k, v in spec.items() if k not in keywords}
    setups = []
    for i, screen_distance in enumerate(screen_distances):
        try:
            problem, levels, _ = lens_problem(
                **{k: v for k, v in spec.items() if k in keywords},
                screen_distance=screen_distance,
            )
            setups.append(prepare(problem, target, levels, None, **options))
        except ValueError as err:
            raise ValueError(f"screen_distances[{i}] = {screen_distance}: {err}") from err
    first = setups[0]
    sol, objective = make_level_solver(first.start)
    max_steps = first.start.max_steps

    solve = _LevelSolve(objective, sol, max_steps)

    histories: list[list[float]] = [[] for _ in screen_distances]
    reports: list[list[dict[str, Any]]] = [[] for _ in screen_distances]
    results = [optx.RESULTS.successful] * len(screen_distances)
    heights: list[np.ndarray | None] = [None] * len(screen_distances)
    for k, shape in enumerate(first.shapes):
        t0 = time.perf_counter()
        items = [
            level_start(setup, setup.start, k, h) for setup, h in zip(setups, heights, strict=True)
        ]
        batch = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *items)
        u, steps, result, losses = map_sharded(
            solve, None, batch, devices=devices, per_device=per_device
        )
        seconds = time.perf_counter() - t0
        for i, (_, model) in enumerate(items):
            n_steps = int(steps[i])
            results[i] = jax.tree.map(lambda x, i=i: jnp.asarray(x[i]), result)
            histories[i].extend(float(v) for v in losses[i, :n_steps])
            try:
                heights[i] = level_heights(model, u[i], k, shape, results[i], throw)
            except RuntimeError as err:
                raise RuntimeError(f"screen_distances[{i}] = {screen_distances[i]}: {err}") from err
            reports[i].append(
                {
                    "shape": shape,
                    "steps": n_steps,
                    "loss": histories[i][-1] if histories[i] else float("nan"),
                    "result": results[i],
                    "seconds": seconds,
                    "first_step_seconds": float("nan"),
                }
            )
    return [
        _finish(setup, h, history, report, result, t_start)
        for setup, h, history, report, result in zip(
            setups, heights, histories, reports, results, strict=True
        )
    ]
