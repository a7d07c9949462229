"""A design's problem and strategies checked and turned into what the stages need
(`prepare` -> `Setup`): the screen, the target scaled to the lens's flux, the weak-lens
constant, the heights grids; and the checks that refuse, before anything is compiled, a
design that cannot run (a bad target or mask, more memory than the machine has).
"""

from __future__ import annotations

import os
import time

import jax.numpy as jnp
import numpy as np

from .._checks import (
    check_int,
    check_number,
    check_photon_work,
    check_real_array,
    check_shape,
)
from ..scene.scene import (
    DirectionalLight,
    HeightField,
    LensScene,
    PlaneReceiver,
    PointLight,
    emission,
)
from .design_setup import Setup
from .image_refine import ImageRefinement, refine_memory
from .lens_model import aperture_coverage
from .numerics import area_average, check_irradiance, neumann_poisson
from .poisson_levels import PoissonLevels
from .problem import DesignProblem, Lens, _length
from .screen_geometry import check_beam_clear, flat_footprint, screen_pose
from .source_blur import deconvolve, source_kernel
from .transport import MAX_PIXELS
from .transport_start import TransportStart


def _check_target(target) -> np.ndarray:
    t = check_real_array(target, "target")
    if (t.shape[0] * t.shape[1] if t.ndim >= 2 else t.size) > MAX_PIXELS:
        raise ValueError(f"`target` {t.shape} has over {MAX_PIXELS} pixels (4096^2)")
    t = t.astype(float)
    if t.ndim == 3 and t.shape[-1] in (3, 4):
        t = t[..., :3] @ np.array([0.2126, 0.7152, 0.0722])  # luminance of an RGB image
    if t.ndim != 2:
        raise ValueError(f"`target` must be a 2-D image (rows, cols), got shape {t.shape}")
    if min(t.shape) < 4:
        raise ValueError(f"`target` needs at least 4x4 pixels, got shape {t.shape}")
    return check_irradiance(t, "there is nothing to design for")


def check_mask(mask, shape) -> np.ndarray:
    if mask is None:
        return np.ones(shape, bool)
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise ValueError(f"`mask` must have the target's shape {tuple(shape)}, got {m.shape}")
    if m.dtype != bool:
        if not np.issubdtype(m.dtype, np.number) or not np.all(np.isin(m, (0, 1))):
            raise ValueError("`mask` must be boolean (or 0/1)")
        m = m.astype(bool)
    if not m.any():
        raise ValueError("`mask` is all False: no pixel may receive light")
    return m


def _vertical(light: DirectionalLight) -> bool:
    d = np.asarray(light.direction, dtype=float)
    return bool(abs(d[0]) + abs(d[1]) == 0.0)


def _flat_lens(light, aperture, thickness: float, screen_distance: float, ior: float):
    """The flat lens (a parallel slab) in NumPy: where the aperture's corners land on the
    screen, ``(x_min, x_max, y_min, y_max)``, and the flux through the aperture (the
    density `lens_photons` gives, integrated over a 64 x 64 midpoint grid).

    A ray leaves a parallel slab in its incoming direction, shifted by its refracted
    path through the glass; no compilation is needed for this."""
    x0, x1, y0, y1 = aperture
    top = screen_distance + thickness
    n = 64
    xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
    ys = y0 + (np.arange(n) + 0.5) * (y1 - y0) / n
    px, py = np.meshgrid(np.r_[x0, xs, x1], np.r_[y0, ys, y1])
    if isinstance(light, DirectionalLight):
        d = np.asarray(light.direction, float)
        d = np.broadcast_to(d / np.linalg.norm(d), px.shape + (3,))
        density = np.ones_like(px)
    else:
        offset = np.stack([px, py, np.full_like(px, top)], axis=-1) - np.asarray(
            light.position, float
        )
        r2 = np.sum(offset**2, axis=-1)
        d = offset / np.sqrt(r2)[..., None]
        density = float(light.intensity) * np.abs(d[..., 2]) / r2 * emission(light, d[..., 2])
    cos_in = -d[..., 2]
    if np.any(cos_in <= 0):
        raise ValueError("`light` does not reach the screen through the flat lens")
    eta = 1.0 / ior
    cos_t = np.sqrt(1.0 - eta**2 * (1.0 - cos_in**2))
    inside = eta * d[..., :2]  # the refracted direction's x, y; its z is -cos_t
    lx = px + thickness * inside[..., 0] / cos_t + screen_distance * d[..., 0] / cos_in
    ly = py + thickness * inside[..., 1] / cos_t + screen_distance * d[..., 1] / cos_in
    corners_x = lx[[0, 0, -1, -1], [0, -1, 0, -1]]
    corners_y = ly[[0, 0, -1, -1], [0, -1, 0, -1]]
    extent = np.array([corners_x.min(), corners_x.max(), corners_y.min(), corners_y.max()])
    flux = float(np.mean(density[1:-1, 1:-1]) * (x1 - x0) * (y1 - y0))
    return extent, flux


