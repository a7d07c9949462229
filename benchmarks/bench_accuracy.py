"""One accuracy-time report: every method and knob setting per scene kind, and the table
`render(scene, tolerance=...)` chooses from.

For each scene kind (one benchmark scene per kind, a small receiver, float32 scene
arrays) every (method, knobs) row is rendered through `jc.render` as a user would call
it and measured:

- ``error``: relative L1 after a Gaussian blur of sigma 1 pixel of both images
  (`scipy.ndimage.gaussian_filter`, ``mode="constant"``),
  ``sum |blur(img) - blur(ref)| / sum blur(ref)``, against the densest run of the NumPy
  reference (`reference.trace_water`, `trace_lens`, `trace_mesh`, `trace_ellipsoid`);
- ``time_s``: median of at least 3 calls after the first (``jax.block_until_ready``;
  fewer than `repeats` once they take over `budget_s`); ``compile_s``: the first call
  minus the median.

The reference is measured too, at several photon counts, each against the densest run
(the densest's own error is estimated from the convergence of the others): that is the
reference's own cost for the same error.

Kinds: ``water`` (`WaterScene`, periodic sea, `two_pass` over its window, supersampling
and Newton steps), ``lens`` (`LensScene`, `caustic_triangles` over photons and
reconstruction), ``mesh`` (`MeshScene`, a bumpy glass blob: caustic triangles, caustics
mapping, adaptive caustic maps, caustic spot lights), ``moving_light`` (`EllipsoidScene`,
a glass ball: spot lights fitted per frame, the mesh methods on the ball as a mesh, and,
for the report only, spot lights interpolated from a precomputed table).

Writes the table ``jaxcaustics/data/accuracy.json`` (``--table``; read by
`render(scene, tolerance=...)`; it holds the raw rows and the run's environment) and the
report ``accuracy.md`` with ``accuracy.png`` (``--output``, default
``benchmarks/results/``). Knobs that must grow with the receiver's resolution (photon
grids) are stored as ``{"per_pixel": f}``: ``round(f * max(rows, cols))``
(`resolve_knobs`).

To regenerate ``jaxcaustics/data/accuracy.json``, with ``benchmarks/results/accuracy.md``
and ``accuracy.png``, run the full benchmark (no arguments, about 6 minutes on 2 cores)::

    python benchmarks/bench_accuracy.py

Other uses::

    python benchmarks/bench_accuracy.py --quick --output /tmp/acc --table /tmp/acc/a.json
    python benchmarks/bench_accuracy.py --kinds water,lens # redo some kinds; the others
                                                           # are kept from the table
    python benchmarks/bench_accuracy.py --report-only      # redo .md and .png from the table
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.internal import METHODS, as_mesh_scene, resolve_knobs

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import environment, git_commit, load, once, pick, timed  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
TABLE = ROOT / "jaxcaustics" / "data" / "accuracy.json"
MD_NAME = "accuracy.md"
PNG_NAME = "accuracy.png"
KINDS = ("water", "lens", "mesh", "moving_light")
METRIC = "relative L1 after 1-px Gaussian blur"
BLUR_PX = 1.0
# knobs whose value must grow with the receiver's resolution, stored per pixel
PER_PIXEL_KNOBS = {name: cls.resolution_knobs for name, cls in METHODS.items()}

# --------------------------------------------------------------------------- configs
# rows per kind: (method, knobs as passed to jc.render (photons absolute, converted to
# per-pixel for the table), as_mesh subdivisions or None)


def _water_rows(windows, supersamples, iterations, auto_supersamples=()):
    rows = []
    for window in windows:
        for s in supersamples + (auto_supersamples if window == "auto" else ()):
            n, m = ("auto", "auto") if window == "auto" else window
            knobs = dict(samples_x=n, channels_y=m, supersample=s, hit_iterations=3)
            rows.append(("twopass", knobs, None))
    for it in iterations:  # Newton steps, at the auto window
        rows.append(
            (
                "twopass",
                dict(samples_x="auto", channels_y="auto", supersample=2, hit_iterations=it),
                None,
            )
        )
    return rows


def _lens_rows(photons):
    return [
        ("triangles", dict(photons=n, reconstruction=r), None)
        for r in ("exact", "gouraud")
        for n in photons
    ]


def _mesh_rows(triangles, mapping, adaptive, csl, as_mesh=None):
    rows = [("triangles", dict(photons=n), as_mesh) for n in triangles]
    rows += [("caustics_mapping", dict(photons=n), as_mesh) for n in mapping]
    rows += [("adaptive", dict(photons=n), as_mesh) for n in adaptive]
    rows += [("spot_lights", dict(rays_per_axis=n), as_mesh) for n in csl]
    return rows


def _ball_rows(csl_rays, csl_lights, meshes):
    rows = [
        ("spot_lights", dict(rays_per_axis=n, max_lights=k), None)
        for k in csl_lights
        for n in csl_rays
    ]
    for sub, (triangles, mapping, adaptive) in meshes.items():
        rows += _mesh_rows(triangles, mapping, adaptive, [], as_mesh=sub)
    return rows


CONFIGS = {
    "full": dict(
        pixels=64,
        repeats=5,
        budget_s=10.0,
        water=dict(
            rows=_water_rows([(3, 2), (5, 4), (7, 6), "auto"], (1, 2, 4), [0, 1], (8,)),
            reference=[1, 2, 4, 8, 16],
            truth=32,
        ),
        lens=dict(
            rows=_lens_rows([33, 65, 129, 257, 513]),
            reference=[64, 128, 256, 512, 1024, 2048],
            truth=4096,
        ),
        mesh=dict(
            rows=_mesh_rows(
                [33, 49, 65, 97], [128, 256, 512, 1024], [256, 512, 1024, 2048], [64, 128]
            ),
            reference=[32, 64, 128, 256, 512, 1024],
            truth=2048,
        ),
        moving_light=dict(
            rows=_ball_rows(
                [64, 128, 256],
                [1, 16],
                {2: ([33, 65], [256, 1024], [512, 2048]), 3: ([33, 65], [256, 1024], [512, 2048])},
            ),
            reference=[32, 64, 128, 256, 512, 1024, 2048],
            truth=4096,
            table=dict(subdivisions=1, rays_per_axis=64, tracking_steps=5, max_lights=4),
        ),
    ),
    "quick": dict(
        pixels=24,
        repeats=3,
        budget_s=2.0,
        water=dict(rows=_water_rows([(3, 2), "auto"], (1,), []), reference=[1, 2], truth=4),
        lens=dict(rows=_lens_rows([13]), reference=[64, 128], truth=256),
        mesh=dict(rows=_mesh_rows([13], [64], [64], [16]), reference=[32, 64], truth=128),
        moving_light=dict(
            rows=_ball_rows([16], [2], {1: ([13], [], [])}),
            reference=[64, 128],
            truth=256,
            table=None,
        ),
    ),
}

# --------------------------------------------------------------------------- scenes

F32 = np.float32


def _light(zenith, azimuth=0.0):
    return jc.DirectionalLight(
        np.asarray(jc.DirectionalLight.from_angles(zenith, azimuth).direction, F32)
    )


def _receiver(extent, pixels):
    return jc.PlaneReceiver(np.asarray(extent, F32), (pixels, pixels))


WATER_EXTENT = (0.0, 2.0, 0.0, 2.0)


def water_scene(pixels):
    """A periodic sea (`wave_heights`, 24 waves, RMS 1 cm, seed 1) over a 2 x 2 m tile,
    1 m deep, light 25 degrees from vertical; heights sampled at the receiver's pixels."""
    heights = jc.wave_heights((pixels, pixels), WATER_EXTENT, 0.0, amplitude=0.01, seed=1)
    return jc.WaterScene(
        jc.HeightField(np.asarray(heights, F32), np.asarray(WATER_EXTENT, F32)),
        _light(25.0, 30.0),
        _receiver(WATER_EXTENT, pixels),
        np.asarray(1.0, F32),
    )


