"""The camera of a photographed caustic: a Gaussian point-spread function.

`camera_blur` applies it (in JAX, differentiable: the forward models of
`recover_surface` and the fold fit see the floor through it); `deconvolve` undoes it
on a target before the transport start, which needs a sharp image (scikit-image's
Richardson-Lucy, a maintained implementation, rather than a hand-written one).
"""

from __future__ import annotations

import math
from typing import cast

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array
from skimage.restoration import richardson_lucy

# Richardson-Lucy iterations that undo a camera blur before the transport start
# (measured on a 128^2 reference caustic under 30-degree light, blurred by 1 pixel with
# 2% noise: height error 2.3% without deconvolution, 1.1% after 10 iterations, 1.4%
# after 30, which sharpen the noise)
DECONVOLUTION_ITERATIONS = 10


def gaussian_taps(sigma: float) -> np.ndarray:
    """The normalised 1-D Gaussian kernel of standard deviation `sigma` pixels, radius
    ``ceil(3 sigma)``."""
    radius = max(1, math.ceil(3.0 * sigma))
    x = np.arange(-radius, radius + 1, dtype=float)
    taps = np.exp(-0.5 * (x / sigma) ** 2)
    return taps / taps.sum()


def camera_blur(image: Array, sigma: float, boundary: str) -> Array:
    """`image` ``(rows, cols[, channels])`` seen through a Gaussian PSF of `sigma`
    pixels (standard deviation), wrapped round a periodic floor, edge-extended
    otherwise: separable sums of shifted slices (differentiable, no gathers)."""
    if sigma == 0:
        return image
    taps = gaussian_taps(sigma)
    radius = len(taps) // 2
    mode = "wrap" if boundary == "periodic" else "edge"
    for axis in (0, 1):
        pad = [(0, 0)] * image.ndim
        pad[axis] = (radius, radius)
        padded = jnp.pad(image, pad, mode=mode)
        size = image.shape[axis]
        image = cast(
            Array,  # `sum` starts from 0, which mypy keeps in its type
            sum(
                float(w) * jax.lax.slice_in_dim(padded, k, k + size, axis=axis)
                for k, w in enumerate(taps)
            ),
        )
    return image


def deconvolve(target: np.ndarray, sigma: float, boundary: str) -> np.ndarray:
    """`target` ``(rows, cols)`` with a Gaussian blur of `sigma` pixels undone by
    `DECONVOLUTION_ITERATIONS` of Richardson-Lucy (scikit-image's, a maintained
    implementation; non-negative by construction), padded like `camera_blur`."""
    if sigma == 0:
        return target
    taps = gaussian_taps(sigma)
    # scikit-image convolves with zeros outside: a band of 4 kernel radii keeps that
    # edge away (with 1 radius, the recovered heights were 13% off instead of 1.1%)
    pad = 4 * (len(taps) // 2)
    scale = float(target.max())
    padded = np.pad(target / scale, pad, mode="wrap" if boundary == "periodic" else "edge")
    sharp = richardson_lucy(
        padded, np.outer(taps, taps), num_iter=DECONVOLUTION_ITERATIONS, clip=False
    )
    return sharp[pad:-pad, pad:-pad] * scale
