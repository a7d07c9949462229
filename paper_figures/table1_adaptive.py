"""Wyman & Nichols, Table 1: photons splatted by dense and adaptive caustic maps.

"Adaptive Caustic Maps Using Deferred Shading" (2009), Table 1, counts the photons
splatted into the caustic map for photon-buffer resolutions 256^2 to 16384^2 (the
Buddha scene) with (a) basic caustic maps, which process the whole dense ``N x N``
photon buffer, (b) adaptive caustic maps with the maximal traversal level metric and
(c) adaptive caustic maps with the maximal caustic-map error metric (their Sections
3.2-4.3). This script makes that table for two scenes, with numbers the paper does not
give:

(a) dense: `jaxcaustics.caustics_mapping` with ``N x N`` photons. The paper's column is
    ``N^2`` (every photon of the buffer is processed); the table also gives the photons
    that are valid (they went through the object) and are actually splatted;
(b) `jaxcaustics.adaptive_caustic_map(metric="traversal")`: a 64^2 base grid, 2 x 2
    clusters that miss the object discarded, the others refined down to the ``N x N``
    level, where all their photons are splatted;
(c) `jaxcaustics.adaptive_caustic_map(metric="error")`: the same, but from the 512^2
    level on a cluster whose four photons land in one caustic-map texel is splatted as
    one photon (the paper's ``check from 512^2``).

For every row the script renders it also gives: photons generated (shaded; adaptive:
all levels), photons splatted, kernel calls (batches), the largest photon buffer of one
call, the time of the call (wall clock, first call: jit compilation included, see
``--repeat``) and the relative L1 error of the receiver image against the ground truth,
``sum |blur(img) - blur(ref)| / sum blur(ref)`` (`jaxcaustics.image_error`), both images
blurred with the same Gaussian of ``--blur`` pixels (default 1; zero outside the
receiver), the reference being
`jaxcaustics.reference.trace_mesh` (NumPy, float64, exact photon tracing with up to
4 interfaces) with ``--reference`` photons per axis over the object's projection.

The scenes, both lit by a directional light 20 degrees off the vertical and seen by a
square receiver (the plane ``z = 0``) about three times the object's size, so that, as
in the paper's scene-wide light frustum, the object covers a modest part (a few percent)
of the light's view, which covers the receiver and the object:

- ``sphere``: a glass icosphere (index 1.5, radius 0.25 m, centre 0.5 m up) over a
  1.5 x 1.5 m receiver;
- ``torus``: a glass torus (radii 0.3 and 0.12 m, tilted 30 degrees about x, centre 0.6 m
  up; watertight, and light may cross it up to four times) over a 2.4 x 2.4 m receiver.

Fixed across rows: the receiver (128 x 128 pixels), the caustic map (512^2 texels over
the light's view), the geometry buffers (1024^2 texels, both methods: so the dense and
the adaptive maps shade the very same photons), ``sigma="auto"`` (``max(0.5, 512 / N)``
texels), a photon-buffer memory limit of 256 MiB per call (the big rows batch).

What differs from the paper: CPU JAX, not OpenGL transform feedback, so times are not
frame rates, and a dense row whose time, extrapolated from the largest dense row run
(time per photon times ``N^2``), exceeds ``--dense-budget`` (120 s) is not rendered: its
``N^2`` is printed with that estimate and the error "not run (time)" (on 2 CPU cores the
dense 16384^2 map, 268M photons, would take half an hour or more); analytic scenes
instead of the Buddha (no hierarchical caustic maps column); the adaptive traversal's
discard test is ``discard="footprint"`` (a cluster is dropped only if no geometry-buffer
texel under it sees the object, so nothing the dense grid finds is lost; ``--discard
samples`` is the paper's test: its four photons miss). The image-space intersection uses
``--iterations`` steps (default 16) of the distance estimate, not the paper's single
step: on the sphere at 1024^2 photons the error is 0.20 with one step (15% of the flux
lost to exit estimates that fall off the object), 0.04 with 8, 0.019 with 16 and 0.013
with 32 steps, so with one step the approximation's own error would hide every change
with ``N``. The errors level off at that floor (and at the image-space method's two
interfaces: the reference follows internal reflections), and once the photons are denser
than the caustic map and the receiver resolve; the reference itself is good to about
0.003 (1024^2 against 1536^2 photons on the sphere).

Writes, to ``--output`` (default ``paper_figures/output/``):

- ``table1_adaptive.md``: the tables (also printed);
- ``table1_adaptive.json``: every number, per-level counts and the settings.

Run ``python paper_figures/table1_adaptive.py`` (15 to 20 minutes on 2 CPU cores, a third
of it jit compilation: every row compiles its own kernels), or ``--quick`` for a smoke
test (the sphere only, 256^2 and 512^2, a 48 x 48 receiver, a 192^2 map, a coarser mesh;
about a minute and a half, nearly all of it compilation).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import jax
import numpy as np
import trimesh

import jaxcaustics as jc
from jaxcaustics import reference

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "output"
NAME = "table1_adaptive"

ZENITH, AZIMUTH = 20.0, 0.0  # degrees
IOR = 1.5
INTERFACES = 4
MIB = 1 << 20

# Full run and --quick: receiver pixels, caustic map and geometry-buffer texels per side,
# reference photons per axis, photon-buffer resolutions, largest dense one rendered,
# mesh detail (icosphere subdivisions; torus major and minor sections).
FULL = dict(
    pixels=128,
    map=512,
    gbuffer=1024,
    reference=1536,
    resolutions=(256, 512, 1024, 2048, 4096, 8192, 16384),
    max_dense=16384,
    subdivisions=4,
    sections=(64, 24),
)
QUICK = dict(
    pixels=48,
    map=192,
    gbuffer=256,
    reference=512,
    resolutions=(256, 512),
    max_dense=512,
    subdivisions=3,
    sections=(32, 12),
)
SCENES = ("sphere", "torus")
QUICK_SCENES = ("sphere",)  # jit compilation dominates --quick: one scene
BLUR = 1.0  # pixels, of the error measure
MEMORY_LIMIT = 256  # MiB
DENSE_BUDGET = 120.0  # seconds: estimated time of the largest dense row rendered
WARM_BELOW = 30.0  # seconds: rows faster than this are timed again, compiled
ITERATIONS = 16
BASE = 64
CHECK_FROM = 512


def sphere_scene(pixels: int, subdivisions: int = FULL["subdivisions"]) -> jc.MeshScene:
    """The glass icosphere (radius 0.25 m, centre 0.5 m up) over a 1.5 m receiver."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.25)
    mesh.apply_translation([0.0, 0.0, 0.5])
    return _scene(mesh, (-0.75, 0.75, -0.75, 0.75), pixels)


