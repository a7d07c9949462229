"""Whether a lens can be milled (`manufacturability`): thickness, slope and curvature of
its top surface on a dense grid inside its outline, against the stock and a ball-end
mill."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..scene.outline import inside_outline
from .lens_sampling import _MM, _check_number, _check_samples, _evaluate, _lens, _outline


def _fmt_at(at: tuple[float, float] | None) -> str:
    return "" if at is None else f" at (x, y) = ({at[0]:.2f}, {at[1]:.2f}) mm"


def _fmt_mm(v: float, none: str = "no concave region") -> str:
    return f"inf ({none})" if math.isinf(v) else f"{v:.4g} mm"


@dataclasses.dataclass(frozen=True)
class ManufacturabilityReport:
    """What `manufacturability` found. Lengths in mm, angles in degrees; positions
    ``(x, y)`` in mm from the aperture's corner ``(x_min, y_min)`` (the frame of
    `lens_solid`).

    **Fields:**

    - `width_mm`, `height_mm`: the aperture.
    - `samples`: ``(rows, cols)`` of the grid the surface was evaluated on.
    - `min_thickness_mm`, `max_thickness_mm`: of the lens (bottom face to top surface),
      and `min_thickness_at_mm` where the minimum is.
    - `max_slope_deg`: the steepest angle of the top surface to the horizontal, and
      `max_slope_at_mm` where it is.
    - `min_radius_mm`: the smallest principal radius of curvature of the top surface of
      either sign (``inf`` for a plane).
    - `min_concave_radius_mm`: the smallest principal radius among the concave
      curvatures (hollows seen from above, which a ball-end mill of a larger radius
      cannot reach); ``inf`` if nothing is concave; `min_concave_radius_at_mm` where it
      is (None if nothing is concave).
    - `tool_radius_mm`, `min_thickness_limit_mm`, `max_slope_limit_deg`: the limits
      checked; `margin_mm`: the band along the edges left out of the checks.
    - `warnings`: one string per limit the design breaks (empty: it can be milled).
    """

    width_mm: float
    height_mm: float
    samples: tuple[int, int]
    min_thickness_mm: float
    min_thickness_at_mm: tuple[float, float]
    max_thickness_mm: float
    max_slope_deg: float
    max_slope_at_mm: tuple[float, float]
    min_radius_mm: float
    min_concave_radius_mm: float
    min_concave_radius_at_mm: tuple[float, float] | None
    tool_radius_mm: float
    min_thickness_limit_mm: float
    max_slope_limit_deg: float
    margin_mm: float
    warnings: tuple[str, ...]

    @property
    def ok(self) -> bool:
        """True when no limit is broken."""
        return not self.warnings

    def to_dict(self) -> dict:
        """Plain JSON-able values (infinite radii become None)."""
        out = dataclasses.asdict(self)
        for key, value in out.items():
            if isinstance(value, float) and math.isinf(value):
                out[key] = None
            elif isinstance(value, tuple):
                out[key] = list(value)
        out["ok"] = self.ok
        return out

    def __str__(self) -> str:
        lines = [
            f"Lens {self.width_mm:.2f} x {self.height_mm:.2f} mm "
            f"(surface sampled on {self.samples[0]} x {self.samples[1]} points"
            + (f", {self.margin_mm:g} mm edge margin left out)" if self.margin_mm else ")"),
            f"  thickness:          {self.min_thickness_mm:.4g} .. {self.max_thickness_mm:.4g}"
            f" mm (min{_fmt_at(self.min_thickness_at_mm)}; "
            f"limit >= {self.min_thickness_limit_mm:g} mm)",
            f"  max slope:          {self.max_slope_deg:.2f} deg{_fmt_at(self.max_slope_at_mm)}"
            f" (limit {self.max_slope_limit_deg:g} deg)",
            f"  min concave radius: {_fmt_mm(self.min_concave_radius_mm)}"
            f"{_fmt_at(self.min_concave_radius_at_mm)}"
            f" (ball-end tool radius {self.tool_radius_mm:g} mm)",
            "  min radius (any):   " + _fmt_mm(self.min_radius_mm, "flat"),
        ]
        if self.ok:
            lines.append("  OK: within all limits.")
        else:
            lines.append(f"  {len(self.warnings)} problem(s):")
            lines.extend(f"  - {w}" for w in self.warnings)
        return "\n".join(lines)


def _principal_curvatures(hx, hy, hxx, hxy, hyy) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``k_min <= k_max`` of the shape operator of ``z = h(x, y)`` with the
    upward normal: positive means the surface bends upwards (concave seen from above)."""
    e, f, g = 1.0 + hx * hx, hx * hy, 1.0 + hy * hy
    w = np.sqrt(1.0 + hx * hx + hy * hy)
    big_l, big_m, big_n = hxx / w, hxy / w, hyy / w
    det = w * w  # E G - F^2
    gauss = (big_l * big_n - big_m * big_m) / det
    mean = (e * big_n - 2.0 * f * big_m + g * big_l) / (2.0 * det)
    root = np.sqrt(np.maximum(mean * mean - gauss, 0.0))
    return mean - root, mean + root


