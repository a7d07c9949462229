"""Photon tracing through a caustic lens (`LensScene`), plain NumPy, float64.

The lens: top surface ``z = screen_distance + thickness + H(x, y)`` (the bicubic of `_surface.py`,
rotation included), flat bottom face ``z = screen_distance`` (an infinite plane), screen ``z = 0``.
A photon belongs to the lens iff its line crosses the top rest plane inside the
(rotated) extent, half-open, and inside the blank's outline (``scene.outline``: the
whole extent, or the ellipse inscribed in it). It hits the top surface at the first
root along its whole line (`intersect_surface`; `_intersect_rays` for a point light's per-photon
directions), refracts in (``eta = 1 / n``), goes straight to the bottom face, refracts
out (``eta = n``, total internal reflection loses it) and lands. Each photon carries its
rest-plane cell's area times 1 (directional light: irradiance relative to the light's
on a horizontal plane) or ``I |w_z| / r^2`` (point light: W/m^2), times both faces'
Fresnel transmittances when ``scene.fresnel``. See the package docstring.

Also holds what the mesh tracer (`_mesh.py`) shares with it: reading lights and
receivers, binning, refraction of per-photon directions, emission-grid arguments.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from ._optics import (
    MAX_EMITTED,
    MAX_PHOTONS,
    _check_bool,
    _check_count,
    _check_int,
    _check_points,
    _Pose,
    _Receiver,
    _rng,
    chunk_photons,
)
from ._surface import _EPS, _GRAZE, _Surface, intersect_surface

# Photons traced per vectorised batch: bounds the memory in use.
_CHUNK = 1 << 17

# Photon fates (codes of the internal status arrays).
LANDED = 0  # reached the plane z = 0 (on or off the receiver)
OUTSIDE = 1  # lens: the line does not cross the rest plane inside the aperture
TIR_TOP = 2  # lens: total internal reflection entering the top surface (index < 1 only)
NO_BOTTOM = 3  # lens: the refracted ray does not go down to the bottom face
TIR_BOTTOM = 4  # lens: total internal reflection at the flat bottom face


# --------------------------------------------------------------------------- shared parts


def _grid_shape(photons_per_axis, limit: int = MAX_PHOTONS) -> tuple[int, int]:
    """``n`` -> ``(n, n)``; ``(rows, cols)`` -> itself (integers >= 1, at most `limit`
    photons in all)."""
    if isinstance(photons_per_axis, numbers.Integral) and not isinstance(photons_per_axis, bool):
        n = _check_int(photons_per_axis, "photons_per_axis")
        shape = n, n
    else:
        try:
            rows, cols = photons_per_axis
        except (TypeError, ValueError) as err:
            raise ValueError(
                f"`photons_per_axis` must be an integer or a pair (rows, cols), got "
                f"{photons_per_axis!r}"
            ) from err
        shape = _check_int(rows, "photons_per_axis[0]"), _check_int(cols, "photons_per_axis[1]")
    _check_count(shape[0] * shape[1], limit, f"`photons_per_axis` {photons_per_axis!r}")
    return shape


def _cells(
    rows: int, cols: int, lo: int, hi: int, rng: np.random.Generator | None
) -> tuple[np.ndarray, np.ndarray]:
    """Fractional grid coordinates ``(j + fx, i + fy)`` of cells ``lo .. hi - 1`` of a
    ``rows x cols`` grid in row-major order (cell centres, or jittered inside the cell)."""
    k = np.arange(lo, hi)
    i, j = np.divmod(k, cols)
    if rng is None:
        return j + 0.5, i + 0.5
    return j + rng.random(k.size), i + rng.random(k.size)


@dataclasses.dataclass(frozen=True)
class _Light:
    """A directional light (unit `direction`) or a point light (`position`, `intensity`)."""

    direction: np.ndarray | None
    position: np.ndarray | None
    intensity: float
    # a point light that emits by Lambert's law facing down (``lambertian`` set: an
    # `AreaLight`'s points): its intensity towards unit ``w`` is ``intensity |w_z|``
    lambertian: bool = False

    @property
    def is_point(self) -> bool:
        return self.position is not None

    @classmethod
    def read(cls, light) -> _Light:
        if hasattr(light, "position"):
            p = np.asarray(light.position, dtype=np.float64)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise ValueError(f"`scene.light.position` must be 3 finite numbers, got {p!r}")
            intensity = float(np.asarray(getattr(light, "intensity", 1.0), dtype=np.float64))
            if not (math.isfinite(intensity) and intensity > 0.0):
                raise ValueError(f"`scene.light.intensity` must be positive, got {intensity}")
            return cls(None, p, intensity, bool(getattr(light, "lambertian", False)))
        try:
            d = np.asarray(light.direction, dtype=np.float64)
        except AttributeError as err:
            raise ValueError(
                "`scene.light` must have a `direction` (directional light) or a `position` "
                "(point light)"
            ) from err
        if d.shape != (3,) or not np.all(np.isfinite(d)):
            raise ValueError(f"`scene.light.direction` must be 3 finite numbers, got {d!r}")
        norm = float(np.linalg.norm(d))
        if not norm > 0.0 or not d[2] / norm < 0.0:
            raise ValueError(f"`scene.light.direction` must point down (z < 0), got {d.tolist()}")
        return cls(d / norm, None, 1.0)


def _read_iors(ior) -> tuple[tuple[float, ...], bool]:
    multichannel = np.ndim(ior) > 0
    iors = tuple(float(v) for v in np.atleast_1d(np.asarray(ior, dtype=np.float64)))
    if not iors or not all(math.isfinite(v) and v > 0.0 for v in iors):
        raise ValueError(f"`scene.ior` must be finite positive indices, got {ior!r}")
    return iors, multichannel


def _refract_rays(
    d: np.ndarray, n: np.ndarray, eta, fresnel: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refract unit directions `d` (3, N) at unit normals `n` (3, N) oriented against them
    (``d.n <= 0``), with ``eta = n_from / n_to`` (scalar or (N,)).

    Returns the unit refracted directions ``T = eta d + (eta cos_i - cos_t) n`` (3, N),
    the unpolarised transmittance ``1 - (Rs + Rp) / 2`` (1 if not `fresnel`; 0 under total
    internal reflection) and the total-internal-reflection mask (``sin^2 theta_t > 1``).
    """
    cos_i = -np.sum(d * n, axis=0)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    tir = sin2_t > 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    t = eta * d + (eta * cos_i - cos_t) * n
    t = t / np.linalg.norm(t, axis=0)
    if fresnel:
        with np.errstate(divide="ignore", invalid="ignore"):
            rs = ((eta * cos_i - cos_t) / (eta * cos_i + cos_t)) ** 2
            rp = ((cos_i - eta * cos_t) / (cos_i + eta * cos_t)) ** 2
            transmittance = 1.0 - 0.5 * (rs + rp)
        # 0/0 only at exact grazing incidence with eta == 1: nothing is transmitted there.
        transmittance = np.where(np.isfinite(transmittance), transmittance, 0.0)
    else:
        transmittance = np.ones_like(cos_i)
    return t, np.where(tir, 0.0, transmittance), tir


