"""Two-pass caustics: what accuracy costs in time.

Measures, on this machine's default JAX device:

1. forward and gradient-of-a-scalar-loss time at 400x300 and 800x600 (N = 7, M = 6):
   median of repeated runs after compilation (``block_until_ready``), compile time
   (``jax.jit(...).lower(...).compile()``) reported apart;
2. error against the NumPy reference as the window (N, M) grows, on a scene whose rays
   move up to ~9 pixels, with the time of each setting;
3. error and time as the number of Newton steps for the surface hit grows, under
   oblique light (60 degrees);
4. the reference's own error and time as its photon count grows, so a row of (2) can be
   matched with the reference time needed for the same error.

Writes ``benchmarks/results/twopass.md`` (tables), ``twopass.json`` (the environment and
the raw rows) and ``twopass_error_vs_time.png``.

    python benchmarks/bench_twopass.py            # full run (a few minutes on 2 cores)
    python benchmarks/bench_twopass.py --quick    # tiny sizes, to check it runs
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxcaustics as jc
from jaxcaustics import reference

# the error of the library's tables, on a periodic sea's caustic (the image wraps)
periodic_error = functools.partial(jc.image_error, boundary="periodic")

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import compile_time, markdown, once, timed, write_results  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def wave_scene(shape, *, zenith=30.0, extent=(0.0, 4.0, 0.0, 3.0)):
    heights = jc.wave_heights(shape, extent, 0.0, amplitude=0.01, seed=1)
    return jc.WaterScene(
        jc.HeightField(np.asarray(heights, np.float32), np.float32(extent)),
        jc.DirectionalLight(np.float32(jc.DirectionalLight.from_angles(zenith, 30.0).direction)),
        jc.PlaneReceiver(np.float32(extent), shape),
        np.float32(1.0),
    )


def speed_table(sizes, repeats) -> list[dict]:
    rows = []
    for cols, rows_ in sizes:
        scene = wave_scene((rows_, cols))

        @jax.jit
        def forward(scene):
            return jc.render(scene, jc.TwoPass.paper(hit_iterations=3))

        @jax.jit
        def gradient(heights, scene):
            s = eqx.tree_at(lambda s: s.surface.heights, scene, heights)
            return jax.grad(
                lambda h: jnp.mean(
                    (forward(eqx.tree_at(lambda s: s.surface.heights, s, h)) - 1.0) ** 2
                )
            )(heights)

        args = (scene.surface.heights, scene)
        forward_c, f_compile = compile_time(forward, scene)
        gradient_c, g_compile = compile_time(gradient, *args)
        f_med = timed(forward_c, scene, repeats=repeats).median
        g_med = timed(gradient_c, *args, repeats=repeats).median
        rows.append(
            dict(
                size=f"{cols}x{rows_}",
                fwd_ms=1e3 * f_med,
                fwd_compile_s=f_compile,
                grad_ms=1e3 * g_med,
                grad_compile_s=g_compile,
                ratio=g_med / f_med,
            )
        )
        print(rows[-1], flush=True)
    return rows


UNIT = (0.0, 1.0, 0.0, 1.0)


def unit_scene(heights, depth, zenith=0.0, azimuth=0.0):
    """A 1 x 1 m periodic scene whose caustic map matches the height field."""
    return jc.WaterScene(
        jc.HeightField(heights, UNIT),
        jc.DirectionalLight.from_angles(zenith, azimuth),
        jc.PlaneReceiver(UNIT, heights.shape),
        depth,
    )


def focusing_scene(size):
    """A bump focusing 1.1 m below a 3 m deep surface: rays move up to ~9 pixels."""
    return unit_scene(jc.internal.gaussian_bump((size, size), UNIT, sigma=0.1, amplitude=0.03), 3.0)


def oblique_scene(size):
    """Two crossing sine waves under light 60 degrees from vertical, 0.5 m deep."""
    terms = ((2, 1, 0.006, 0.0), (1, 3, 0.0045, 1.0))
    return unit_scene(jc.sine_sum((size, size), UNIT, terms=terms), 0.5, 60.0, 10.0)


def ripple_scene(size):
    """Waves with caustic lines a few pixels wide, where one sample per pixel ripples."""
    terms = ((5, 2, 0.002, 0.0), (3, 6, 0.0015, 1.0))
    return unit_scene(jc.sine_sum((size, size), UNIT, terms=terms), 0.5, 30.0, 20.0)


def window_table(scene, truth, windows, repeats) -> list[dict]:
    rows = []
    for n, m in windows:
        if n == "auto":
            n, m = jc.internal.auto_window(scene)
        fn = jax.jit(
            lambda s, n=n, m=m: jc.render(
                s, samples_x=n, channels_y=m, supersample=1, return_stats=True
            )
        )
        fn, compile_s = compile_time(fn, scene)
        t = timed(fn, scene, repeats=repeats)
        image, stats = t.out
        rows.append(
            dict(
                N=n,
                M=m,
                error=periodic_error(image, truth),
                time_ms=1e3 * t.median,
                compile_s=compile_s,
                missed=float(stats["missed_flux_fraction"][0]),
            )
        )
        print(rows[-1], flush=True)
    return rows


def knob_table(scene, truth, knob, values, repeats) -> list[dict]:
    """Error (1 px blur and none) and time of `render` as one knob takes `values`.

    The window is sized for the scene (`auto_window`) so that it does not dominate.
    """
    n, m = jc.internal.auto_window(scene)
    rows = []
    for value in values:
        fn = jax.jit(
            lambda s, value=value: jc.render(
                s, samples_x=n, channels_y=m, **({"supersample": 1} | {knob: value})
            )
        )
        t = timed(fn, scene, repeats=repeats)
        rows.append(
            {
                knob: value,
                "error": periodic_error(t.out, truth),
                "error_no_blur": periodic_error(t.out, truth, blur=0.01),
                "time_ms": 1e3 * t.median,
            }
        )
        print(rows[-1], flush=True)
    return rows


def reference_table(scene, truth, photon_counts) -> list[dict]:
    rows = []
    for p in photon_counts:
        seconds, image = once(lambda p=p: reference.trace_water(scene, photons_per_axis=p))
        rows.append(
            dict(photons_per_axis=p, error=periodic_error(image, truth), time_ms=1e3 * seconds)
        )
        print(rows[-1], flush=True)
    return rows


def reference_time_at(error, ref_rows) -> float | None:
    """Reference time for `error`, interpolated in log-log between measured counts."""
    pts = sorted((r["error"], r["time_ms"]) for r in ref_rows)
    for (e0, t0), (e1, t1) in zip(pts, pts[1:], strict=False):
        if e0 <= error <= e1:
            w = np.log(error / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(t0) + w * (np.log(t1) - np.log(t0))))
    return None


def _series(ax, rows, label_key, style, label):
    ax.loglog([r["time_ms"] for r in rows], [r["error"] for r in rows], style, label=label)
    for r in rows:
        ax.annotate(
            f"{r[label_key]}",
            (r["time_ms"], r["error"]),
            fontsize=7,
            textcoords="offset points",
            xytext=(4, 2),
        )


def plot(window_rows, ref_rows, knob_rows, path):
    """Left: window size against the reference's cost; right: the other two knobs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    _series(left, window_rows, "N", "o-", "two-pass, window N (M = N - 1)")
    _series(left, ref_rows, "photons_per_axis", "s--", "NumPy reference, p x p photons/pixel")
    left.set_title("Focusing bump (rays move up to 9 px)")
    for (key, rows), style in zip(knob_rows.items(), ("o-", "^-"), strict=True):
        _series(right, rows, key, style, f"two-pass, {key}")
    right.set_title("Newton steps (60 deg) and samples per pixel (30 deg)")
    for ax in (left, right):
        ax.set_xlabel("time per image [ms] (median after compilation)")
        ax.set_ylabel("relative L1 error vs reference (1 px blur)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check it runs")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)

    if args.quick:
        sizes, size, repeats, truth_p = [(40, 30)], 32, 2, 8
        windows, iters, ref_counts = [(3, 2), (7, 6), ("auto", "auto")], [0, 3], [1, 2]
        factors = [1, 2]
    else:
        sizes, size, repeats, truth_p = [(400, 300), (800, 600)], 128, 15, 32
        windows = [(3, 2), (5, 4), (7, 6), (9, 8), (11, 10), (13, 12), (15, 14), ("auto", "auto")]
        iters, ref_counts = [0, 1, 2, 3, 5], [1, 2, 3, 4, 6, 8, 12]
        factors = [1, 2, 3, 4]

    print(f"device: {jax.devices()[0]}", flush=True)
    speed = speed_table(sizes, repeats)

    scene = focusing_scene(size // 2)
    truth = reference.trace_water(scene, photons_per_axis=truth_p)
    window_rows = window_table(scene, truth, windows, repeats)
    ref_rows = reference_table(scene, truth, ref_counts)
    for r in window_rows:
        r["ref_ms_same_error"] = reference_time_at(r["error"], ref_rows)

    oblique = oblique_scene(size)
    oblique_truth = reference.trace_water(oblique, photons_per_axis=truth_p)
    iter_rows = knob_table(oblique, oblique_truth, "hit_iterations", iters, repeats)
    ripple = ripple_scene(size)
    ripple_truth = reference.trace_water(ripple, photons_per_axis=truth_p)
    super_rows = knob_table(ripple, ripple_truth, "supersample", factors, repeats)

    text = [
        "# Two-pass caustics benchmark\n",
        f"Device: `{jax.devices()[0]}`; float32; median of {repeats} runs after compilation;"
        " `*compile_s`: `jax.jit(...).lower(...).compile()`, timed apart.\n",
        "\n## Speed (N = 7, M = 6, 3 Newton steps; a periodic sea at 30 degrees)\n\n",
        markdown(
            speed,
            ["size", "fwd_ms", "grad_ms", "ratio", "fwd_compile_s", "grad_compile_s"],
            {
                "fwd_ms": "{:.1f}",
                "grad_ms": "{:.1f}",
                "ratio": "{:.2f}",
                "fwd_compile_s": "{:.2f}",
                "grad_compile_s": "{:.2f}",
            },
        ),
        f"\n## Error against the window ({size // 2}x{size // 2}, focusing bump, rays move up to"
        " ~9 px;"
        f" truth: reference with {truth_p}^2 photons per pixel)\n\n",
        markdown(
            window_rows,
            ["N", "M", "error", "missed", "time_ms", "compile_s", "ref_ms_same_error"],
            {
                "error": "{:.4f}",
                "missed": "{:.4f}",
                "time_ms": "{:.2f}",
                "compile_s": "{:.2f}",
                "ref_ms_same_error": "{:.0f}",
            },
        ),
        "\n## The reference's own error against its photon count\n\n",
        markdown(
            ref_rows,
            ["photons_per_axis", "error", "time_ms"],
            {"error": "{:.4f}", "time_ms": "{:.0f}"},
        ),
        f"\n## Newton steps for the surface hit (60 degrees, {size}x{size}, auto window)\n\n",
        markdown(
            iter_rows,
            ["hit_iterations", "error", "time_ms"],
            {"error": "{:.4f}", "time_ms": "{:.2f}"},
        ),
        f"\n## Samples per pixel (S x S; crossing waves at 30 degrees, {size}x{size}, auto"
        " window)\n\n",
        markdown(
            super_rows,
            ["supersample", "error", "error_no_blur", "time_ms"],
            {"error": "{:.4f}", "error_no_blur": "{:.4f}", "time_ms": "{:.2f}"},
        ),
    ]
    raw = dict(
        speed=speed,
        window=window_rows,
        reference=ref_rows,
        hit_iterations=iter_rows,
        supersample=super_rows,
    )
    write_results("twopass", raw, "".join(text), dict(quick=args.quick), args.output)
    plot(
        window_rows,
        ref_rows,
        {"hit_iterations": iter_rows, "supersample": super_rows},
        args.output / "twopass_error_vs_time.png",
    )
    print("".join(text))
    print(f"wrote {args.output / 'twopass.md'} and twopass_error_vs_time.png")


if __name__ == "__main__":
    main()