# bytes per height sample of the finest level (measured: peak memory of one Poisson step,
# 0.83 GB at 256^2 heights and 1.08 GB at 512^2: 1.3 kB a sample), and the fixed part
_BYTES_PER_SAMPLE, _BYTES_FIXED = 1300, 1 << 30
# a machine that does not say how much memory it has is taken to have this (bytes)
_UNKNOWN_MEMORY = 8 << 30


def _physical_memory() -> int | None:
    """This machine's memory in bytes (None where the platform does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def default_memory_limit() -> int:
    """A design's `memory_limit` by default: half of this machine's memory (bytes; 4 GiB
    where the platform does not say). More would swap, or be killed after minutes of
    work."""
    physical = _physical_memory()
    return (physical or _UNKNOWN_MEMORY) // 2


def check_design_memory_limit(memory_limit) -> int:
    """`memory_limit` of a design (bytes; ``None``: `default_memory_limit`), checked: at
    least the fixed part of a design's memory (`_BYTES_FIXED`, 1 GiB)."""
    if memory_limit is None:
        return default_memory_limit()
    limit = check_int(memory_limit, "memory_limit", 1)
    if limit < _BYTES_FIXED:
        raise ValueError(
            f"`memory_limit` {limit} bytes: a design needs at least {_BYTES_FIXED} bytes "
            "(1 GiB: the compiled solvers and their buffers)"
        )
    return limit


def design_memory(shape, oversample: int, extra: int) -> int:
    """The estimated peak memory of a design (bytes): the (largest) heights grid `shape`
    times `oversample`^2 photon cells at `_BYTES_PER_SAMPLE` each, `extra` bytes (the
    image refinement's rasteriser budget), and the fixed part. The predicted caustic is
    traced in bands within the limit and is not counted."""
    return _BYTES_FIXED + extra + _BYTES_PER_SAMPLE * shape[0] * shape[1] * oversample**2


def _check_design_memory(shape, oversample: int, extra: int, memory_limit: int) -> None:
    """Refuse, before anything is compiled, a design whose estimated memory
    (`design_memory`) exceeds `memory_limit` (it would swap or be killed after minutes
    of work), naming the estimate, the limit and the knobs that lower it."""
    estimate = design_memory(shape, oversample, extra)
    if estimate <= memory_limit:
        return
    grid = estimate - _BYTES_FIXED - extra
    knobs = "`levels` or `heights_shape`" + (" or `oversample`" if oversample > 1 else "")
    knobs += " (the grid follows the target's size by default)"
    raise ValueError(
        f"the design needs about {estimate / 2**30:.1f} GiB (heights grid {tuple(shape)}: "
        f"{grid / 2**30:.1f} GiB at {_BYTES_PER_SAMPLE} bytes a sample), over `memory_limit` "
        f"({memory_limit / 2**30:.1f} GiB; by default half of this machine's memory): lower "
        f"{knobs}, or raise `memory_limit`"
    )


# the predicted caustic's photons per side by default, at most (unless that is under two
# a pixel side). Measured on the lettering at 1024 pixels (1024^2 heights), the same
# design predicted with 4097^2 photons and 2049^2: relative L2 0.0859 and 0.0853 against
# 0.0859 for its height map traced by `reference.trace_lens_triangles`, in 104 s and 24 s
PREDICT_PHOTONS_MAX = 2049


