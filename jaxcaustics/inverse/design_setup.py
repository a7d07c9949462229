"""A checked design (`Setup`): its problem, its strategies and what every stage needs,
made by `jaxcaustics.inverse.lens_setup.prepare`. The strategies read it; it imports none
of them."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..scene.mirror import MirrorScene
from ..scene.scene import HeightField, LensScene, PlaneReceiver
from .problem import DesignProblem, Mirror

# a target pixel below this fraction of the mean is dark; a target with more than
# `DARK_SHARE` of its pixels dark has dark regions, across which the transport's map jumps
DARK_LEVEL = 0.05
DARK_SHARE = 0.1


def has_dark_regions(goal) -> bool:
    """Whether more than `DARK_SHARE` of `goal`'s pixels are below `DARK_LEVEL` times
    its mean (a silhouette or lettering on black; not a photograph)."""
    g = np.asarray(goal, float)
    return float(np.mean(g < DARK_LEVEL * g.mean())) > DARK_SHARE


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
    pose: Any = None  # the screen's `ScreenPose`; None: the ground under a lens
    # whether the screen's s and t axes run against the blank's x and y (a mirror's do;
    # for the report: the transport on the screen needs no reversal)
    flips: tuple[bool, bool] = (False, False)
    # an extended source's image on the screen (`source_blur.source_kernel`); with one,
    # `goal` is the target deconvolved by it and `seen` the target itself
    kernel: Any = None
    seen: Any = None
    # bytes the design may take (`lens_setup.check_design_memory_limit`): the predicted
    # caustic is traced in bands within it, the image refinement's rasteriser in part of it
    memory_limit: int = 4 << 30

    width = property(lambda self: self.problem.outline.width)
    height = property(lambda self: self.problem.outline.height)
    thickness = property(lambda self: self.problem.element.thickness)
    screen_distance = property(lambda self: self.problem.screen.distance)
    light = property(lambda self: self.problem.light)
    top = property(lambda self: self.problem.top)
    is_mirror = property(lambda self: isinstance(self.problem.element, Mirror))
    # the target as it should be seen (under the source): `goal` but for a source's blur
    seen_goal = property(lambda self: self.goal if self.seen is None else self.seen)

    @property
    def boundary(self) -> str:
        """The designed surface's `HeightField` boundary (the start's)."""
        return self.start.boundary

    def check_thickness(self, heights) -> None:
        """A `ValueError` naming `thickness` when `heights` (``max = 0``) dip through
        the blank's bottom face (raised in the scene, it named the internal `surface`,
        after the start, before the refinement)."""
        relief = float(np.max(heights) - np.min(heights))
        if self.thickness + float(np.min(heights)) <= 0.0:
            raise ValueError(
                f"`thickness` {self.thickness} m is too thin for the design: its relief is "
                f"{relief:.4g} m, so the surface dips through the bottom face: a thicker "
                "blank, or `max_relief` (folds the relief into Fresnel zones)"
            )

    def element_scene(self, heights) -> LensScene | MirrorScene:
        """The design's element with `heights` (bicubic over the aperture, `boundary`):
        a `LensScene` or a `MirrorScene`."""
        surface = HeightField(heights, self.aperture, self.boundary)
        outline = self.problem.outline.lens_outline
        element = self.problem.element
        if isinstance(element, Mirror):  # `is_mirror`
            return MirrorScene(surface, self.light, self.receiver, self.pose, outline=outline)
        return LensScene(
            surface,
            self.light,
            self.receiver,
            self.thickness,
            self.screen_distance,
            ior=element.ior,
            outline=outline,
            screen_pose=self.pose,
        )
