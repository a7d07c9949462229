"""A water caustic to recover from: read, shaped and checked before anything runs.

A target is irradiance relative to flat water (`recover_surface`), a 2-D image, or one
channel per index of refraction. Water moves light, it does not absorb it: an array
given as is must have a mean near 1 (`TARGET_MEAN`).
"""

from __future__ import annotations

import os

import numpy as np

from .._checks import check_real_array
from ..io.images import read_image
from .numerics import check_irradiance
from .transport import MAX_PIXELS

# an unnormalised target's mean must lie here: water moves light, it does not absorb it
# (a mean of 0.01 was recovered with an image error of 1290), though light can leave a
# receiver smaller than the water or gather on one larger
TARGET_MEAN = (0.2, 5.0)


def check_target_mean(target: np.ndarray) -> None:
    """A `ValueError` naming `target` when its mean lies outside `TARGET_MEAN`."""
    mean = float(target.mean())
    if not TARGET_MEAN[0] <= mean <= TARGET_MEAN[1]:
        raise ValueError(
            f"`target` has mean {mean:.3g}: water refracts the light, it neither absorbs "
            "nor adds any, so its caustic's mean is near 1 (flat water's irradiance); give "
            "the irradiance relative to flat water, or normalize=True"
        )


def load_target(target, ior) -> np.ndarray:
    """`target` (a file path, or an array) as a float array ``(rows, cols)``, or
    ``(rows, cols, channels)`` for a tuple `ior`; a `ValueError` (a missing file: a
    `FileNotFoundError`) naming it."""
    channels = len(ior) if isinstance(ior, tuple) else 0
    if isinstance(target, (str, os.PathLike)):
        try:
            arr = np.asarray(read_image(target, as_gray=channels == 0), dtype=float)
        except FileNotFoundError as err:
            raise FileNotFoundError(f"`target`: {err}") from err
        except ValueError as err:
            raise ValueError(f"`target`: {err}") from err
        if channels and arr.ndim == 3 and arr.shape[2] == 4:
            arr = arr[..., :3]
    else:
        arr = check_real_array(target, "target")
        if (arr.shape[0] * arr.shape[1] if arr.ndim >= 2 else arr.size) > MAX_PIXELS:
            raise ValueError(f"`target` {arr.shape} has over {MAX_PIXELS} pixels (4096^2)")
        arr = arr.astype(float)
    want = 3 if channels else 2
    if arr.ndim != want or (channels and arr.shape[2] != channels):
        what = f"(rows, cols, {channels})" if channels else "(rows, cols)"
        raise ValueError(f"`target` must have shape {what} for ior={ior!r}, got {arr.shape}")
    if arr.shape[0] < 2 or arr.shape[1] < 2:
        raise ValueError(f"`target` needs at least 2x2 pixels, got shape {arr.shape}")
    if arr.shape[0] * arr.shape[1] > MAX_PIXELS:
        raise ValueError(f"`target` {arr.shape} has over {MAX_PIXELS} pixels (4096^2)")
    return check_irradiance(arr, "there is no caustic to match")


def check_above_ground(heights, rest_depth: float, target: np.ndarray, found_by: str) -> None:
    """A `ValueError` naming `target` and `rest_depth` when the recovered `heights`
    (metres about the rest level) reach the ground: no water that deep makes the target's
    caustic (it was reported as the internal "`surface` reaches the ground", after the
    whole recovery). Slopes focus light in proportion to the depth, so the waves a caustic
    needs shrink as ``1 / rest_depth^2`` relative to it: deeper water can."""
    low = float(np.min(heights))
    if rest_depth + low > 0:
        return
    peak = float(np.max(target) / np.mean(target))
    raise ValueError(
        f"`target` cannot be made by water `rest_depth` {rest_depth:g} m deep: the waves "
        f"that focus it (peak {peak:.3g} x the mean) dip {-low:.3g} m below the rest level "
        f"({found_by}), through the ground. Deeper water makes the same caustic with gentler "
        "waves: check `rest_depth`, and the target's exposure (a picture's gamma)"
    )