def predict_photons_default(target_shape, refined: int | None = None) -> int:
    """The predicted caustic's photons per side by default: 4 per pixel side, at most
    `PREDICT_PHOTONS_MAX` but at least 2 per pixel side (a 1024-pixel target: 2049;
    traced in bands when they do not fit in `memory_limit` at once). Where that cap
    makes it the image refinement's own photon grid (`refined` per side), 4 per pixel
    side: the heights were fitted to that grid's image, which flatters them (the camera
    at 1024 pixels, refined on 2049^2 photons: predicted 0.031 on them, 0.034 on
    4097^2, and its height map traced by the reference 0.034)."""
    side = max(target_shape)
    n = min(4 * side + 1, max(PREDICT_PHOTONS_MAX, 2 * side + 1))
    return 4 * side + 1 if n == refined else n


def _check_initial(initial) -> None:
    start_heights = np.asarray(initial)
    if start_heights.ndim != 2 or min(start_heights.shape) < 2:
        raise ValueError(f"`initial` must be (rows, cols) heights, got {start_heights.shape}")
    real = np.issubdtype(start_heights.dtype, np.floating) or np.issubdtype(
        start_heights.dtype, np.integer
    )
    if not real:
        raise ValueError(f"`initial` must hold real numbers, got {start_heights.dtype}")
    if not np.all(np.isfinite(start_heights)):
        raise ValueError("`initial` contains NaN or infinite heights")


