"""Caustic maps against caustic triangles: error and time on two glass meshes.

Measures, on this machine's default JAX device (float32 scenes), on two mesh scenes
(a receiver of 2 x 2 m at 128 x 128 pixels on ``z = 0``, light 10 degrees from vertical,
index 1.5, up to 4 interfaces, no Fresnel):

- ``sphere``: a glass ball (trimesh icosphere, 3 subdivisions, 1280 faces, radius 0.5 m,
  centre 1 m above the receiver);
- ``torus``: a glass torus (trimesh torus, major radius 0.3 m, minor radius 0.2 m,
  40 x 16 sections, 1280 faces, watertight), tilted 30 degrees about x, centre 1 m up:
  not convex, genus one, light through both sides of the ring (four interfaces).

Methods, each against the NumPy reference (`reference.trace_mesh`, float64) with many
photons (relative L1 error, no blur):

1. dense caustics mapping (`caustics_mapping`, Shah et al.) with the image-space
   intersection estimate, for ``N x N`` photons over the light's view, each ``N`` at the
   best of a few splat radii ``sigma = f R / N`` texels (``f`` in 1, 2, 4, and 0.5 when 1
   wins; ``R`` the caustic map's resolution, its default);
2. the same with ``intersection="exact"`` (photons ray traced through the mesh), at the
   image-space run's best ``sigma`` for the same ``N``;
3. adaptive caustic maps (`adaptive_caustic_map`, Wyman & Nichols) with each stopping
   metric (``"traversal"``, ``"error"`` checked from a ``check_from`` grid on), for several
   equivalent dense grids, at the dense run's best ``sigma`` for the same ``N``; the
   whole host-side traversal is the timed unit;
4. caustic triangles (`caustic_triangles`, exact reconstruction, window ``"auto"``) for
   several photon grids (exact ray tracing of an ``n x n`` vertex grid over the
   generator);
5. the reference itself at fewer photons (not differentiable; for scale).

Time: median of repeated calls of the public function after a first one (which
compiles), ``jax.block_until_ready`` on the image; compile time = first call minus the
median. Writes ``benchmarks/results/caustic_maps.md`` (tables), ``caustic_maps.json``
(the environment and the raw rows) and ``caustic_maps_error_vs_time.png``.

    python benchmarks/bench_caustic_maps.py                # full run (~20 min on 2 cores)
    python benchmarks/bench_caustic_maps.py --quick        # small grids, to check it runs
    python benchmarks/bench_caustic_maps.py --report-only  # redo .md and .png from the .json
"""

from __future__ import annotations

import argparse
import functools
import inspect
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxcaustics as jc
from jaxcaustics import reference

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import (  # noqa: E402
    Timing,
    environment,
    once,
    pick,
    read_results,
    timed,
    write_results,
)

# relative L1 without a blur (jc.image_error at blur 0)
unblurred_error = functools.partial(jc.image_error, blur=0.0)

RESULTS = Path(__file__).parent / "results"
NAME = "caustic_maps"
MD_NAME = f"{NAME}.md"
PNG_NAME = "caustic_maps_error_vs_time.png"
PIXELS = 128
EXTENT = (-1.0, 1.0, -1.0, 1.0)  # the receiver, metres
ZENITH_DEG = 10.0
SIGMA_FACTORS = (1.0, 2.0, 4.0)  # splat radii searched: f * R / N texels (0.5 if 1 wins)
BUDGETS = (0.2, 0.1, 0.07, 0.05, 0.03)  # error budgets of the "what to pick" table

DENSE = "caustics mapping, image space"
DENSE_EXACT = "caustics mapping, exact"
ADAPTIVE = {"traversal": "adaptive, traversal", "error": "adaptive, error"}
TRIANGLES = "caustic triangles"
REFERENCE = "NumPy reference"
METHODS = (DENSE, DENSE_EXACT, ADAPTIVE["traversal"], ADAPTIVE["error"], TRIANGLES)
STYLES = {  # the same marker and colour for a method in every panel
    DENSE: ("o-", "C0"),
    DENSE_EXACT: ("s-", "C1"),
    ADAPTIVE["traversal"]: ("^-", "C2"),
    ADAPTIVE["error"]: ("v-", "C3"),
    TRIANGLES: ("D-", "C4"),
    REFERENCE: ("x--", "0.5"),
}

