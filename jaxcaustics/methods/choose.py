"""Choosing a method and its knobs for an accuracy budget: ``render(scene, tolerance=t)``.

The choice reads accuracy-time tables measured by ``benchmarks/bench_accuracy.py`` and
stored with the package (``jaxcaustics/data/accuracy.json``): for each scene kind (height-
field water, lens slab, mesh refractor, moving light) one benchmark scene, and for every
method and knob setting that runs on it, its error against the NumPy reference (relative
L1 after a 1-pixel Gaussian blur of both images) and its time per render after
compilation. Among the settings whose method can do everything the scene calls for
(`method_support`), the fastest whose measured error times `margin` is within the
tolerance is picked.

The tables are measurements on one scene per kind and one machine: an error measured on
the benchmark scene is an estimate for another scene of the same kind (the `margin`
absorbs some of the difference), and times scale with the receiver's pixel count and the
machine.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Callable
from importlib import resources
from typing import Any, Literal

import numpy as np

from .. import reference
from .._checks import check_choice, check_number, check_real_array
from ..scene.ellipsoid import EllipsoidScene
from ..scene.mesh import MeshScene
from ..scene.scene import LensScene, WaterScene
from .registry import method_class

#: scene type -> the kind of scene its accuracy table was measured on
SCENE_KINDS = {
    WaterScene: "water",
    LensScene: "lens",
    MeshScene: "mesh",
    EllipsoidScene: "moving_light",
}
#: default safety factor: a setting is chosen only if its measured error times this is
#: within the tolerance. On the held-out scenes of ``benchmarks/bench_tolerance.py`` the
#: choosable settings' errors were at most 1.9 times their tabled errors.
DEFAULT_MARGIN = 2.0


@dataclasses.dataclass(frozen=True)
class Choice:
    """What ``render(scene, tolerance=...)`` picked, and why.

    - `kind`: the scene kind whose table was used (``"water"``, ``"lens"``, ``"mesh"``,
      ``"moving_light"``).
    - `method`, `knobs`: what is passed to `render` (knobs resolved for the scene's
      receiver).
    - `as_mesh`: ``None``, or ``{"subdivisions": k}`` when an `EllipsoidScene` is
      rendered as the triangle mesh `Ellipsoid.to_mesh(k)` in a `MeshScene`.
    - `tolerance`, `margin`: the request.
    - `expected_error`: the error this setting measured on the kind's benchmark scene.
    - `expected_time_s`: its measured time per render (after compilation), seconds,
      scaled by the ratio of the scene's pixel count to the benchmark's (a rough guide:
      machines differ).
    - `table_time_s`, `table_pixels`: the measurement as stored.
    - `candidates`: how many settings of the table the scene's effects allow, and
      `meeting`: how many of them meet the tolerance.
    - `excluded`: ``{method: reason}`` for the table's methods the scene rules out.
    - `row`: the table row chosen, as stored.
    """

    kind: str
    method: str
    knobs: dict[str, Any]
    as_mesh: dict[str, int] | None
    tolerance: float
    margin: float
    expected_error: float
    expected_time_s: float
    table_time_s: float
    table_pixels: tuple[int, int]
    candidates: int
    meeting: int
    excluded: dict[str, str]
    row: dict[str, Any]

    def __str__(self) -> str:
        knobs = ", ".join(f"{k}={v!r}" for k, v in self.knobs.items())
        mesh = f" on its {self.as_mesh['subdivisions']}-subdivision mesh" if self.as_mesh else ""
        return (
            f"{self.method}({knobs}){mesh} for a {self.kind} scene: expected error "
            f"{self.expected_error:.3g} (tolerance {self.tolerance:.3g}, margin "
            f"{self.margin:g}) in about {self.expected_time_s:.3g} s per render after "
            f"compilation ({self.meeting} of {self.candidates} measured settings meet it)"
        )


def image_error(image, reference, blur: float = 1.0, boundary: str = "constant") -> float:
    """The accuracy tables' error: ``sum |g(image) - g(reference)| / sum |g(reference)|``,
    relative L1 after a Gaussian blur ``g`` of `blur` pixels (standard deviation) of
    both images. The one image error of the library, its tests, benchmarks and figures.

    **Arguments:** `image`, `reference`: arrays of the same shape ``(rows, cols)`` or
    ``(rows, cols, channels)`` (channels are blurred separately); `blur` >= 0, pixels
    (0: no blur); `boundary`: beyond the image, ``"constant"`` (zero: a receiver with
    nothing around it) or ``"periodic"`` (the image wraps: a periodic sea's caustic).

    **Returns:** the error, a float (0 for equal images).

    ```pycon
    >>> reference = np.zeros((16, 16)); reference[4:12, 4:12] = 1.0
    >>> round(jc.image_error(1.1 * reference, reference), 3)  # 10% too bright
    0.1
    >>> jc.image_error(reference, reference)
    0.0

    ```
    """
    from scipy.ndimage import gaussian_filter

    a = check_real_array(image, "image").astype(float)
    b = check_real_array(reference, "reference").astype(float)
    if a.shape != b.shape or a.ndim not in (2, 3):
        raise ValueError(
            f"`image` {a.shape} and `reference` {b.shape} must have one shape (rows, cols"
            "[, channels])"
        )
    for name, array in (("image", a), ("reference", b)):
        if not np.all(np.isfinite(array)):
            raise ValueError(f"`{name}` contains NaN or infinite values")
    blur = check_number(blur, "blur", low=0.0)
    periodic = check_choice(boundary, "boundary", ("constant", "periodic")) == "periodic"
    mode: Literal["constant", "wrap"] = "wrap" if periodic else "constant"
    sigma = (blur, blur, 0.0)[: a.ndim]
    ga = gaussian_filter(a, sigma, mode=mode)
    gb = gaussian_filter(b, sigma, mode=mode)
    total = np.abs(gb).sum()
    if not total > 0:
        raise ValueError("`reference` is black: the relative error is undefined")
    return float(np.abs(ga - gb).sum() / total)


def reference_image(scene, **knobs) -> np.ndarray:
    """The NumPy reference's image of `scene`, float64: `reference.trace_water`,
    `trace_lens`, `trace_mesh` or `trace_ellipsoid` by the scene's kind, with `knobs`
    (``photons_per_axis``: per pixel side for water, across the object otherwise)."""
    import inspect

    tracers: dict[str, Callable[..., Any]] = {
        "water": reference.trace_water,
        "lens": reference.trace_lens,
        "mesh": reference.trace_mesh,
        "moving_light": reference.trace_ellipsoid,
    }
    tracer = tracers[scene_kind(scene)]
    names = set(inspect.signature(tracer).parameters) - {"scene", "return_stats"}
    unknown = sorted(set(knobs) - names)
    if unknown:
        raise ValueError(
            f"`{unknown[0]}` is not a knob of {tracer.__name__} (its knobs: "
            f"{', '.join(sorted(names))})"
        )
    return np.asarray(tracer(scene, **knobs))


def allowed_rows(scene, rows: list[dict]) -> tuple[list[dict], dict[str, str]]:
    """The table `rows` whose method can render `scene` (`method_support`; rows with
    ``as_mesh`` only for an `EllipsoidScene`, judged on its mesh), and ``{method:
    reason}`` for the methods ruled out."""
    meshes: dict[int, MeshScene] = {}  # one mesh per subdivision level
    # one verdict per method and mesh (a table has many rows of each method)
    verdicts: dict[tuple[str, int | None], str | None] = {}
    allowed: list[dict] = []
    excluded: dict[str, str] = {}
    for row in rows:
        target, k = scene, None
        if row.get("as_mesh"):
            if not isinstance(scene, EllipsoidScene):
                continue
            k = row["as_mesh"]["subdivisions"]
            if k not in meshes:
                meshes[k] = as_mesh_scene(scene, k)
            target = meshes[k]
        if (row["method"], k) not in verdicts:
            verdicts[row["method"], k] = method_support(row["method"], target)
        reason = verdicts[row["method"], k]
        if reason is None:
            allowed.append(row)
        else:
            excluded.setdefault(row["method"], reason)
    return allowed, excluded


@functools.cache
def _packaged_table() -> dict:
    text = resources.files("jaxcaustics").joinpath("data/accuracy.json").read_text()
    return json.loads(text)


def accuracy_table() -> dict:
    """The stored accuracy-time table (see ``benchmarks/bench_accuracy.py``), as a dict:
    ``table["kinds"][kind]["rows"]`` are the measured settings of that scene kind."""
    return _packaged_table()


def scene_kind(scene) -> str:
    """The kind of `scene` for the accuracy tables (see `SCENE_KINDS`)."""
    for cls, kind in SCENE_KINDS.items():
        if isinstance(scene, cls):
            return kind
    raise ValueError(
        "`scene` must be a WaterScene, LensScene, MeshScene or EllipsoidScene, got "
        f"{type(scene).__name__}"
    )


def method_support(method: str, scene) -> str | None:
    """``None`` if `method` can render everything `scene` calls for, else the reason it
    cannot (an effect the method does not simulate, or a shape it cannot represent).
    `method`: a name in `METHODS` (``"twopass"``, ``"triangles"``,
    ``"caustics_mapping"``, ``"adaptive"``, ``"spot_lights"``); `scene`: a scene of a
    kind in `SCENE_KINDS`. Each method's own `Method.support` says it."""
    cls = method_class(method)
    scene_kind(scene)
    return cls().support(scene)


def as_mesh_scene(scene: EllipsoidScene, subdivisions: int) -> MeshScene:
    """`scene` with its ellipsoid (and ellipsoid occluders) as triangle meshes
    (`Ellipsoid.to_mesh(subdivisions)`), for the mesh methods."""
    return MeshScene(
        scene.generator.to_mesh(subdivisions),
        scene.light,
        scene.receiver,
        ior=scene.ior,
        fresnel=scene.fresnel,
        interfaces=scene.interfaces,
        occluders=tuple(o.to_mesh(subdivisions) for o in scene.occluders),
    )


def resolve_knobs(
    method: str, knobs: dict, shape: tuple[int, int], table_pixels: tuple[int, int]
) -> dict:
    """A table row's knobs for a receiver of `shape` ``(rows, cols)``.

    Photon grids are stored per pixel, ``{"per_pixel": f}``: they become ``round(f *
    max(rows, cols))``, and never fewer than the ``round(f * max(table_pixels))``
    measured (the detail a grid resolves is in the scene, not only in the receiver's
    pixels: fewer photons than measured would not keep the measured error). Adaptive
    caustic maps' grids are then rounded up to their `base` (64) times a power of two
    (`Method.rounded`).
    Other knobs are passed as stored.
    """
    side, table_side = max(shape), max(table_pixels)
    out = {
        name: max(round(v["per_pixel"] * side), round(v["per_pixel"] * table_side))
        if isinstance(v, dict)
        else v
        for name, v in knobs.items()
    }
    rounded = method_class(method).from_knobs(**out).rounded()
    return {name: rounded.knobs()[name] for name in out}


def _check_tolerance(tolerance, margin) -> tuple[float, float]:
    return (
        check_number(tolerance, "tolerance", low=0.0, low_open=True),
        check_number(margin, "margin", low=1.0),
    )


def choose_method(
    scene,
    tolerance: float,
    *,
    method: str | None = None,
    margin: float = DEFAULT_MARGIN,
    table: dict | None = None,
) -> Choice:
    """The fastest measured method and knobs expected to render `scene` within
    `tolerance`.

    **Arguments:**

    - `scene`: a `WaterScene`, `LensScene`, `MeshScene` or `EllipsoidScene`.
    - `tolerance`: the largest acceptable error against the reference: relative L1
      after a Gaussian blur of 1 pixel of both images (``sum |blur(image) -
      blur(reference)| / sum blur(reference)``).
    - `method`: restrict the choice to one method's knobs.
    - `margin`: a setting qualifies if its measured error times `margin` is within
      `tolerance` (>= 1; default 2), for scenes harder than the benchmark's.
    - `table`: an accuracy table in the schema of `accuracy_table()` (default: the
      stored one).

    **Returns:** a `Choice`. Raises `ValueError` if no setting the scene allows meets
    the tolerance (naming the smallest error measured) or the scene's kind has no table.
    """
    tolerance, margin = _check_tolerance(tolerance, margin)
    kind = scene_kind(scene)
    if method is not None:
        method_class(method)
    if table is not None and not isinstance(table, dict):
        raise ValueError(
            f"`table` must be a dict in the schema of accuracy_table(), got {type(table).__name__}"
        )
    table = accuracy_table() if table is None else table
    if kind not in table.get("kinds", {}):
        raise ValueError(f"the accuracy table has no {kind!r} scenes; pass `method=` instead")
    if isinstance(scene, MeshScene) and scene.effects.reflection:
        raise ValueError(
            "the accuracy table's mesh scene is a refractor; mirrors are not measured: pass "
            "`method=` (e.g. 'triangles') instead of `tolerance`"
        )
    entry = table["kinds"][kind]
    rows = [r for r in entry["rows"] if r.get("choosable", True)]
    if method is not None:
        rows = [r for r in rows if r["method"] == method]
        if not rows:
            raise ValueError(f"`method` {method!r} has no measured settings for {kind} scenes")
    allowed, excluded = allowed_rows(scene, rows)
    if not allowed:
        raise ValueError(f"no measured method can render this {kind} scene: {excluded}")
    meeting = [r for r in allowed if r["error"] * margin <= tolerance]
    if not meeting:
        best = min(allowed, key=lambda r: r["error"])
        raise ValueError(
            f"`tolerance` {tolerance:g} is below what any measured setting reaches on "
            f"{kind} scenes with margin {margin:g}: the smallest error is "
            f"{best['error']:.3g} ({best['method']} {best['knobs']}); pass a larger "
            "tolerance, or use the reference tracer"
        )
    row = min(meeting, key=lambda r: (r["time_s"], r["error"]))
    shape = tuple(scene.receiver.shape)
    table_pixels = tuple(entry["pixels"])
    scale = (shape[0] * shape[1]) / (table_pixels[0] * table_pixels[1])
    return Choice(
        kind=kind,
        method=row["method"],
        knobs=resolve_knobs(row["method"], row["knobs"], shape, table_pixels),
        as_mesh=row.get("as_mesh") or None,
        tolerance=tolerance,
        margin=margin,
        expected_error=float(row["error"]),
        expected_time_s=float(row["time_s"]) * scale,
        table_time_s=float(row["time_s"]),
        table_pixels=table_pixels,  # type: ignore[arg-type]
        candidates=len(allowed),
        meeting=len(meeting),
        excluded=excluded,
        row=row,
    )
