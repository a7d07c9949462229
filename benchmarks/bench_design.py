"""Caustic lens design (`design_lens`, ``start="poisson"``: the weak-lens start and the
coarse-to-fine irradiance solve) in the setting of Mitsuba 3's caustics tutorial; the
default transport start is measured by `bench_design_contrast.py`.

A lens 2 x 2 units (metres here), index 1.5, a 0.5 blank, the screen 7 units past it,
collimated light straight down; target: scikit-image's ``camera`` area-averaged to
128 x 128. Each row is one `design_lens` call in a fresh Python process (so JIT
compilation is counted every time), float32, this machine's default JAX device.
Per row: steps, wall time (compilation included), an estimate of the compilation, the
final loss, and the error of the design, relative L2 between unit-mean images
(`verify.relative_l2`): rendered by the independent NumPy reference
(`reference.trace_lens`, 3072^2 photons) and as the design's forward model predicts it
(`LensDesign.predicted`, caustic triangles). The default row also measures the
reference's noise floor (3072^2 against 4096^2 photons).

Writes ``benchmarks/results/design.md`` (table), ``design.json`` (the environment and
the raw numbers, read back by ``--rows`` and ``--report-only``) and ``design.png`` (error
against time; the default run's loss history).

    python benchmarks/bench_design.py                  # all rows (~6 min on 2 idle cores)
    python benchmarks/bench_design.py --rows lm,lbfgs  # rerun some rows, keep the others
    python benchmarks/bench_design.py --report-only    # redraw the table and plot
    python benchmarks/bench_design.py --quick          # one tiny level, to check it runs
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import git_commit, once, pick, read_results, write_results  # noqa: E402

RESULTS = Path(__file__).parent / "results"
PHOTONS, NOISE_PHOTONS = 3072, 4096  # reference photons per axis; the noise check's
SETTING = dict(width=2.0, height=2.0, thickness=0.5, screen_distance=7.0, ior=1.5)
# name -> (label, design_lens arguments beyond SETTING)
ROWS = {
    "lm": ("LM, default", {}),
    "lm20": ("LM, 20 steps", dict(max_steps=20)),
    "lm64": ("LM, from 64", dict(levels=(64, 128, 256))),
    "lm128": ("LM, up to 128", dict(levels=(32, 64, 128))),
    "gn": ("Gauss-Newton", dict(solver="gauss_newton")),
    "lbfgs": ("L-BFGS, 100 steps", dict(solver="lbfgs", max_steps=100)),
    "lbfgs400": ("L-BFGS, 400 steps", dict(solver="lbfgs", max_steps=400)),
    "relief": ("LM, relief 0.02 (Fresnel)", dict(max_relief=0.02)),
}
QUICK = dict(levels=(32,), max_steps=3)
MITSUBA = (426.0, 0.27)  # quoted from the issue (200 Adam steps on 2 cores), not measured


def target():
    from skimage import data

    from jaxcaustics.internal import area_average

    return area_average(data.camera().astype(float), (128, 128))


def result_name(result) -> str:
    """The name of an Optimistix result code (``max_steps_reached``, ...)."""
    import optimistix as optx

    for n, item in optx.RESULTS._name_to_item.items():
        if bool(result == item):
            return n
    return str(result)


def one(name: str, quick: bool) -> dict:
    """Design row `name` in this process; the row's numbers (JSON-able)."""
    import jax
    import numpy as np

    from jaxcaustics import design_lens, reference, relative_l2

    kwargs = {**ROWS[name][1], **(QUICK if quick else {})}
    t = target()
    stamps = []  # (level, seconds since the start) after every solver step
    load = [os.getloadavg()[0]]
    start = time.perf_counter()
    row = dict(name=name, label=ROWS[name][0], kwargs={k: str(v) for k, v in kwargs.items()})
    try:
        d = design_lens(
            t,
            **SETTING,
            start="poisson",  # this benchmark measures the Poisson start's solvers
            **kwargs,
            throw=False,
            callback=lambda info: stamps.append((info["level"], time.perf_counter() - start)),
        )
    except Exception as err:  # report what happens (e.g. a diverging solver), do not tune
        row.update(failed=f"{type(err).__name__}: {err}", total_s=time.perf_counter() - start)
        row["steps"] = len(stamps)
        return row
    levels = []
    for k, lev in enumerate(d.levels):
        times = [s for level, s in stamps if level == k]
        gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
        step = statistics.median(gaps) if gaps else 0.0
        levels.append(
            dict(
                shape=list(lev["shape"]),
                steps=lev["steps"],
                loss=lev["loss"],
                result=result_name(lev["result"]),
                seconds=lev["seconds"],
                first_step_seconds=lev["first_step_seconds"],
                step_seconds=step,
                compile_s=max(lev["first_step_seconds"] - step, 0.0),
            )
        )
    load.append(os.getloadavg()[0])
    reference_s, image = once(reference.trace_lens, d.scene, PHOTONS)
    row.update(
        levels=levels,
        steps=sum(lev["steps"] for lev in levels),
        max_steps=kwargs.get("max_steps", 40),
        shapes="-".join(str(lev["shape"][1]) for lev in levels),
        total_s=d.timings["total"],
        predict_s=d.timings["predict"],
        compile_s=sum(lev["compile_s"] for lev in levels),
        opt_s=sum(lev["seconds"] - lev["compile_s"] for lev in levels),
        other_s=d.timings["total"] - sum(lev["seconds"] for lev in levels),
        loss=d.loss_history[-1] if d.loss_history else None,
        error=relative_l2(image, t),
        error_predicted=relative_l2(d.predicted, t),
        relief=d.relief,
        finite=bool(np.all(np.isfinite(d.heights))),
        reference_s=reference_s,
        load=load,
        history=d.loss_history,
        stamps=[s for _, s in stamps],
        jax=jax.__version__,
        device=str(jax.devices()[0]),
        date=datetime.date.today().isoformat(),
        commit=git_commit(),
    )
    if name == "lm" and not quick:  # the reference's own noise at PHOTONS per axis
        finer = reference.trace_lens(d.scene, NOISE_PHOTONS)
        row.update(
            noise=relative_l2(image, finer),
            error_finer=relative_l2(finer, t),
            noise_coarse=relative_l2(reference.trace_lens(d.scene, PHOTONS // 2), finer),
        )
    return row


def run_row(name: str, quick: bool) -> dict:
    """`one(name)` in a fresh process (compilation counted every time)."""
    cmd = [sys.executable, __file__, "--one", name] + (["--quick"] if quick else [])
    start = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("ROW ")]
    if out.returncode or not lines:
        row = dict(name=name, label=ROWS[name][0], failed=out.stderr.strip()[-500:])
    else:
        row = json.loads(lines[-1][4:])
    row["process_s"] = time.perf_counter() - start
    return row


def fmt(value, spec="{:.3f}"):
    return "-" if value is None else spec.format(value)


def table(rows) -> str:
    cols = [
        "row",
        "solver",
        "levels",
        "max steps/level",
        "steps taken",
        "total s",
        "compile s",
        "optimise s",
        "other s",
        "final loss",
        "error (reference)",
        "error (predicted)",
        "relief m",
        "load",
    ]
    text = "| " + " | ".join(cols) + " |\n|" + "---|" * len(cols) + "\n"
    for r in rows:
        kw = ROWS[r["name"]][1]
        if "failed" in r:
            text += f"| {r['label']} | failed: {r['failed'][:200]} |\n"
            continue
        cells = [
            r["label"],
            kw.get("solver", "levenberg_marquardt"),
            r["shapes"],
            str(r["max_steps"]),
            str(r["steps"]),
            fmt(r["total_s"], "{:.0f}"),
            fmt(r["compile_s"], "{:.0f}"),
            fmt(r["opt_s"], "{:.0f}"),
            fmt(r["other_s"], "{:.0f}"),
            fmt(r["loss"], "{:.4g}"),
            fmt(r["error"], "{:.4f}"),
            fmt(r["error_predicted"], "{:.4f}"),
            fmt(r["relief"], "{:.3f}"),
            "/".join(f"{x:.1f}" for x in r["load"]),
        ]
        text += "| " + " | ".join(cells) + " |\n"
    return text


def levels_table(rows) -> str:
    text = "| row | level (heights) | steps | loss | result | s | first step s | step s |\n"
    text += "|---|---|---|---|---|---|---|---|\n"
    for r in rows:
        for lev in r.get("levels", []):
            text += (
                f"| {r['label']} | {lev['shape'][0]}x{lev['shape'][1]} | {lev['steps']} |"
                f" {lev['loss']:.4g} | {lev['result']} | {lev['seconds']:.1f} |"
                f" {lev['first_step_seconds']:.1f} | {lev['step_seconds']:.2f} |\n"
            )
    return text


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, r in enumerate(r for r in rows if r.get("error") is not None):
        ax.plot(r["total_s"], r["error"], "osD^vPXh"[k % 8], color=f"C{k}", label=r["label"])
    ax.plot(*MITSUBA, "*", color="k", markersize=13)
    ax.annotate(
        "Mitsuba 3, 200 Adam steps\n(quoted from the issue, not measured)", MITSUBA,
        fontsize=7, xytext=(-150, 6), textcoords="offset points",
    )  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(FormatStrFormatter("%g"))
    ax.tick_params(which="minor", labelsize=6)
    ax.set_xlabel("wall time of the design [s] (compilation included)")
    ax.set_ylabel(f"relative L2 vs target (reference, {PHOTONS}^2 photons)")
    ax.set_title("camera 128x128, Mitsuba tutorial setting, 2 CPU cores", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    lm = next((r for r in rows if r["name"] == "lm" and r.get("history")), None)
    if lm is not None:
        first = 0
        for lev in lm["levels"]:  # one line per level (the gaps between: compilation)
            last = first + lev["steps"]
            t = lm["stamps"][first:last]
            bx.semilogy(t, lm["history"][first:last], ".-", color="C0", markersize=3)
            bx.axvline(t[0], color="grey", lw=0.5)
            bx.annotate(
                f"{lev['shape'][1]}^2", (t[0], 1), xycoords=("data", "axes fraction"),
                fontsize=7, xytext=(2, -10), textcoords="offset points",
            )  # fmt: skip
            first = last
        bx.set_xlabel("time since design_lens started [s]")
        bx.set_ylabel("loss 0.5 sum(residual^2), each level's own")
        bx.set_title("LM, default levels: loss after every step (gaps: compilation)", fontsize=9)
        bx.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def report(rows, out: Path, quick: bool, wall: str | None, env=None):
    lm = next((r for r in rows if r["name"] == "lm" and "failed" not in r), {})
    date = lm.get("date", datetime.date.today().isoformat())
    old = (out / "design.md").read_text() if (out / "design.md").exists() else ""
    before = old.split("\nRun: ", 1)[1].split(".\n", 1)[0] if "\nRun: " in old else None
    if wall is None:  # --report-only: keep the run's line
        wall = before or "?"
    elif wall.startswith("rows") and before:  # --rows: say what was rerun
        wall = f"{before}; {wall}"
    text = [
        "# Caustic lens design benchmark (Mitsuba 3 tutorial setting)\n\n",
        f"Machine: 2 CPU cores, no GPU; JAX {lm.get('jax', '?')} on `{lm.get('device', '?')}`,"
        f" float32; {date}; commit {lm.get('commit', '?')}."
        " Regenerate: `python benchmarks/bench_design.py`"
        " (`--rows lm,gn` reruns some rows and keeps the others).\n\n",
        "Setting: lens 2 x 2 m, index 1.5, blank 0.5 m thick, screen 7 m past the lens"
        " (`screen_distance=7.0`), collimated light straight down; target: scikit-image's `camera`"
        " area-averaged to 128x128. Each row is one `design_lens` call in a fresh process"
        " (compilation counted every time).\n\n",
        "Columns: `levels`: heights samples per side, coarse to fine; `steps taken`: solver"
        " steps over all levels; `total s`: the `design_lens` call (compilation, initial"
        " guess and the predicted caustic included); `compile s`: per level, the first step"
        " (solver init + compilation + one step) minus the median of that level's later"
        " steps, summed; `optimise s`: the levels' time minus that; `other s`: the rest of"
        " `total s` (checks, the flat lens's flux and the weak-lens start before the first"
        " level, the predicted caustic after the last, mostly their compilation);"
        " `final loss`: 0.5 sum(residual^2)"
        " of the last level; `error (reference)`: relative L2 (unit-mean images,"
        f" `verify.relative_l2`) of the NumPy reference's render ({PHOTONS}^2 photons)"
        " against the target; `error (predicted)`: the same for the design's own forward"
        " model (`LensDesign.predicted`); `relief m`: max - min of the heights; `load`: the"
        " 1-minute load average at the start / end of the design.\n\n",
        table(rows),
    ]
    if "noise" in lm:
        text.append(
            f"\nReference noise floor (default LM design): {PHOTONS}^2 against"
            f" {NOISE_PHOTONS}^2 photons differ by {lm['noise']:.4f}"
            f" ({PHOTONS // 2}^2 against {NOISE_PHOTONS}^2: {lm['noise_coarse']:.4f}); the"
            f" error at {NOISE_PHOTONS}^2 photons is {lm['error_finer']:.4f} (at"
            f" {PHOTONS}^2: {lm['error']:.4f}). The reference took {lm['reference_s']:.0f} s"
            f" at {PHOTONS}^2.\n"
        )
    text += [
        "\nFor scale, **Mitsuba 3** (numbers quoted from the issue, *not measured by us*): on"
        " a machine like this (2 CPU cores) its differentiable particle tracer takes about"
        " 1.1 s per Adam step at 128x128; after 200 steps (426 s) its design reaches relative"
        " L2 0.27; its full 1000-step schedule would take about 26 minutes.\n",
        "\n## Per level\n\n",
        levels_table(rows),
        f"\nRun: {wall}.\n",
    ]
    if quick:
        text.insert(1, "**Quick check only (one 32^2 level, 3 steps): not results.**\n\n")
    if "\n## Notes" in old and not quick:  # hand-written notes survive a rerun
        text.append("\n## Notes" + old.split("\n## Notes", 1)[1].rstrip())
        text.append("\n")
    raw = [  # the loss history of the default row only (for the plot); 6 digits
        {k: v for k, v in r.items() if r["name"] == "lm" or k not in ("history", "stamps")}
        for r in rows
    ]
    raw = json.loads(json.dumps(raw), parse_float=lambda x: float(f"{float(x):.6g}"))
    write_results("design", raw, "".join(text), out=out, env=env)
    plot(rows, out / "design.png")
    print("".join(text))


def previous(out: Path) -> tuple[dict, dict | None]:
    """The rows stored in ``<out>/design.json`` by name, and their run's environment."""
    data = read_results("design", out)
    if data is None:
        return {}, None
    return {r["name"]: r for r in data["rows"]}, data["environment"]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--one", choices=list(ROWS), help=argparse.SUPPRESS)
    parser.add_argument("--rows", help=f"comma-separated subset of {','.join(ROWS)}")
    parser.add_argument(
        "--report-only", action="store_true", help="rewrite design.md/.png from its raw results"
    )
    parser.add_argument("--quick", action="store_true", help="one tiny level, to check it runs")
    parser.add_argument("--out", "--output", dest="out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.one:
        print("ROW " + json.dumps(one(args.one, args.quick)), flush=True)
        return
    args.out.mkdir(parents=True, exist_ok=True)
    names = pick(parser, args.rows or ",".join(ROWS), ROWS, "rows")
    rows, env = ({}, None) if args.quick else previous(args.out)
    if args.report_only:
        report([rows[n] for n in ROWS if n in rows], args.out, False, None, env)
        return
    start = time.perf_counter()
    for name in names:
        rows[name] = run_row(name, args.quick)
        r = rows[name]
        print(
            name,
            {k: r.get(k) for k in ("total_s", "compile_s", "steps", "error", "failed")},
            flush=True,
        )
    wall = (
        f"rows {', '.join(names)} rerun in {(time.perf_counter() - start) / 60:.1f} min"
        if args.rows
        else f"all rows in {(time.perf_counter() - start) / 60:.1f} min"
    )
    ordered = [rows[n] for n in ROWS if n in rows]
    report(ordered, args.out, args.quick, wall)


if __name__ == "__main__":
    main()