def torus_scene(pixels: int, sections=FULL["sections"]) -> jc.MeshScene:
    """The glass torus (radii 0.3 and 0.12 m, tilted 30 degrees about x, centre 0.6 m
    up) over a 2.4 m receiver."""
    mesh = trimesh.creation.torus(0.3, 0.12, major_sections=sections[0], minor_sections=sections[1])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.radians(30.0), [1, 0, 0]))
    mesh.apply_translation([0.0, 0.0, 0.6])
    return _scene(mesh, (-1.2, 1.2, -1.2, 1.2), pixels)


def _scene(mesh, extent, pixels: int) -> jc.MeshScene:
    if not mesh.is_watertight:
        raise RuntimeError("the generator mesh must be watertight")
    if mesh.bounds[0][2] <= 0.0:
        raise RuntimeError("the generator must lie above the receiver z = 0")
    return jc.MeshScene(
        jc.Mesh.from_trimesh(mesh),
        jc.DirectionalLight.from_angles(ZENITH, AZIMUTH),
        jc.PlaneReceiver(extent, (pixels, pixels)),
        ior=IOR,
        interfaces=INTERFACES,
    )


def make_scene(name: str, settings: dict) -> jc.MeshScene:
    if name == "sphere":
        return sphere_scene(settings["pixels"], settings["subdivisions"])
    if name == "torus":
        return torus_scene(settings["pixels"], settings["sections"])
    raise ValueError(f"unknown scene {name!r}")


def _timed(render, repeat: int, warm_below: float):
    """Run `render` (returning a `CausticMapResult`): the last result, its image and
    the time, and whether that time includes jit compilation. ``repeat > 1``: the
    median of the calls after the first; otherwise the first call's time, or, if it
    took less than `warm_below` seconds, a second call's (compiled already)."""
    # every row compiles its own kernels (static photon counts, levels, buffer sizes);
    # XLA's CPU executables each hold dozens of memory mappings, and a full run's
    # thousands of them would pass the kernel's limit (vm.max_map_count, 65530: LLVM
    # "Cannot allocate memory", then a segfault), so drop the previous rows' ones
    jax.clear_caches()
    times, result = [], None
    count = max(1, repeat)
    k = 0
    while k < count:
        start = time.perf_counter()
        result = render()
        image = np.asarray(result.image)  # waits for the computation
        times.append(time.perf_counter() - start)
        k += 1
        if count == 1 and k == 1 and times[0] < warm_below:
            count = 2
    if len(times) == 1:
        return result, image, times[0], True
    return result, image, statistics.median(times[1:]), False