# per mode: photon counts per method (N for N x N), reference photons per axis
CONFIGS = {
    "full": dict(
        dense=[32, 64, 128, 256, 512, 1024, 2048],
        dense_exact=[32, 64],
        traversal=[256, 512, 1024, 2048],
        error=[512, 1024, 2048],
        check_from=512,
        triangles=[33, 65, 97],
        truth=2048,
        ref_checks=[512, 1024],
        repeats=5,
    ),
    "quick": dict(
        dense=[64, 128],
        dense_exact=[32],
        traversal=[128, 256],
        error=[256],
        check_from=128,
        triangles=[17, 33],
        truth=512,
        ref_checks=[256],
        repeats=3,
    ),
}


# ----------------------------------------------------------------------------- scenes


def _scene(mesh, pixels, dtype=np.float32):
    """A `MeshScene` whose arrays are all `dtype` (float32 even when JAX's x64 is on, as
    in the test session)."""
    generator = jc.Mesh.from_trimesh(mesh)
    light = jc.DirectionalLight.from_angles(ZENITH_DEG)
    return jc.MeshScene(
        jc.Mesh(np.asarray(generator.vertices, dtype), np.asarray(generator.faces)),
        jc.DirectionalLight(np.asarray(light.direction, dtype)),
        jc.PlaneReceiver(np.asarray(EXTENT, dtype), (pixels, pixels)),
        ior=1.5,
        interfaces=4,
    )


