"""What `recover_surface` returns: a `RecoveryResult`, with a `RecoveryLevel` per level of
its image-space solve."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import optimistix as optx

from ..scene.scene import WaterScene


@dataclasses.dataclass(frozen=True)
class RecoveryLevel:
    """One level of the coarse-to-fine solve.

    - `level`: index of the level (0 is the coarsest).
    - `shape`: ``(rows, cols)`` of the height grid solved for.
    - `heights`: the level's solution, metres (as solved: mean not removed).
    - `initial_loss`: the objective at the level's initial guess.
    - `loss`: the objective (``0.5 * sum(residual^2)``, Optimistix's, as `design_lens`
      reports) at the solution.
    - `steps`: the solver's number of steps.
    - `result`: the `optimistix.RESULTS` code (``optimistix.RESULTS.successful`` or why
      not).
    - `window`: the two-pass window ``(N, M)`` used.
    - `time_s`: wall time of the level, compilation included.
    """

    level: int
    shape: tuple[int, int]
    heights: np.ndarray
    initial_loss: float
    loss: float
    steps: int
    result: Any
    window: tuple[int, int]
    time_s: float


@dataclasses.dataclass(frozen=True)
class RecoveryResult:
    """What `recover_surface` found.

    - `heights`: the recovered height field, metres, ``heights_shape``, mean removed
      (the mean is unobservable).
    - `image`: the caustic rendered from the recovered surface (receiver shape),
      seen through the camera's `blur`.
    - `target`: the target as compared (normalised if asked).
    - `loss`: the final objective, the sum of squares of all residuals (without an
      image-space solve: the image misfit's mean square).
    - `image_rmse`: root mean square of ``image - target``.
    - `image_error`: ``||image - target|| / ||target - mean(target)||``, the misfit
      relative to the target's contrast; for a target with almost no contrast (below
      1e-3 of ``||target||``: flat water's) ``||image - target|| / ||target||``.
    - `missed_flux_fraction`: per channel, light of the final surface that fell outside
      the gather window (should be ~0).
    - `levels`: a `RecoveryLevel` per coarse-to-fine level.
    - `solver`: the image-space solver's name (``"none"`` without one).
    - `time_s`: total wall time, compilation included.
    - `scene`: the `WaterScene` with the recovered surface (as solved, mean included).
    - `stages`: a report (dict) per stage of the transport start (``stage``: transport,
      landing fit, irradiance fit, then a fold fit per blur when it ran; ``steps``,
      ``rms``, ``seconds``), empty without it.
    """

    heights: np.ndarray
    image: np.ndarray
    target: np.ndarray
    loss: float
    image_rmse: float
    image_error: float
    missed_flux_fraction: np.ndarray
    levels: tuple[RecoveryLevel, ...]
    solver: str
    time_s: float
    scene: WaterScene
    stages: tuple[dict, ...] = ()

    @property
    def steps(self) -> tuple[int, ...]:
        """Solver steps per level."""
        return tuple(level.steps for level in self.levels)

    @property
    def results(self) -> tuple[Any, ...]:
        """`optimistix.RESULTS` code per level."""
        return tuple(level.result for level in self.levels)

    @property
    def success(self) -> bool:
        """Whether every level ended with ``optimistix.RESULTS.successful``."""
        return all(bool(r == optx.RESULTS.successful) for r in self.results)

    @property
    def messages(self) -> tuple[str, ...]:
        """Human-readable result per level (empty string: successful)."""
        # the class is indexed through Equinox's enumeration metaclass, unknown to mypy
        return tuple(optx.RESULTS[r] for r in self.results)  # type: ignore[misc]