def _row(method: str, n: int, timed, truth, blur: float) -> dict:
    result, image, seconds, compiled = timed
    stats = result.stats
    row = dict(
        method=method,
        photons=n,
        dense_count=n * n,
        generated=int(stats["generated"]),
        splatted=int(stats["splatted"]),
        batches=int(stats["batches"]),
        peak_buffer_photons=int(stats["peak_buffer_photons"]),
        peak_buffer_bytes=int(stats["peak_buffer_bytes"]),
        seconds=seconds,
        compile_included=compiled,
        rel_l1=jc.image_error(image, truth, blur),
        rel_l1_unblurred=jc.image_error(image, truth, 0.0),
        flux_ratio=float(image.sum() / truth.sum()),
        missed_flux_fraction=float(np.asarray(result.missed_flux_fraction).ravel()[0]),
        rendered=True,
    )
    for key in ("generated_per_level", "splatted_per_level", "refined_per_level"):
        if key in stats:
            row[key] = [int(k) for k in stats[key]]
    return row


def run_scene(name: str, settings: dict, args) -> dict:
    scene = make_scene(name, settings)
    faces = int(scene.generator.faces.shape[0])
    start = time.perf_counter()
    truth = reference.trace_mesh(scene, settings["reference"])
    ref_s = time.perf_counter() - start
    print(
        f"[{name}] reference: {settings['reference']}^2 photons through {faces} faces, "
        f"{settings['pixels']}^2 pixels: {ref_s:.1f} s",
        flush=True,
    )
    common = dict(
        map_resolution=settings["map"],
        sigma="auto",
        gbuffer_resolution=settings["gbuffer"],
        iterations=args.iterations,
        memory_limit=args.memory_limit * MIB,
    )
    rows = []
    dense_rate = None  # seconds per dense photon, of the largest dense row run
    for n in settings["resolutions"]:
        estimate = None if dense_rate is None else dense_rate * n * n
        if n <= settings["max_dense"] and (estimate is None or estimate <= args.dense_budget):
            timed = _timed(
                lambda n=n: jc.internal.caustics_mapping(scene, photons=n, **common),
                args.repeat,
                args.warm_below,
            )
            rows.append(_row("dense", n, timed, truth, args.blur))
            dense_rate = timed[2] / (n * n)
        else:
            rows.append(
                dict(
                    method="dense",
                    photons=n,
                    dense_count=n * n,
                    generated=n * n,
                    rendered=False,
                    estimated_seconds=estimate,
                )
            )
        _report(name, rows[-1])
        for metric in ("traversal", "error"):
            timed = _timed(
                lambda n=n, metric=metric: jc.internal.adaptive_caustic_map(
                    scene,
                    photons=n,
                    base=BASE,
                    metric=metric,
                    check_from=CHECK_FROM,
                    discard=args.discard,
                    **common,
                ),
                args.repeat,
                args.warm_below,
            )
            rows.append(_row(metric, n, timed, truth, args.blur))
            _report(name, rows[-1])
    view = np.asarray(timed[0].view.window, dtype=float)
    return dict(
        scene=name,
        faces=faces,
        extent=[float(k) for k in np.asarray(scene.receiver.extent)],
        view_window=view.tolist(),
        reference_seconds=ref_s,
        reference_flux=float(truth.sum()),
        rows=rows,
    )


def _report(name: str, row: dict) -> None:
    n = row["photons"]
    if not row["rendered"]:
        print(f"[{name}] {n}^2 dense: not run (time)", flush=True)
        return
    print(
        f"[{name}] {n}^2 {row['method']}: generated {row['generated']:,}, splatted "
        f"{row['splatted']:,}, {row['batches']} batches, {row['seconds']:.1f} s, "
        f"rel. L1 {row['rel_l1']:.4f}",
        flush=True,
    )


METHOD_NAMES = {
    "dense": "(a) dense caustic map",
    "traversal": "(b) adaptive, max traversal",
    "error": "(c) adaptive, max map error",
}