def prepare(
    problem: DesignProblem,
    target,
    start: TransportStart | PoissonLevels,
    finish: ImageRefinement | None,
    *,
    mask=None,
    heights_shape=None,
    max_relief=None,
    predict_photons=None,
    warn_error=0.15,
    initial=None,
    memory_limit=None,
) -> Setup:
    """Check a design (`ValueError` naming the argument) and compute what the stages
    need: the screen, the scaled target, the weak-lens constant, the grids."""
    if not isinstance(problem, DesignProblem):
        raise ValueError(f"`problem` must be a DesignProblem, got {type(problem).__name__}")
    if not isinstance(start, (TransportStart, PoissonLevels)):
        raise ValueError(
            f"`start` must be a TransportStart or PoissonLevels, got {type(start).__name__}"
        )
    if finish is not None and not isinstance(finish, ImageRefinement):
        raise ValueError(f"`finish` must be an ImageRefinement or None, got {finish!r}")
    width, height = problem.outline.width, problem.outline.height
    thickness = problem.element.thickness
    screen_distance, light = problem.screen.distance, problem.light
    t = _check_target(target)
    m = check_mask(mask, t.shape)
    if not np.any(t[m] > 0):
        raise ValueError("`target` is zero everywhere inside `mask`: there is no light to place")
    if predict_photons is not None:
        predict_photons = check_int(predict_photons, "predict_photons", 2)
        check_photon_work(predict_photons**2, 1, "predict_photons")
    memory_limit = check_design_memory_limit(memory_limit)
    if initial is not None:
        _check_initial(initial)
    if max_relief is not None:
        max_relief = _length(max_relief, "max_relief")
    warn_error = check_number(warn_error, "warn_error", low=0.0, low_open=True)
    if isinstance(start, PoissonLevels) and problem.posed:
        raise ValueError(
            "`start`: the Poisson levels need the ground screen under a lens; design a "
            "mirror or a posed screen with the TransportStart"
        )
    if isinstance(start, PoissonLevels) and problem.outline.lens_outline != "rectangle":
        raise ValueError(
            "`start`: the Poisson levels need light over the whole rectangle (their "
            "residual takes the log of each cell's flux); design a "
            f"{type(problem.outline).__name__} outline with the TransportStart"
        )
    if isinstance(start, TransportStart):
        shapes = [start.shape(t.shape, width, height)]
    else:
        shapes = start.shapes(t.shape, width, height)
    if heights_shape is not None:
        shapes[-1] = check_shape(heights_shape, "heights_shape", 4)
    # the image refinement adds its rasteriser budget
    extra = refine_memory(memory_limit) if finish is not None else 0
    oversample = start.oversample
    largest = max(shapes, key=lambda s: s[0] * s[1])
    _check_design_memory(largest, oversample, extra, memory_limit)
    aperture = problem.outline.extent
    dtype = jnp.result_type(float)
    pose = screen_pose(problem)
    coverage = float(np.mean(aperture_coverage(problem.outline.lens_outline, aperture, (64, 64))))
    flips = (False, False)
    if isinstance(problem.element, Lens):
        ior = problem.element.ior
        LensScene(  # checks the light against the lens (a point light inside it, ...)
            HeightField(np.zeros((4, 4)), aperture, "clamp"),
            light,
            PlaneReceiver(np.array([-1.0, 1.0, -1.0, 1.0]), t.shape),
            thickness,
            screen_distance,
            ior=ior,
            outline=problem.outline.lens_outline,
            screen_pose=pose,
        )
    if pose is None:
        footprint, flat_flux = _flat_lens(light, aperture, thickness, screen_distance, ior)
    else:
        footprint, flat_flux, flips = flat_footprint(problem, pose)
    flat_flux *= coverage
    given = problem.screen.extent
    screen = footprint if given is None else np.asarray(given, float)
    if pose is not None:
        check_beam_clear(problem, pose, screen)
    receiver = PlaneReceiver(screen, t.shape)

    # the target: unit mean over the screen, masked, plus the floor, scaled to the flux
    floor = start.floor
    tm = np.where(m, t, 0.0)
    tm = tm / tm.mean()
    goal = (tm + floor) / (1.0 + floor)
    pixel_area = (screen[1] - screen[0]) * (screen[3] - screen[2]) / t.size
    flux_scale = flat_flux / (goal.sum() * pixel_area)
    # an extended source blurs the caustic: the transport aims at the target deconvolved
    kernel, seen = source_kernel(problem, pose, screen, t.shape), None
    if kernel is not None:
        sharp = np.maximum(deconvolve(goal, kernel), floor / (1.0 + floor))  # the floor kept
        seen, goal = goal, sharp * (goal.mean() / sharp.mean())

    vertical = isinstance(light, DirectionalLight) and _vertical(light)
    if isinstance(problem.element, Lens):
        weak = (ior - 1.0) * (screen_distance + thickness / ior)
    else:  # a mirror turns a ray by twice its slope
        weak = 2.0 * screen_distance
    if isinstance(light, PointLight):  # a diverging beam: the screen is magnified
        lz = float(np.asarray(light.position)[2])
        below = lz - screen_distance - thickness if isinstance(problem.element, Lens) else lz
        weak *= (lz) / max(below, 1e-12)

    # ------------------------------------------------------------ initial guess
    t0 = time.perf_counter()
    rows0, cols0 = shapes[0]
    goal0 = area_average(goal, (rows0, cols0))
    dx0, dy0 = width / cols0, height / rows0
    # the weak-lens estimate of the relief (black regions counted at 1% of the mean)
    u = jnp.asarray(-np.log(np.maximum(goal0, 1e-2)), dtype)
    h0 = np.asarray(neumann_poisson(u, dx0, dy0)) / weak
    relief0 = float(h0.max() - h0.min())
    if isinstance(start, PoissonLevels) and relief0 >= thickness:
        raise ValueError(
            f"`thickness` {thickness} m is too thin: the weak-lens estimate of the relief is "
            f"{relief0:.4g} m, so the surface would dip through the bottom face"
        )
    timings = {"initial_guess": time.perf_counter() - t0}
    return Setup(
        problem=problem,
        start=start,
        finish=finish,
        target_shape=tuple(t.shape),
        shapes=shapes,
        aperture=aperture,
        screen=screen,
        receiver=receiver,
        goal=goal,
        goal0=goal0,
        flux_scale=flux_scale,
        vertical=vertical,
        weak=weak,
        predict_photons=predict_photons,
        max_relief=max_relief,
        initial=initial,
        timings=timings,
        memory_limit=memory_limit,
        warn_error=float(warn_error),
        pose=pose,
        flips=flips,
        kernel=kernel,
        seen=seen,
    )
