"""Exporting a caustic lens for fabrication: a watertight solid, height maps, a report.

Everything exported is in **millimetres** (the scene is in metres), in the lens's own
frame: the origin is the aperture's corner ``(x_min, y_min)`` of ``surface.extent``, ``x``
and ``y`` run along the height field's own axes (a field with a `rotation` is exported
unrotated: the rotation is how the lens sits in its holder, not part of its shape), the
flat bottom face is the plane ``z = 0`` and the top surface is
``z = thickness + H(x, y)``, with ``H`` the Catmull-Rom bicubic of ``surface.heights``
evaluated by `height_and_gradient`: the exported surface is the one the renderer traced.

- `lens_height_map`: the top surface ``z`` (mm) sampled on a grid over the aperture.
- `lens_solid`: that grid closed into a watertight `trimesh.Trimesh` (top, flat bottom,
  four side walls, outward normals).
- `manufacturability`: thickness, slope and curvature of the top surface on a dense grid,
  with warnings where a ball-end mill or the stock cannot make it.
- `export_lens`: writes STL / OBJ, the height map as 16-bit PNG (+ JSON sidecar) and
  float32 EXR, and the report as JSON and text.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_shape
from ..io.images import check_folder, write_exr, write_png_linear16
from ..scene.scene import HeightField, LensScene
from ..scene.surface import height_and_gradient

__all__ = [
    "ManufacturabilityReport",
    "export_lens",
    "lens_height_map",
    "lens_solid",
    "manufacturability",
]

_MM = 1000.0  # millimetres per metre
_MESH_FORMATS = ("stl", "obj", "ply")
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
    elif isinstance(scene_or_surface, HeightField):
        if thickness is None:
            raise ValueError("`thickness` (metres) is required with a HeightField")
        surface = scene_or_surface
        t = _check_number(thickness, "thickness", low=0.0, low_inclusive=False)
    else:
        raise ValueError(
            "`scene_or_surface` must be a LensScene or a HeightField, "
            f"got {type(scene_or_surface).__name__}"
        )
    heights = np.asarray(surface.heights)
    field = HeightField(
        jnp.asarray(heights), np.asarray(surface.extent, dtype=float), surface.boundary
    )
    return field, t


def _check_samples(samples, surface: HeightField, factor: int) -> tuple[int, int]:
    if samples is None:
        rows, cols = surface.shape
        rows, cols = factor * rows + 1, factor * cols + 1
        if rows * cols > MAX_SAMPLES:
            raise ValueError(
                f"`samples`: the default grid {(rows, cols)} ({factor} per height sample) "
                f"has over {MAX_SAMPLES} points; pass a smaller `samples`"
            )
        return rows, cols
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


# --------------------------------------------------------------------------- the solid


def _boundary_loop(rows: int, cols: int) -> np.ndarray:
    """Grid indices of the border, counter-clockwise seen from above (+z)."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    return np.concatenate(
        [idx[0, :], idx[1:, -1], idx[-1, -2::-1], idx[-2:0:-1, 0]]  # y_min, x_max, ...
    )


def _solid_arrays(z: np.ndarray, width: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = z.shape
    gx, gy = np.meshgrid(np.linspace(0.0, width, cols), np.linspace(0.0, height, rows))
    top = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
    loop = _boundary_loop(rows, cols)
    n_top, n_loop = top.shape[0], loop.size
    bottom = np.concatenate([top[loop, :2], np.zeros((n_loop, 1))], axis=1)  # the border at z = 0
    centre = np.array([[0.5 * width, 0.5 * height, 0.0]])
    vertices = np.concatenate([top, bottom, centre])

    # top: two triangles per cell, counter-clockwise seen from above (normals up)
    idx = np.arange(n_top).reshape(rows, cols)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    top_faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])

    # side walls: a quad per border edge ta -> tb (counter-clockwise), outward normals
    ta, tb = loop, np.roll(loop, -1)
    ba = n_top + np.arange(n_loop)
    bb = np.roll(ba, -1)
    walls = np.concatenate([np.stack([ta, ba, bb], 1), np.stack([ta, bb, tb], 1)])

    # bottom: a fan from the centre, clockwise seen from above (normals down)
    fan = np.stack([np.full(n_loop, n_top + n_loop), bb, ba], 1)
    return vertices, np.concatenate([top_faces, walls, fan])


