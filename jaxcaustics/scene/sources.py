"""Extended light sources: the Sun's disc (`SunLight`) and a flat emitter near the
element, an LED's die or a torch's exit (`AreaLight`).

A caustic lens hangs under the Sun, not under a point at infinity: the Sun is a disc
0.533 degrees across, so every point of the caustic is spread into a small disc on the
screen (2.3 mm across at 500 mm), which sets the finest detail a design can show.
`SunLight` is a `DirectionalLight` (its centre's direction) that also carries the disc:
what takes only a direction renders its centre; the design, the reference and
`verify_lens` integrate over the disc.

An `AreaLight` is likewise a `PointLight` at its centre that also carries its size: a
flat Lambertian emitter facing down, whose points each cast the caustic from a little
aside; it is sampled by `AreaLight.points` (a stratified grid over a rectangle, a
sunflower over a disc).

The disc is sampled by `jaxcaustics.reference.disc_directions` (a sunflower pattern:
even, stratified cover of the disc, with limb-darkening weights; NumPy, so that the
reference tracer, which imports no JAX, samples it the same way).
"""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np

from .._checks import check_number
from ..reference._sources import area_points, disc_directions
from .scene import DirectionalLight, PointLight

# the Sun's angular radius seen from the Earth, degrees (its mean: 0.2666 at 1 au)
SUN_ANGULAR_RADIUS_DEG = 0.2665


class SunLight(DirectionalLight):
    """Sunlight: collimated light from a disc of angular radius `angular_radius_deg`
    about `direction`.

    **Arguments:**

    - `direction`: shape ``(3,)``, the direction the light from the disc's centre
      travels (``z < 0``), as for `DirectionalLight`; default straight down.
    - `angular_radius_deg`: the disc's angular radius, degrees (the Sun: 0.2665, the
      default), in ``(0, 5]``.
    - `limb_darkening`: the linear limb-darkening coefficient ``u`` in ``[0, 1]``: the
      disc's radiance at a point whose ray leaves the Sun's surface at ``mu = cos(angle to
      its normal)`` is ``1 - u (1 - mu)``; 0 (default): a uniform disc; the Sun in
      visible light: about 0.6.

    It is a `DirectionalLight`: wherever one is taken, a `SunLight` is too. Use
    `SunLight.from_angles(zenith_deg, azimuth_deg)` to build one from angles.
    """

    angular_radius: float = eqx.field(static=True)  # radians
    limb_darkening: float = eqx.field(static=True)

    def __init__(
        self,
        direction=(0.0, 0.0, -1.0),
        angular_radius_deg: float = SUN_ANGULAR_RADIUS_DEG,
        limb_darkening: float = 0.0,
    ):
        super().__init__(direction)
        radius = check_number(angular_radius_deg, "angular_radius_deg", low=0.0, high=5.0,
                              low_open=True)  # fmt: skip
        self.angular_radius = math.radians(radius)
        self.limb_darkening = check_number(limb_darkening, "limb_darkening", low=0.0, high=1.0)

    @classmethod
    def from_angles(  # type: ignore[override]
        cls,
        zenith_deg: float,
        azimuth_deg: float = 0.0,
        angular_radius_deg: float = SUN_ANGULAR_RADIUS_DEG,
        limb_darkening: float = 0.0,
    ) -> SunLight:
        """The Sun at `zenith_deg` from vertical, its light travelling towards
        `azimuth_deg` (from +x towards +y)."""
        centre = DirectionalLight.from_angles(zenith_deg, azimuth_deg)
        return cls(np.asarray(centre.direction), angular_radius_deg, limb_darkening)

    @property
    def angular_radius_deg(self) -> float:
        return math.degrees(self.angular_radius)

    def directions(self, samples: int) -> tuple[np.ndarray, np.ndarray]:
        """`samples` directions over the disc and their weights (summing to 1):
        ``((samples, 3) unit vectors, (samples,))``."""
        return disc_directions(
            np.asarray(self.direction, float), self.angular_radius, samples, self.limb_darkening
        )


AREA_SHAPES = ("rectangle", "disc")


class AreaLight(PointLight):
    """A flat emitter facing straight down, of `size` at `position`: an LED's die, a
    torch's exit, a frosted lamp.

    **Arguments:**

    - `position`: shape ``(3,)``, metres: the emitter's centre, above everything it
      lights.
    - `size`: metres: ``(width along x, height along y)`` of a rectangle, or a disc's
      diameter (one number, or ``shape="disc"``).
    - `shape`: ``"rectangle"`` (default; a square for one number) or ``"disc"``.
    - `intensity`: the whole emitter's radiant intensity straight down, W/sr (> 0).
    - `lambertian`: the emitter follows Lambert's law (default): its intensity towards
      a direction ``cos(angle from straight down)`` times `intensity` (for a lens 50 mm
      across 100 mm below, 0.94 at the corners); False: each point radiates equally
      everywhere, as a `PointLight`.

    It is a `PointLight` at its centre: wherever one is taken, an `AreaLight` is too;
    the design, the reference and `verify_lens` integrate over its area.
    """

    size: tuple[float, float] = eqx.field(static=True)
    shape: str = eqx.field(static=True)
    lambertian: bool = eqx.field(static=True)

    def __init__(self, position, size, shape=None, intensity=1.0, lambertian=True):
        super().__init__(position, intensity)
        if shape is not None and shape not in AREA_SHAPES:
            raise ValueError(f"`shape` must be one of {AREA_SHAPES}, got {shape!r}")
        sizes = np.atleast_1d(np.asarray(size, dtype=float))
        if sizes.shape not in ((1,), (2,)) or not np.all(np.isfinite(sizes) & (sizes > 0)):
            raise ValueError(
                f"`size` must be one positive length or (width, height) in metres, got {size!r}"
            )
        if shape == "disc" and sizes.shape != (1,):
            raise ValueError(f"`size` of a disc is its diameter (one number), got {size!r}")
        if not isinstance(lambertian, bool):
            raise ValueError(f"`lambertian` must be True or False, got {lambertian!r}")
        self.size = (float(sizes[0]), float(sizes[-1]))
        self.shape = shape or "rectangle"
        self.lambertian = lambertian

    def points(self, samples: int) -> tuple[np.ndarray, np.ndarray]:
        """About `samples` points over the emitter (a rectangle's: the centres of a
        ``k x k`` grid of equal cells, ``k = round(sqrt(samples))``; a disc's: a
        sunflower) and their weights, equal, summing to 1: ``((n, 3), (n,))``."""
        return area_points(self, samples)
