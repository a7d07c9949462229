"""High-contrast design targets (made before any tuning of the design; never tuned to).

- `silhouette`: scikit-image's ``horse``, bright on black (33% of the screen lit).
- `lettering`: white text "JAX" over "caustics" on black (matplotlib's Agg renderer).
- `dots`: twelve bright Gaussian dots (1.2 px standard deviation) on black, placed by a
  seeded random generator at least 12 px apart and 12 px from the edges.

Each is a ``(size, size)`` float array in ``[0, 1]`` with exact zeros over the dark
regions (values below 1e-3 set to 0).
"""

from __future__ import annotations

import numpy as np


def _area_average(image: np.ndarray, size: int) -> np.ndarray:
    from jaxcaustics.internal import area_average as average

    return average(np.asarray(image, float), (size, size))


def _clean(image: np.ndarray) -> np.ndarray:
    image = np.clip(image / image.max(), 0.0, 1.0)
    return np.where(image < 1e-3, 0.0, image)


def silhouette(size: int = 128) -> np.ndarray:
    from skimage import data

    return _clean(_area_average(~data.horse(), size))


def lettering(size: int = 128) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 4), dpi=128, facecolor="black")
    canvas = FigureCanvasAgg(fig)
    fig.text(
        0.5, 0.62, "JAX", color="white", ha="center", va="center", fontsize=78, fontweight="bold"
    )
    fig.text(0.5, 0.28, "caustics", color="white", ha="center", va="center", fontsize=44)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba(), float)[..., 0]
    return _clean(_area_average(rgba, size))  # row 0 at the top, as in scikit-image


def dots(size: int = 128, count: int = 12, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    margin, spacing = 12, 12
    centres: list[np.ndarray] = []
    while len(centres) < count:
        c = rng.uniform(margin, size - margin, 2)
        if all(np.hypot(*(c - d)) >= spacing for d in centres):
            centres.append(c)
    y, x = np.mgrid[0:size, 0:size] + 0.5
    image = sum(np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 1.2**2)) for cx, cy in centres)
    return _clean(image)


TARGETS = {"silhouette": silhouette, "lettering": lettering, "dots": dots}