def sphere_scene(pixels=PIXELS):
    """A glass ball: icosphere (3 subdivisions), radius 0.5 m, centre 1 m up."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    mesh.apply_translation([0.0, 0.0, 1.0])
    return _scene(mesh, pixels)


def torus_scene(pixels=PIXELS):
    """A glass torus (radii 0.3 and 0.2 m, 40 x 16 sections), tilted 30 degrees about x,
    centre 1 m up."""
    import trimesh

    mesh = trimesh.creation.torus(0.3, 0.2, major_sections=40, minor_sections=16)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.radians(30), [1, 0, 0]))
    mesh.apply_translation([0.0, 0.0, 1.0])
    if not mesh.is_watertight:
        raise RuntimeError("the torus mesh is not watertight")
    return _scene(mesh, pixels)


SCENES = {
    "sphere": ("glass ball (icosphere, 1280 faces)", sphere_scene),
    "torus": ("tilted glass torus (1280 faces)", torus_scene),
}


# ---------------------------------------------------------------------------- measures


def timing(fn, repeats, first=None):
    """`harness.timed` at this benchmark's budgets: at least 3 calls after the first,
    fewer than `repeats` once they took over 10 s, and 2 once over 20 s (the exact ray
    tracers on a CPU)."""
    return timed(fn, repeats=repeats, budget_s=10.0, long_s=20.0, first=first)


def _row(method, photons, error, t, generated, splatted, **knobs):
    """A table row; `t` a `harness.Timing`."""
    return dict(
        method=method,
        photons=photons,
        generated=int(generated),
        splatted=int(splatted),
        error=error,
        ms=1e3 * t.median,
        compile_s=t.compile_s,
        runs=t.runs,
        **knobs,
    )


def _map_row(method, n, t, truth, **knobs):
    """The row of a caustic map (`t.out`: its result), printed."""
    stats = t.out.stats
    error = unblurred_error(t.out.image, truth)
    row = _row(method, n, error, t, stats["generated"], stats["splatted"], **knobs)
    print("  ", row, flush=True)
    return row


def default_of(fn, name):
    return inspect.signature(fn).parameters[name].default


def reference_rows(scene, truth_p, checks):
    """The truth (reference at `truth_p` photons per axis) and rows for the reference at
    `checks` photons per axis (ascending) against it, each timed once."""

    def trace(p):
        took, (image, stats) = once(lambda: reference.trace_mesh(scene, p, return_stats=True))
        return image, stats, Timing(took, [took], image)  # one call, nothing to compile

    truth, stats, truth_t = trace(truth_p)
    print(f"  reference {truth_p}^2: {truth_t.first:.1f} s", flush=True)
    rows = []
    for p in checks:
        image, st, t = trace(p)
        error = unblurred_error(image, truth)
        rows.append(_row(REFERENCE, p, error, t, st["emitted"], st["on_receiver"]))
        print("  ", rows[-1], flush=True)
    truth_row = _row(REFERENCE, truth_p, None, truth_t, stats["emitted"], stats["on_receiver"])
    return truth, rows, truth_row


def dense_rows(scene, truth, grids, map_resolution, repeats):
    """Image-space caustics mapping at each N, at the best of a few splat radii."""
    rows = []
    for n in grids:
        tried = {}  # factor -> (error, first call s, result)

        def call(f, n=n):
            return jc.internal.caustics_mapping(scene, photons=n, sigma=f * map_resolution / n)

        def attempt(f, tried=tried, call=call):
            first, result = once(call, f)
            tried[f] = (unblurred_error(result.image, truth), first, result)

        for f in SIGMA_FACTORS:
            attempt(f)
        if min(tried, key=lambda f: tried[f][0]) == SIGMA_FACTORS[0]:
            attempt(SIGMA_FACTORS[0] / 2)
        best = min(tried, key=lambda f: tried[f][0])
        sigma = best * map_resolution / n
        t = timing(lambda call=call, best=best: call(best), repeats, first=tried[best][1])
        searched = ", ".join(
            f"{f * map_resolution / n:g}: {tried[f][0]:.4f}" for f in sorted(tried)
        )
        knobs = f"sigma {sigma:g} (errors at sigma {searched})"
        rows.append(_map_row(DENSE, n, t, truth, sigma=sigma, knobs=knobs))
    return rows


def dense_exact_rows(scene, truth, grids, sigmas, repeats):
    rows = []
    for n in grids:
        sigma = sigmas[n]

        def call(n=n, sigma=sigma):
            return jc.internal.caustics_mapping(scene, photons=n, sigma=sigma, intersection="exact")

        t = timing(call, repeats)
        rows.append(_map_row(DENSE_EXACT, n, t, truth, sigma=sigma, knobs=f"sigma {sigma:g}"))
    return rows


def adaptive_rows(scene, truth, grids, metric, check_from, sigmas, repeats):
    rows = []
    for n in grids:
        sigma = sigmas[n]

        def call(n=n, sigma=sigma):
            return jc.internal.adaptive_caustic_map(
                scene, photons=n, metric=metric, check_from=check_from, sigma=sigma
            )

        t = timing(call, repeats)
        knobs = f"sigma {sigma:g}" + (f", check from {check_from}^2" if metric == "error" else "")
        knobs += f", {t.out.stats['batches']} kernel calls"
        rows.append(_map_row(ADAPTIVE[metric], n, t, truth, sigma=sigma, knobs=knobs))
    return rows


def triangle_rows(scene, truth, grids, repeats):
    rows = []
    for n in grids:
        t = timing(lambda n=n: jc.internal.caustic_triangles(scene, photons=n), repeats)
        result = t.out
        valid = int(np.asarray(result.photons.valid).any(axis=0).sum())
        missed = float(np.asarray(result.missed_flux_fraction)[0])
        rows.append(
            _row(
                TRIANGLES,
                n,
                unblurred_error(result.image, truth),
                t,
                n * n,
                valid,
                knobs=f"exact reconstruction, window auto (missed flux {missed:.1e})",
            )
        )
        print("  ", rows[-1], flush=True)
    return rows


def run_scene(name, config):
    label, make = SCENES[name]
    scene = make()
    dtypes = {str(x.dtype) for x in jax.tree.leaves(scene) if hasattr(x, "dtype")}
    assert scene.generator.vertices.dtype == np.float32, dtypes
    print(f"scene {name}: {label}", flush=True)
    map_resolution = 2 * PIXELS  # caustics_mapping's default: twice the receiver's side
    truth, ref_rows, truth_row = reference_rows(scene, config["truth"], config["ref_checks"])
    repeats = config["repeats"]
    dense = dense_rows(scene, truth, config["dense"], map_resolution, repeats)
    sigmas = {r["photons"]: r["sigma"] for r in dense}

    def sigma_at(n):  # the dense run's best radius at the same N (else f = 2)
        return sigmas.get(n, 2.0 * map_resolution / n)

    need = set(config["dense_exact"]) | set(config["traversal"]) | set(config["error"])
    sigmas = {n: sigma_at(n) for n in need}
    rows = dense + dense_exact_rows(scene, truth, config["dense_exact"], sigmas, repeats)
    for metric in ("traversal", "error"):
        rows += adaptive_rows(
            scene, truth, config[metric], metric, config["check_from"], sigmas, repeats
        )
    rows += triangle_rows(scene, truth, config["triangles"], repeats)
    rows += ref_rows
    checks = sorted((r for r in ref_rows if r["error"] is not None), key=lambda r: r["photons"])
    return dict(
        name=name,
        label=label,
        rows=rows,
        truth=truth_row,
        truth_checks=[(r["photons"], r["error"]) for r in checks],
        map_resolution=map_resolution,
    )


# ------------------------------------------------------------------------------ report


def pareto(rows):
    """The rows no other row beats on both time and error (library methods only)."""
    front, best = [], math.inf
    for r in sorted(rows, key=lambda r: (r["ms"], r["error"])):
        if r["error"] < best:
            front.append(r)
            best = r["error"]
    return front


def _library_rows(result):
    return [r for r in result["rows"] if r["method"] != REFERENCE and r["error"] is not None]


def markdown_table(rows, front_ids) -> str:
    cols = [
        "method",
        "photons",
        "knobs",
        "generated",
        "splatted",
        "error",
        "time ms",
        "compile s",
        "runs",
    ]
    head = "| " + " | ".join(cols) + " |\n|" + "|".join(["---"] * 3 + ["--:"] * 6) + "|\n"
    body = []
    for r in rows:
        mark = " **(P)**" if id(r) in front_ids else ""
        body.append(
            "| "
            + " | ".join(
                [
                    r["method"] + mark,
                    f"{r['photons']}^2",
                    r.get("knobs", "") or "float64, binned",
                    f"{r['generated']:,}",
                    f"{r['splatted']:,}",
                    "-" if r["error"] is None else f"{r['error']:.4f}",
                    f"{r['ms']:.1f}" if r["ms"] < 1e4 else f"{r['ms']:.0f}",
                    "-" if r["method"] == REFERENCE else f"{r['compile_s']:.1f}",
                    str(r["runs"]),
                ]
            )
            + " |\n"
        )
    return head + "".join(body)


def budget_table(result) -> str:
    lib = _library_rows(result)
    refs = [r for r in result["rows"] if r["method"] == REFERENCE and r["error"] is not None]
    lines = [
        "| error budget | fastest library setting | its error | time ms |"
        " NumPy reference (not differentiable) |\n|--:|---|--:|--:|---|\n"
    ]
    for budget in BUDGETS:
        ok = [r for r in lib if r["error"] <= budget]
        ok_ref = [r for r in refs if r["error"] <= budget]
        ref_text = (
            "-"
            if not ok_ref
            else "{}^2 photons, {:.0f} ms".format(
                *min(((r["photons"], r["ms"]) for r in ok_ref), key=lambda x: x[1])
            )
        )
        if ok:
            r = min(ok, key=lambda r: r["ms"])
            lines.append(
                f"| {budget:g} | {r['method']}, {r['photons']}^2"
                + (f", sigma {r['sigma']:g}" if "sigma" in r else "")
                + f" | {r['error']:.4f} | {r['ms']:.1f} | {ref_text} |\n"
            )
        else:
            lines.append(f"| {budget:g} | none measured | - | - | {ref_text} |\n")
    return "".join(lines)


def plot(results, path):
    """One panel per scene: error against time, log-log, one line per method, the Pareto
    front of the library methods highlighted."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5.6 * len(results), 4.4), squeeze=False)
    for ax, result in zip(axes[0], results, strict=True):
        front = pareto(_library_rows(result))
        ax.loglog(
            [r["ms"] for r in front],
            [r["error"] for r in front],
            "-",
            drawstyle="steps-post",
            color="gold",
            lw=7,
            alpha=0.45,
            solid_capstyle="round",
            label="Pareto front (library methods)",
            zorder=1,
        )
        for method in (*METHODS, REFERENCE):
            rows = sorted(
                (r for r in result["rows"] if r["method"] == method and r["error"] is not None),
                key=lambda r: r["photons"],
            )
            if not rows:
                continue
            style, color = STYLES[method]
            ax.loglog(
                [r["ms"] for r in rows],
                [r["error"] for r in rows],
                style,
                color=color,
                ms=5,
                label=method,
                zorder=2,
            )
            for r in rows:
                ax.annotate(
                    str(r["photons"]),
                    (r["ms"], r["error"]),
                    fontsize=6,
                    textcoords="offset points",
                    xytext=(3, 2),
                    color=color,
                )
        ax.set_title(f"{result['name']}: {result['label']}", fontsize=9)
        ax.set_xlabel("time per call [ms] (median after compilation)", fontsize=8)
        ax.set_ylabel(
            f"relative L1 error vs reference {result['truth']['photons']}^2 (no blur)", fontsize=8
        )
        ax.tick_params(labelsize=7)
        for axis, subs in ((ax.xaxis, (1.0, 3.0)), (ax.yaxis, (1.0, 2.0, 5.0))):
            axis.set_major_locator(matplotlib.ticker.LogLocator(subs=subs))
            axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def truth_error_text(result) -> str:
    checks = result["truth_checks"]
    truth_p = result["truth"]["photons"]
    text = ", ".join(f"{p}^2: {e:.4f}" for p, e in checks)
    out = f"the reference's own error against it: {text}"
    if checks and checks[-1][0] * 2 == truth_p:
        half, e1 = checks[-1]
        out += f" ({half}^2 has half the truth's photons per axis"
        if len(checks) >= 2 and 0 < e1 < checks[-2][1]:
            rate = checks[-2][1] / e1
            out += (
                f"; at the observed {rate:.1f}x less error per doubling, the truth's own"
                f" error is about {e1 / rate:.4f})"
            )
        else:
            out += f"; the truth's own error is below that, about {e1 / 2:.4f} at first order)"
    return out