def markdown(results: list[dict], settings: dict, args, total_s: float) -> str:
    """The tables as markdown."""
    device = jax.devices()[0]
    dtype = "float64" if jax.config.jax_enable_x64 else "float32"
    lines = [
        "# Wyman & Nichols, Table 1: photons splatted into the caustic map",
        "",
        f"Receiver {settings['pixels']}x{settings['pixels']} pixels, caustic map "
        f"{settings['map']}^2, geometry buffers {settings['gbuffer']}^2, sigma='auto', "
        f"image-space intersection ({args.iterations} iteration(s)), base grid {BASE}^2, "
        f"error metric checked from {CHECK_FROM}^2, discard='{args.discard}', memory limit "
        f"{args.memory_limit} MiB per call, {dtype} on {device.platform} "
        f"({jax.device_count()} device(s)). Light: directional, {ZENITH:g} deg zenith. "
        f"Reference: `reference.trace_mesh`, {settings['reference']}^2 photons, "
        f"{INTERFACES} interfaces.",
        "",
        f"Error: relative L1 `sum|blur(img) - blur(ref)| / sum(blur(ref))`, both images "
        f"blurred with the same Gaussian of sigma = {args.blur:g} px (zero outside the "
        "receiver). Time: wall clock of one call, "
        + (
            f"a second call (jit-compiled already) where the first took less than "
            f"{args.warm_below:g} s, else the first call, jit compilation included "
            "(marked *)."
            if args.repeat <= 1
            else f"median of {args.repeat - 1} calls after a warm-up call."
        )
        + (
            f" Dense rows above {settings['max_dense']}^2 are not run."
            if settings["max_dense"] < max(settings["resolutions"])
            else ""
        )
        + " A dense row whose estimated time (the largest dense row run's time per "
        f"photon, times N^2) exceeds {args.dense_budget:g} s is not run (time): its N^2 is "
        "given with that estimate.",
        "",
        f"Total run time: {total_s:.0f} s.",
        "",
    ]
    # paper-style summary: photons processed / splatted per method
    header = "| photon buffer |"
    rule = "|---|"
    for res in results:
        header += (
            f" {res['scene']}: dense N^2 | {res['scene']}: dense, valid splatted | "
            f"{res['scene']}: adaptive, max traversal | {res['scene']}: adaptive, "
            "max map error |"
        )
        rule += "---:|---:|---:|---:|"
    lines += [
        "## Table 1 (photons splatted)",
        "",
        "Dense: N^2 photons processed, and those of them that are valid and splatted; "
        "adaptive: photons splatted (a merged cluster counts once).",
        "",
        header,
        rule,
    ]
    for n in settings["resolutions"]:
        line = f"| {n}^2 |"
        for res in results:
            rows = {r["method"]: r for r in res["rows"] if r["photons"] == n}
            dense = rows["dense"]
            valid = f"{dense['splatted']:,}" if dense["rendered"] else "not run (time)"
            line += (
                f" {n * n:,} | {valid} | {rows['traversal']['splatted']:,} | "
                f"{rows['error']['splatted']:,} |"
            )
        lines.append(line)
    lines.append("")
    for res in results:
        w = res["view_window"]
        x0, x1, y0, y1 = (float(f"{v:.6g}") for v in res["extent"])
        lines += [
            f"## {res['scene']} ({res['faces']} faces; receiver x, y in "
            f"[{x0:g}, {x1:g}] x [{y0:g}, {y1:g}] m, light's "
            f"view {w[1] - w[0]:.3g} x {w[3] - w[2]:.3g} m; reference "
            f"{res['reference_seconds']:.0f} s)",
            "",
            "| photon buffer | method | generated | splatted | splatted / N^2 | batches "
            "| peak buffer (MiB) | time (s) | rel. L1 | unblurred | flux / ref |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for row in res["rows"]:
            n = row["photons"]
            name = METHOD_NAMES[row["method"]]
            if not row["rendered"]:
                est = row["estimated_seconds"]
                est = "" if est is None else f" (est. {est:.0f} s)"
                lines.append(
                    f"| {n}^2 | {name} | {n * n:,} | - | - | - | - | not run{est} "
                    "| not run (time) | - | - |"
                )
                continue
            lines.append(
                f"| {n}^2 | {name} | {row['generated']:,} | {row['splatted']:,} | "
                f"{row['splatted'] / (n * n):.2%} | {row['batches']} | "
                f"{row['peak_buffer_bytes'] / MIB:.1f} | {row['seconds']:.1f}"
                f"{'*' if row['compile_included'] else ''} | "
                f"{row['rel_l1']:.4f} | {row['rel_l1_unblurred']:.4f} | "
                f"{row['flux_ratio']:.3f} |"
            )
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--scenes",
        nargs="+",
        choices=SCENES,
        default=None,
        help="scenes to run (default: both; --quick: sphere)",
    )
    parser.add_argument(
        "--max-resolution",
        type=int,
        default=None,
        metavar="N",
        help="largest photon buffer per side (default: 16384; --quick: 512)",
    )
    parser.add_argument(
        "--max-dense",
        type=int,
        default=None,
        metavar="N",
        help=f"largest dense photon buffer rendered (default: {FULL['max_dense']}; larger "
        "rows are 'not run (time)')",
    )
    parser.add_argument(
        "--dense-budget",
        type=float,
        default=DENSE_BUDGET,
        metavar="SECONDS",
        help="skip ('not run (time)') a dense row whose time, extrapolated from the "
        f"largest dense row run (time per photon), exceeds this (default: {DENSE_BUDGET:g})",
    )
    parser.add_argument(
        "--size", type=int, default=None, metavar="PIXELS", help="receiver pixels per axis"
    )
    parser.add_argument("--map", type=int, default=None, help="caustic map texels per side")
    parser.add_argument("--gbuffer", type=int, default=None, help="geometry buffer texels")
    parser.add_argument(
        "--reference", type=int, default=None, metavar="N", help="reference photons per axis"
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=ITERATIONS,
        help=f"image-space intersection steps (default: {ITERATIONS}; the paper: 1)",
    )
    parser.add_argument(
        "--discard",
        choices=("footprint", "samples"),
        default="footprint",
        help="adaptive discard test (default: footprint; the paper: samples)",
    )
    parser.add_argument(
        "--memory-limit",
        type=int,
        default=MEMORY_LIMIT,
        metavar="MIB",
        help=f"photon buffer per call, MiB (default: {MEMORY_LIMIT})",
    )
    parser.add_argument("--blur", type=float, default=BLUR, help="error blur, pixels")
    parser.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="calls per row: 1 (default): the first call's time, or a second call's if "
        "the first took less than --warm-below; more: the median of the calls after the "
        "first (a warm-up)",
    )
    parser.add_argument(
        "--warm-below",
        type=float,
        default=WARM_BELOW,
        metavar="SECONDS",
        help=f"with --repeat 1, time a second call of rows whose first call took less "
        f"(default: {WARM_BELOW:g} s; 0: always the first call)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="256^2 and 512^2 only, small receiver, map and meshes",
    )
    parser.add_argument("--output", "--out", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    args = parser.parse_args(argv)

    settings = dict(QUICK if args.quick else FULL)
    for key, value in (
        ("pixels", args.size),
        ("map", args.map),
        ("gbuffer", args.gbuffer),
        ("reference", args.reference),
        ("max_dense", args.max_dense),
    ):
        if value is not None:
            settings[key] = value
    if args.max_resolution is not None:
        settings["resolutions"] = tuple(
            n for n in FULL["resolutions"] if n <= args.max_resolution
        ) or (FULL["resolutions"][0],)

    start = time.perf_counter()
    scenes = args.scenes or (QUICK_SCENES if args.quick else SCENES)
    results = [run_scene(name, settings, args) for name in scenes]
    total_s = time.perf_counter() - start

    text = markdown(results, settings, args, total_s)
    print()
    print(text)
    args.output.mkdir(parents=True, exist_ok=True)
    md_path = args.output / f"{NAME}.md"
    md_path.write_text(text + "\n")
    summary = dict(
        settings=dict(
            settings,
            iterations=args.iterations,
            discard=args.discard,
            memory_limit_mib=args.memory_limit,
            blur_px=args.blur,
            repeat=args.repeat,
            base=BASE,
            check_from=CHECK_FROM,
            zenith_deg=ZENITH,
            ior=IOR,
            interfaces=INTERFACES,
            x64=bool(jax.config.jax_enable_x64),
        ),
        total_seconds=total_s,
        scenes=results,
    )
    json_path = args.output / f"{NAME}.json"
    json_path.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {md_path}")
    print(f"wrote {json_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
