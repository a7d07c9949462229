"""`render`: the one entry point from a scene to an irradiance image."""

from __future__ import annotations

from typing import Any

from jaxtyping import Array

from ._methods.twopass import two_pass
from ._scene import WaterScene

METHODS = {"twopass": two_pass}


def render(scene: WaterScene, method: str = "twopass", *, return_stats: bool = False, **knobs: Any):
    """Render the caustics of `scene` on its receiver.

    **Arguments:**

    - `scene`: the scene (for now a `WaterScene`).
    - `method`: ``"twopass"`` (Yuksel & Keyser). Later methods plug in here.
    - `return_stats`: also return a dict of diagnostics (for ``"twopass"``:
      ``missed_flux_fraction`` per channel).
    - `**knobs`: the method's quality knobs (``"twopass"``: ``samples_x``,
      ``channels_y``, ``hit_iterations``; see `two_pass`).

    **Returns:** the irradiance image, relative to the irradiance the light gives a
    horizontal plane: ``(rows, cols)`` for a single index of refraction, ``(rows, cols,
    channels)`` for a sequence of indices. With `return_stats`, ``(image, stats)``.
    """
    if method not in METHODS:
        raise ValueError(f"`method` must be one of {sorted(METHODS)}, got {method!r}")
    result = METHODS[method](scene, **knobs)
    if return_stats:
        stats: dict[str, Array] = {"missed_flux_fraction": result.missed_flux_fraction}
        return result.image, stats
    return result.image