def lens_solid(scene_or_surface, thickness=None, *, samples=None):
    """The lens as a watertight solid in millimetres, ready for STL / OBJ export.

    The top is `lens_height_map` triangulated (two triangles per grid cell), the bottom
    the plane ``z = 0`` (a fan of triangles), closed by four vertical side walls; faces
    wind counter-clockwise seen from outside (outward normals). The origin is the
    aperture's corner ``(x_min, y_min)``: the solid spans ``[0, width] x [0, height]`` in
    ``x, y`` and ``[0, thickness + max H]`` in ``z`` (all mm). A rotated field is exported
    in its own (unrotated) frame.

    **Arguments:**

    - `scene_or_surface`: a `LensScene` (its `thickness` is used) or a `HeightField`.
    - `thickness`: metres (> 0); required with a `HeightField`, None with a `LensScene`.
    - `samples`: ``(rows, cols)`` of the top's sampling grid; default twice the heights'
      grid plus one (see `lens_height_map`).

    **Returns:** a `trimesh.Trimesh` (``units = "mm"``), checked to be watertight and a
    volume.

    Raises `ValueError` for bad arguments or a top surface that reaches the bottom face.
    """
    surface, t = _lens(scene_or_surface, thickness)
    return _trimesh(*_top_mm(surface, t, samples))


def _trimesh(z: np.ndarray, width: float, height: float):
    import trimesh

    vertices, faces = _solid_arrays(z, width, height)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.units = "mm"
    if not (mesh.is_watertight and mesh.is_volume):  # pragma: no cover - a bug if so
        raise RuntimeError("internal error: the lens solid is not a closed volume")
    return mesh


# --------------------------------------------------------------------------- analysis


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

    thick = (t + h) * _MM
    slope = np.degrees(np.arctan(np.hypot(hx, hy)))
    k_min, k_max = _principal_curvatures(hx, hy, hxx, hxy, hyy)  # 1/m
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
        frac = float(np.mean(thick < min_t))
        warnings.append(
            f"too thin: {float(thick.flat[i_thin]):.4g} mm{_fmt_at(at(i_thin))} is below the "
            f"minimum thickness {min_t:g} mm ({100 * frac:.3g}% of the aperture)"
        )
    if float(slope.flat[i_steep]) > max_s:
        frac = float(np.mean(slope > max_s))
        warnings.append(
            f"too steep: {float(slope.flat[i_steep]):.2f} deg{_fmt_at(at(i_steep))} exceeds "
            f"the maximum slope {max_s:g} deg ({100 * frac:.3g}% of the aperture)"
        )
    if min_concave < tool:
        frac = float(np.mean(k_max * tool > _MM))
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
        max_thickness_mm=float(thick.max()),
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


# --------------------------------------------------------------------------- files


def _check_formats(formats) -> tuple[str, ...]:
    if isinstance(formats, str):
        formats = (formats,)
    try:
        out = tuple(str(f).lower() for f in formats)
    except TypeError as err:
        raise ValueError(
            f"`formats` must be a sequence of {_MESH_FORMATS}, got {formats!r}"
        ) from err
    bad = [f for f in out if f not in _MESH_FORMATS]
    if not out:
        raise ValueError(f"`formats` must name at least one of {_MESH_FORMATS}, got {formats!r}")
    if bad:
        raise ValueError(f"`formats` must be among {_MESH_FORMATS}, got {bad}")
    return tuple(dict.fromkeys(out))


