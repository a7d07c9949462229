"""Photon tracing off a caustic mirror (`MirrorScene`), plain NumPy, float64.

The mirror's face is ``z = H(x, y)`` about its rest plane ``z = 0`` (the bicubic of
`_surface.py`, rotation included). A photon belongs to the mirror iff its line crosses
the rest plane inside the (rotated) extent, half-open, and inside the outline (as for
lenses, `_lens._in_aperture`). It meets the face at the first root along its whole line
(the lens's safe march and Newton); a hit outside the extent or the outline misses the
blank (the ray leans out past an edge lying below the rest plane: lost). Light that
comes in over a low edge from outside the aperture is not traced (a band ``|H(edge)|
tan(lean)`` wide along that edge). It reflects about the face's normal
(``d - 2 (d . n) n``), and lands on the screen's plane (``scene.screen_pose``: its
``(s, t)`` frame) if it reaches the screen's lit face ahead of it. Each photon carries its
rest-plane cell's area times 1 (directional light) or ``I |w_z| / r^2`` (point light),
times the face's reflectance.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._lens import (
    _CHUNK,
    _emit_lens,
    _grid_shape,
    _image,
    _in_aperture,
    _Light,
    _rays_to_surface,
    _read_outline,
)
from ._optics import _check_bool, _check_points, _Pose, _Receiver, _rng, chunk_photons
from ._surface import _Surface


@dataclasses.dataclass(frozen=True)
class _Mirror:
    """A `MirrorScene` read into float64 NumPy values (duck typed, validated)."""

    surface: _Surface
    light: _Light
    receiver: _Receiver
    pose: _Pose
    reflectance: float
    outline: str | tuple


def _read_mirror(scene) -> _Mirror:
    try:
        surface, light, receiver, pose = (
            scene.surface,
            scene.light,
            scene.receiver,
            scene.screen_pose,
        )
        heights, extent, boundary = surface.heights, surface.extent, surface.boundary
    except AttributeError as err:
        raise ValueError(f"`scene` must be a MirrorScene-like object: {err}") from err
    if pose is None:
        raise ValueError("`scene.screen_pose` is needed: a mirror's screen faces its face")
    reflectance = float(np.asarray(getattr(scene, "reflectance", 1.0), dtype=np.float64))
    if not 0.0 < reflectance <= 1.0:
        raise ValueError(f"`scene.reflectance` must be in (0, 1], got {reflectance}")
    surf = _Surface.build(heights, extent, boundary, getattr(surface, "rotation", 0.0))
    mirror = _Mirror(
        surf,
        _Light.read(light),
        _Receiver.read(receiver),
        _Pose.read(pose),  # type: ignore[arg-type]
        reflectance,
        _read_outline(getattr(scene, "outline", "rectangle")),
    )
    if mirror.light.is_point:
        assert mirror.light.position is not None
        if not mirror.light.position[2] > float(surf.heights.max()):
            raise ValueError("the point light must lie above the mirror's face")
    return mirror


def _trace_mirror(mirror: _Mirror, xs: np.ndarray, ys: np.ndarray):
    """Trace rest-plane points off the mirror: the screen's ``(s, t)``, the flux per unit
    of rest-plane area (0 where lost) and whether each photon reached the screen's
    plane, each (N,)."""
    n = xs.shape[0]
    gs, gt, weight = np.zeros(n), np.zeros(n), np.zeros(n)
    reached = np.zeros(n, dtype=bool)
    for lo in range(0, n, _CHUNK):
        sel = lo + np.flatnonzero(
            _in_aperture(mirror.surface, xs[lo : lo + _CHUNK], ys[lo : lo + _CHUNK], mirror.outline)
        )
        if not sel.size:
            continue
        cx, cy = xs[sel], ys[sel]
        w, density, t, hx, hy = _rays_to_surface(mirror.surface, mirror.light, 0.0, cx, cy)
        p = np.stack([cx + t * w[0], cy + t * w[1], t * w[2]])
        normal = np.stack([-hx, -hy, np.ones_like(hx)]) / np.sqrt(1.0 + hx * hx + hy * hy)
        cos_i = np.sum(w * normal, axis=0)
        out = w - 2.0 * cos_i * normal
        s, t_, ok = mirror.pose.land(p, out)
        # a hit beyond the blank's edge misses the mirror
        ok &= (cos_i < 0.0) & _in_aperture(mirror.surface, p[0], p[1], mirror.outline)
        gs[sel], gt[sel] = np.where(ok, s, 0.0), np.where(ok, t_, 0.0)
        weight[sel] = np.where(ok, density * mirror.reflectance, 0.0)
        reached[sel] = ok
    return gs, gt, weight, reached


def trace_mirror_photons(scene, xs, ys) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trace photons off a `MirrorScene` from points ``(xs, ys)`` (N,) of its rest plane
    ``z = 0``. Returns the landing points in the screen's ``(s, t)`` frame ``(N, 2)``
    (0 where lost), the flux per unit of rest-plane area each carries ``(N,)`` and
    whether it reached the screen's plane ``(N,)``."""
    mirror = _read_mirror(scene)
    x, y = _check_points(xs, ys)
    s, t, weight, reached = _trace_mirror(mirror, x, y)
    return np.stack([s, t], axis=-1), weight, reached


def trace_mirror(
    scene,
    photons_per_axis=512,
    *,
    jitter: bool = False,
    seed=0,
    return_stats: bool = False,
    memory_limit: int | None = None,
):
    """Irradiance on the screen of a `MirrorScene` by forward photon tracing (ground
    truth): the aperture cut into a grid of equal cells as for lenses
    (`emit_lens_photons`), one photon per cell (at its centre, or jittered), traced
    exactly and binned into the receiver's pixels (in the screen's ``(s, t)`` frame).

    Arguments as `trace_lens`'s. Returns the image ``(rows, cols)``, float64:
    irradiance relative to the light's on a horizontal plane (directional light) or
    W/m^2 (point light); with `return_stats`, also ``{"emitted", "landed",
    "on_receiver"}`` (photon counts).
    """
    mirror = _read_mirror(scene)
    chunk = chunk_photons(memory_limit, _CHUNK)
    rows, cols = _grid_shape(photons_per_axis)
    rng = _rng(jitter, seed)
    return_stats = _check_bool(return_stats, "return_stats")
    rec = mirror.receiver
    flux = np.zeros((1, rec.shape[0] * rec.shape[1]))
    landed = on_receiver = 0
    total = rows * cols
    for lo in range(0, total, chunk):
        xs, ys, area = _emit_lens(mirror, rows, cols, lo, min(lo + chunk, total), rng)  # type: ignore[arg-type]
        s, t, weight, reached = _trace_mirror(mirror, xs, ys)
        f, m = rec.bin(s, t, weight * area)
        flux[0] += f
        on_receiver += m
        landed += int(np.count_nonzero(reached))
    image = _image(rec, flux, False)
    if not return_stats:
        return image
    return image, {"emitted": total, "landed": landed, "on_receiver": on_receiver}
