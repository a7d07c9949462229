"""Catmull-Rom height field and exact ray/surface intersection (plain NumPy, float64)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._optics import _real

BOUNDARY_MODES = ("periodic", "clamp", "extrapolate")

# Bound on the Catmull-Rom interpolant over t in [0, 1]: the negative weights
# w(-1) = -t(1-t)^2/2 and w(2) = -t^2(1-t)/2 sum to -t(1-t)/2 >= -1/8, so the positive ones
# sum to at most 9/8; in 2-D the positive tensor weights sum to at most
# (9/8)^2 + (1/8)^2 = 82/64, hence H lies within the taps' [min, max] widened by 18/64 of
# their range.
_OVERSHOOT = 18.0 / 64.0
# max over t in [0, 1] of |w'(t)| and |w''(t)| for taps -1, 0, 1, 2.
_MAX_ABS_DW = np.array([0.5, 25.0 / 18.0, 25.0 / 18.0, 0.5])
_MAX_ABS_D2W = np.array([2.0, 5.0, 5.0, 2.0])
_EPS = np.finfo(np.float64).eps
# Samples padded on each side of the height array, so that the four taps of any point are
# consecutive entries: a query's base tap is wrapped (periodic), or its coordinate is
# clipped to [-2, n + 1] (clamp, where the taps then all repeat an edge sample, exactly as
# clipping each tap does; extrapolate, where the oddly reflected surface levels off).
_PAD = 4
# The marcher may step blindly over dips of the surface below the ray shallower than this
# fraction of the surface's height range (see `intersect_surface`).
_GRAZE = 1e-10


def _weights(t: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Catmull-Rom weights and their derivatives d/dt for taps -1, 0, 1, 2."""
    t2 = t * t
    t3 = t2 * t
    w = [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
    dw = [
        0.5 * (-3.0 * t2 + 4.0 * t - 1.0),
        0.5 * (9.0 * t2 - 10.0 * t),
        0.5 * (-9.0 * t2 + 8.0 * t + 1.0),
        0.5 * (3.0 * t2 - 2.0 * t),
    ]
    return w, dw


def _base_tap(coord: np.ndarray, n: int, periodic: bool) -> tuple[np.ndarray, np.ndarray]:
    """Index of tap 0 in the padded array, and the fractional position t."""
    if not periodic:
        coord = np.clip(coord, -2.0, n + 1.0)
    base = np.floor(coord)
    t = coord - base
    j0 = base.astype(np.int64)
    j0 = np.mod(j0, n) if periodic else j0
    return j0 + _PAD, t


def _row_peaks(window: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Max of |P'(t)| and |P''(t)| over t in [0, 1] for 1-D interpolants along rows.

    ``P`` is the Catmull-Rom interpolant along a row of `window` between taps j and j+1
    (taps ``window[:, j:j+4]``); results have shape ``(rows, cols - 3)``, per unit of the
    sample spacing. ``P'`` is a quadratic in t (ends and vertex checked) and ``P''`` is
    linear (ends), so both maxima are exact.
    """
    h_m, h_0, h_1, h_2 = (window[:, k : window.shape[1] - 3 + k] for k in range(4))
    qa = 0.5 * (-3.0 * h_m + 9.0 * h_0 - 9.0 * h_1 + 3.0 * h_2)
    qb = 0.5 * (4.0 * h_m - 10.0 * h_0 + 8.0 * h_1 - 2.0 * h_2)
    qc = 0.5 * (h_1 - h_m)
    slope = np.maximum(np.abs(qc), np.abs(qa + qb + qc))
    with np.errstate(divide="ignore", invalid="ignore"):
        tv = -qb / (2.0 * qa)
    inner = (qa != 0.0) & (tv > 0.0) & (tv < 1.0)
    tv = np.where(inner, tv, 0.0)
    slope = np.maximum(slope, np.where(inner, np.abs((qa * tv + qb) * tv + qc), 0.0))
    curvature = np.maximum(np.abs(qb), np.abs(2.0 * qa + qb))
    return slope, curvature


def _across_rows(peak: np.ndarray, derivative: bool) -> np.ndarray:
    """Bound ``sum_a |c_a(s)| peak[i + a]`` over s in [0, 1] for each cell row i.

    ``c_a`` are the Catmull-Rom weights (or, with `derivative`, their derivatives, bounded
    tap by tap by their maxima). For the weights the sum is maximised over 129 values of
    s, plus its largest possible change between them (a Lipschitz bound): rigorous.
    """
    m = np.stack([peak[k : peak.shape[0] - 3 + k] for k in range(4)])  # (4, cells_y, cells_x)
    if derivative:
        return np.einsum("k,kij->ij", _MAX_ABS_DW, m)
    s = np.linspace(0.0, 1.0, 129)
    w = np.abs(np.stack(_weights(s)[0]))  # (4, 129)
    sampled = np.max(np.einsum("ks,kij->sij", w, m), axis=0)
    return sampled + np.einsum("k,kij->ij", _MAX_ABS_DW, m) * (0.5 * (s[1] - s[0]))


@dataclasses.dataclass(frozen=True, eq=False)
class _Surface:
    """A validated float64 height field, with per-cell bounds for the intersection.

    The bounds hold over every bicubic cell a query can fall in (for "clamp" and
    "extrapolate" also the extension cells outside the samples): the interpolant's range
    ``[h_lo, h_hi]``, and per cell upper bounds of ``|Hx|``, ``|Hy|``, ``|Hxx|``,
    ``|Hxy|``, ``|Hyy|`` (arrays of the cells' shape).

    The bounds are along the field's own axes. A rotated field (`rotation`, radians,
    counter-clockwise about the centre of `extent`) is evaluated at world points mapped
    into its own frame, and its gradient rotated back to world axes; a caller bounding a
    directional derivative rotates the direction into the field's frame (`to_field`).
    """

    heights: np.ndarray  # (rows, cols)
    padded: np.ndarray  # (rows + 2 _PAD, cols + 2 _PAD): the boundary's padding
    extent: tuple[float, float, float, float]
    periodic: bool
    rotation: float
    h_lo: float
    h_hi: float
    bound_x: np.ndarray
    bound_y: np.ndarray
    bound_xx: np.ndarray
    bound_xy: np.ndarray
    bound_yy: np.ndarray

    @property
    def dx(self) -> float:
        return (self.extent[1] - self.extent[0]) / self.heights.shape[1]

    @property
    def dy(self) -> float:
        return (self.extent[3] - self.extent[2]) / self.heights.shape[0]

    def to_field(self, vx, vy):
        """A world vector's components along the field's own axes (rotated by -rotation)."""
        if self.rotation == 0.0:
            return vx, vy
        c, s = np.cos(self.rotation), np.sin(self.rotation)
        return c * vx + s * vy, c * vy - s * vx

    @classmethod
    def build(cls, heights, extent, boundary, rotation=0.0) -> _Surface:
        h = np.asarray(heights)
        if h.dtype.kind not in "iuf":
            raise ValueError(f"`heights` must be real numbers, got dtype {h.dtype}")
        h = np.ascontiguousarray(h, dtype=np.float64)
        if h.ndim != 2 or h.shape[0] < 2 or h.shape[1] < 2:
            raise ValueError(f"`heights` must be 2-D with at least 2x2 samples, got {h.shape}")
        if not np.all(np.isfinite(h)):
            raise ValueError("`heights` contains NaN or infinite values")
        ext = np.asarray(extent)
        if ext.dtype.kind not in "iuf" or ext.shape != (4,) or not np.all(np.isfinite(ext)):
            raise ValueError(
                f"`extent` must be 4 finite numbers (x_min, x_max, y_min, y_max), got {ext!r}"
            )
        ext = ext.astype(np.float64)
        if not (ext[1] > ext[0] and ext[3] > ext[2]):
            raise ValueError(f"`extent` must have x_max > x_min and y_max > y_min, got {ext}")
        if boundary not in BOUNDARY_MODES:
            raise ValueError(f"`boundary` must be one of {BOUNDARY_MODES}, got {boundary!r}")
        try:
            rot = np.asarray(rotation, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"`rotation` must be a number (radians), got {rotation!r}") from err
        if rot.shape != () or not np.isfinite(rot):
            raise ValueError(f"`rotation` must be one finite number (radians), got {rotation!r}")
        periodic = boundary == "periodic"
        rows, cols = h.shape
        dx = (ext[1] - ext[0]) / cols
        dy = (ext[3] - ext[2]) / rows
        if boundary == "extrapolate":  # h[-k] = 2 h[0] - h[k]: linear surfaces continue
            padded = np.pad(h, _PAD, mode="reflect", reflect_type="odd")
        else:
            padded = np.pad(h, _PAD, mode="wrap" if periodic else "edge")
        # The cells a query can fall in: base taps 0..n-1 (periodic) or -3..n+1 (clamp);
        # cell (i, j) uses the taps window[i:i+4, j:j+4].
        r0, r1 = (0, rows - 1) if periodic else (-3, rows + 1)
        c0, c1 = (0, cols - 1) if periodic else (-3, cols + 1)
        window = padded[_PAD + r0 - 1 : _PAD + r1 + 3, _PAD + c0 - 1 : _PAD + c1 + 3]
        taps = [
            window[a : window.shape[0] - 3 + a, b : window.shape[1] - 3 + b]
            for a in range(4)
            for b in range(4)
        ]
        lo, hi = np.minimum.reduce(taps), np.maximum.reduce(taps)
        pad = 64.0 * _EPS * float(np.abs(h).max())  # so that rounding stays inside
        slope_x, curv_x = _row_peaks(window)
        slope_y, curv_y = (a.T for a in _row_peaks(window.T))
        safety = 1.0 + 1e-9
        return cls(
            heights=h,
            padded=padded,
            extent=(float(ext[0]), float(ext[1]), float(ext[2]), float(ext[3])),
            periodic=periodic,
            rotation=float(rot),
            h_lo=float((lo - _OVERSHOOT * (hi - lo)).min()) - pad,
            h_hi=float((hi + _OVERSHOOT * (hi - lo)).max()) + pad,
            bound_x=_across_rows(slope_x, False) * (safety / dx),
            bound_y=_across_rows(slope_y.T, False).T * (safety / dy),
            bound_xx=_across_rows(curv_x, False) * (safety / dx**2),
            bound_xy=_across_rows(slope_x, True) * (safety / (dx * dy)),
            bound_yy=_across_rows(curv_y.T, False).T * (safety / dy**2),
        )

    def evaluate(
        self, x: np.ndarray, y: np.ndarray, grad: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """H, dH/dx, dH/dy at points (x, y) (1-D float64 arrays of equal length).

        With ``grad=False`` only H is computed (the slopes are returned as None).
        """
        if self.rotation != 0.0:  # into the field's frame, about the extent's centre
            cx = 0.5 * (self.extent[0] + self.extent[1])
            cy = 0.5 * (self.extent[2] + self.extent[3])
            x, y = self.to_field(x - cx, y - cy)
            x, y = x + cx, y + cy
        rows, cols = self.heights.shape
        stride = self.padded.shape[1]
        flat = self.padded.ravel()
        u = (x - self.extent[0]) / self.dx - 0.5
        v = (y - self.extent[2]) / self.dy - 0.5
        jx, tx = _base_tap(u, cols, self.periodic)
        iy, ty = _base_tap(v, rows, self.periodic)
        base = iy * stride + jx
        wx, dwx = _weights(tx)
        wy, dwy = _weights(ty)
        value = np.zeros_like(tx)
        grad_x = np.zeros_like(tx)
        grad_y = np.zeros_like(tx)
        for a in range(4):
            row = base + (a - 1) * stride
            g = np.zeros_like(tx)  # the interpolant along this row of taps
            gd = np.zeros_like(tx)  # its derivative in u
            for b in range(4):
                s = flat[row + (b - 1)]
                g += wx[b] * s
                if grad:
                    gd += dwx[b] * s
            value += wy[a] * g
            if grad:
                grad_x += wy[a] * gd
                grad_y += dwy[a] * g
        if not grad:
            return value, None, None
        if not self.periodic:  # level beyond the clipped coordinate (extrapolate)
            grad_x = np.where((u < -2.0) | (u > cols + 1.0), 0.0, grad_x)
            grad_y = np.where((v < -2.0) | (v > rows + 1.0), 0.0, grad_y)
        grad_x, grad_y = grad_x / self.dx, grad_y / self.dy
        if self.rotation != 0.0:  # back to world axes
            c, s = np.cos(self.rotation), np.sin(self.rotation)
            grad_x, grad_y = c * grad_x - s * grad_y, s * grad_x + c * grad_y
        return value, grad_x, grad_y


def surface_height(
    heights, extent, boundary, x, y, rotation=0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Evaluate the Catmull-Rom height field and its analytic gradient.

    **Arguments:**

    - `heights`: array-like of shape ``(rows, cols)``, height samples in metres, indexed
      ``[y, x]``, sitting at the pixel centres of `extent`.
    - `extent`: array-like of shape ``(4,)``, ``(x_min, x_max, y_min, y_max)`` in metres,
      covering the pixel edges.
    - `boundary`: ``"periodic"``, ``"clamp"`` or ``"extrapolate"``: tap indices wrap
      modulo the size, are clipped to ``[0, n - 1]``, or (extrapolate) continue the
      samples by odd reflection about the edge sample.
    - `x`, `y`: array-likes, query coordinates in metres (broadcast together to a common
      shape ``S``).
    - `rotation`: angle in radians (a float) by which the field (sample grid and extent)
      is rotated about the centre of `extent`, counter-clockwise seen from above (+x
      towards +y); default 0.0.

    **Returns:** ``(H, Hx, Hy)``: float64 `np.ndarray` objects, each of shape ``S``: the
    height (metres) and its slopes ``dH/dx``, ``dH/dy`` (dimensionless) along the world
    axes.
    """
    surf = _Surface.build(heights, extent, boundary, rotation)
    try:
        xb, yb = np.broadcast_arrays(_real(x, "x"), _real(y, "y"))
    except ValueError as err:
        if "`" in str(err):
            raise
        raise ValueError(f"`x` and `y` must broadcast together: {err}") from err
    shape = xb.shape
    h, hx, hy = surf.evaluate(xb.ravel(), yb.ravel())
    assert hx is not None and hy is not None
    return h.reshape(shape), hx.reshape(shape), hy.reshape(shape)


def intersect_surface(
    surf: _Surface, rest_depth: float, direction: np.ndarray, cx: np.ndarray, cy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First intersection of the rays ``(cx, cy, rest_depth) + t d`` with the water surface.

    The hit is the smallest root of ``f(t) = t d_z - H(c + t d_xy)`` (the height of the ray
    above the surface), searched from ``t_top``, where the ray is above the surface's
    upper bound, down to ``t_bot``, where it is below its lower bound. With ``L`` the
    largest ``|f'|`` and ``K`` the largest ``|f''|`` allowed by the per-cell bounds:

    - if ``f' < 0`` everywhere (always at normal incidence) the root is unique and
      ``[t_top, t_bot]`` brackets it;
    - otherwise the ray marches from ``t_top``. From a point with ``f > 0`` it may step by
      ``max(f / L, 2 f / (sqrt(f'^2 + 2 K f) - f'))``, within which ``f`` provably stays
      positive (the second is where the lower parabola ``f + f' s - K s^2 / 2`` reaches 0:
      a Newton-like step from above near a root), but at least by a floor step ``s0``
      with ``K s0^2 / 8`` = 1e-10 of the height range: a dip of the surface below the
      ray shallower than that may be stepped over, nothing deeper. The first point with
      ``f <= 0`` closes the bracket;

    and the bracket is refined by safeguarded Newton iteration (bisection fallback) to
    machine precision.

    **Arguments:**

    - `surf`: a `_Surface`.
    - `rest_depth`: a float, the height ``z`` of the rest plane the rays start on.
    - `direction`: `np.ndarray` of shape ``(3,)``, the unit direction of travel,
      ``d_z < 0``.
    - `cx`, `cy`: `np.ndarray` of shape ``(N,)``, start points on the rest plane, metres.

    **Returns:** ``(t, hx, hy)``: `np.ndarray` objects of shape ``(N,)``: the ray
    parameter of the hit (the hit is ``(cx, cy, rest_depth) + t d``) and the surface
    slopes there.
    """
    d_x, d_y, d_z = (float(c) for c in direction)
    t_top = surf.h_hi / d_z  # z(t_top) = rest + upper bound of H: above the surface
    t_bot = surf.h_lo / d_z  # below the surface
    n = cx.shape[0]
    # Largest rate at which the ray can approach the surface, and largest |f''|: the
    # per-cell bounds are along the field's axes, so the direction is taken there too.
    d_u, d_v = surf.to_field(d_x, d_y)
    rise = float((abs(d_u) * surf.bound_x + abs(d_v) * surf.bound_y).max())
    curv = float(
        (
            d_u * d_u * surf.bound_xx
            + 2.0 * abs(d_u * d_v) * surf.bound_xy
            + d_v * d_v * surf.bound_yy
        ).max()
    )

    def f(t, idx):
        h, hx, hy = surf.evaluate(cx[idx] + t * d_x, cy[idx] + t * d_y)
        return t * d_z - h, d_z - (hx * d_x + hy * d_y), hx, hy

    a = np.full(n, t_top)
    b = np.full(n, t_bot)
    x = np.clip(0.0, a, b)  # Newton's start: the rest plane, for a monotone f
    if rise >= -d_z:  # f may have several roots: march to the first
        lipschitz = -d_z + rise
        floor = np.sqrt(8.0 * _GRAZE * (surf.h_hi - surf.h_lo) / curv) if curv > 0 else 0.0
        idx = np.arange(n)
        ta = a.copy()
        fa, fpa, _, _ = f(ta, idx)
        touch = fa <= 0.0  # only by rounding: the surface touches the upper bound
        b[touch] = t_top
        idx, ta, fa, fpa = idx[~touch], ta[~touch], fa[~touch], fpa[~touch]
        for _ in range(1_000_000):
            if not idx.size:
                break
            with np.errstate(divide="ignore", invalid="ignore"):
                parabola = 2.0 * fa / (np.sqrt(fpa * fpa + 2.0 * curv * fa) - fpa)
            step = np.maximum(np.maximum(fa / lipschitz, np.nan_to_num(parabola)), floor)
            tn = np.minimum(ta + step, t_bot)
            fn, fpn, _, _ = f(tn, idx)
            found = (fn <= 0.0) | (tn >= t_bot)
            a[idx[found]] = ta[found]
            b[idx[found]] = tn[found]
            keep = ~found
            idx, ta, fa, fpa = idx[keep], tn[keep], fn[keep], fpn[keep]
        else:  # pragma: no cover
            raise RuntimeError("ray marching did not reach the surface")
        x = a.copy()

    # Safeguarded Newton on [a, b], f(a) > 0 >= f(b) (or a == b).
    scale = max(abs(t_top), abs(t_bot), 1e-300)
    t_hit, gx_hit, gy_hit = np.empty(n), np.empty(n), np.empty(n)
    idx = np.arange(n)
    for _ in range(200):
        fx, fpx, hx, hy = f(x, idx)
        above = fx > 0.0
        a[idx] = np.where(above, x, a[idx])
        b[idx] = np.where(above, b[idx], x)
        aa, bb = a[idx], b[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = x - fx / fpx
        xn = np.where((xn > aa) & (xn < bb), xn, 0.5 * (aa + bb))
        tol = 4.0 * _EPS * np.maximum(np.abs(x), scale)
        done = (fx == 0.0) | (np.abs(xn - x) <= tol) | (bb - aa <= tol)
        t_hit[idx[done]] = x[done]
        gx_hit[idx[done]] = hx[done]
        gy_hit[idx[done]] = hy[done]
        idx, x = idx[~done], xn[~done]
        if not idx.size:
            break
    else:  # pragma: no cover - bisection alone converges in far fewer iterations
        raise RuntimeError("ray/surface intersection did not converge")
    return t_hit, gx_hit, gy_hit