def export_lens(
    scene_or_surface,
    directory,
    *,
    thickness=None,
    name: str = "lens",
    samples=None,
    tool_radius_mm=1.0,
    min_thickness_mm=1.0,
    max_slope_deg=60.0,
    margin_mm=0.0,
    formats: Sequence[str] = ("stl", "obj"),
) -> dict[str, Path]:
    """Writes a lens for fabrication: meshes, height maps and a manufacturability report.

    All lengths in the files are millimetres, in the frame of `lens_solid` (origin at the
    aperture's corner ``(x_min, y_min)``, flat bottom at ``z = 0``). Files, in
    `directory` (created if missing; existing files are overwritten):

    - ``{name}.stl`` / ``.obj`` / ``.ply`` (per `formats`): the watertight solid.
    - ``{name}_height.png``: 16-bit grayscale of `lens_height_map` (the top's ``z`` above
      the bottom, mm), its minimum at 0 and maximum at 65535; row 0 of the file is
      ``y = 0``, column 0 is ``x = 0``, pixels are the grid's vertices (the first and
      last rows and columns lie on the aperture's edges).
    - ``{name}_height.json``: the PNG's mapping (``min_mm``, ``max_mm``: ``z = min_mm +
      v / 65535 * (max_mm - min_mm)``), the size and pitch of the grid.
    - ``{name}_height.exr``: the same height map, float32, mm (exact).
    - ``{name}_report.json`` / ``{name}_report.txt``: the `manufacturability` report.

    **Arguments:**

    - `scene_or_surface`: a `LensScene` or a `HeightField` (then give `thickness`).
    - `directory`: the output folder.
    - `thickness`: metres (> 0) with a `HeightField`; None with a `LensScene`.
    - `name`: file name stem (no path separators).
    - `samples`: ``(rows, cols)`` of the mesh and height-map grid (see `lens_height_map`).
    - `tool_radius_mm`, `min_thickness_mm`, `max_slope_deg`, `margin_mm`: for the report
      (see `manufacturability`).
    - `formats`: mesh formats to write, among ``"stl"``, ``"obj"``, ``"ply"``.

    **Returns:** a dict of the written paths with keys the mesh formats and
    ``"height_png"``, ``"height_json"``, ``"height_exr"``, ``"report_json"``,
    ``"report_txt"``.
    """
    d = check_folder(directory, "directory")
    if not isinstance(name, str) or not name or name != Path(name).name or name in (".", ".."):
        raise ValueError(f"`name` must be a plain file name stem, got {name!r}")
    fmts = _check_formats(formats)
    report = manufacturability(
        scene_or_surface,
        thickness=thickness,
        tool_radius_mm=tool_radius_mm,
        min_thickness_mm=min_thickness_mm,
        max_slope_deg=max_slope_deg,
        margin_mm=margin_mm,
    )
    surface, t = _lens(scene_or_surface, thickness)
    z, width, height = _top_mm(surface, t, samples)
    mesh = _trimesh(z, width, height)

    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"`directory` {str(d)!r} cannot be created: {err}") from err
    paths: dict[str, Path] = {}
    for fmt in fmts:
        paths[fmt] = d / f"{name}.{fmt}"
        mesh.export(paths[fmt], file_type=fmt)
    paths["height_png"] = d / f"{name}_height.png"
    lo, hi = write_png_linear16(paths["height_png"], z)
    paths["height_json"] = d / f"{name}_height.json"
    rows, cols = z.shape
    sidecar = {
        "file": paths["height_png"].name,
        "quantity": "z of the top surface above the flat bottom face",
        "unit": "mm",
        "min_mm": lo,
        "max_mm": hi,
        "decode": "z_mm = min_mm + v / 65535 * (max_mm - min_mm)",
        "shape": [rows, cols],
        "width_mm": width,
        "height_mm": height,
        "pitch_mm": [width / (cols - 1), height / (rows - 1)],
        "layout": "pixel [i, j] at x = j * pitch_mm[0], y = i * pitch_mm[1] mm; "
        "row 0 (top of the file) is y = 0",
        "boundary": surface.boundary,  # of the bicubic sampled (`HeightField`)
    }
    paths["height_json"].write_text(json.dumps(sidecar, indent=2) + "\n")
    paths["height_exr"] = d / f"{name}_height.exr"
    write_exr(paths["height_exr"], z)
    paths["report_json"] = d / f"{name}_report.json"
    paths["report_json"].write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    paths["report_txt"] = d / f"{name}_report.txt"
    paths["report_txt"].write_text(str(report) + "\n")
    return paths
