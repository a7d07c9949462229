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

import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..io.images import check_folder, write_exr, write_png_linear16
from ..scene.outline import outline_radius
from ..scene.scene import HeightField
from .lens_sampling import (
    _MM,
    _check_samples,
    _evaluate_jit,
    _lens,
    _outline,
    _top_mm,
    lens_height_map,
)
from .manufacturability import ManufacturabilityReport, manufacturability
from .round_solid import ring_angles, ring_points, round_solid_arrays

__all__ = [
    "ManufacturabilityReport",
    "export_lens",
    "lens_height_map",
    "lens_solid",
    "manufacturability",
]

_MESH_FORMATS = ("stl", "obj", "ply")


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
    the plane ``z = 0`` (a fan of triangles), closed by four vertical side walls (a
    `LensScene` with an ellipse or polygon outline: the top on rings over the outline,
    one wall round it, `round_solid`); faces
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
    outline = _outline(scene_or_surface)
    if outline != "rectangle":
        return _trimesh(*_round_solid(surface, t, samples, outline))
    return _trimesh(*_solid_arrays(*_top_mm(surface, t, samples)))


def _round_solid(surface: HeightField, thickness: float, samples, outline):
    """An elliptical or polygonal lens's solid (`round_solid`), its rings as fine as
    `samples`."""
    rows, cols = _check_samples(samples, surface, 2)
    rings = max(1, (max(rows, cols) - 1) // 2)
    x0, x1, y0, y1 = (float(v) for v in np.asarray(surface.extent))
    radius = None
    corners: Sequence[float] = ()
    if outline != "ellipse":  # a polygon: its radius, its corners on every ring
        radius = lambda theta: outline_radius(outline, theta)  # noqa: E731
        corners = [np.arctan2(v, u) for u, v in outline]
    angles = ring_angles(rings, corners)
    x, y = ring_points(angles, x1 - x0, y1 - y0, radius)  # metres from the corner
    dtype = surface.heights.dtype
    h = np.asarray(
        _evaluate_jit(
            surface, jnp.asarray(x + x0, dtype), jnp.asarray(y + y0, dtype), curvature=False
        )[0],
        float,
    )
    z = (thickness + h) * _MM
    if not float(z.min()) > 0.0:
        raise ValueError(
            f"`scene_or_surface`: the top surface dips to {float(z.min()):.6g} mm at or below "
            "the bottom face (thickness + H(x, y) <= 0)"
        )
    return round_solid_arrays(x * _MM, y * _MM, z, angles)


def _trimesh(vertices: np.ndarray, faces: np.ndarray):
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.units = "mm"
    if not (mesh.is_watertight and mesh.is_volume):  # pragma: no cover - a bug if so
        raise RuntimeError("internal error: the lens solid is not a closed volume")
    return mesh


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
    formats: Sequence[str] = ("stl",),
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
    - `formats`: mesh formats to write, among ``"stl"`` (binary; the default),
      ``"obj"``, ``"ply"``. A design with 1024^2 heights is sampled on 2049^2 points:
      8.4M faces, 420 MB as binary STL (measured; at 1025^2 points: 105 MB as STL, 87 MB
      as OBJ).

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
    mesh = lens_solid(scene_or_surface, thickness, samples=samples)
    surface, t = _lens(scene_or_surface, thickness)
    z, width, height = _top_mm(surface, t, samples)  # the height map: all the rectangle

    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"`directory` {str(d)!r} cannot be created: {err}") from err
    # every file written into a staging folder beside them, then renamed into place: a
    # failure (a full disk, a bad mesh) leaves none of them half written or alone
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.partial-", dir=d))
    try:
        staged = _write_export(staging, name, fmts, mesh, z, width, height, surface,
                               scene_or_surface, report)  # fmt: skip
        paths = {}
        for key, path in staged.items():
            paths[key] = d / path.name
            os.replace(path, paths[key])
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return paths


def _write_export(
    d, name, fmts, mesh, z, width, height, surface, scene_or_surface, report
) -> dict[str, Path]:
    """`export_lens`'s files written into `d`: ``{kind: path}``."""
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
        # the blank's outline (`LensScene.outline`): the solid is cut to it
        "outline": _outline(scene_or_surface),
    }
    paths["height_json"].write_text(json.dumps(sidecar, indent=2) + "\n")
    paths["height_exr"] = d / f"{name}_height.exr"
    write_exr(paths["height_exr"], z)
    paths["report_json"] = d / f"{name}_report.json"
    paths["report_json"].write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    paths["report_txt"] = d / f"{name}_report.txt"
    paths["report_txt"].write_text(str(report) + "\n")
    return paths
