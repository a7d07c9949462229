"""A checked design (`Setup`): its problem, its strategies and what every stage needs,
made by `jaxcaustics.inverse.lens_setup.prepare`. The strategies read it; it imports none
of them."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..scene.scene import HeightField, LensScene, PlaneReceiver
from .problem import DesignProblem


@dataclasses.dataclass
class Setup:
    """A checked design (`prepare`): the problem, its strategies, and what every stage
    needs."""

    problem: DesignProblem
    start: Any  # a `TransportStart` or `PoissonLevels`
    finish: Any  # an `ImageRefinement` or None
    target_shape: tuple[int, int]
    shapes: list[tuple[int, int]]  # the heights grids, coarse to fine
    aperture: np.ndarray  # (4,) the blank's extent, metres
    screen: np.ndarray  # (4,) the screen's extent, metres
    receiver: PlaneReceiver
    goal: np.ndarray  # the target at unit mean, masked, plus the floor
    goal0: np.ndarray  # `goal` on the first grid
    flux_scale: float  # `goal` times this is the irradiance the lens's flux gives
    vertical: bool  # collimated light straight down
    weak: float  # D of the weak-lens relation, metres
    predict_photons: int | None
    max_relief: float | None
    initial: Any
    timings: dict[str, float]
    warn_error: float = 0.15

    width = property(lambda self: self.problem.outline.width)
    height = property(lambda self: self.problem.outline.height)
    thickness = property(lambda self: self.problem.element.thickness)
    ior = property(lambda self: self.problem.element.ior)
    screen_distance = property(lambda self: self.problem.screen.distance)
    light = property(lambda self: self.problem.light)

    @property
    def boundary(self) -> str:
        """The designed surface's `HeightField` boundary (the start's)."""
        return self.start.boundary

    def lens_scene(self, heights) -> LensScene:
        """The design's lens with `heights` (bicubic over the aperture, `boundary`)."""
        return LensScene(
            HeightField(heights, self.aperture, self.boundary),
            self.light,
            self.receiver,
            self.thickness,
            self.screen_distance,
            ior=self.ior,
            outline=self.problem.outline.lens_outline,
        )