# --------------------------------------------------------------------------- the lens


@dataclasses.dataclass(frozen=True)
class _Lens:
    """A `LensScene` read into float64 NumPy values (duck typed, validated)."""

    surface: _Surface
    light: _Light
    receiver: _Receiver
    thickness: float
    screen_distance: float
    iors: tuple[float, ...]
    multichannel: bool
    fresnel: bool
    # "rectangle", "ellipse" (the one inscribed in the extent) or a polygon's vertices in
    # the extent's frame normalised to [-1, 1]^2
    outline: str | tuple = "rectangle"
    pose: _Pose | None = None  # the screen's pose; None: the ground z = 0

    @property
    def top(self) -> float:
        return self.screen_distance + self.thickness


def _positive(value, name: str) -> float:
    v = float(np.asarray(value, dtype=np.float64))
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"`scene.{name}` must be finite and positive, got {v}")
    return v


def _read_lens(scene) -> _Lens:
    try:
        surface, light, receiver = scene.surface, scene.light, scene.receiver
        heights, extent, boundary = surface.heights, surface.extent, surface.boundary
        thickness, screen_distance, ior, fresnel = (
            scene.thickness,
            scene.screen_distance,
            scene.ior,
            scene.fresnel,
        )
    except AttributeError as err:
        raise ValueError(f"`scene` must be a LensScene-like object: {err}") from err
    surf = _Surface.build(heights, extent, boundary, getattr(surface, "rotation", 0.0))
    lens = _Lens(
        surf,
        _Light.read(light),
        _Receiver.read(receiver),
        _positive(thickness, "thickness"),
        _positive(screen_distance, "screen_distance"),
        *_read_iors(ior),
        bool(fresnel),
        _read_outline(getattr(scene, "outline", "rectangle")),
        _Pose.read(getattr(scene, "screen_pose", None)),
    )
    if lens.thickness + float(surf.heights.min()) <= 0.0:
        raise ValueError(
            "`scene.surface` dips through the bottom face (thickness + min(heights) <= 0)"
        )
    if lens.light.is_point:
        assert lens.light.position is not None
        if not lens.light.position[2] > lens.top + float(surf.heights.max()):
            raise ValueError("the point light must lie above the top of the lens")
    return lens


