"""A design as rounds (`solve_in_rounds`): each Poisson level, or the transport start and
its target corrections (`prediction.py`), then the finish, one round each, checkpointed
after every round (`jaxcaustics.inverse.checkpoint.run_rounds`), so that an interrupted
design resumes where it stopped and ends where an uninterrupted one does.

A checkpoint holds every round's heights and a fingerprint of what the design was made
from (the target as used, the problem, the strategies, the options that change the
result); resuming a checkpoint of another design is refused, naming the file and
what differs.
"""

from __future__ import annotations

import dataclasses
import os
import time

import numpy as np
import optimistix as optx

from .checkpoint import fingerprint, refuse_another_run, run_rounds
from .design_setup import Setup
from .poisson_levels import PoissonLevels
from .prediction import corrected_goal, predict_caustic, relative_l2

_PARTS = ("target", "problem and strategies", "heights grids", "screen", "initial heights")


def _fingerprint(setup: Setup) -> np.ndarray:
    """A digest of each part of a design that changes its rounds (`_PARTS`)."""
    parts = (
        np.asarray(setup.goal),
        (setup.problem, setup.start, setup.finish),
        repr(setup.shapes).encode(),
        np.asarray(setup.screen, float),
        b"" if setup.initial is None else np.asarray(setup.initial, float),
    )
    return fingerprint(dict(zip(_PARTS, parts, strict=True)))


def _corrections(setup: Setup) -> int:
    """Rounds of target correction after the transport start (none after the levels)."""
    start = setup.start
    return 0 if isinstance(start, PoissonLevels) else start.correction_rounds(setup)


def _round_shapes(setup: Setup) -> list[tuple[int, int]]:
    """The heights grid each round ends on."""
    if isinstance(setup.start, PoissonLevels):
        shapes = list(setup.shapes)
    else:
        shapes = [setup.shapes[-1]] * (1 + _corrections(setup))
    return shapes + ([setup.shapes[-1]] if setup.finish is not None else [])


def solve_in_rounds(
    setup: Setup,
    history: list[float],
    callback,
    throw: bool,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    progress: bool = False,
):
    """The start's rounds, then the finish's: ``(heights, level_reports, result)``.

    A round loaded from `checkpoint` (with `resume`) is not run again: its report is
    ``{"stage": "checkpoint", "shape": ..., "result": RESULTS.successful}`` and its
    steps are not in `history`. Ctrl-C raises `KeyboardInterrupt` after the last
    completed round's checkpoint."""
    shapes = _round_shapes(setup)
    state = {
        "heights": tuple(np.zeros(s) for s in shapes),
        "goal": np.asarray(setup.goal, float),  # the target the last solve aimed at
        "fingerprint": _fingerprint(setup),
    }
    refuse_another_run(checkpoint, resume, state, _PARTS, "design")
    reports: list[dict] = []
    shown = [lambda text: None]  # the progress bar's live text while a round runs

    def step_done(info):
        rows, cols = info["shape"]
        shown[0](f"{rows}x{cols} step {info['step']} loss {info['loss']:.4g}")
        if callback is not None:
            callback(info)

    results = [optx.RESULTS.successful]  # the design's result: its start's last
    ran = [0]  # rounds run in this call (the others came from the checkpoint)
    start, finish = setup.start, setup.finish

    def store(state, k, h):
        ran[0] += 1
        heights = list(state["heights"])
        heights[k] = h
        return {**state, "heights": tuple(heights)}

    def level(k):
        def run(state):
            previous = None if k == 0 else state["heights"][k - 1]
            h, report, result = start.solve_level(setup, k, previous, history, step_done, throw)
            reports.append(report)
            results.append(result)
            return store(state, k, h)

        return run

    def transport(state):
        h, stage_reports, result = start.solve(setup, history, step_done)
        if setup.max_relief is None:  # (folded at the end otherwise) said before the rest
            setup.check_thickness(h)
        reports.extend(stage_reports)
        results.append(result)
        return store(state, 0, h)

    def correct(k):
        def run(state):
            t0 = time.perf_counter()
            h = state["heights"][k - 1]
            predicted = predict_caustic(setup, h)[0]
            goal = corrected_goal(state["goal"], setup.goal, predicted)
            # a mirror's solve starts from the heights reached; a lens's from its own
            # start (its heights carry their edge bevel, whose steep rim sent a warm fit
            # to NaN: measured under 30-degree light on the camera at 128^2)
            warm = h if setup.is_mirror else setup.initial
            again = dataclasses.replace(setup, goal=goal, initial=warm)
            reports.append(
                {
                    "stage": "target correction",
                    "shape": tuple(h.shape),
                    "steps": 1,
                    "loss": relative_l2(predicted, setup.goal),  # before it
                    "result": optx.RESULTS.successful,
                    "seconds": time.perf_counter() - t0,
                    "first_step_seconds": float("nan"),
                }
            )
            h, stage_reports, result = start.solve(again, history, step_done)
            reports.extend(stage_reports)
            results.append(result)
            return {**store(state, k, h), "goal": goal}

        return run

    def refine(state):
        h, report = finish.refine(setup, state["heights"][-2], history, step_done)
        if report is not None:  # None: nothing to refine
            reports.append(report)
        return store(state, len(shapes) - 1, h)

    if isinstance(start, PoissonLevels):
        rounds = [level(k) for k in range(len(setup.shapes))]
    else:
        rounds = [transport] + [correct(k) for k in range(1, 1 + _corrections(setup))]
    if finish is not None:
        rounds.append(refine)

    def live(run):
        def with_report(state, report):
            shown[0] = report
            return run(state)

        return with_report

    state, done, interrupted = run_rounds(
        [live(run) for run in rounds],
        state,
        checkpoint=checkpoint,
        resume=resume,
        describe=lambda s: f"{len(history)} steps",
        progress=progress,
        label="designing",
        live=True,
    )
    if interrupted:
        where = "" if checkpoint is None else f"; resume from {str(checkpoint)!r}"
        raise KeyboardInterrupt(f"design interrupted after {done} of {len(rounds)} rounds{where}")
    loaded = [
        {"stage": "checkpoint", "shape": shape, "result": optx.RESULTS.successful}
        for shape in shapes[: len(rounds) - ran[0]]
    ]
    return np.asarray(state["heights"][-1]), loaded + reports, results[-1]
