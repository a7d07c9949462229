"""The caustic a design predicts (`predict_caustic`), and the target corrected by it
(`corrected_goal`) for another transport start under leaning light or off a mirror, where
the landing point also moves with the surface's height. See the design notes
(``docs/design-notes.md``).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from scipy.ndimage import gaussian_filter

from ..methods.triangles.method import (
    band_bytes,
    caustic_triangles,
    trace_photons,
    triangle_window,
    triangles_image,
)
from ..scene.mirror import MirrorScene
from ..scene.scene import LensScene
from .design_setup import Setup
from .lens_setup import predict_photons_default

PREDICT_WINDOW = 16  # pixels: the prediction's largest triangle window
_BLUR = 0.7  # pixels: the correction's Gaussian
_CLIP = (0.5, 2.0)  # the correction's ratio, per round


def predict_caustic(
    setup: Setup, h, refined: int | None = None
) -> tuple[np.ndarray, float, int, LensScene | MirrorScene]:
    """The caustic of `setup`'s element with heights `h` (caustic triangles at the
    design's `predict_photons`; `refined`: the image refinement's photons per side, if
    it ran, which the default avoids: `predict_photons_default`): ``(image (rows,
    cols), flux fraction missed, window, scene)``. Photons that fit in half of the
    design's `memory_limit` are traced at once; more are traced and drawn in bands of
    rows (`caustic_triangles`' banded render: the same image, `test_design_memory`)."""
    scene = setup.element_scene(h)
    n_pred = setup.predict_photons or predict_photons_default(setup.target_shape, refined)
    if band_bytes(n_pred * n_pred, 1, jnp.result_type(float)) > setup.memory_limit // 2:
        result = caustic_triangles(
            scene, photons=n_pred, window=PREDICT_WINDOW, memory_limit=setup.memory_limit
        )
        image = np.asarray(result.image)
        lost = float(np.asarray(result.missed_flux_fraction).ravel()[0])
        return image if image.ndim == 2 else image[..., 0], lost, PREDICT_WINDOW, scene
    # the window that holds 99.9% of the flux, at most PREDICT_WINDOW pixels: the few
    # triangles stretched across a dark gap would otherwise size it (32 pixels: 4x the
    # time of 16 for 0.26% of the image, measured on a design for a dozen dots)
    photons = trace_photons(scene, (n_pred, n_pred), memory_limit=setup.memory_limit // 2)
    window = min(PREDICT_WINDOW, triangle_window(photons, scene.receiver))
    # drawn from these photons (`caustic_triangles` would trace them again: 4.5 s against
    # 2.5 s at 513^2, compilation included, the same image to 1e-7)
    images, missed = triangles_image(photons, scene.receiver, window=window)
    return np.asarray(images[0]), float(missed[0]), window, scene


def relative_l2(image: np.ndarray, target: np.ndarray) -> float:
    """``|a - b| / |b|`` of the two images scaled to unit mean."""
    a = image / image.mean() if image.mean() > 0 else image
    b = target / target.mean()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def corrected_goal(goal: np.ndarray, target: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """`goal` (the target the last solve aimed at) times the blurred ratio of `target`
    to `predicted` (both at unit mean), clipped; at `goal`'s mean."""
    t = target / target.mean()
    e = predicted / max(float(predicted.mean()), 1e-300)
    ratio = gaussian_filter(t, _BLUR) / np.maximum(gaussian_filter(e, _BLUR), 1e-3)
    corrected = goal * np.clip(ratio, *_CLIP)
    return corrected * (goal.mean() / corrected.mean())
