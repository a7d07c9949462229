"""Caustic spot lights (Liu, Dong, Bao & Peng 2008): fitting, evaluation, error, precomputation.

Measures, on this machine's default JAX device, for a glass sphere (radius 0.3 m, centre
1 m above the receiver, index 1.5, two interfaces, no Fresnel) lit by a directional light
20 degrees from vertical; the scene's arrays are float32 (so the fit and the rendering
run in float32, also in a test session with JAX's x64 on):

- ``fit``: the time to get the CSLs of one light direction: `trace_exit_rays` (N x N
  parallel rays over the ball's bounding sphere) then `fit_spot_lights` (defaults: up
  to 16 lights, 95% of the energy, 64^2 light-plane images), for several N (the paper
  traces 1280^2); the tracing alone is timed too;
- ``eval``: the time to render an 800 x 600 receiver (``samples=1``) from a fitted set,
  `render_spot_lights` as called and under `jax.jit`, with the set's 16 slots and with
  its active lights only;
- ``error``: the error of `spot_lights` (256^2 rays, 2 x 2 samples per pixel) on a 2 x 2
  m receiver of 128 x 128 pixels against the reference (`reference.trace_ellipsoid`,
  2048^2 photons, float64) as a function of ``max_lights`` and of ``energy_fraction``,
  with the reference's own time; timed: the fit on the traced rays and the rendering
  under `jax.jit`;
- ``precompute``: `precompute_spot_lights` (the per-scene phase of Sect. 4: a CSL set per
  icosphere direction, tracking along every edge both ways, matching and triples) for
  42 directions (subdivisions=1), with its phases; the 162-direction run (subdivisions=2,
  the paper's) is extrapolated from it and run for real when the estimate is under
  ``--precompute-limit-min`` minutes.

Time: median of repeated calls after a first one (which compiles), with
``jax.block_until_ready``; compile time = first call minus the median. Error: relative L1
``sum |blur(img) - blur(ref)| / sum blur(ref)``, both blurred by a Gaussian of 1 pixel
(`scipy.ndimage.gaussian_filter`, ``mode="constant"``); the unblurred error is given too.

Writes ``spot_lights.md`` (tables), ``spot_lights.json`` (the environment and the raw
rows) and ``spot_lights_error.png`` to ``--output`` (default ``benchmarks/results/``).

    python benchmarks/bench_spot_lights.py                  # full run (25-60 min, 2 cores)
    python benchmarks/bench_spot_lights.py --quick          # tiny sizes, to check it runs
    python benchmarks/bench_spot_lights.py --parts precompute  # one part; the others are
                                                            # kept from the .json
    python benchmarks/bench_spot_lights.py --report-only    # redo .md and .png from the .json

``--keep-previous-precompute`` (with ``--parts precompute``) keeps the precomputation
already in the .json as earlier runs, for comparison (an earlier library version, say).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxcaustics as jc
from jaxcaustics import reference

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import (  # noqa: E402
    environment,
    git_commit,
    load,
    once,
    pick,
    read_results,
    timed,
    write_results,
)

RESULTS = Path(__file__).parent / "results"
NAME = "spot_lights"
MD_NAME = f"{NAME}.md"
PNG_NAME = "spot_lights_error.png"
PARTS = ("fit", "eval", "error", "precompute")
# the paper's 1280^2 rays need about 1.5 GB for the fit (`fit_bytes`, float32): over the
# library's 1 GiB default `memory_limit`, which then refuses them before compiling
FIT_MEMORY = 4 << 30

ZENITH_DEG = 20.0
RADIUS = 0.3  # m
CENTRE = (0.0, 0.0, 1.0)  # m
EXTENT = (-1.0, 1.0, -1.0, 1.0)  # the error receiver, metres
BLUR_PX = 1.0

CONFIGS = {
    "full": dict(
        fit_rays=[256, 512, 1280],
        repeats=5,
        eval_shape=(600, 800),  # rows, cols: 800 x 600 pixels
        eval_set_rays=1280,  # the lights rendered in "eval": the set fitted at this N
        error_pixels=128,
        error_rays=256,
        max_lights=[1, 2, 3, 4, 8, 16],
        energy_fractions=[0.5, 0.8, 0.9, 0.95, 0.99],
        truth=2048,
        ref_check=1024,
        error_repeats=3,
        precompute=dict(
            rays_per_axis=256,
            tracking_steps=20,
            tracking_rays_per_axis=None,
            fit_knobs={},
            measure=1,  # subdivisions measured
            target=2,  # subdivisions extrapolated (and run if under the limit)
            limit_min=40.0,  # minutes
        ),
    ),
    "quick": dict(
        fit_rays=[32],
        repeats=3,
        eval_shape=(60, 80),
        eval_set_rays=32,
        error_pixels=32,
        error_rays=32,
        max_lights=[1, 16],
        energy_fractions=[0.5, 0.95],
        truth=256,
        ref_check=128,
        error_repeats=3,
        precompute=dict(
            rays_per_axis=16,
            tracking_steps=2,
            tracking_rays_per_axis=None,
            fit_knobs=dict(max_lights=2, resolution=8, axis_iterations=10, fit_steps=10),
            measure=0,
            target=1,
            limit_min=0.0,  # extrapolate only: one precomputation compiles for long enough
        ),
    ),
}


# ----------------------------------------------------------------------------- scene


def sphere_scene(shape=(128, 128), extent=EXTENT, dtype=np.float32):
    """The glass ball over the floor, every array `dtype`."""
    light = jc.DirectionalLight.from_angles(ZENITH_DEG)
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere(np.asarray(CENTRE, dtype), dtype(RADIUS)),
        jc.DirectionalLight(np.asarray(light.direction, dtype)),
        jc.PlaneReceiver(np.asarray(extent, dtype), tuple(shape)),
        ior=1.5,
    )


# ---------------------------------------------------------------------------- timing


def timing(fn, repeats):
    """`harness.timed` at this benchmark's budgets: at least 3 calls after the first,
    fewer than `repeats` once they took over 30 s, and 2 once over 120 s."""
    return timed(fn, repeats=repeats, budget_s=30.0, long_s=120.0)


def _start():
    """Wall time, load and library commit at the start of a part (the commit is read at
    the start: the code is imported then, and a shared checkout may move on during a
    long run)."""
    return time.time(), (load(), git_commit())


def _part_meta(start_wall, start):
    start_load, commit = start
    return dict(
        commit=commit,
        started=time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(start_wall)),
        elapsed_s=time.time() - start_wall,
        load_before=start_load,
        load_after=load(),
    )


# ------------------------------------------------------------------------------ parts


def part_fit(config):
    """Trace + fit for one light direction, at each ray count."""
    start_wall, start_load = _start()
    scene = sphere_scene()
    rows, sets = [], {}
    for n in config["fit_rays"]:

        def trace(n=n):
            return jc.internal.trace_exit_rays(scene, n)

        def trace_fit(n=n):
            return jc.internal.fit_spot_lights(
                jc.internal.trace_exit_rays(scene, n), memory_limit=FIT_MEMORY
            )

        t = timing(trace_fit, config["repeats"])
        lights, info = t.out
        traced = timing(trace, config["repeats"])
        rays = traced.out
        sets[n] = lights
        rows.append(
            dict(
                rays=n,
                ms=1e3 * t.median,
                compile_s=t.compile_s,
                runs=t.runs,
                trace_ms=1e3 * traced.median,
                trace_compile_s=traced.compile_s,
                lights=int(np.sum(np.asarray(lights.active))),
                slots=len(lights),
                fraction=float(info.fraction),
                discarded=float(info.discarded_energy / info.total_energy),
                exiting=int(np.sum(np.asarray(rays.energy) > 0)),
                bundle_rays=[int(x) for x in np.asarray(info.rays) if x > 0],
                dtype=str(lights.origin.dtype),
            )
        )
        print("  fit", rows[-1], flush=True)
    return dict(rows=rows, **_part_meta(start_wall, start_load)), sets


def part_eval(config, lights):
    """Render an 800 x 600 receiver from one fitted set (16 slots, and active only)."""
    start_wall, start_load = _start()
    rows_, cols_ = config["eval_shape"]
    half = cols_ / rows_  # square pixels: 2 m tall, 2 cols/rows m wide
    receiver = jc.PlaneReceiver(np.asarray((-half, half, -1.0, 1.0), np.float32), (rows_, cols_))
    active = np.asarray(lights.active)
    trimmed = lights[np.flatnonzero(active)]
    rows = []
    for label, chosen in (("all slots", lights), ("active only", trimmed)):
        jitted = jax.jit(lambda lt: jc.internal.render_spot_lights(lt, receiver, samples=1))
        for mode, fn in (
            ("as called", lambda c=chosen: jc.internal.render_spot_lights(c, receiver, samples=1)),
            ("jax.jit", lambda c=chosen, j=jitted: j(c)),
        ):
            t = timing(fn, max(config["repeats"], 5))
            image = t.out
            rows.append(
                dict(
                    lights=label,
                    slots=len(chosen),
                    active=int(np.sum(np.asarray(chosen.active))),
                    mode=mode,
                    ms=1e3 * t.median,
                    compile_s=t.compile_s,
                    runs=t.runs,
                    dtype=str(image.dtype),
                    finite=bool(np.all(np.isfinite(np.asarray(image)))),
                )
            )
            print("  eval", rows[-1], flush=True)
    return dict(
        rows=rows,
        shape=[rows_, cols_],
        extent=[-half, half, -1.0, 1.0],
        set_rays=config["eval_set_rays"],
        resolution=int(lights.resolution),
        **_part_meta(start_wall, start_load),
    )


def part_error(config):
    """`spot_lights` against the reference, over max_lights and energy_fraction. The image
    is the public `spot_lights`'s; the times are its two costly steps, timed apart:
    `fit_spot_lights` on the traced rays (jitted inside the library) and
    `render_spot_lights` of the fitted set under `jax.jit` (see section 2 on why not as
    called)."""
    start_wall, start_load = _start()
    p = config["error_pixels"]
    scene = sphere_scene((p, p))
    truth_s, truth = once(reference.trace_ellipsoid, scene, config["truth"])
    check_s, check = once(reference.trace_ellipsoid, scene, config["ref_check"])
    ref = dict(
        truth=config["truth"],
        truth_s=truth_s,
        check=config["ref_check"],
        check_s=check_s,
        check_error=jc.image_error(check, truth),
        check_error_raw=jc.image_error(check, truth, 0),
    )
    print("  reference", ref, flush=True)
    n = config["error_rays"]
    rays = jc.internal.trace_exit_rays(scene, n)
    render = jax.jit(
        lambda lights: jc.internal.render_spot_lights(lights, scene.receiver, samples=2)
    )
    done = {}

    def measure(max_lights, energy_fraction):
        key = (max_lights, energy_fraction)
        if key in done:
            return done[key]

        def fit():
            return jc.internal.fit_spot_lights(
                rays, max_lights=max_lights, energy_fraction=energy_fraction
            )

        fitted = timing(fit, config["error_repeats"])
        result = jc.internal.spot_lights(  # the same fit (compiled now) and its rendering
            scene, rays_per_axis=n, max_lights=max_lights, energy_fraction=energy_fraction
        )
        info = result.fit_info[0]
        lights = result.lights[0]
        rendered = timing(lambda: render(lights), config["error_repeats"])
        done[key] = dict(
            max_lights=max_lights,
            energy_fraction=energy_fraction,
            lights=int(result.stats["lights"][0]),
            fraction=float(info.fraction),
            discarded=float(info.discarded_energy / info.total_energy),
            error=jc.image_error(result.image, truth),
            error_raw=jc.image_error(result.image, truth, 0),
            fit_ms=1e3 * fitted.median,
            fit_compile_s=fitted.compile_s,
            fit_runs=fitted.runs,
            render_ms=1e3 * rendered.median,
            render_compile_s=rendered.compile_s,
            render_runs=rendered.runs,
            dtype=str(result.image.dtype),
        )
        print("  error", done[key], flush=True)
        return done[key]

    by_lights = [measure(k, 0.95) for k in config["max_lights"]]
    by_energy = [measure(16, f) for f in config["energy_fractions"]]
    return dict(
        by_lights=by_lights,
        by_energy=by_energy,
        reference=ref,
        rays=n,
        pixels=p,
        **_part_meta(start_wall, start_load),
    )


class _PhaseClock:
    """Times `precompute_spot_lights`'s phases while it runs, by wrapping the
    `map_sharded` (one call per batched phase, "CSL sets" and "tracking") and
    `build_spot_light_table` (matching and triples, on the host) it calls (the names in
    its module's globals, `precompute_spot_lights.__globals__`), and by timing every
    chunk of the batched phases through the progress-bar hook (`tqdm.auto.tqdm`, which
    `map_sharded` imports when called; each chunk ends with a blocking `device_get`, the
    first includes compilation). The wrappers call the originals unchanged and are
    removed on exit; the library's code is not modified."""

    def __init__(self, log=print):
        self.phases = {}
        self.log = log

    def __enter__(self):
        import tqdm.auto

        # the names `precompute_spot_lights` looks up when it runs: its module's globals
        self._names = names = jc.precompute_spot_lights.__globals__
        self._map, self._build = names["map_sharded"], names["build_spot_light_table"]
        self._tqdm = tqdm.auto.tqdm
        clock = self

        def map_sharded(fn, shared, batch, *, desc=None, chunk=None, devices=None, **kw):
            items = int(np.shape(jax.tree.leaves(batch)[0])[0])
            n_dev = len(jax.devices() if devices is None else devices)
            size = n_dev if chunk is None else -(-int(chunk) // n_dev) * n_dev
            size = min(size, -(-items // n_dev) * n_dev)
            chunks = -(-items // size)
            chunk_times = []

            def tqdm_timer(iterable, **_):
                previous = None
                for x in iterable:
                    now = time.perf_counter()
                    if previous is not None:
                        chunk_times.append(now - previous)
                        k, took = len(chunk_times), chunk_times[-1]
                        clock.log(f"    {desc}: chunk {k}/{chunks}: {took:.1f} s")
                    previous = now
                    yield x
                if previous is not None:
                    chunk_times.append(time.perf_counter() - previous)

            tqdm.auto.tqdm = tqdm_timer
            start = time.perf_counter()
            try:
                out = clock._map(fn, shared, batch, desc=desc, chunk=chunk, devices=devices, **kw)
            finally:
                tqdm.auto.tqdm = clock._tqdm
            took = time.perf_counter() - start
            clock.phases[desc] = dict(
                s=took, items=items, chunk=size, chunks=chunks, chunk_s=chunk_times
            )
            clock.log(f"    {desc}: {took:.1f} s for {items} items in {chunks} chunks")
            return out

        def build(*args, **kwargs):
            start = time.perf_counter()
            out = clock._build(*args, **kwargs)
            clock.phases["matching and triples"] = dict(s=time.perf_counter() - start)
            return out

        names["map_sharded"] = map_sharded
        names["build_spot_light_table"] = build
        return self

    def __exit__(self, *exc):
        import tqdm.auto

        self._names["map_sharded"] = self._map
        self._names["build_spot_light_table"] = self._build
        tqdm.auto.tqdm = self._tqdm
        return False


def directions_count(subdivisions):
    directions, faces = jc.internal.icosphere_directions(subdivisions)
    edges = jc.internal.direction_edges(faces)
    return len(directions), len(edges), len(faces)


def per_device_path() -> str:
    """How `precompute_spot_lights` batches its items here: its `per_device` default
    (``"map"`` on CPU, ``"vmap"`` elsewhere), or ``"vmap"`` for a library without it."""
    import inspect

    if "per_device" not in inspect.signature(jc.precompute_spot_lights).parameters:
        return "vmap"
    return "map" if jax.devices()[0].platform == "cpu" else "vmap"


def run_precompute(scene, subdivisions, settings, log=print):
    """One timed `precompute_spot_lights` call and its phases."""
    commit = git_commit()
    with _PhaseClock(log) as clock:
        start_load = load()
        total, table = once(
            lambda: jc.precompute_spot_lights(
                scene,
                subdivisions=subdivisions,
                rays_per_axis=settings["rays_per_axis"],
                tracking_steps=settings["tracking_steps"],
                tracking_rays_per_axis=settings["tracking_rays_per_axis"],
                progress=False,
                **settings["fit_knobs"],
            )
        )
    v, e, f = directions_count(subdivisions)
    active = np.asarray(table.lights.active)
    return dict(
        subdivisions=subdivisions,
        directions=v,
        edges=e,
        faces=f,
        total_s=total,
        phases=clock.phases,
        mean_lights=float(active.sum(axis=1).mean()),
        max_lights_used=int(active.sum(axis=1).max()),
        slots=int(table.max_lights),
        max_triples=int(table.max_triples),
        mean_triples=float(np.asarray(table.triple_active).sum(axis=1).mean()),
        dtype=str(table.lights.origin.dtype),
        per_device=per_device_path(),
        commit=commit,
        load_before=start_load,
        load_after=load(),
        estimate=False,
    )


def extrapolate(measured, subdivisions):
    """The time of `subdivisions` from a measured run. A batched phase: its compile
    overhead (the first chunk minus the median of the others, if positive) plus, for
    every chunk at the new size, the mean time of the measured chunks after the first
    (the mean, not the median: chunk times vary with the directions in them, and the
    total is what is extrapolated). The host phase scales with the number of faces;
    whatever the phases leave out of the measured total is added as is."""
    v, e, f = directions_count(subdivisions)
    items = {"CSL sets": v, "tracking": 2 * e}
    phases, total = {}, 0.0
    for name, phase in measured["phases"].items():
        if name in items:
            times = phase["chunk_s"]
            rest = times[1:] or times
            compile_s = max(times[0] - statistics.median(rest), 0.0)
            chunks = -(-items[name] // phase["chunk"])
            s = compile_s + statistics.fmean(rest) * chunks
            phases[name] = dict(s=s, items=items[name], chunk=phase["chunk"], chunks=chunks)
        else:
            s = phase["s"] * f / measured["faces"]
            phases[name] = dict(s=s)
        total += s
    other = measured["total_s"] - sum(p["s"] for p in measured["phases"].values())
    return dict(
        subdivisions=subdivisions,
        directions=v,
        edges=e,
        faces=f,
        total_s=total + other,
        phases=phases,
        estimate=True,
        from_subdivisions=measured["subdivisions"],
        per_device=measured.get("per_device", "vmap"),
        commit=measured.get("commit"),
    )


def redo_estimates(part):
    """Recompute the estimate rows of a precompute part from its measured rows (for
    ``--report-only``: the estimate is derived data)."""
    runs = part["runs"]
    measured = [r for r in runs if not r["estimate"]]
    out = []
    for r in runs:
        if r["estimate"]:
            source = next(m for m in measured if m["subdivisions"] == r["from_subdivisions"])
            r = extrapolate(source, r["subdivisions"])
        out.append(r)
    return dict(part, runs=out)


def part_precompute(config, limit_min, log=print):
    start_wall, start_load = _start()
    settings = {k: v for k, v in config["precompute"].items() if k != "limit_min"}
    scene = sphere_scene()
    runs = []
    log(f"  precompute: subdivisions={settings['measure']}")
    measured = run_precompute(scene, settings["measure"], settings, log)
    runs.append(measured)
    log(f"  precompute {_short(measured)}")
    estimate = extrapolate(measured, settings["target"])
    runs.append(estimate)
    log(f"  estimate {_short(estimate)}")
    if estimate["total_s"] < 60 * limit_min:
        real = run_precompute(scene, settings["target"], settings, log)
        runs.append(real)
        log(f"  precompute {_short(real)}")
    fit_defaults = {k: v for k, v in _fit_defaults().items() if k not in settings["fit_knobs"]}
    return dict(
        runs=runs,
        limit_min=limit_min,
        settings=dict(
            settings,
            tracking_rays_per_axis=settings["tracking_rays_per_axis"] or settings["rays_per_axis"],
            fit_knobs=dict(fit_defaults, **settings["fit_knobs"]),
        ),
        devices=[str(d) for d in jax.devices()],
        per_device=per_device_path(),
        **_part_meta(start_wall, start_load),
    )


def _fit_defaults():
    import inspect

    params = inspect.signature(jc.internal.fit_spot_lights).parameters
    keep = ("max_lights", "energy_fraction", "resolution", "cells", "axis_iterations", "fit_steps")
    return {k: params[k].default for k in keep}


def _short(run):
    phases = ", ".join(f"{k} {v['s']:.0f} s" for k, v in run["phases"].items())
    return f"{run['directions']} directions: {run['total_s']:.0f} s ({phases})"


# ----------------------------------------------------------------------------- report


def _f(x, digits=4):
    return "-" if x is None else f"{x:.{digits}f}"


def _ms(x):
    return f"{x:,.0f}" if x >= 100 else f"{x:.1f}"


def _load_text(part):
    before = ", ".join(f"{x:g}" for x in part["load_before"])
    after = ", ".join(f"{x:g}" for x in part["load_after"])
    commit = f" at commit `{part['commit']}`" if part.get("commit") else ""
    return (
        f"Run {part['started']}{commit} ({part['elapsed_s'] / 60:.1f} min); load average"
        " (1, 5, 15"
        f" min) before: {before}; after: {after}."
    )


def fit_section(part, meta, parts=None) -> str:
    rows = part["rows"]
    out = [
        "\n## 1. Fitting the CSLs of one light direction\n\n",
        "`trace_exit_rays(scene, N)` then `fit_spot_lights(rays)` with its defaults"
        " (`max_lights=16`, `energy_fraction=0.95`, `resolution=64`, `cells=32`), one light"
        f" direction ({ZENITH_DEG:g} degrees), {rows[0]['dtype']}; time per direction ="
        " median of `runs` calls after a first (compiling) one; `compile s` = first call"
        " minus the median (the fit compiles once per ray count; `below noise`: the first"
        " call was not measurably slower than the median, the compilation being within"
        " the run-to-run spread of such long calls). `trace ms`: the tracing"
        " alone (already in the total). `exiting`: rays that leave the ball (the grid"
        " covers its bounding sphere); `energy held`: `FitInfo.fraction`; `discarded`:"
        " energy set aside by slots that found no bundle. " + _load_text(part) + "\n\n",
        "| traced rays | exiting | lights | rays per light | energy held | discarded |"
        " trace + fit ms | trace ms | first call s | compile s | runs |\n",
        "|--:|--:|--:|---|--:|--:|--:|--:|--:|--:|--:|\n",
    ]
    for r in rows:
        first = r["ms"] / 1e3 + r["compile_s"]
        compile_s = f"{r['compile_s']:.1f}" if r["compile_s"] > 0 else "below noise"
        out.append(
            f"| {r['rays']}^2 | {r['exiting']:,} | {r['lights']} of {r['slots']} |"
            f" {', '.join(f'{x:,}' for x in r['bundle_rays'])} | {r['fraction']:.4f} |"
            f" {r['discarded']:.4f} | {_ms(r['ms'])} | {_ms(r['trace_ms'])} |"
            f" {first:.1f} | {compile_s} | {r['runs']} |\n"
        )
    return "".join(out)


def eval_section(part, meta, parts=None) -> str:
    rows_, cols_ = part["shape"]
    r0 = part["rows"][0]
    out = [
        f"\n## 2. Evaluating the CSLs on a {cols_} x {rows_} receiver\n\n",
        f"`render_spot_lights(lights, PlaneReceiver(extent, ({rows_}, {cols_})), samples=1)`"
        f" ({cols_} x {rows_} pixels, one point each, extent"
        f" {', '.join(f'{x:.3g}' for x in part['extent'])} m), with the set fitted in"
        f" section 1 at {part['set_rays']}^2 rays: {r0['active']} active lights in"
        f" {r0['slots']} slots, {part['resolution']}^2 light-plane images, {r0['dtype']}."
        " `all slots`: the set as fitted (`max_lights` slots, inactive ones included);"
        " `active only`: the same set cut to its active lights (`lights[active]`, the same"
        " image), to show what the inactive slots cost. `as called`: the public function"
        " as it is (not under `jax.jit`; whatever it traces or compiles per call is in"
        " the time); `jax.jit`: the same call under `jax.jit`. Time: median of `runs`"
        " calls after the first, `block_until_ready`; `compile s`: first call minus the"
        " median. " + _load_text(part) + "\n\n",
        "| lights rendered | slots | call | time ms | compile s | runs |\n",
        "|---|--:|---|--:|--:|--:|\n",
    ]
    for r in part["rows"]:
        out.append(
            f"| {r['lights']} ({r['active']} active) | {r['slots']} | {r['mode']} |"
            f" {_ms(r['ms'])} | {_noisy(r['compile_s'])} | {r['runs']} |\n"
        )
    return "".join(out)


def _noisy(s):
    """A compile time, or "below noise" when the first call was not measurably slower."""
    return f"{s:.1f}" if s >= 0.05 else "below noise"


def _compile(s):
    """A compile time, or "cached" when the first call was not slower than the rest
    (compiled earlier in the run)."""
    return "cached" if s < 0.05 else f"{s:.1f}"


def _error_table(rows, first_col, key):
    out = [
        f"| {first_col} | lights used | energy held | discarded | error (1 px blur) |"
        " error (no blur) | fit ms | fit compile s | render ms | render compile s |\n",
        "|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n",
    ]
    for r in rows:
        discarded = f"{r['discarded']:.4f}" if "discarded" in r else "-"
        out.append(
            f"| {r[key]:g} | {r['lights']} | {r['fraction']:.4f} | {discarded} |"
            f" {r['error']:.4f} |"
            f" {r['error_raw']:.4f} | {_ms(r['fit_ms'])} | {_compile(r['fit_compile_s'])} |"
            f" {_ms(r['render_ms'])} | {_compile(r['render_compile_s'])} |\n"
        )
    return "".join(out)


def error_section(part, meta, parts=None) -> str:
    ref = part["reference"]
    p = part["pixels"]
    return "".join(
        [
            "\n## 3. Error against the reference\n\n",
            f"`spot_lights(scene, rays_per_axis={part['rays']}, max_lights=K,"
            " energy_fraction=f)` (2 x 2 samples per pixel, its default; the image in the"
            " library's units, irradiance relative to that of the light on a horizontal"
            f" plane) on a 2 x 2 m receiver of {p} x {p} pixels against"
            f" `reference.trace_ellipsoid(scene, {ref['truth']})` (float64, exact ray"
            f" tracing, {ref['truth']}^2 photons binned). Error: relative L1 `sum |blur(img)"
            " - blur(ref)| / sum blur(ref)`, both blurred by a Gaussian of sigma"
            f' {BLUR_PX:g} pixel (`scipy.ndimage.gaussian_filter`, `mode="constant"`);'
            " the unblurred error is given too. Time, median of calls after the first"
            f" ({part['by_lights'][0]['fit_runs']} or more): `fit ms`,"
            f" `fit_spot_lights(rays, max_lights=K, energy_fraction=f)` on the {part['rays']}^2"
            " traced rays (the tracing is in section 1; every `max_lights` compiles anew, a"
            " static knob; `energy_fraction` does not); `render ms`: `render_spot_lights` of"
            " the fitted set (`samples=2`, the set's `max_lights` slots) under `jax.jit`;"
            " `cached`: compiled earlier in the run. Fit and render in"
            f" {part['by_lights'][0]['dtype']}. " + _load_text(part) + "\n\n",
            f"Reference: {ref['truth']}^2 photons took {ref['truth_s']:.1f} s (NumPy,"
            f" float64, one call, not differentiable); {ref['check']}^2 photons took"
            f" {ref['check_s']:.1f} s and differ from it by {ref['check_error']:.4f} (1 px"
            f" blur; {ref['check_error_raw']:.4f} unblurred): the truth's own error is"
            " below that (about half at first order).\n\n",
            "Against the number of CSLs (`energy_fraction=0.95`):\n\n",
            _error_table(part["by_lights"], "max_lights", "max_lights"),
            "\nAgainst the energy threshold (`max_lights=16`):\n\n",
            _error_table(part["by_energy"], "energy_fraction", "energy_fraction"),
            f"\n![Error against the number of CSLs and the energy threshold]({PNG_NAME})\n",
        ]
    )


def _precompute_row(run):
    ph = run["phases"]
    label = "**estimate**" if run["estimate"] else "measured"
    if run["estimate"]:
        label += f" (from {run['from_subdivisions']})"

    def cell(name):
        if name not in ph:
            return "-"
        s = ph[name]["s"]
        text = f"{s:,.0f}" if s >= 10 else f"{s:.2f}"
        if not run["estimate"] and "chunk_s" in ph[name]:
            times = ph[name]["chunk_s"]
            steady = statistics.median(times[1:]) if len(times) > 1 else times[0]
            text += (
                f" ({ph[name]['chunks']} x {ph[name]['chunk']}; first {times[0]:.0f},"
                f" median {steady:.1f})"
            )
        return text

    extra = (
        "- | -"
        if run["estimate"]
        else f"{run['mean_lights']:.2f} (max {run['max_lights_used']}) |"
        f" {run['mean_triples']:.2f} (max {run['max_triples']})"
    )
    path = f"`{run.get('per_device', 'vmap')}`"
    if run.get("commit"):
        path += f" ({run['commit']})"
    return (
        f"| {run['subdivisions']} | {run['directions']} | {run['edges']} | {run['faces']} |"
        f" {path} | {label} | {cell('CSL sets')} | {cell('tracking')} |"
        f" {cell('matching and triples')} |"
        f" {run['total_s']:,.0f} s ({run['total_s'] / 60:.1f} min) | {extra} |\n"
    )


def precompute_section(part, meta, parts=None) -> str:
    s = part["settings"]
    knobs = ", ".join(f"`{k}={v}`" for k, v in s["fit_knobs"].items())
    measured = [r for r in part["runs"] if not r["estimate"]]
    dtype = measured[0]["dtype"] if measured else "?"
    target = [r for r in part["runs"] if r["subdivisions"] == s["target"]]
    ran_target = any(not r["estimate"] for r in target)

    def numbers(xs):
        return ", ".join(f"{x:g}" for x in xs)

    loads = "; ".join(
        f"{r['directions']} directions: load before {numbers(r['load_before'])},"
        f" after {numbers(r['load_after'])}"
        for r in measured
    )
    big = directions_count(s["target"])[0]
    if ran_target:
        verdict = (
            f"The estimate for {big} directions was under {part['limit_min']:g} min, so that"
            " run was made for real (its `measured` row)."
        )
    elif part["limit_min"] > 0:
        verdict = (
            f"The estimate for {big} directions is over {part['limit_min']:g} min, so that run"
            " was **not** made: its row is an extrapolation, not a measurement."
        )
    else:
        verdict = f"The {big}-direction row is an extrapolation only (not run in this mode)."
    return "".join(
        [
            "\n## 4. Precomputation (per scene, Sect. 4)\n\n",
            f"`precompute_spot_lights(scene, subdivisions=S, rays_per_axis={s['rays_per_axis']},"
            f" tracking_steps={s['tracking_steps']})`: tracking at"
            f" {s['tracking_rays_per_axis']}^2 rays per step, fit knobs {knobs}"
            f" (`fit_spot_lights`'s defaults unless passed), {dtype} (the table's dtype,"
            f" JAX's default float), on {', '.join(part['devices'])} ({meta['cpus']} CPU"
            f" cores, shared), batching path `per_device='{part.get('per_device', 'vmap')}'`"
            " (the library's default on this device at that commit: `map` runs a chunk's"
            " items one after the other with `lax.map`, `vmap` vectorises them, its while"
            " loops running until the slowest item is done). Phases, timed around the"
            " library's own calls (see `_PhaseClock`): **CSL sets** (trace and fit every"
            " direction, in chunks of directions), **tracking** (every edge both ways,"
            " `tracking_steps` traces and axis refinements, in chunks of directed edges),"
            " **matching and triples** (host). A phase's cell: seconds (chunks x items per"
            " chunk; first chunk s, which includes compilation, and the median of"
            " the others). The estimate (`extrapolate`) takes for each batched phase its"
            " compile overhead (first chunk minus the median of the others) plus its number"
            " of chunks at the new size times the mean time of the measured chunks after the"
            " first, and scales the host phase by the number of faces. "
            + verdict
            + " "
            + _load_text(part)
            + f" Per run: {loads}.\n\n",
            "| subdivisions | directions | edges | faces | path (commit) | kind | CSL sets s |"
            " tracking s | matching and triples s | total | lights per direction |"
            " triples per face |\n",
            "|--:|--:|--:|--:|---|---|---|---|--:|--:|--:|--:|\n",
            *(_precompute_row(r) for r in part["runs"]),
            _previous_text(part),
            _per_direction(part, parts),
            "\nThe paper reports 4 to 8 hours per scene for 162 directions at 1280^2 rays"
            " (a 2008 PC, a mesh of 20k to 48k vertices), with 7.6 to 8.5 CSLs per"
            " direction and 9.7 to 12 triples per face (its Table 2).\n",
        ]
    )


def _previous_text(part) -> str:
    """Rows of earlier precomputation runs kept with ``--keep-previous-precompute``."""
    previous = part.get("previous") or []
    if not previous:
        return ""
    rows = [_precompute_row(r) for old in previous for r in old["runs"]]
    loads = " ".join(_load_text(old) for old in previous)
    return (
        "\nEarlier runs, kept for comparison (an earlier library, or another `per_device`"
        " path: `vmap` batches a chunk's items with `jax.vmap`, so its while loops run until"
        " the slowest item is done; `map` runs them one after the other with `lax.map`). "
        + loads
        + "\n\n| subdivisions | directions | edges | faces | path (commit) | kind | CSL sets s |"
        " tracking s | matching and triples s | total | lights per direction |"
        " triples per face |\n|--:|--:|--:|--:|---|---|---|---|--:|--:|--:|--:|\n" + "".join(rows)
    )


def _per_direction(part, parts) -> str:
    """The CSL-sets phase's time per direction against one direction alone (section 1)."""
    measured = [r for r in part["runs"] if not r["estimate"]]
    if not measured or "CSL sets" not in measured[0]["phases"]:
        return ""
    phase = measured[0]["phases"]["CSL sets"]
    times = phase["chunk_s"][1:] or phase["chunk_s"]
    each = statistics.fmean(times) / phase["chunk"]
    text = (
        f"\nPer direction, the CSL-sets phase (path `{measured[0].get('per_device', 'vmap')}`,"
        f" {phase['chunk']} directions per chunk) took {each:.1f} s (mean chunk after the"
        f" first / {phase['chunk']})"
    )
    rays = part["settings"]["rays_per_axis"]
    fit_rows = [r for r in (parts or {}).get("fit", {}).get("rows", []) if r["rays"] == rays]
    if fit_rows:
        text += (
            f"; one direction alone (section 1, {rays}^2 rays, the same knobs) took"
            f" {fit_rows[0]['ms'] / 1e3:.1f} s (at a different load: compare the load averages)"
        )
    return text + ".\n"


SECTIONS = dict(
    fit=fit_section, eval=eval_section, error=error_section, precompute=precompute_section
)


def plot(part, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = part["reference"]
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 3.2))
    for ax, rows, key, label in (
        (axes[0], part["by_lights"], "max_lights", "max_lights (energy_fraction 0.95)"),
        (axes[1], part["by_energy"], "energy_fraction", "energy_fraction (max_lights 16)"),
    ):
        x = [r[key] for r in rows]
        ax.plot(x, [r["error"] for r in rows], "o-", color="C0", label="1 px blur")
        ax.plot(x, [r["error_raw"] for r in rows], "s--", color="C1", label="no blur")
        for r in rows:
            ax.annotate(
                f"{r['lights']}", (r[key], r["error"]), textcoords="offset points",
                xytext=(3, 4), fontsize=6,
            )  # fmt: skip
        ax.axhline(
            ref["check_error"], color="0.5", ls=":", lw=1,
            label=f"reference {ref['check']}^2 vs {ref['truth']}^2 (1 px blur)",
        )  # fmt: skip
        if key == "max_lights":
            ax.set_xscale("log", base=2)
            ax.set_xticks(x)
            ax.set_xticklabels([f"{v:g}" for v in x])
        ax.set_xlabel(label, fontsize=8)
        ax.set_ylabel(f"relative L1 error vs reference {ref['truth']}^2", fontsize=8)
        ax.set_ylim(bottom=0)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6, loc="best")
    fig.suptitle(
        f"Caustic spot lights, glass ball, {part['rays']}^2 rays, {part['pixels']}^2 pixels"
        " (numbers: lights used)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


NOTES = """
## Notes

- All times on a shared machine (see the load averages of each section: above the core
  count, this benchmark got only part of the CPU), so they can be off by tens of percent.
- The fit and the tracking are fixed-shape JAX programs (masks, `lax.while_loop`s): the
  bundles' ray assignment and the rasterisation touch every traced ray for every light
  slot, so their cost grows with the traced rays times the slots used. Under `vmap`
  (precomputation) a batch's while loops run until the slowest member is done.
- Section 2 shows what inactive light slots and calling the renderer outside `jax.jit`
  cost at the commit it ran at (the library's rendering changed in `f48f552`: compiled
  once per shape, inactive slots skipped; runs before it scanned every slot and
  recompiled at every un-jitted call).
"""


def write_report(data, out: Path) -> str:
    """The report of `data` (``meta``, ``rows``: the parts, ``environment`` when known),
    written with the data beside it."""
    meta, parts = data["meta"], data["rows"]
    text = [
        "# Caustic spot lights benchmark (Liu, Dong, Bao & Peng 2008)\n\n",
        f"Generated by `benchmarks/bench_spot_lights.py{' --quick' if meta['quick'] else ''}`."
        f" Device: `{meta['device']}` ({meta['cpus']} CPU cores, {meta['machine']}), JAX"
        f" {meta['jax']}; **float32** scene arrays, fit and rendering (the reference is"
        " float64)."
        + " Sections can come from separate runs (`--parts`): each gives the commit it ran"
        " at and the load average (`os.getloadavg()`) before and after it; the machine"
        " was shared with other jobs.\n\n",
        f"Scene: `EllipsoidScene(Ellipsoid.sphere({CENTRE}, {RADIUS}),"
        f" DirectionalLight.from_angles({ZENITH_DEG:g}), PlaneReceiver(...), ior=1.5)`:"
        " a glass ball of radius 0.3 m, centre 1 m above the receiver (z = 0), light"
        f" {ZENITH_DEG:g} degrees from vertical, two interfaces, no Fresnel.\n",
    ]
    for name in PARTS:
        if name in parts:
            text.append(SECTIONS[name](parts[name], meta, parts))
    text.append(NOTES)
    report = "".join(text)
    write_results(NAME, parts, report, dict(meta=meta), out, data.get("environment"))
    if "error" in parts:
        plot(parts["error"], out / PNG_NAME)
    return report


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check it runs")
    parser.add_argument("--out", "--output", dest="out", type=Path, default=RESULTS)
    parser.add_argument(
        "--parts",
        default=",".join(PARTS),
        help=f"comma-separated, of {','.join(PARTS)}; parts not run are kept from an"
        f" existing {NAME}.json of the same mode",
    )
    parser.add_argument(
        "--precompute-limit-min",
        type=float,
        default=None,
        help="run the larger precomputation (162 directions) only if its estimate is under"
        " this many minutes (default 40; 0 in quick mode)",
    )
    parser.add_argument(
        "--keep-previous-precompute",
        action="store_true",
        help="with --parts precompute: keep the existing precompute results as earlier runs",
    )
    parser.add_argument("--report-only", action="store_true", help=f"rewrite from {NAME}.json")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    md = args.out / MD_NAME
    old = read_results(NAME, args.out)
    if args.report_only:
        if old is None:
            parser.error(f"no {NAME}.json in {args.out}")
        data = old
        if "precompute" in data["rows"]:
            part = redo_estimates(data["rows"]["precompute"])
            if "previous" in part:
                part["previous"] = [redo_estimates(x) for x in part["previous"]]
            data["rows"]["precompute"] = part
        print(write_report(data, args.out))
        return
    parts = pick(parser, args.parts, PARTS, "parts")
    config = CONFIGS["quick" if args.quick else "full"]
    env = environment()
    meta = {k: env[k] for k in ("device", "jax", "cpus", "machine", "commit")}
    meta.update(quick=args.quick, config=config)
    data = dict(environment=env, meta=meta, rows={})
    previous = []
    if set(parts) != set(PARTS) and old is not None:
        if old["meta"]["quick"] == args.quick:
            data["rows"] = {k: v for k, v in old["rows"].items() if k not in parts}
            if args.keep_previous_precompute and "precompute" in old["rows"]:
                kept = old["rows"]["precompute"]
                previous = kept.pop("previous", []) + [kept]
    print(f"device: {meta['device']}; load {load()}", flush=True)
    sets = None
    if "fit" in parts:
        data["rows"]["fit"], sets = part_fit(config)
    elif "eval" in parts:  # the set to render, fitted once (untimed)
        n = config["eval_set_rays"]
        sets = {n: jc.internal.fit_spot_lights(jc.internal.trace_exit_rays(sphere_scene(), n))[0]}
    if "eval" in parts:
        data["rows"]["eval"] = part_eval(config, sets[config["eval_set_rays"]])
    if "error" in parts:
        data["rows"]["error"] = part_error(config)
    if "precompute" in parts:
        limit = args.precompute_limit_min
        data["rows"]["precompute"] = part_precompute(
            config,
            config["precompute"]["limit_min"] if limit is None else limit,
            log=lambda text: print(text, flush=True),
        )
        if previous:
            data["rows"]["precompute"]["previous"] = previous
    print(write_report(data, args.out))
    print(f"wrote {md}" + (f" and {PNG_NAME}" if "error" in data["rows"] else ""))


if __name__ == "__main__":
    main()