def lens_scene(pixels):
    """The smooth lens of `bench_triangles.py`: a bump and a dimple (16^2 clamped height
    samples) on a 10 cm square slab 1 cm thick, screen 30 cm below, normal light."""
    x = (np.arange(16) + 0.5) / 16 * 2 - 1
    xx, yy = np.meshgrid(x, x)
    heights = 1.5e-3 * np.exp(-((xx - 0.2) ** 2 + (yy + 0.1) ** 2) / 0.15) - 1e-3 * np.exp(
        -((xx + 0.3) ** 2 + (yy - 0.3) ** 2) / 0.1
    )
    return jc.LensScene(
        jc.HeightField(np.asarray(heights, F32), np.asarray((0.0, 0.1, 0.0, 0.1), F32), "clamp"),
        _light(0.0, 20.0),
        _receiver((-0.02, 0.12, -0.02, 0.12), pixels),
        np.asarray(0.01, F32),
        np.asarray(0.3, F32),
    )


def blob_mesh(subdivisions=2):
    """A bumpy glass blob: trimesh's icosphere (`subdivisions`) with its radius modulated,
    0.4 m * (1 + 0.12 x y + 0.1 sin 3z + 0.08 x^2) on the unit sphere, centre 1 m up."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(sphere.vertices)
    r = 0.4 * (1 + 0.12 * v[:, 0] * v[:, 1] + 0.1 * np.sin(3 * v[:, 2]) + 0.08 * v[:, 0] ** 2)
    return jc.Mesh(np.asarray(v * r[:, None] + [0.0, 0.0, 1.0], F32), np.asarray(sphere.faces))


def mesh_scene(pixels):
    """The blob (320 faces) over a 2 x 2 m receiver, light 10 degrees from vertical,
    index 1.5, two interfaces, no Fresnel."""
    return jc.MeshScene(blob_mesh(2), _light(10.0), _receiver((-1, 1, -1, 1), pixels), ior=1.5)


def ball_scene(pixels):
    """The glass ball of `bench_spot_lights.py`: radius 0.3 m, centre 1 m up, index 1.5,
    over a 2 x 2 m receiver, light 20 degrees from vertical (azimuth 30)."""
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere(np.asarray((0.0, 0.0, 1.0), F32), F32(0.3)),
        _light(20.0, 30.0),
        _receiver((-1, 1, -1, 1), pixels),
        ior=1.5,
    )


KIND_SCENES = {  # kind -> (scene builder, reference tracer)
    "water": (water_scene, "trace_water"),
    "lens": (lens_scene, "trace_lens"),
    "mesh": (mesh_scene, "trace_mesh"),
    "moving_light": (ball_scene, "trace_ellipsoid"),
}


def trace_reference(function: str, scene, photons: int) -> np.ndarray:
    """``reference.<function>`` at `photons` per axis (per pixel for water)."""
    if function == "trace_water":
        return reference.trace_water(scene, photons_per_axis=photons)
    return getattr(reference, function)(scene, photons)


# --------------------------------------------------------------------------- knobs


def table_knobs(method: str, knobs: dict, pixels: int) -> dict:
    """`knobs` as stored in the table: the resolution-scaled ones as ``{"per_pixel": f}``."""
    out = dict(knobs)
    for name in PER_PIXEL_KNOBS.get(method, ()):
        if name in out:
            f = round(out[name] / pixels, 6)
            if round(f * pixels) != out[name]:
                raise ValueError(f"{name}={out[name]} is not recovered from {f} per pixel")
            out[name] = {"per_pixel": f}
    return out


def scene_for_row(scene, row: dict):
    """The scene a table row renders: `scene` itself, or as a mesh (``as_mesh``)."""
    if row.get("as_mesh"):
        return as_mesh_scene(scene, row["as_mesh"]["subdivisions"])
    return scene


# --------------------------------------------------------------------------- measures


def knob_label(method: str, knobs: dict, as_mesh) -> str:
    """A short label: ``photons 65^2, gouraud``, ``N 3 M 2 S 2 it 3``..."""
    if method == "twopass":
        n, m = knobs["samples_x"], knobs["channels_y"]
        window = "auto" if n == "auto" else f"{n}x{m}"
        text = f"{window} S{knobs['supersample']} it{knobs['hit_iterations']}"
    elif method == "spot_lights":
        if "rays_per_axis" not in knobs:
            text = "table"
        else:
            text = f"{knobs['rays_per_axis']}^2 rays"
            if "max_lights" in knobs:
                text += f" K{knobs['max_lights']}"
    else:
        text = f"{knobs['photons']}^2"
        if knobs.get("reconstruction", "exact") != "exact":
            text += f" {knobs['reconstruction']}"
    if as_mesh is not None:
        text += f" sub{as_mesh}"
    return text


def transfers(method: str, knobs: dict) -> bool:
    """Whether a setting's error here says something about another scene of the kind,
    so that `render(tolerance=)` may choose it. Not for: a fixed two-pass window (it
    suits this scene's slopes only; ``"auto"`` sizes it for any scene), Gouraud triangles
    and caustic spot lights (model errors that do not fall with their knobs and, on the
    held-out scenes of ``bench_tolerance.py``, were 2 to 4 times larger than here)."""
    if method == "twopass":
        return knobs.get("samples_x") == "auto"
    if method == "triangles":
        return knobs.get("reconstruction", "exact") == "exact"
    return method != "spot_lights"


def estimate_of(scene, method: str, knobs: dict, as_mesh) -> dict:
    """The method's own error estimate (`jc.internal.estimate_error`: this setting against its
    next coarser one, with one subdivision fewer for an ellipsoid's mesh) and whether it
    is this setting's (``False``: at the coarsest, the estimate of the next finer one)."""
    instance = METHODS[method].from_knobs(**knobs)
    _, estimate = jc.internal.estimate_error(scene, instance, subdivisions=as_mesh)
    return dict(estimate=estimate.error, estimate_of_row=bool(estimate.fine == instance))


def measure_row(scene, truth, method, knobs, as_mesh, config) -> dict:
    pixels = max(scene.receiver.shape)
    row = dict(
        method=method,
        knobs=table_knobs(method, knobs, pixels),
        as_mesh=None if as_mesh is None else {"subdivisions": as_mesh},
        choosable=transfers(method, knobs),
    )
    target = scene_for_row(scene, row)
    call_knobs = resolve_knobs(method, row["knobs"], scene.receiver.shape, scene.receiver.shape)
    assert call_knobs == knobs, (call_knobs, knobs)
    t = timed(
        lambda: jc.render(target, method, return_stats=True, **call_knobs),
        repeats=config["repeats"],
        budget_s=config["budget_s"],
    )
    image, stats = t.out
    row.update(
        error=jc.image_error(image, truth),
        missed_flux=float(np.max(np.asarray(stats["missed_flux_fraction"]))),
        time_s=t.median,
        compile_s=max(t.compile_s, 0.0),
        runs=t.runs,
        label=knob_label(method, knobs, as_mesh),
    )
    row.update(estimate_of(scene, method, call_knobs, as_mesh))
    if "lights" in stats:  # spot lights: active lights of the (first channel's) set
        row["lights"] = int(np.asarray(stats["lights"][0]))
    if as_mesh is not None:
        row["faces"] = int(target.generator.faces.shape[0])
    return row


def table_row(scene, truth, settings, config) -> dict:
    """Spot lights interpolated per frame from `precompute_spot_lights(scene, **settings)`
    (report only): the precomputation timed once, the frame (`interpolate_spot_lights`
    then `render(scene, "spot_lights", lights=...)`) timed as the other rows."""
    precompute_s, table = once(lambda: jc.precompute_spot_lights(scene, progress=False, **settings))
    direction = scene.light.unit_direction

    def frame():
        lights = jc.internal.interpolate_spot_lights(table, direction)
        return jc.render(scene, "spot_lights", lights=lights)

    t = timed(frame, repeats=config["repeats"], budget_s=config["budget_s"])
    return dict(
        method="spot_lights",
        knobs={},
        as_mesh=None,
        error=jc.image_error(t.out, truth),
        time_s=t.median,
        compile_s=max(t.compile_s, 0.0),
        choosable=False,
        runs=t.runs,
        label=f"table sub{settings['subdivisions']}",
        precompute=dict(settings),
        precompute_s=precompute_s,
        directions=int(len(table.directions)),
    )


def densest_error(rows: list[dict], truth_p: int) -> float | None:
    """The densest reference run's own error, extrapolated: the error of the others
    falls as ``photons^-a`` (``a`` from the two densest of them; 1 with only one), so
    the densest's is the second densest's times ``(p2 / p_densest)^a``."""
    pts = sorted((r["knobs"]["photons_per_axis"], r["error"]) for r in rows)
    if not pts:
        return None
    p1, e1 = pts[-1]
    order = 1.0
    if len(pts) >= 2:
        p0, e0 = pts[-2]
        if e0 > e1 > 0:
            order = math.log(e0 / e1) / math.log(p1 / p0)
    return e1 * (p1 / truth_p) ** order


def run_kind(kind: str, config: dict, log=print) -> dict:
    settings = config[kind]
    build, function = KIND_SCENES[kind]
    scene = build(config["pixels"])
    started, load_before, commit = time.time(), load(), git_commit()
    log(f"{kind}: {build.__doc__.splitlines()[0]} load {load_before}")
    truth_s, truth = once(trace_reference, function, scene, settings["truth"])
    log(f"  truth {settings['truth']}: {truth_s:.1f} s")
    ref_rows = []
    for p in settings["reference"]:
        took, image = once(trace_reference, function, scene, p)
        ref_rows.append(
            dict(
                function=function,
                knobs={"photons_per_axis": p},
                error=jc.image_error(image, truth),
                time_s=took,
            )
        )
        log(f"  {ref_rows[-1]}")
    ref_rows.append(
        dict(
            function=function,
            knobs={"photons_per_axis": settings["truth"]},
            error=densest_error(ref_rows, settings["truth"]),
            time_s=truth_s,
            error_estimated=True,
        )
    )
    rows, failed = [], []
    for method, knobs, as_mesh in settings["rows"]:
        try:
            rows.append(measure_row(scene, truth, method, knobs, as_mesh, config))
        except Exception as error:  # noqa: BLE001 - recorded in the report, run goes on
            failed.append(
                dict(method=method, knobs=knobs, as_mesh=as_mesh, error=repr(error)[:300])
            )
            log(f"  FAILED {method} {knobs} {as_mesh}: {error!r}")
            continue
        log(
            f"  {rows[-1]['method']} {rows[-1]['label']}: error {rows[-1]['error']:.4f}"
            f" {1e3 * rows[-1]['time_s']:.1f} ms (compile {rows[-1]['compile_s']:.1f} s)"
        )
    if settings.get("table"):
        try:
            rows.append(table_row(scene, truth, settings["table"], config))
            log(f"  table: {rows[-1]}")
        except Exception as error:  # noqa: BLE001
            failed.append(
                dict(method="spot_lights", knobs=settings["table"], error=repr(error)[:300])
            )
            log(f"  FAILED table {error!r}")
    return dict(
        scene=" ".join(build.__doc__.split()),
        scene_type=type(scene).__name__,
        pixels=list(scene.receiver.shape),
        rows=rows,
        reference=ref_rows,
        failed=failed,
        started=time.strftime("%Y-%m-%d %H:%M", time.localtime(started)),
        commit=commit,
        elapsed_s=time.time() - started,
        load_before=load_before,
        load_after=load(),
        repeats=config["repeats"],
        budget_s=config["budget_s"],
    )


# --------------------------------------------------------------------------- report


def device_text(env: dict) -> str:
    if env["backend"] == "cpu":
        return f"cpu, {env['cpus']} cores"
    return f"{env['backend']}, {env['device_kind']}"


def reference_time_at(error: float, ref_rows: list[dict]) -> str:
    """The reference's time for `error`, log-log interpolated between its photon counts."""
    pts = sorted((r["error"], r["time_s"]) for r in ref_rows if r["error"])
    if not pts:
        return "-"
    if error < pts[0][0]:
        return f"> {pts[0][1]:.3g} s"
    if error > pts[-1][0]:
        return f"< {pts[-1][1]:.3g} s"
    for (e0, t0), (e1, t1) in zip(pts, pts[1:], strict=False):
        if e0 <= error <= e1:
            w = math.log(error / e0) / math.log(e1 / e0) if e1 > e0 else 0.0
            return f"{math.exp(math.log(t0) + w * math.log(t1 / t0)):.3g} s"
    return "-"


def pareto_ids(rows: list[dict]) -> set[int]:
    """Rows no other choosable row beats on both time and error."""
    front, best = set(), math.inf
    for i, r in sorted(enumerate(rows), key=lambda ir: (ir[1]["time_s"], ir[1]["error"])):
        if r["choosable"] and r["error"] < best:
            front.add(i)
            best = r["error"]
    return front


def knobs_text(row: dict) -> str:
    parts = []
    for k, v in row["knobs"].items():
        v = f"{v['per_pixel']:g}/px" if isinstance(v, dict) else v
        parts.append(f"{k}={v}")
    if "lights" in row:
        parts.append(f"{row['lights']} lights used")
    if row.get("as_mesh"):
        parts.append(
            f"as mesh: {row['as_mesh']['subdivisions']} subdivisions ({row.get('faces')} faces)"
        )
    if row.get("precompute"):
        pre = ", ".join(f"{k}={v}" for k, v in row["precompute"].items())
        parts.append(
            f"precomputed table ({pre}; {row['directions']} directions,"
            f" {row['precompute_s']:.0f} s once)"
        )
    return ", ".join(parts)


def kind_markdown(kind: str, result: dict) -> str:
    rows = result["rows"]
    front = pareto_ids(rows)
    pixels = "x".join(str(p) for p in result["pixels"])
    refs = result["reference"]
    truth = refs[-1]
    out = [
        f"\n## {kind}\n\n",
        f"{result['scene']} Receiver {pixels} pixels. Truth: `reference.{truth['function']}`"
        f" at {truth['knobs']['photons_per_axis']} photons per axis"
        f"{' per pixel' if truth['function'] == 'trace_water' else ''}"
        f" ({truth['time_s']:.1f} s; its own error estimated at {truth['error']:.2g})."
        f" Run {result['started']} at commit `{result['commit']}`"
        f" ({result['elapsed_s'] / 60:.1f} min); load average (1, 5, 15 min) before:"
        f" {', '.join(f'{x:g}' for x in result['load_before'])};"
        f" after: {', '.join(f'{x:g}' for x in result['load_after'])}.\n\n",
        "| method | knobs | error | estimate | time ms | compile s | runs | missed flux"
        " | reference for the same error |\n",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|\n",
    ]
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["method"], rows[i]["time_s"]))
    for i in order:
        r = rows[i]
        missed = f"{r['missed_flux']:.1e}" if r.get("missed_flux") is not None else "-"
        name = (
            r["method"]
            + (" **(P)**" if i in front else "")
            + ("" if r["choosable"] else " (not chosen)")
        )
        estimate = "-"
        if r.get("estimate") is not None:
            estimate = f"{r['estimate']:.4f}" + ("" if r["estimate_of_row"] else " (finer)")
        out.append(
            f"| {name} | {knobs_text(r)} | {r['error']:.4f} | {estimate}"
            f" | {1e3 * r['time_s']:.1f} |"
            f" {r['compile_s']:.1f} | {r['runs']} | {missed}"
            f" | {reference_time_at(r['error'], refs)} |\n"
        )
    out += [
        "\nThe reference (NumPy, float64, one call each; error against the densest run):\n\n",
        "| photons per axis | error | time s |\n|--:|--:|--:|\n",
    ]
    for r in refs:
        est = " (estimated)" if r.get("error_estimated") else ""
        err = "-" if r["error"] is None else f"{r['error']:.4f}{est}"
        out.append(f"| {r['knobs']['photons_per_axis']} | {err} | {r['time_s']:.2f} |\n")
    if result.get("failed"):
        out.append("\nRows that failed (left out of the table):\n\n")
        out += [
            f"- `{f['method']}` {f['knobs']} as_mesh={f.get('as_mesh')}: {f['error']}\n"
            for f in result["failed"]
        ]
    return "".join(out)


