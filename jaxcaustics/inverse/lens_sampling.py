"""The lens's top surface as the exports see it: the inputs checked (a `LensScene` or a
`HeightField` and its thickness), the bicubic ``H`` evaluated on grids in blocks, and
`lens_height_map`. Millimetres, in the lens's own frame (the origin at the aperture's
corner ``(x_min, y_min)``, the flat bottom at ``z = 0``)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_shape
from ..scene.mirror import MirrorScene
from ..scene.scene import HeightField, LensScene
from ..scene.surface import height_and_gradient

_MM = 1000.0  # millimetres per metre
_BLOCK_POINTS = 1 << 18  # points per surface evaluation (bounds the memory used)
# most grid points of a solid, height map or report (4096^2: about 3 GB for the solid's
# trimesh and 2 GB for the report's derivatives; more takes minutes and runs out of memory)
MAX_SAMPLES = 1 << 24
_evaluate_jit = jax.jit(height_and_gradient, static_argnames="curvature")


# --------------------------------------------------------------------------- inputs


def _check_number(value, name: str, *, low: float, low_inclusive: bool) -> float:
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise ValueError(f"`{name}` must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`{name}` must be a number, got {value!r}") from err
    if not math.isfinite(v):
        raise ValueError(f"`{name}` must be finite, got {v}")
    if v < low or (v == low and not low_inclusive):
        bound = f">= {low:g}" if low_inclusive else f"> {low:g}"
        raise ValueError(f"`{name}` must be {bound}, got {v}")
    return v


def _lens(scene_or_surface, thickness) -> tuple[HeightField, float]:
    """The unrotated height field and the thickness in metres."""
    if isinstance(scene_or_surface, LensScene):
        if thickness is not None:
            raise ValueError(
                "`thickness` must be None for a LensScene (its own thickness is used), "
                f"got {thickness!r}"
            )
        surface, t = scene_or_surface.surface, float(scene_or_surface.thickness)
    elif isinstance(scene_or_surface, (HeightField, MirrorScene)):
        if thickness is None:
            raise ValueError(
                "`thickness` (metres: the blank's) is required with a HeightField or a MirrorScene"
            )
        surface = (
            scene_or_surface.surface
            if isinstance(scene_or_surface, MirrorScene)
            else scene_or_surface
        )
        t = _check_number(thickness, "thickness", low=0.0, low_inclusive=False)
    else:
        raise ValueError(
            "`scene_or_surface` must be a LensScene, a MirrorScene or a HeightField, "
            f"got {type(scene_or_surface).__name__}"
        )
    heights = np.asarray(surface.heights)
    field = HeightField(
        jnp.asarray(heights), np.asarray(surface.extent, dtype=float), surface.boundary
    )
    return field, t


def _check_samples(samples, surface: HeightField, factor: int) -> tuple[int, int]:
    """`samples` checked, or by default `factor` points per height sample (plus one),
    fewer (2, then 1) where that grid would have over `MAX_SAMPLES` points (the report's
    4 per sample of a 1024^2 design: 4097^2)."""
    if samples is None:
        rows, cols = surface.shape
        for f in sorted({factor, min(factor, 2), 1}, reverse=True):
            if (f * rows + 1) * (f * cols + 1) <= MAX_SAMPLES:
                return f * rows + 1, f * cols + 1
        raise ValueError(
            f"`samples`: the default grid {(rows + 1, cols + 1)} (one per height sample) "
            f"has over {MAX_SAMPLES} points; pass a smaller `samples`"
        )
    return check_shape(samples, "samples", 2, max_size=MAX_SAMPLES)


# --------------------------------------------------------------------------- sampling


def _node_grid(surface: HeightField, samples: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """Node coordinates (metres, world) spanning the extent edge to edge."""
    x0, x1, y0, y1 = (float(v) for v in np.asarray(surface.extent))
    return np.linspace(x0, x1, samples[1]), np.linspace(y0, y1, samples[0])


def _evaluate(surface: HeightField, xs, ys, *, curvature: bool) -> list[np.ndarray]:
    """`height_and_gradient` on the grid ``ys x xs``, in row blocks of a fixed shape."""
    dtype = surface.heights.dtype
    block = max(1, min(len(ys), _BLOCK_POINTS // len(xs)))
    parts: list[list[np.ndarray]] = []
    for start in range(0, len(ys), block):
        rows = ys[start : start + block]
        n = len(rows)
        if n < block:  # pad to the block's shape: one compilation for all blocks
            rows = np.concatenate([rows, np.full(block - n, rows[-1])])
        gx, gy = np.meshgrid(xs, rows)
        out = _evaluate_jit(
            surface,
            jnp.asarray(gx, dtype=dtype),
            jnp.asarray(gy, dtype=dtype),
            curvature=curvature,
        )
        parts.append([np.asarray(t, dtype=float)[:n] for t in out])
    return [np.concatenate(terms, axis=0) for terms in zip(*parts, strict=True)]


def _top_mm(surface: HeightField, thickness: float, samples) -> tuple[np.ndarray, float, float]:
    samples = _check_samples(samples, surface, 2)
    xs, ys = _node_grid(surface, samples)
    (h,) = _evaluate(surface, xs, ys, curvature=False)[:1]
    z = (thickness + h) * _MM
    if not float(z.min()) > 0.0:
        raise ValueError(
            f"`scene_or_surface`: the top surface dips to {float(z.min()):.6g} mm at or below "
            "the bottom face (thickness + H(x, y) <= 0)"
        )
    return z, (xs[-1] - xs[0]) * _MM, (ys[-1] - ys[0]) * _MM


def lens_height_map(scene_or_surface, thickness=None, *, samples=None) -> np.ndarray:
    """The lens's top surface, sampled on a grid of vertices over the aperture.

    **Arguments:**

    - `scene_or_surface`: a `LensScene` (its `thickness` is used) or a `HeightField`.
    - `thickness`: metres from the bottom face to the rest plane of the top surface (> 0);
      required with a `HeightField`, must be None with a `LensScene`.
    - `samples`: ``(rows, cols)`` of the grid (two ints, each >= 2, at most
      `MAX_SAMPLES` points); default ``(2 rows + 1, 2 cols + 1)`` of
      ``surface.heights``, so that the grid holds every sample's centre and every pixel
      edge.

    **Returns:** float64 array of shape ``samples``, millimetres: ``z = thickness + H``
    of the top surface above the flat bottom. Entry ``[i, j]`` lies at
    ``x = j * width / (cols - 1)``, ``y = i * height / (rows - 1)`` mm from the aperture's
    corner ``(x_min, y_min)``: the first and last rows and columns lie on the aperture's
    edges.
    """
    surface, t = _lens(scene_or_surface, thickness)
    return _top_mm(surface, t, samples)[0]


def _outline(scene_or_surface) -> str | tuple:
    if isinstance(scene_or_surface, (LensScene, MirrorScene)):
        return scene_or_surface.outline
    return "rectangle"
