"""What an extended source does to a design's caustic: its image on the screen (the blur
kernel, `source_kernel`), the target pre-compensated for it (`deconvolve`), and what it
allows. See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np
from scipy.signal import fftconvolve

from ..scene.scene import DirectionalLight, PointLight
from ..scene.sources import AreaLight, SunLight
from .screen_geometry import flat_landing

KERNEL_SAMPLES = 4096  # directions over the disc that draw the kernel
DECONVOLVE_ITERATIONS = 200  # Richardson-Lucy's (its regularisation: fewer, smoother)
# the target that even the best pre-compensation cannot bring within this of itself
# (relative L2, blurred by the source) asks for finer detail than the source gives
SOURCE_WARN = 0.05


def source_kernel(problem, pose, screen, shape) -> np.ndarray | None:
    """The image of `problem`'s light source on its screen, in pixels of the screen's
    grid (`screen`: its extent in the screen's frame, `shape`: ``(rows, cols)``):
    ``(k, k)``, ``k`` odd, summing to 1, rows along the screen's ``t``; None for a
    collimated or point light (no blur)."""
    light = problem.light
    make: type[DirectionalLight] | type[PointLight]
    if isinstance(light, SunLight):  # a disc of directions
        samples, weights = light.directions(KERNEL_SAMPLES)
        make, middle = DirectionalLight, np.asarray(light.direction, float)
    elif isinstance(light, AreaLight):  # a die: seen through a pinhole at the centre
        samples, weights = light.points(KERNEL_SAMPLES)
        make, middle = PointLight, np.asarray(light.position, float)
    else:
        return None
    zero = np.zeros(1)

    def landing(sample) -> np.ndarray:
        lit = _with_light(problem, make(sample))
        s, t, _ = flat_landing(lit, pose, zero, zero)
        return np.array([s[0], t[0]])

    offsets = np.array([landing(q) for q in samples]) - landing(middle)
    pixel = np.array(
        [(screen[1] - screen[0]) / shape[1], (screen[3] - screen[2]) / shape[0]], float
    )
    return _splat(offsets / pixel, weights)


def _with_light(problem, light):
    return eqx.tree_at(lambda p: p.light, problem, light)


def _splat(offsets: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weights at offsets ``(n, 2)`` (pixels, ``(s, t)``) splatted bilinearly onto a
    square odd grid centred on 0: ``[row (t), col (s)]``, summing to 1."""
    half = int(math.ceil(np.abs(offsets).max())) + 1
    size = 2 * half + 1
    kernel = np.zeros((size, size))
    x, y = offsets[:, 0] + half, offsets[:, 1] + half
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            np.add.at(kernel, (y0 + dy, x0 + dx), weights * wy * wx)
    return kernel / kernel.sum()


def blur_radius(kernel: np.ndarray) -> float:
    """The source's blur on the screen, pixels: the radius of the disc of the kernel's
    second moment (``sqrt(2 <r^2>)``: a uniform disc's radius)."""
    half = kernel.shape[0] // 2
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1]
    return float(np.sqrt(2.0 * np.sum(kernel * (xx**2 + yy**2))))


def blur(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """`image` ``(rows, cols)`` convolved with `kernel` (zero beyond the screen: light
    spread past its edge is lost), non-negative."""
    return np.maximum(fftconvolve(image, kernel, mode="same"), 0.0)


def deconvolve(goal: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """The non-negative image whose blur by `kernel` (light past the screen's edge lost)
    best matches `goal`: Richardson-Lucy, `DECONVOLVE_ITERATIONS`, at `goal`'s mean.

    Each update is divided by the kernel's share that falls on the screen (Bertero and
    Boccacci's boundary correction). `skimage.restoration.richardson_lucy` pads with
    zeros instead, and its updates stall near the edges, where the blur loses light off
    the screen (measured on the camera in Mitsuba's setting, 2.3-pixel blur: 0.109
    relative L2 after 80 iterations, the edges half as bright as the target; this one
    0.075 after 80, 0.069 after 200)."""
    flipped = kernel[::-1, ::-1]
    share = fftconvolve(np.ones_like(goal), flipped, mode="same")
    sharp = np.full_like(goal, goal.mean(), dtype=float)
    for _ in range(DECONVOLVE_ITERATIONS):
        seen = np.maximum(fftconvolve(sharp, kernel, mode="same"), 1e-12)
        sharp = np.maximum(sharp * fftconvolve(goal / seen, flipped, mode="same") / share, 0.0)
    return sharp * (goal.mean() / sharp.mean())


def source_limit(setup) -> tuple[float, str | None]:
    """An extended source's blur on `setup`'s screen (pixels) and, when the target asks
    for finer detail than it allows, the warning saying so: the deconvolved goal, blurred
    again, is as near as any design can come (`SOURCE_WARN`)."""
    radius = blur_radius(setup.kernel)
    seen = setup.seen / setup.seen.mean()
    best = blur(setup.goal, setup.kernel)
    best = best / best.mean()
    floor = float(np.linalg.norm(best - seen) / np.linalg.norm(seen))
    if floor <= SOURCE_WARN:
        return radius, None
    light = setup.light
    pixel_mm = 1000.0 * (setup.screen[1] - setup.screen[0]) / setup.target_shape[1]
    if isinstance(light, SunLight):
        what = f"a disc {2 * light.angular_radius_deg:.3g} degrees across"
    else:
        what = f"{light.shape} {1000 * light.size[0]:.3g} x {1000 * light.size[1]:.3g} mm"
    return radius, (
        f"design: the source ({what}) "
        f"blurs each point of the caustic into a disc {radius:.2g} pixels in radius on the "
        f"screen ({radius * pixel_mm:.2g} mm): the target's detail finer than about "
        f"{2 * radius:.2g} pixels cannot be shown, and even the best pre-compensation "
        f"stays {floor:.3f} (relative L2) from it. For a sharper picture: a shorter "
        "`screen_distance` (the blur grows with it), a larger lens for the same picture "
        "(its pixels grow, the blur does not), a smaller source, or a softer target"
    )
