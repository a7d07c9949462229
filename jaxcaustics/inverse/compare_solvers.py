"""Water recovery's solvers compared on one surface (`compare_solvers`): each recovers a
known surface from its own two-pass caustic, twice (compilation apart), and
`format_comparison` tabulates heights error, image error, steps and times."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..methods.twopass import two_pass
from ..scene.scene import DirectionalLight, HeightField, PlaneReceiver, WaterScene
from .numerics import resample_heights
from .recover import SOLVERS, recover_surface
from .solvers import SolverName


def compare_solvers(
    true_heights,
    *,
    extent,
    rest_depth,
    light: DirectionalLight,
    image_shape: Sequence[int],
    ior: float = 1.333,
    solvers: Sequence[SolverName] = SOLVERS,
    solver_options: dict[str, dict[str, Any]] | None = None,
    **options: Any,
) -> list[dict[str, Any]]:
    """Recover `true_heights` from its own caustic with each solver, twice.

    The target is the two-pass caustic (``image_shape`` pixels, window ``"auto"``, the
    same `hit_iterations` / `supersample` as the solve) of `true_heights` over
    `extent`; `options` go to `recover_surface` (``heights_shape`` defaults to the
    shape of `true_heights`) and ``solver_options[name]`` overrides them per solver.
    Each solver runs twice with the same arguments: the first time includes
    compilation, the second reuses it.

    **Returns:** a row per solver: ``solver``, ``height_error`` (relative L2 error of
    the heights, means removed), ``image_error`` (`RecoveryResult.image_error`),
    ``loss``, ``steps`` (total over levels), ``success``, ``time_first_s`` (compile
    included), ``time_s`` (compiled) and ``compile_s`` (their difference). See
    `format_comparison` for a Markdown table.
    """
    true_heights = np.asarray(true_heights, dtype=float)
    options.setdefault("heights_shape", true_heights.shape)
    options.setdefault("start", "ripple")  # the solvers compared from flat water
    scene = WaterScene(
        HeightField(true_heights, extent, options.get("boundary", "periodic")),
        light,
        PlaneReceiver(options.get("receiver_extent", extent), image_shape),
        rest_depth,
        ior=ior,
    )
    target = np.asarray(
        two_pass(
            scene,
            samples_x="auto",
            channels_y="auto",
            hit_iterations=options.get("hit_iterations", 3),
            supersample=options.get("supersample", 1),
        ).image
    )
    truth = np.asarray(
        resample_heights(
            true_heights,
            extent,
            tuple(options["heights_shape"]),
            options.get("boundary", "periodic"),
        )
    )
    truth = truth - truth.mean()
    rows = []
    for name in solvers:
        kwargs = {**options, **(solver_options or {}).get(name, {})}
        times = []
        for _ in range(2):
            t0 = time.perf_counter()
            result = recover_surface(
                target,
                extent=extent,
                rest_depth=rest_depth,
                light=light,
                ior=ior,
                solver=name,
                **kwargs,
            )
            times.append(time.perf_counter() - t0)
        rows.append(
            {
                "solver": name,
                "height_error": float(
                    np.linalg.norm(result.heights - truth) / np.linalg.norm(truth)
                ),
                "image_error": result.image_error,
                "loss": result.loss,
                "steps": sum(result.steps),
                "success": result.success,
                "time_first_s": times[0],
                "time_s": times[1],
                "compile_s": times[0] - times[1],
            }
        )
    return rows


def format_comparison(rows: Sequence[dict[str, Any]]) -> str:
    """The rows of `compare_solvers` as a Markdown table."""
    lines = [
        "| solver | height error | image error | loss | steps | converged | time (s) |"
        " time incl. compile (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['solver']} | {r['height_error']:.2e} | {r['image_error']:.2e} |"
            f" {r['loss']:.2e} | {r['steps']} | {'yes' if r['success'] else 'no'} |"
            f" {r['time_s']:.2f} | {r['time_first_s']:.1f} |"
        )
    return "\n".join(lines)