def _read_outline(outline) -> str | tuple:
    if isinstance(outline, str):
        if outline not in ("rectangle", "ellipse"):
            raise ValueError(f"`scene.outline` must be 'rectangle' or 'ellipse', got {outline!r}")
        return outline
    v = np.asarray(outline, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.all(np.isfinite(v)):
        raise ValueError(f"`scene.outline` must be a name or (x, y) vertices, got {outline!r}")
    return tuple(map(tuple, v))


def _field_to_world(surf: _Surface, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points given in the field's own frame, in world coordinates (rotated by +rotation
    about the centre of the extent)."""
    if surf.rotation == 0.0:
        return u, v
    e = surf.extent
    cx, cy = 0.5 * (e[0] + e[1]), 0.5 * (e[2] + e[3])
    c, s = math.cos(surf.rotation), math.sin(surf.rotation)
    return cx + c * (u - cx) - s * (v - cy), cy + s * (u - cx) + c * (v - cy)


def _in_aperture(
    surf: _Surface, x: np.ndarray, y: np.ndarray, outline: str | tuple = "rectangle"
) -> np.ndarray:
    """Whether world points of the rest plane lie in the (rotated) extent, half-open, and
    inside the outline: the ellipse inscribed in it (rim included), or a polygon."""
    e = surf.extent
    if surf.rotation != 0.0:
        cx, cy = 0.5 * (e[0] + e[1]), 0.5 * (e[2] + e[3])
        x, y = surf.to_field(x - cx, y - cy)
        x, y = x + cx, y + cy
    inside = (x >= e[0]) & (x < e[1]) & (y >= e[2]) & (y < e[3])
    if outline == "rectangle":
        return inside
    ex = (x - 0.5 * (e[0] + e[1])) / (0.5 * (e[1] - e[0]))
    ey = (y - 0.5 * (e[2] + e[3])) / (0.5 * (e[3] - e[2]))
    if isinstance(outline, str):  # "ellipse", the only other name `_read_outline` takes
        return inside & (ex * ex + ey * ey <= 1.0)
    # a polygon: the crossing number of a ray towards +x (odd: inside)
    crossings = np.zeros(x.shape, dtype=bool)
    for (xa, ya), (xb, yb) in zip(outline, outline[1:] + outline[:1], strict=True):
        if ya == yb:
            continue
        straddles = (ya > ey) != (yb > ey)
        crossings ^= straddles & (ex < xa + (ey - ya) * ((xb - xa) / (yb - ya)))
    return inside & crossings


def _intersect_rays(
    surf: _Surface,
    wx: np.ndarray,
    wy: np.ndarray,
    wz: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`intersect_surface` for rays with their own unit directions ``(wx, wy, wz)``,
    ``wz < 0``: the first root of ``f(t) = t w_z - H(c + t w_xy)`` along the whole line
    ``(cx, cy, rest) + t w``, by the same provably safe march and safeguarded Newton.

    The per-ray bounds on ``|f'|`` and ``|f''|`` use the largest per-cell slope and
    curvature bounds of the whole field (at least as large as `intersect_surface`'s, so at
    least as safe; the steps are only shorter).
    """
    n = cx.shape[0]
    t_top = surf.h_hi / wz  # above the surface's upper bound
    t_bot = surf.h_lo / wz  # below its lower bound
    d_u, d_v = surf.to_field(wx, wy)
    rise = np.abs(d_u) * float(surf.bound_x.max()) + np.abs(d_v) * float(surf.bound_y.max())
    curv = (
        d_u * d_u * float(surf.bound_xx.max())
        + 2.0 * np.abs(d_u * d_v) * float(surf.bound_xy.max())
        + d_v * d_v * float(surf.bound_yy.max())
    )

    def f(t, idx):
        h, hx, hy = surf.evaluate(cx[idx] + t * wx[idx], cy[idx] + t * wy[idx])
        return t * wz[idx] - h, wz[idx] - (hx * wx[idx] + hy * wy[idx]), hx, hy

    a, b = t_top.copy(), t_bot.copy()
    x = np.clip(0.0, a, b)  # Newton's start for a monotone f: the rest plane
    march = np.flatnonzero(rise >= -wz)  # f may have several roots: march to the first
    if march.size:
        lipschitz = -wz + rise
        with np.errstate(divide="ignore"):
            floor = np.where(
                curv > 0.0, np.sqrt(8.0 * _GRAZE * (surf.h_hi - surf.h_lo) / curv), 0.0
            )
        idx = march
        ta = a[idx]
        fa, fpa, _, _ = f(ta, idx)
        touch = fa <= 0.0  # only by rounding: the surface touches the upper bound
        b[idx[touch]] = t_top[idx[touch]]
        idx, ta, fa, fpa = idx[~touch], ta[~touch], fa[~touch], fpa[~touch]
        for _ in range(1_000_000):
            if not idx.size:
                break
            with np.errstate(divide="ignore", invalid="ignore"):
                parabola = 2.0 * fa / (np.sqrt(fpa * fpa + 2.0 * curv[idx] * fa) - fpa)
            step = np.maximum(np.maximum(fa / lipschitz[idx], np.nan_to_num(parabola)), floor[idx])
            tn = np.minimum(ta + step, t_bot[idx])
            fn, fpn, _, _ = f(tn, idx)
            found = (fn <= 0.0) | (tn >= t_bot[idx])
            a[idx[found]] = ta[found]
            b[idx[found]] = tn[found]
            keep = ~found
            idx, ta, fa, fpa = idx[keep], tn[keep], fn[keep], fpn[keep]
        else:  # pragma: no cover
            raise RuntimeError("ray marching did not reach the surface")
        x[march] = a[march]

    # Safeguarded Newton on [a, b], f(a) > 0 >= f(b) (or a == b).
    scale = np.maximum(np.maximum(np.abs(t_top), np.abs(t_bot)), 1e-300)
    t_hit, gx_hit, gy_hit = np.empty(n), np.empty(n), np.empty(n)
    idx = np.arange(n)
    for _ in range(200):
        if not idx.size:
            break
        fx, fpx, hx, hy = f(x, idx)
        above = fx > 0.0
        a[idx] = np.where(above, x, a[idx])
        b[idx] = np.where(above, b[idx], x)
        aa, bb = a[idx], b[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = x - fx / fpx
        xn = np.where((xn > aa) & (xn < bb), xn, 0.5 * (aa + bb))
        tol = 4.0 * _EPS * np.maximum(np.abs(x), scale[idx])
        done = (fx == 0.0) | (np.abs(xn - x) <= tol) | (bb - aa <= tol)
        t_hit[idx[done]] = x[done]
        gx_hit[idx[done]] = hx[done]
        gy_hit[idx[done]] = hy[done]
        idx, x = idx[~done], xn[~done]
    else:  # pragma: no cover - bisection alone converges in far fewer iterations
        if idx.size:
            raise RuntimeError("ray/surface intersection did not converge")
    return t_hit, gx_hit, gy_hit


def _rays_to_surface(surf: _Surface, light: _Light, top: float, cx, cy):
    """The light's rays through rest-plane points ``(cx, cy, top)`` and where they meet
    the surface ``z = top + H``: unit directions ``w`` (3, N), the flux density (1, or
    ``I |w_z| / r^2`` for a point light), the distance ``t`` along ``w`` from the rest
    plane to the hit and the slopes ``(hx, hy)`` there."""
    if light.is_point:
        assert light.position is not None
        w = np.stack([cx - light.position[0], cy - light.position[1]])
        w = np.concatenate([w, np.full((1, cx.size), top - light.position[2])])
        r2 = np.sum(w * w, axis=0)
        w = w / np.sqrt(r2)
        density = light.intensity * np.abs(w[2]) / r2
        if light.lambertian:
            density = density * np.abs(w[2])
        t, hx, hy = _intersect_rays(surf, w[0], w[1], w[2], cx, cy)
    else:
        assert light.direction is not None
        w = np.repeat(light.direction[:, None], cx.size, axis=1)
        density = np.ones(cx.size)
        t, hx, hy = intersect_surface(surf, top, light.direction, cx, cy)
    return w, density, t, hx, hy


def _trace_lens(
    lens: _Lens, xs: np.ndarray, ys: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Trace rest-plane points through the lens, one channel per index.

    Returns landing x, y, the flux per unit of rest-plane area, and the status, each of
    shape (C, N) (landing points and weight 0 where the photon is lost).
    """
    n, c = xs.shape[0], len(lens.iors)
    gx, gy, weight = np.zeros((c, n)), np.zeros((c, n)), np.zeros((c, n))
    status = np.full((c, n), OUTSIDE, dtype=np.int8)
    surf, light, top, screen_distance = lens.surface, lens.light, lens.top, lens.screen_distance
    up = np.array([[0.0], [0.0], [1.0]])
    for lo in range(0, n, _CHUNK):
        sel = lo + np.flatnonzero(
            _in_aperture(surf, xs[lo : lo + _CHUNK], ys[lo : lo + _CHUNK], lens.outline)
        )
        if not sel.size:
            continue
        cx, cy = xs[sel], ys[sel]
        w, density, t, hx, hy = _rays_to_surface(surf, light, top, cx, cy)
        p = np.stack([cx + t * w[0], cy + t * w[1], top + t * w[2]])
        normal = np.stack([-hx, -hy, np.ones_like(hx)]) / np.sqrt(1.0 + hx * hx + hy * hy)
        for k, ior in enumerate(lens.iors):
            d1, tr1, tir1 = _refract_rays(w, normal, 1.0 / ior, lens.fresnel)
            down = ~tir1 & (d1[2] < 0.0) & (p[2] > screen_distance)
            with np.errstate(divide="ignore", invalid="ignore"):
                bottom = p + np.where(down, (screen_distance - p[2]) / d1[2], 0.0) * d1
            d2, tr2, tir2 = _refract_rays(d1, up, ior, lens.fresnel)
            ok = down & ~tir2
            if lens.pose is None:
                with np.errstate(divide="ignore", invalid="ignore"):
                    s = np.where(ok, -screen_distance / d2[2], 0.0)
                lx, ly = bottom[0] + s * d2[0], bottom[1] + s * d2[1]
            else:  # (a ray that misses the screen's lit face counts as landed, off it)
                lx, ly, reached = lens.pose.land(bottom, d2)
                ok &= reached
            gx[k, sel] = np.where(ok, lx, 0.0)
            gy[k, sel] = np.where(ok, ly, 0.0)
            weight[k, sel] = np.where(ok, density * tr1 * tr2, 0.0)
            st = np.full(sel.size, LANDED, dtype=np.int8)
            st[~down] = NO_BOTTOM
            st[tir1] = TIR_TOP
            st[down & tir2] = TIR_BOTTOM
            status[k, sel] = st
    return gx, gy, weight, status


def trace_lens_photons(scene, xs, ys) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trace photons through a `LensScene` from points of the top rest plane.

    Photon ``k`` travels along the line of the light (a directional light's direction, or
    from a point light's position) through ``(xs[k], ys[k], screen_distance + thickness)``; it
    belongs to the lens iff that point lies in the aperture (``surface.extent``, rotated
    with the field). It hits the top surface at the first root along the whole line,
    refracts into the glass, goes to the bottom face ``z = screen_distance``, refracts out (total
    internal reflection loses it) and lands on ``z = 0``.

    **Arguments:**

    - `scene`: a `LensScene`, read by duck typing (see the module docstring).
    - `xs`, `ys`: array-likes of shape ``(N,)``: points of the rest plane
      ``z = screen_distance + thickness``, metres.

    **Returns:** ``(landing_xy, weight, alive)``:

    - `landing_xy`: `np.ndarray` of shape ``(C, N, 2)``, landing points on ``z = 0`` (0
      where not alive), ``C = len(scene.iors)``.
    - `weight`: `np.ndarray` of shape ``(C, N)``, the flux per unit of (horizontal)
      rest-plane area the photon's bundle carries to the screen: the product of the
      Fresnel transmittances of both faces (1 without Fresnel) for a directional light
      (relative to the light's irradiance on a horizontal plane), times ``I |w_z| / r^2``
      for a point light (``w`` the unit ray direction, ``r`` the distance from the light
      to the rest-plane point); 0 where not alive. A photon standing for rest-plane area
      ``A`` adds ``weight * A`` to the flux of the pixel it lands in.
    - `alive`: `np.ndarray` of bools, shape ``(C, N)``, False outside the aperture, under
      total internal reflection, or when the ray in the glass does not go down to the
      bottom face.
    """
    lens = _read_lens(scene)
    x, y = _check_points(xs, ys)
    gx, gy, weight, status = _trace_lens(lens, x, y)
    return np.stack([gx, gy], axis=-1), weight, status == LANDED


def emit_lens_photons(
    scene, photons_per_axis=512, *, jitter: bool = False, seed=0
) -> tuple[np.ndarray, np.ndarray, float]:
    """The rest-plane start points `trace_lens` uses.

    The aperture (``surface.extent``, in the field's own frame for a rotated field) is
    cut into a ``rows x cols`` grid of equal cells, one photon per cell at its centre (or
    uniformly jittered inside it); points are then rotated with the field into world
    coordinates.

    **Returns:** ``(xs, ys, area)``:

    - `xs`, `ys`: `np.ndarray` of shape ``(rows * cols,)``, start points on the rest
      plane, row-major over the grid.
    - `area`: a float, the rest-plane area of one cell, m^2.
    """
    lens = _read_lens(scene)
    rows, cols = _grid_shape(photons_per_axis, MAX_EMITTED)
    xs, ys, area = _emit_lens(lens, rows, cols, 0, rows * cols, _rng(jitter, seed))
    return xs, ys, area


def _emit_lens(
    lens: _Lens, rows: int, cols: int, lo: int, hi: int, rng
) -> tuple[np.ndarray, np.ndarray, float]:
    e = lens.surface.extent
    hx, hy = (e[1] - e[0]) / cols, (e[3] - e[2]) / rows
    fx, fy = _cells(rows, cols, lo, hi, rng)
    xs, ys = _field_to_world(lens.surface, e[0] + fx * hx, e[2] + fy * hy)
    return xs, ys, hx * hy


def trace_lens(
    scene,
    photons_per_axis=512,
    *,
    jitter: bool = False,
    seed=0,
    return_stats: bool = False,
    memory_limit: int | None = None,
):
    """Irradiance on the screen of a `LensScene` by forward photon tracing (ground truth).

    The aperture is cut into a grid of equal cells (`emit_lens_photons`); each photon
    starts at its cell's centre (or a jittered point in it) on the top rest plane, carries
    the cell's area times its flux density (`trace_lens_photons`: Fresnel factors, and
    ``I |w_z| / r^2`` for a point light), is traced exactly and binned into the receiver's
    pixels; photons landing off the receiver are dropped.

    **Arguments:**

    - `scene`: a `LensScene`, read by duck typing (see the module docstring).
    - `photons_per_axis`: the emission grid over the aperture, an int or
      ``(rows, cols)`` photons along the field's y and x axes; an integer ``n`` gives
      ``n x n``; default 512. The accuracy knob: the flux binned is exact up to the
      quadrature of the grid (midpoint rule over each cell).
    - `jitter`: jitter each photon uniformly inside its cell
      (``numpy.random.default_rng(seed)``, draws in row-major cell order); default False.
    - `seed`: int seed for the jitter; default 0.
    - `return_stats`: also return a dict of photon counts (ints, or one int per channel
      for a sequence of indices); default False: ``emitted``, ``lost_tir`` (total
      internal reflection at either face), ``lost_no_bottom`` (the refracted ray does not
      go down to the bottom face), ``landed`` (on ``z = 0``), ``on_receiver``.
    - `memory_limit`: bytes of photons traced at a time, an int or None (``PHOTON_BYTES``
      = 1024 per photon, an estimate of its arrays and temporaries); default None: 2^17
      (128 MiB) photons at a time. The image does not depend on it (up to the order of
      float64 sums).

    **Returns:** a float64 `np.ndarray` of shape ``(rows, cols)`` for a scalar
    ``scene.ior``, ``(rows, cols, C)`` for ``C`` indices: irradiance relative to the
    light's irradiance on a horizontal plane (directional light; a flat slab under normal
    light gives 1 without Fresnel), or W/m^2 (point light). With `return_stats`,
    ``(image, stats)``.
    """
    lens = _read_lens(scene)
    chunk = chunk_photons(memory_limit, _CHUNK)
    rows, cols = _grid_shape(photons_per_axis)
    rng = _rng(jitter, seed)
    return_stats = _check_bool(return_stats, "return_stats")
    rec = lens.receiver
    c = len(lens.iors)
    flux = np.zeros((c, rec.shape[0] * rec.shape[1]))
    counts = {k: np.zeros(c, dtype=np.int64) for k in ("lost_tir", "lost_no_bottom", "landed")}
    on_receiver = np.zeros(c, dtype=np.int64)
    total = rows * cols
    for lo in range(0, total, chunk):
        xs, ys, area = _emit_lens(lens, rows, cols, lo, min(lo + chunk, total), rng)
        gx, gy, weight, status = _trace_lens(lens, xs, ys)
        for k in range(c):
            f, m = rec.bin(gx[k], gy[k], weight[k] * area)
            flux[k] += f
            on_receiver[k] += m
            counts["lost_tir"][k] += np.count_nonzero(
                (status[k] == TIR_TOP) | (status[k] == TIR_BOTTOM)
            )
            counts["lost_no_bottom"][k] += np.count_nonzero(status[k] == NO_BOTTOM)
            counts["landed"][k] += np.count_nonzero(status[k] == LANDED)
    image = _image(rec, flux, lens.multichannel)
    if not return_stats:
        return image
    stats = {"emitted": np.full(c, total, dtype=np.int64), **counts, "on_receiver": on_receiver}
    return image, _finish_stats(stats, lens.multichannel)


def _image(rec: _Receiver, flux: np.ndarray, multichannel: bool) -> np.ndarray:
    """(C, rows * cols) flux -> an image (rows, cols[, C]) of flux per pixel area."""
    rows, cols = rec.shape
    out = (flux.T / rec.pixel_area).reshape(rows, cols, flux.shape[0])
    return out if multichannel else out[..., 0]


def _finish_stats(stats: dict[str, np.ndarray], multichannel: bool) -> dict:
    if multichannel:
        return {k: tuple(int(x) for x in v) for k, v in stats.items()}
    return {k: int(v[0]) for k, v in stats.items()}