def manufacturability(
    scene_or_surface,
    *,
    thickness=None,
    tool_radius_mm=1.0,
    min_thickness_mm=1.0,
    max_slope_deg=60.0,
    margin_mm=0.0,
    samples=None,
) -> ManufacturabilityReport:
    """Checks whether a lens can be milled with a ball-end tool from a slab.

    The top surface (the bicubic the renderer uses) is evaluated with its first and
    second derivatives on a dense grid of vertices over the aperture. The principal
    curvatures are the eigenvalues of the shape operator of ``z = h(x, y)`` (upward
    normal); a positive one is concave seen from above, a hollow that a ball of a larger
    radius cannot reach.

    With ``boundary="clamp"`` the outermost one and a half samples are shaped by the
    clamped edge (the surface levels off there, and the interpolant bends sharply where
    the design had a slope): that is part of the surface that is exported, and it is
    checked unless `margin_mm` leaves it out. ``"extrapolate"`` (`design_lens`'s) keeps
    the edge slope out to the rim instead.

    **Arguments:**

    - `scene_or_surface`: a `LensScene` or a `HeightField` (then give `thickness`).
    - `thickness`: metres (> 0) with a `HeightField`; None with a `LensScene`.
    - `tool_radius_mm`: radius of the ball-end mill (> 0).
    - `min_thickness_mm`: the thinnest the lens may be anywhere (>= 0).
    - `max_slope_deg`: the steepest the top surface may be, in (0, 90] degrees.
    - `margin_mm`: width of a band along each edge of the aperture that is left out of
      all checks (>= 0; e.g. the part held by the lens holder or trimmed away).
    - `samples`: ``(rows, cols)`` of the evaluation grid, which spans the aperture less
      the margin; default ``(4 rows + 1, 4 cols + 1)`` of ``surface.heights``.

    **Returns:** a `ManufacturabilityReport`; its `warnings` name each broken limit, the
    worst value, where it is and the fraction of the aperture affected.
    """
    tool = _check_number(tool_radius_mm, "tool_radius_mm", low=0.0, low_inclusive=False)
    min_t = _check_number(min_thickness_mm, "min_thickness_mm", low=0.0, low_inclusive=True)
    max_s = _check_number(max_slope_deg, "max_slope_deg", low=0.0, low_inclusive=False)
    if max_s > 90.0:
        raise ValueError(f"`max_slope_deg` must be in (0, 90], got {max_s}")
    margin = _check_number(margin_mm, "margin_mm", low=0.0, low_inclusive=True)
    surface, t = _lens(scene_or_surface, thickness)
    shape = _check_samples(samples, surface, 4)
    x0, x1, y0, y1 = (float(v) for v in np.asarray(surface.extent))
    width, height = (x1 - x0) * _MM, (y1 - y0) * _MM
    if not 2.0 * margin < min(width, height):
        raise ValueError(
            f"`margin_mm` ({margin:g}) leaves nothing of the {width:g} x {height:g} mm aperture"
        )
    m = margin / _MM
    xs, ys = np.linspace(x0 + m, x1 - m, shape[1]), np.linspace(y0 + m, y1 - m, shape[0])
    h, hx, hy, hxx, hxy, hyy = _evaluate(surface, xs, ys, curvature=True)
    px, py = (xs - x0) * _MM, (ys - y0) * _MM

    def at(flat_index) -> tuple[float, float]:
        i, j = np.unravel_index(int(flat_index), h.shape)
        return float(px[j]), float(py[i])

    # an elliptical blank: only the points inside it (its rim included) are milled
    gx, gy = np.meshgrid(xs, ys)
    inside = inside_outline(_outline(scene_or_surface), (x0 + m, x1 - m, y0 + m, y1 - m), gx, gy)
    thick = np.where(inside, (t + h) * _MM, np.inf)
    slope = np.where(inside, np.degrees(np.arctan(np.hypot(hx, hy))), 0.0)
    k_min, k_max = _principal_curvatures(hx, hy, hxx, hxy, hyy)  # 1/m
    k_min, k_max = np.where(inside, k_min, 0.0), np.where(inside, k_max, 0.0)
    # rounding noise of a plane (radii beyond 10^9 apertures) is no curvature
    tiny = 1e-9 * _MM / max(width, height)
    k_min, k_max = (np.where(np.abs(k) < tiny, 0.0, k) for k in (k_min, k_max))
    k_abs = np.maximum(np.abs(k_min), np.abs(k_max))
    biggest = float(k_abs.max())
    min_radius = _MM / biggest if biggest > 0 else math.inf
    i_concave = int(np.argmax(k_max))
    concave = float(k_max.flat[i_concave])
    if concave > 0:
        min_concave, concave_at = _MM / concave, at(i_concave)
    else:
        min_concave, concave_at = math.inf, None

    warnings = []
    i_thin, i_steep = int(np.argmin(thick)), int(np.argmax(slope))
    if float(thick.flat[i_thin]) < min_t:
        frac = float(np.mean(thick[inside] < min_t))
        warnings.append(
            f"too thin: {float(thick.flat[i_thin]):.4g} mm{_fmt_at(at(i_thin))} is below the "
            f"minimum thickness {min_t:g} mm ({100 * frac:.3g}% of the aperture)"
        )
    if float(slope.flat[i_steep]) > max_s:
        frac = float(np.mean(slope[inside] > max_s))
        warnings.append(
            f"too steep: {float(slope.flat[i_steep]):.2f} deg{_fmt_at(at(i_steep))} exceeds "
            f"the maximum slope {max_s:g} deg ({100 * frac:.3g}% of the aperture)"
        )
    if min_concave < tool:
        frac = float(np.mean(k_max[inside] * tool > _MM))
        warnings.append(
            f"concave radius {min_concave:.4g} mm{_fmt_at(concave_at)} is below the tool "
            f"radius {tool:g} mm: a ball-end mill of that size cannot reach the bottom of "
            f"this hollow ({100 * frac:.3g}% of the aperture)"
        )
    return ManufacturabilityReport(
        width_mm=width,
        height_mm=height,
        samples=shape,
        min_thickness_mm=float(thick.flat[i_thin]),
        min_thickness_at_mm=at(i_thin),
        max_thickness_mm=float(thick[inside].max()),
        max_slope_deg=float(slope.flat[i_steep]),
        max_slope_at_mm=at(i_steep),
        min_radius_mm=min_radius,
        min_concave_radius_mm=min_concave,
        min_concave_radius_at_mm=concave_at,
        tool_radius_mm=tool,
        min_thickness_limit_mm=min_t,
        max_slope_limit_deg=max_s,
        margin_mm=margin,
        warnings=tuple(warnings),
    )
