"""Where a design's screen stands and what the flat element puts on it, in NumPy (no
compilation): the screen's pose from the `Screen` (`screen_pose`), the flat element's
footprint, flux and orientation on it (`flat_footprint`), and the check that a screen
does not stand in the light on its way to the element (`check_beam_clear`).

The central ray leaves the light towards the centre of the blank's top (a lens) or face
(a mirror). Through a flat lens (a parallel slab) it leaves in its own direction, shifted
by its path in the glass; off a flat mirror it leaves reflected, ``(d_x, d_y, -d_z)``.
A posed screen's centre lies `Screen.distance` along it from where it leaves the element.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene.scene import DirectionalLight, emission
from ..scene.screen_pose import ScreenPose
from .problem import DesignProblem, Lens

# how far (degrees) the image of the blank's x axis may turn away from the screen's
# s axis (or its reverse): the transport maps the blank's grid onto the screen's
_MAX_TURN_DEG = 5.0


def _rays_in(problem: DesignProblem, px: np.ndarray, py: np.ndarray):
    """Unit directions ``(..., 3)`` of the light at rest-plane points and their flux
    density (1, or ``I |d_z| / r^2`` for a point light)."""
    light, top = problem.light, problem.top
    if isinstance(light, DirectionalLight):
        d = np.asarray(light.direction, float)
        d = np.broadcast_to(d / np.linalg.norm(d), px.shape + (3,))
        return d, np.ones_like(px)
    offset = np.stack([px, py, np.full_like(px, top)], axis=-1) - np.asarray(light.position, float)
    r2 = np.sum(offset**2, axis=-1)
    d = offset / np.sqrt(r2)[..., None]
    density = float(np.asarray(light.intensity)) * np.abs(d[..., 2]) / r2
    return d, density * emission(light, d[..., 2])


def _leave(problem: DesignProblem, px, py, d):
    """Where rays of directions `d` through rest-plane points leave the flat element, and
    their directions then: ``(points (..., 3), directions (..., 3))``."""
    element = problem.element
    if isinstance(element, Lens):
        cos_in = -d[..., 2]
        eta = 1.0 / element.ior
        cos_t = np.sqrt(1.0 - eta**2 * (1.0 - cos_in**2))
        run = element.thickness / cos_t  # the refracted path's length in the glass
        points = np.stack(
            [
                px + run * eta * d[..., 0],
                py + run * eta * d[..., 1],
                np.full_like(px, problem.screen.distance),
            ],
            axis=-1,
        )
        return points, d
    return np.stack([px, py, np.zeros_like(px)], axis=-1), d * np.array([1.0, 1.0, -1.0])


def screen_pose(problem: DesignProblem) -> ScreenPose | None:
    """The pose of `problem`'s screen (`None`: the ground ``z = 0`` under a lens)."""
    if not problem.posed:
        return None
    zero = np.zeros(())
    d, _ = _rays_in(problem, zero, zero)
    point, out = _leave(problem, zero, zero, d)
    screen = problem.screen
    centre = point + screen.distance * out
    normal = -out if screen.normal in (None, "beam") else np.asarray(screen.normal)
    if not float(np.dot(normal, out)) < -1e-6:
        raise ValueError(
            f"`screen`: its normal {np.round(normal, 4).tolist()} does not face the beam that "
            f"leaves the element (direction {np.round(out, 4).tolist()})"
        )
    try:
        pose = ScreenPose(centre, normal, screen.up)
    except ValueError as err:
        raise ValueError(f"`screen`: {err}") from err
    if isinstance(problem.element, Lens) and not centre[2] < problem.screen.distance:
        raise ValueError("`screen`: a lens's screen must lie below its bottom face")
    if not isinstance(problem.element, Lens) and not centre[2] > 0.0:
        raise ValueError("`screen`: a mirror's screen must stand in front of it (z > 0)")
    return pose


def _land(pose: ScreenPose, points: np.ndarray, directions: np.ndarray):
    """`ScreenPose.land` in NumPy: ``(s, t, reached)``."""
    n, c = np.asarray(pose.normal, float), np.asarray(pose.centre, float)
    up = np.asarray(pose.up, float)
    right = np.cross(up, n)
    towards = directions @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        run = ((c - points) @ n) / towards
    reached = (towards < 0) & (run > 0)
    q = points + np.where(reached, run, 0.0)[..., None] * directions - c
    return q @ right, q @ up, reached