def observations(result) -> str:
    """Side-by-side comparisons at equal N, from the rows."""
    by = {(r["method"], r["photons"]): r for r in result["rows"]}
    lines = []

    def pairs(a, b):
        return [(by[a, n], by[b, n]) for m, n in by if m == a and (b, n) in by]

    for d, a in pairs(DENSE, ADAPTIVE["traversal"]):
        lines.append(
            f"- {a['photons']}^2, adaptive traversal against the dense grid: error"
            f" {a['error']:.4f} vs {d['error']:.4f}, {a['ms']:.0f} vs {d['ms']:.0f} ms"
            f" ({d['ms'] / a['ms']:.1f}x faster), {a['generated'] / d['generated']:.0%} of"
            f" the photons shaded, {a['splatted']:,} vs {d['splatted']:,} splatted.\n"
        )
    for t, e in pairs(ADAPTIVE["traversal"], ADAPTIVE["error"]):
        lines.append(
            f"- {e['photons']}^2, adaptive error metric against traversal: error"
            f" {e['error']:.4f} vs {t['error']:.4f}, {e['ms']:.0f} vs {t['ms']:.0f} ms,"
            f" {e['splatted'] / t['splatted']:.0%} of the splats.\n"
        )
    for d, x in pairs(DENSE, DENSE_EXACT):
        lines.append(
            f"- {x['photons']}^2, exact intersection against image space: error"
            f" {x['error']:.4f} vs {d['error']:.4f}, {x['ms']:.0f} vs {d['ms']:.0f} ms.\n"
        )
    return "".join(lines)