def markdown(table: dict) -> str:
    text = [
        "# Accuracy against time, per scene kind\n\n",
        "Generated by `python benchmarks/bench_accuracy.py` (one command; `--kinds` redoes"
        " some kinds, `--report-only` redoes this file and the figure from the table)."
        f" Table for `render(scene, tolerance=...)`: `jaxcaustics/data/accuracy.json`"
        f" (written {table['generated']} at commit `{table['commit']}`)."
        f" Device: {table['device']} (JAX {table.get('jax', '?')}); scene arrays"
        f" {table['dtype']}; the reference in float64 (NumPy).\n\n",
        f"Error: {METRIC}, `sum |blur(img) - blur(ref)| / sum blur(ref)` (Gaussian of sigma 1"
        ' pixel, `scipy.ndimage.gaussian_filter`, `mode="constant"`), against the NumPy'
        " reference's densest run. Time: `jc.render(scene, method, **knobs)` as called,"
        " median of `runs` calls after a first one (at least 3; fewer than 5 once they took"
        " over 10 s), `jax.block_until_ready`; `compile s`: the first call minus the median."
        " `estimate`: the method's own estimate of its error on this scene"
        " (`jc.internal.estimate_error`: the difference between this setting and the next coarser"
        " one of its accuracy knob; `(finer)`: at the coarsest, the estimate for the next"
        " finer setting), which `render(scene, tolerance=t)` refines with where it was"
        " measured reliable; how far to trust it on held-out scenes:"
        " [estimate.md](estimate.md) and its plot below."
        " `missed flux`: the largest"
        " `missed_flux_fraction` over the channels that `render(..., return_stats=True)`"
        " reports (light the method knows it left out: outside a window, unfitted by the"
        " spot lights; negative: Gouraud overshoot)."
        " Knobs written `f/px` are `round(f * max(rows, cols))` (photon grids per axis)."
        " **(P)**: on the Pareto front (no other choosable row is both faster and more"
        " accurate). `(not chosen)`: measured, but `render(scene, tolerance=...)` never"
        " picks it, because its error here does not carry over to other scenes of the kind"
        " (`transfers`: a fixed two-pass window suits this scene's slopes only; Gouraud"
        " triangles and caustic spot lights have model errors that do not fall with their"
        " knobs and were 2 to 4 times larger on the held-out scenes of"
        " `bench_tolerance.py`). `reference for the same error`: the NumPy reference's time at that"
        " error, log-log interpolated between its photon counts (`<`, `>`: outside them)."
        " The machine (2 CPU cores) was shared with other jobs: the load averages are given"
        " per kind; above 2, this benchmark got only part of the CPU and times can be off"
        " by a factor of two or more.\n\n",
        f"![Error against time per scene kind]({PNG_NAME})\n\n",
        "![Error estimates against the true error on held-out scenes](estimate.png)\n",
    ]
    for kind in KINDS:
        if kind in table["kinds"]:
            text.append(kind_markdown(kind, table["kinds"][kind]))
    return "".join(text)


