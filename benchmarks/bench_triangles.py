"""Caustic triangles against Gaussian photon splats: error and time per photon count.

Measures, on this machine's default JAX device, on the smooth lens of
``tests/test_triangles_reference.py`` (a bump and a dimple, 10 cm square, screen 30 cm
below, normal light; float32):

1. for photon grids of 65^2 .. 1025^2 vertices (64^2 .. 1024^2 cells): the error of
   caustic triangles (exact reconstruction; Gouraud with 2 x 2 and 4 x 4 samples per
   pixel) against the NumPy reference, unblurred and after a 1-pixel blur (relative L1),
   with the time of one forward call (photon tracing + reconstruction, one jitted call,
   the triangle window fixed by `triangle_window` outside the timing) and of the gradient of
   a scalar loss ``sum(weights * image)`` with respect to the lens heights: median of
   repeated runs after compilation (``block_until_ready``), compile time
   (``lower(...).compile()``) apart;
2. Gaussian splatting of the same photons at its best radius for each photon count
   (searched over 0.1 .. 3 pixels, by the unblurred error), timed the same way;
3. the reference's own error (against the reference with twice its photons per axis)
   and time.

A 64 x 64-pixel screen, and in the full run a 256 x 256-pixel one as well (exact
triangles and splats only).

Writes ``benchmarks/results/triangles.md`` (tables), ``triangles.json`` (the environment
and the raw rows) and ``triangles_error_vs_time.png``.

    python benchmarks/bench_triangles.py            # full run (minutes on 2 cores)
    python benchmarks/bench_triangles.py --quick    # 65^2 and 129^2 only, to check it runs
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.internal import splat_photons, trace_photons, triangle_window

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import compile_time, markdown, once, timed, write_results  # noqa: E402

RESULTS = Path(__file__).parent / "results"
APERTURE = (0.0, 0.1, 0.0, 0.1)  # a 10 cm square lens
SIGMAS = (0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0)  # splat radii, pixels


def smooth_lens(pixels=64, dtype=np.float32):
    """The smooth lens of ``tests/test_triangles_reference.py`` at normal light: a bump
    and a dimple on a 10 cm square lens (16^2 height samples, clamped), 1 cm thick, screen
    30 cm below, 14 cm square, ``pixels`` x ``pixels``."""
    x = (np.arange(16) + 0.5) / 16 * 2 - 1
    xx, yy = np.meshgrid(x, x)
    heights = 1.5e-3 * np.exp(-((xx - 0.2) ** 2 + (yy + 0.1) ** 2) / 0.15) - 1e-3 * np.exp(
        -((xx + 0.3) ** 2 + (yy - 0.3) ** 2) / 0.1
    )
    light = jc.DirectionalLight.from_angles(0.0, 20.0)
    return jc.LensScene(
        jc.HeightField(np.asarray(heights, dtype), np.asarray(APERTURE, dtype), "clamp"),
        jc.DirectionalLight(np.asarray(light.direction, dtype)),
        jc.PlaneReceiver(np.asarray((-0.02, 0.12, -0.02, 0.12), dtype), (pixels, pixels)),
        np.asarray(0.01, dtype),
        np.asarray(0.3, dtype),
    )


def with_heights(scene, heights):
    return eqx.tree_at(lambda s: s.surface.heights, scene, heights)


def time_method(scene, forward_fn, weights, repeats):
    """Forward and gradient timings of ``forward_fn(scene) -> (image, extras)``; the
    gradient is that of ``sum(weights * (image - 1)^2)`` with respect to the lens
    heights (a loss that needs the image itself: for a loss linear in the image the
    reverse pass would skip the forward's scatter into pixels). Returns the timings and
    the forward's output."""
    forward = eqx.filter_jit(forward_fn)

    @eqx.filter_jit
    def gradient(heights, scene):
        def loss(h):
            return jnp.sum(weights * (forward_fn(with_heights(scene, h))[0] - 1.0) ** 2)

        return jax.grad(loss)(heights)

    args = (scene.surface.heights, scene)
    forward_c, f_compile = compile_time(forward, scene)
    gradient_c, g_compile = compile_time(gradient, *args)
    # at least 3 runs, fewer than `repeats` once they took over 10 s
    f = timed(forward_c, scene, repeats=repeats, budget_s=10.0)
    timings = dict(
        fwd_ms=1e3 * f.median,
        grad_ms=1e3 * timed(gradient_c, *args, repeats=repeats, budget_s=10.0).median,
        compile_s=f_compile,
        grad_compile_s=g_compile,
    )
    return timings, f.out


def triangle_rows(scene, truth, grids, weights, repeats, reconstruction, supersample=2):
    rows = []
    for n in grids:
        window = triangle_window(trace_photons(scene, (n, n)), scene.receiver)

        def forward_fn(s, n=n, window=window):
            result = jc.internal.caustic_triangles(
                s, photons=n, reconstruction=reconstruction, window=window, supersample=supersample
            )
            return result.image, result.missed_flux_fraction

        timings, (image, missed) = time_method(scene, forward_fn, weights, repeats)
        row = dict(
            photons=n,
            window=window,
            error=jc.image_error(image, truth, blur=0.0),
            error_blur=jc.image_error(image, truth),
            missed=float(missed[0]),
            **timings,
        )
        rows.append(row)
        print(reconstruction, supersample, row, flush=True)
    return rows


def best_sigma(photons, receiver, truth):
    """Splat errors over `SIGMAS` (ascending; stops once both errors have risen twice in a
    row past their minimum): ``(sigma, error, blurred error)`` at the best unblurred
    error, and ``(sigma, blurred error)`` at the best blurred one."""
    found = []
    for sigma in SIGMAS:
        image = np.asarray(splat_photons(photons, receiver, sigma)[0])
        found.append((sigma, jc.image_error(image, truth, blur=0.0), jc.image_error(image, truth)))
        rising = [len(found) >= 3 and found[-1][k] > found[-2][k] > found[-3][k] for k in (1, 2)]
        if all(rising):
            break
    by_error = min(found, key=lambda f: f[1])
    by_blur = min(found, key=lambda f: f[2])
    return by_error, (by_blur[0], by_blur[2])


def splat_rows(scene, truth, grids, weights, repeats):
    rows = []
    for n in grids:
        photons = trace_photons(scene, (n, n))
        (sigma, error, error_blur), (sigma_blur, best_blur) = best_sigma(
            photons, scene.receiver, truth
        )

        def forward_fn(s, n=n, sigma=sigma):
            return splat_photons(trace_photons(s, (n, n)), s.receiver, sigma)[0], None

        row = dict(
            photons=n,
            sigma=sigma,
            error=error,
            error_blur=error_blur,
            sigma_blur=sigma_blur,
            best_blur=best_blur,
            **time_method(scene, forward_fn, weights, repeats)[0],
        )
        rows.append(row)
        print("splats", row, flush=True)
    return rows


def reference_rows(scene, counts, truth_p):
    """The reference at `truth_p` photons per axis (the truth) and its error and time at
    each of `counts` (ascending) against it."""
    truth_s, truth = once(reference.trace_lens, scene, truth_p)
    rows = []
    for p in counts:
        seconds, image = once(reference.trace_lens, scene, p)
        rows.append(
            dict(
                photons=p,
                error=jc.image_error(image, truth, blur=0.0),
                error_blur=jc.image_error(image, truth),
                fwd_ms=1e3 * seconds,
            )
        )
        print("reference", rows[-1], flush=True)
    rows.append(dict(photons=truth_p, error=None, error_blur=None, fwd_ms=1e3 * truth_s))
    return truth, rows


FMT = {
    "photons": "{}^2",
    "error": "{:.4f}",
    "error_blur": "{:.4f}",
    "best_blur": "{:.4f}",
    "missed": "{:.1e}",
    "fwd_ms": "{:.1f}",
    "grad_ms": "{:.1f}",
    "compile_s": "{:.2f}",
    "grad_compile_s": "{:.2f}",
}
TRIANGLE_COLUMNS = [
    "photons",
    "window",
    "error",
    "error_blur",
    "missed",
    "fwd_ms",
    "grad_ms",
    "compile_s",
    "grad_compile_s",
]
SPLAT_COLUMNS = [
    "photons",
    "sigma",
    "error",
    "error_blur",
    "sigma_blur",
    "best_blur",
    "fwd_ms",
    "grad_ms",
    "compile_s",
    "grad_compile_s",
]
REFERENCE_COLUMNS = ["photons", "error", "error_blur", "fwd_ms"]
STYLES = {  # the same marker and colour for a method in every panel
    "exact triangles": ("o-", "C0"),
    "Gouraud triangles, 2x2 samples": ("^-", "C1"),
    "Gouraud triangles, 4x4 samples": ("v-", "C2"),
    "Gaussian splats, best sigma": ("s-", "C3"),
    "NumPy reference": ("D--", "C4"),
}


def plot(panels, path):
    """One panel per screen: error (unblurred) against forward time, one line per method
    (label: its rows), points labelled by photons per axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4), squeeze=False)
    for ax, (title, series) in zip(axes[0], panels.items(), strict=True):
        for label, rows in series.items():
            style, color = STYLES.get(label, ("x-", "k"))
            rows = [r for r in rows if r["error"] is not None]
            times, errors = [r["fwd_ms"] for r in rows], [r["error"] for r in rows]
            ax.loglog(times, errors, style, color=color, label=label)
            for r in rows:
                ax.annotate(
                    f"{r['photons']}",
                    (r["fwd_ms"], r["error"]),
                    fontsize=7,
                    textcoords="offset points",
                    xytext=(4, 2),
                )
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("forward time [ms] (median after compilation)")
        ax.set_ylabel("relative L1 error vs reference (no blur)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def run_screen(pixels, grids, truth_p, ref_counts, supersamples, repeats, weights_seed=0):
    """All tables for one screen size: ``(sections of markdown, plot series)``."""
    scene = smooth_lens(pixels)
    truth, ref = reference_rows(scene, ref_counts, truth_p)
    weights = jnp.asarray(
        np.random.default_rng(weights_seed).uniform(size=(pixels, pixels)), jnp.float32
    )
    methods = {"exact triangles": triangle_rows(scene, truth, grids, weights, repeats, "exact")}
    for s in supersamples:
        methods[f"Gouraud triangles, {s}x{s} samples"] = triangle_rows(
            scene, truth, grids, weights, repeats, "gouraud", s
        )
    methods["Gaussian splats, best sigma"] = splat_rows(scene, truth, grids, weights, repeats)
    text = []
    for label, rows in methods.items():
        splats = label.startswith("Gaussian")
        text += [
            f"\n### {label} ({pixels}x{pixels} pixels)\n\n",
            markdown(rows, SPLAT_COLUMNS if splats else TRIANGLE_COLUMNS, FMT),
        ]
    text += [
        f"\n### The reference ({pixels}x{pixels} pixels): error against itself at"
        f" {truth_p}^2 photons, time (NumPy, float64)\n\n",
        markdown(ref, REFERENCE_COLUMNS, {**FMT, "fwd_ms": "{:.0f}"}),
    ]
    return text, {**methods, "NumPy reference": ref}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="65^2 and 129^2 photons only")
    parser.add_argument("--out", "--output", dest="out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    # screens: pixels -> (photon grids, reference photons per axis, its own error at)
    if args.quick:
        screens, supersamples, repeats = {64: ([65, 129], 512, [256])}, [2], 3
    else:
        grids = [65, 129, 257, 513, 1025]
        screens = {64: (grids, 8192, [1024, 2048, 4096]), 256: (grids, 8192, [2048, 4096])}
        supersamples, repeats = [2, 4], 7

    start = time.perf_counter()
    device = jax.devices()[0]
    print(f"device: {device}", flush=True)
    truths = ", ".join(f"{t}^2 photons at {p}x{p} pixels" for p, (_, t, _) in screens.items())
    text = [
        "# Caustic triangles benchmark\n\n",
        f"Device: `{device}`; float32 scene; median of {repeats} runs after compilation"
        " (3 where they would take over 10 s).\n",
        "Scene: the smooth lens of `tests/test_triangles_reference.py` (a bump and a dimple on"
        " a 10 cm square lens, screen 30 cm below), normal light. Truth: the NumPy reference"
        f" (`reference.trace_lens`; float64, photons at cell centres, binned) with {truths}.\n\n",
        "Columns: `photons`: vertices of the photon grid (n^2 vertices, (n - 1)^2 cells);"
        " `error`: relative L1 against the truth, no blur; `error_blur`: after a Gaussian blur"
        " of 1 pixel; `missed`: flux fraction beyond the triangle window (`triangle_window`);"
        " `fwd_ms`: photon tracing + reconstruction, one jitted call; `grad_ms`: gradient of"
        " `sum(weights * (image - 1)^2)` (fixed random weights) with respect to the lens"
        " heights (16^2), one jitted call; `compile_s`, `grad_compile_s`: lowering and"
        " compiling them (`lower(...).compile()`), timed apart. Splats: `sigma` (pixels) is"
        " the radius of least unblurred error among"
        f" {', '.join(str(s) for s in SIGMAS)} (searched upwards, stopping once the error"
        " has risen twice), timed at that radius; `sigma_blur`, `best_blur`: the radius of"
        " least blurred error and that error.\n",
    ]
    panels = {}
    for pixels, (grids, truth_p, ref_counts) in screens.items():
        supers = supersamples if pixels == 64 else []
        section, series = run_screen(pixels, grids, truth_p, ref_counts, supers, repeats)
        text += [f"\n## {pixels}x{pixels}-pixel screen\n", *section]
        panels[f"smooth lens, {pixels}x{pixels} pixels"] = series
    elapsed = time.perf_counter() - start
    text.insert(
        2,
        f"Total run time {elapsed / 60:.1f} min. The machine (2 CPU cores) was shared with"
        " other jobs during the run, so times can be off by tens of percent.\n",
    )
    write_results("triangles", panels, "".join(text), dict(quick=args.quick), args.out)
    plot(panels, args.out / "triangles_error_vs_time.png")
    print("".join(text))
    print(f"wrote {args.out / 'triangles.md'} and triangles_error_vs_time.png")


if __name__ == "__main__":
    main()