NOTES = """
## Notes

- Both maps' geometry buffers default to min(N, 1024) texels, so at equal N the adaptive
  traversal splats the dense grid's photons that go through the object and gives the
  same image (compare `splatted` and the errors). An earlier run with the adaptive
  buffers at the paper's quarter of the map's resolution (256 texels here) was as
  accurate on the ball but not on the torus (0.1309 against 0.1156 at 1024^2).
- The image-space intersection follows two interfaces only and converges slowly near
  the silhouette (see `caustics_mapping`); its error levels off at large N, above the
  truth's own error. The exact intersection removes that, but at the photon counts that
  fit in this run the splat radius dominates the error.
- `intersection="exact"` and caustic triangles trace every photon against every face
  (brute force, `jaxcaustics.trace.intersect.nearest_hits`), milliseconds per photon on this
  CPU; the NumPy reference traces the same mesh much faster per photon, but it is not
  differentiable and not jit-compatible.
- A Pareto point is only as good as the timings: the machine was shared (see the load
  above); compile times of the adaptive maps add up over their kernel sizes.
"""


def write_report(meta, results, out: Path, env=None) -> str:
    text = [
        "# Caustic maps benchmark: dense and adaptive caustic maps against caustic triangles\n\n",
        f"Generated by `benchmarks/bench_caustic_maps.py{' --quick' if meta['quick'] else ''}`."
        f" Device: `{meta['device']}`, JAX {meta['jax']}; float32 scenes. Total run time"
        f" {meta['elapsed_s'] / 60:.1f} min."
        + (f" Library at commit `{meta['commit']}`." if meta.get("commit") else "")
        + "\n\n",
        f"Load (`uptime`) before the run: `{meta['uptime_before']}`; after:"
        f" `{meta['uptime_after']}`. The machine has {meta['cpus']} CPU cores and was"
        " shared with other jobs, so times can be off by tens of percent (the load"
        " average counts runnable processes: above the core count, this benchmark got"
        " only part of the CPU).\n\n",
        "Scenes: receiver 2 x 2 m (`PlaneReceiver((-1, 1, -1, 1), (128, 128))`) on z = 0,"
        f" `DirectionalLight.from_angles({ZENITH_DEG:g})`, `ior=1.5`, `interfaces=4`, no"
        " Fresnel, smooth normals. **sphere**: trimesh icosphere (3 subdivisions, 1280 faces),"
        " radius 0.5 m, centre 1 m up. **torus**: `trimesh.creation.torus(0.3, 0.2,"
        " major_sections=40, minor_sections=16)` (1280 faces, watertight) tilted 30 degrees"
        " about x, centre 1 m up.\n\n",
        "Error: relative L1 (sum |image - truth| / sum truth) over the 128 x 128 pixels, **no"
        " blur**, against the NumPy reference `reference.trace_mesh` (float64, exact ray"
        " tracing, photons at cell centres over the generator's projection, binned). The"
        " image is the caustic light only (light through the generator).\n\n",
        "Time: median of `runs` calls of the public function after a first call (at least 3,"
        " fewer once they took over 10 s, 2 once over 20 s), `jax.block_until_ready` on the"
        " image; `compile s` = first call minus the median (for the exact ray tracers it is"
        " within the run-to-run noise). For the adaptive maps the whole host-side traversal"
        " (every kernel call) is one timed call. The reference is timed once.\n\n",
        "Knobs: `photons` is N for an N x N grid (caustic maps: over the light's view, which"
        " covers the receiver and the object, so most photons miss the object; triangles:"
        " vertices over the generator; reference: cells over the generator's projection)."
        f" Caustic map resolution R = {meta['map_resolution']} (the default, twice the"
        " receiver's side), geometry buffers at their default (min(N, 1024) texels for"
        " both), image-space intersection with"
        f" `iterations={meta['iterations']}` (the default; two interfaces only), base grid 64"
        " for the adaptive maps with the default host-driven traversal (`capacity` not set),"
        " `discard` at its default"
        f" (`{meta['discard']}`). Dense image space: `sigma` (splat standard deviation, map"
        " texels) is the best unblurred error among f R / N for f = 1, 2, 4 (and 0.5 when 1"
        " wins); the errors of all radii tried are listed. Dense exact and adaptive use the"
        " dense image-space best `sigma` at the same N. `generated`: photons shaded or traced"
        " (all levels for adaptive); `splatted`: photons added to the map (a merged cluster"
        " counts once), valid photons for triangles, photons binned on the receiver for the"
        " reference. **(P)**: on the Pareto front of the library methods (no other library"
        " method is both faster and more accurate; the reference is left out of it).\n",
    ]
    for result in results:
        truth = result["truth"]
        lib = _library_rows(result)
        front_ids = {id(r) for r in pareto(lib)}
        text += [
            f"\n## {result['name']}: {result['label']}\n\n",
            f"Truth: the reference with {truth['photons']}^2 photons ({truth['ms'] / 1e3:.0f} s);"
            f" {truth_error_text(result)}.\n\n",
            markdown_table(result["rows"], front_ids),
            "\nFastest measured setting for an error budget:\n\n",
            budget_table(result),
            "\nAt equal N:\n\n",
            observations(result),
        ]
    text += [
        NOTES,
        "\n![Error against time](caustic_maps_error_vs_time.png)\n",
    ]
    report = "".join(text)
    write_results(NAME, results, report, extra=dict(meta=meta), out=out, env=env)
    plot(results, out / PNG_NAME)
    return report


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "load average: " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small grids, to check it runs")
    parser.add_argument("--scenes", default="sphere,torus", help="comma-separated: sphere,torus")
    parser.add_argument("--out", "--output", dest="out", type=Path, default=RESULTS)
    parser.add_argument(
        "--report-only",
        action="store_true",
        help=f"rewrite {MD_NAME} and the plot from the rows stored in {NAME}.json",
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.report_only:
        data = read_results(NAME, args.out)
        if data is None:
            parser.error(f"no {NAME}.json in {args.out}")
        print(write_report(data["meta"], data["rows"], args.out, data["environment"]))
        return
    names = pick(parser, args.scenes, SCENES, "scenes")
    config = CONFIGS["quick" if args.quick else "full"]
    env = environment()
    meta = {k: env[k] for k in ("device", "jax", "cpus", "commit")}
    meta.update(
        quick=args.quick,
        uptime_before=uptime(),
        map_resolution=2 * PIXELS,
        iterations=default_of(jc.internal.caustics_mapping, "iterations"),
        discard=default_of(jc.internal.adaptive_caustic_map, "discard"),
        config=config,
    )
    print(f"device: {meta['device']}; {meta['uptime_before']}", flush=True)
    start = time.perf_counter()
    results = [run_scene(name, config) for name in names]
    meta["elapsed_s"] = time.perf_counter() - start
    meta["uptime_after"] = uptime()
    print(write_report(meta, results, args.out, env))
    print(f"wrote {args.out / MD_NAME} and {PNG_NAME}")


if __name__ == "__main__":
    main()