METHOD_STYLES = {
    "twopass": ("o", "C0"),
    "triangles": ("D", "C1"),
    "caustics_mapping": ("s", "C2"),
    "adaptive": ("^", "C3"),
    "spot_lights": ("v", "C4"),
}


def plot(table: dict, path: Path) -> None:
    """One log-log panel per kind: error against time, one marker and colour per method
    (hollow: rendered as a mesh; faint: measured but never chosen; grey star: a
    precomputed spot-light table, per frame), the reference as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = [k for k in KINDS if k in table["kinds"]]
    cols = 2 if len(kinds) > 1 else 1
    nrows = math.ceil(len(kinds) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(6.2 * cols, 4.6 * nrows), squeeze=False)
    for ax, kind in zip(axes.flat, kinds, strict=False):
        result = table["kinds"][kind]
        for method, (marker, color) in METHOD_STYLES.items():
            for mesh, choosable in ((False, True), (True, True), (False, False), (True, False)):
                rows = [
                    r
                    for r in result["rows"]
                    if r["method"] == method
                    and "precompute" not in r
                    and r["choosable"] == choosable
                    and bool(r["as_mesh"]) == mesh
                ]
                if not rows:
                    continue
                label = method + (" (ball as mesh)" if mesh else "")
                label += "" if choosable else " (not chosen)"
                ax.loglog(
                    [r["time_s"] for r in rows],
                    [r["error"] for r in rows],
                    marker,
                    color=color,
                    mfc="none" if mesh else color,
                    alpha=1.0 if choosable else 0.35,
                    ls="none",
                    label=label,
                )
                for r in rows:
                    ax.annotate(
                        r["label"],
                        (r["time_s"], r["error"]),
                        fontsize=5,
                        xytext=(3, 1),
                        textcoords="offset points",
                    )
        for r in result["rows"]:
            if "precompute" in r:
                ax.loglog(
                    r["time_s"],
                    r["error"],
                    "*",
                    color="0.4",
                    ms=9,
                    label=f"spot lights, {r['label']} (per frame)",
                )
        refs = [r for r in result["reference"] if r["error"]]
        ax.loglog(
            [r["time_s"] for r in refs],
            [r["error"] for r in refs],
            "k--",
            marker="x",
            lw=1,
            label="NumPy reference",
        )
        for r in refs:
            ax.annotate(
                f"{r['knobs']['photons_per_axis']}",
                (r["time_s"], r["error"]),
                fontsize=5,
                xytext=(3, -6),
                textcoords="offset points",
            )
        ax.set_title(f"{kind} ({'x'.join(map(str, result['pixels']))} px)", fontsize=9)
        ax.set_xlabel("time per image [s]", fontsize=8)
        ax.set_ylabel("rel. L1 error (1 px blur)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=6)
    for ax in list(axes.flat)[len(kinds) :]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def write_report(table: dict, output: Path) -> None:
    output.mkdir(parents=True, exist_ok=True)
    (output / MD_NAME).write_text(markdown(table))
    plot(table, output / PNG_NAME)


def _existing(path: Path) -> dict | None:
    if path.exists():
        data = json.loads(path.read_text())
        if data.get("schema") == 1:
            return data
    return None


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check it runs")
    parser.add_argument(
        "--kinds", default=",".join(KINDS), help=f"comma-separated: {','.join(KINDS)}"
    )
    parser.add_argument("--output", type=Path, default=RESULTS, help="folder for the .md and .png")
    parser.add_argument("--table", type=Path, default=TABLE, help="the JSON table's path")
    parser.add_argument("--report-only", action="store_true", help="redo .md and .png from --table")
    args = parser.parse_args(argv)
    if args.report_only:
        table = _existing(args.table)
        if table is None:
            parser.error(f"no table at {args.table}")
        write_report(table, args.output)
        return
    kinds = pick(parser, args.kinds, KINDS, "kinds")
    config = CONFIGS["quick" if args.quick else "full"]
    previous = _existing(args.table)
    env = environment()
    table = dict(
        schema=1,
        generated=time.strftime("%Y-%m-%d %H:%M"),
        commit=env["commit"],
        device=device_text(env),
        dtype="float32",
        metric=METRIC,
        jax=env["jax"],
        quick=args.quick,
        environment=env,
        kinds={},
    )
    if previous is not None and previous.get("quick", False) == args.quick:
        table["kinds"] = {k: v for k, v in previous["kinds"].items() if k not in kinds}
    print(f"device: {table['device']}; load {load()}", flush=True)
    for kind in kinds:
        table["kinds"][kind] = run_kind(kind, config, log=lambda *a: print(*a, flush=True))
        table["kinds"] = {k: table["kinds"][k] for k in KINDS if k in table["kinds"]}
        args.table.parent.mkdir(parents=True, exist_ok=True)
        args.table.write_text(json.dumps(table, indent=1) + "\n")  # after every kind
        write_report(table, args.output)
    print(f"wrote {args.table}, {args.output / MD_NAME} and {PNG_NAME}")


if __name__ == "__main__":
    main()