def flat_footprint(problem: DesignProblem, pose: ScreenPose):
    """The flat element on a posed screen: the footprint ``(s_min, s_max, t_min, t_max)``
    of the aperture's light, the flux through the aperture (the rectangle's: the
    outline's coverage is applied by the caller), and whether the screen's ``s`` and
    ``t`` axes run against the blank's ``x`` and ``y`` (a mirror reverses one).

    Refuses (naming `screen`) a pose whose axes are turned against the blank's image by
    more than `_MAX_TURN_DEG` (the transport maps grid onto grid), or that misses part
    of the light."""
    x0, x1, y0, y1 = problem.outline.extent
    n = 64
    xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
    ys = y0 + (np.arange(n) + 0.5) * (y1 - y0) / n
    px, py = np.meshgrid(np.r_[x0, xs, x1], np.r_[y0, ys, y1])
    d, density = _rays_in(problem, px, py)
    points, out = _leave(problem, px, py, d)
    s, t, reached = _land(pose, points, out)
    if not reached.all():
        raise ValueError("`screen`: part of the flat element's light does not reach the screen")
    extent = np.array([s.min(), s.max(), t.min(), t.max()])
    mid_r, mid_c = n // 2, n // 2
    along_x = np.array([s[mid_r, -1] - s[mid_r, 0], t[mid_r, -1] - t[mid_r, 0]])
    along_y = np.array([s[-1, mid_c] - s[0, mid_c], t[-1, mid_c] - t[0, mid_c]])
    turn = max(
        math.degrees(math.atan2(abs(along_x[1]), abs(along_x[0]))),
        math.degrees(math.atan2(abs(along_y[0]), abs(along_y[1]))),
    )
    if turn > _MAX_TURN_DEG:
        raise ValueError(
            f"`screen`: its axes are turned {turn:.1f} degrees from the image of the blank's "
            f"axes (at most {_MAX_TURN_DEG:g}): choose `up` along the image of the blank's y "
            "axis"
        )
    flips = (bool(along_x[0] < 0), bool(along_y[1] < 0))
    flux = float(np.mean(density[1:-1, 1:-1]) * (x1 - x0) * (y1 - y0))
    return extent, flux, flips


def check_beam_clear(problem: DesignProblem, pose: ScreenPose, extent) -> None:
    """Refuse (naming `screen`) a screen that stands in the light on its way to the
    element: a 17 x 17 grid of its points, each tested for casting a shadow on the
    aperture (the line from the light through the point meets the element's rest plane
    inside the aperture, the point lying between the two)."""
    s0, s1, t0, t1 = extent
    ss, tt = np.meshgrid(np.linspace(s0, s1, 17), np.linspace(t0, t1, 17))
    right = np.cross(np.asarray(pose.up, float), np.asarray(pose.normal, float))
    points = (
        np.asarray(pose.centre, float)
        + ss[..., None] * right
        + tt[..., None] * np.asarray(pose.up, float)
    )
    top, light = problem.top, problem.light
    if isinstance(light, DirectionalLight):
        d = np.asarray(light.direction, float)
        d = np.broadcast_to(d / np.linalg.norm(d), points.shape)
        ahead = points[..., 2] > top
    else:
        d = points - np.asarray(light.position, float)
        ahead = (points[..., 2] > top) & (points[..., 2] < float(np.asarray(light.position)[2]))
    run = (top - points[..., 2]) / d[..., 2]
    hit = points + run[..., None] * d
    x0, x1, y0, y1 = problem.outline.extent
    inside = (hit[..., 0] >= x0) & (hit[..., 0] <= x1) & (hit[..., 1] >= y0) & (hit[..., 1] <= y1)
    if np.any(ahead & inside):
        raise ValueError(
            "`screen` stands in the light on its way to the element (it would shade it): "
            "move it further along the outgoing beam, or lean the light more"
        )


def flat_landing(problem: DesignProblem, pose: ScreenPose | None, px, py):
    """Where the flat element sends the light through rest-plane points ``(px, py)``,
    in the screen's frame (``x, y`` of the ground under a lens without a pose), and the
    light's flux density there: ``(s, t, density)``."""
    px, py = np.asarray(px, float), np.asarray(py, float)
    d, density = _rays_in(problem, px, py)
    points, out = _leave(problem, px, py, d)
    if pose is None:  # the ground z = 0
        run = -points[..., 2] / out[..., 2]
        return points[..., 0] + run * out[..., 0], points[..., 1] + run * out[..., 1], density
    s, t, _ = _land(pose, points, out)
    return s, t, density
