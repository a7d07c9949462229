"""How run time scales with the device count, on simulated CPU devices.

For each device count (default 1, 2, 4, 8) a fresh Python process is started with
``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (JAX reads the flag once, at
start-up) and ``JAX_PLATFORMS=cpu``; it times four sharded workloads, float32:

- ``water batch``: `render_batch` of 32 water surfaces (256^2 heights and pixels,
  two-pass), the batch split across the devices;
- ``photon bands``: `caustic_triangles(..., devices=N)` on one lens (513^2 photons), the
  photon bands split across the devices (skipped when `caustic_triangles` has no
  `devices` argument);
- ``CSL fits``: `map_sharded` over the caustic-spot-light fits of 8 light directions
  (on a cone of 40 degrees about straight down; glass sphere, 64^2 rays, 4 lights);
- ``design variants``: `design_lens_variants` over 8 screen distances (32^2 target, one 32^2
  level, 10 Levenberg-Marquardt steps; the predicted caustics, 65^2 photons, on the
  host one after the other).

Per workload and device count: the first call (compilation included) and the median of
the later calls (``block_until_ready``; the outputs gathered to NumPy where the API does);
speed-up = median at 1 device / median at N. Simulated devices are threads of one
process sharing the machine's cores: on a 2-core machine ideal scaling stops at 2
devices, and more devices only add overhead (and compilation: with ``per_device="map"``
a single-device program is compiled for every device). The load average before and
after each process is recorded (other work on the machine slows every row).

Writes ``benchmarks/results/scaling.md`` (table), ``scaling.json`` (the environment and
the raw numbers) and ``scaling.png`` (speed-up against devices).

    python benchmarks/bench_scaling.py                # 1, 2, 4, 8 devices (~8 min on 2 cores)
    python benchmarks/bench_scaling.py --devices 1,2  # some device counts
    python benchmarks/bench_scaling.py --quick        # tiny sizes, 1 and 2 devices
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import timed, write_results  # noqa: E402

RESULTS = Path(__file__).parent / "results"
WORKLOADS = ("water batch", "photon bands", "CSL fits", "design variants")
FULL = dict(
    water=32, water_n=256, photons=513, lens_n=64, screen=128, csl=8, rays=64,
    throws=8, target=32, steps=10, repeats=3,
)  # fmt: skip
QUICK = dict(
    water=4, water_n=16, photons=65, lens_n=16, screen=32, csl=2, rays=16,
    throws=2, target=8, steps=2, repeats=1,
)  # fmt: skip


# --------------------------------------------------------------------------- worker


def _timed(fn, repeats: int) -> dict:
    try:
        t = timed(fn, repeats=repeats)
    except Exception as err:  # a failing workload is reported, the others still run
        return {"skipped": f"failed: {type(err).__name__}: {str(err).splitlines()[0][:120]}"}
    return {"first": t.first, "median": t.median, "times": t.times}


def worker(n_devices: int, size: dict) -> dict:
    """Time the workloads on the first `n_devices` devices (in this process)."""
    import functools
    import inspect

    import jax
    import numpy as np

    import jaxcaustics as jc
    from jaxcaustics import render_batch
    from jaxcaustics.devices import gather_to_host, map_sharded, stack_scenes
    from jaxcaustics.internal import caustic_triangles, design_lens_variants

    assert len(jax.devices()) == n_devices, jax.devices()
    rng = np.random.default_rng(0)
    out: dict = {}

    # water batch
    n = size["water_n"]
    waters = stack_scenes(
        [
            jc.WaterScene(
                jc.HeightField(0.01 * rng.normal(size=(n, n)), [-1.0, 1.0, -1.0, 1.0]),
                jc.DirectionalLight([0.2, 0.0, -1.0]),
                jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], (n, n)),
                1.0,
            )
            for _ in range(size["water"])
        ]
    )
    out["water batch"] = _timed(
        lambda: gather_to_host(render_batch(waters, jc.TwoPass.paper())), size["repeats"]
    )

    # photon bands
    if "devices" in inspect.signature(caustic_triangles).parameters:
        m = size["lens_n"]
        x = np.linspace(-1.0, 1.0, m)
        lens = jc.LensScene(
            jc.HeightField(
                -0.02 * (x[None] ** 2 + x[:, None] ** 2) + 2e-3 * rng.normal(size=(m, m)),
                [-0.5, 0.5, -0.5, 0.5],
                "clamp",
            ),
            jc.DirectionalLight([0.0, 0.0, -1.0]),
            jc.PlaneReceiver([-0.6, 0.6, -0.6, 0.6], (size["screen"],) * 2),
            0.1,
            1.0,
        )
        window = 8  # fixed: "auto" would time a window search too
        out["photon bands"] = _timed(
            lambda: (
                caustic_triangles(
                    lens, photons=size["photons"], window=window, devices=n_devices
                ).image
            ),
            size["repeats"],
        )
    else:
        out["photon bands"] = {"skipped": "caustic_triangles has no `devices` argument"}

    # CSL fits over light directions
    from jaxcaustics import Ellipsoid, EllipsoidScene
    from jaxcaustics.internal import fit_direction

    sphere = EllipsoidScene(
        Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight([0.0, 0.0, -1.0]),
        jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], (32, 32)),
        ior=1.5,
    )
    # directions of travel on a cone about straight down (zenith 0 to 40 degrees)
    k = np.arange(size["csl"])
    zenith, azimuth = np.radians(40.0) * k / max(1, k[-1]), 2.4 * k
    directions = np.stack(
        [np.sin(zenith) * np.cos(azimuth), np.sin(zenith) * np.sin(azimuth), -np.cos(zenith)],
        axis=1,
    ).astype(np.float32)
    fit = functools.partial(
        fit_direction, rays_per_axis=size["rays"], fit_knobs={"max_lights": 4}
    )  # one callable for every call: compiled once per device
    out["CSL fits"] = _timed(lambda: map_sharded(fit, sphere, directions), size["repeats"])

    # design variants
    t = size["target"]
    y, x = np.mgrid[-1 : 1 : t * 1j, -1 : 1 : t * 1j]
    target = np.exp(-((x - 0.3) ** 2 + y**2) / 0.1) + 0.2
    throws = list(np.linspace(0.2, 0.6, size["throws"]))
    spec = dict(
        width=0.05, height=0.05, thickness=0.01, levels=(t,), max_steps=size["steps"],
        predict_photons=2 * t + 1,
    )  # fmt: skip
    out["design variants"] = _timed(
        lambda: [d.heights for d in design_lens_variants(target, screen_distances=throws, **spec)],
        size["repeats"],
    )
    return out


# --------------------------------------------------------------------------- driver


def run_devices(n_devices: int, quick: bool) -> dict:
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    env["JAX_PLATFORMS"] = "cpu"
    repo = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = repo + os.pathsep + env.get("PYTHONPATH", "")
    command = [sys.executable, __file__, "--worker", str(n_devices)]
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    result = subprocess.run(
        command + (["--quick"] if quick else []),
        capture_output=True,
        text=True,
        env=env,
        timeout=1800,
    )
    if result.returncode != 0:
        raise RuntimeError(f"{n_devices} devices: the worker failed:\n{result.stderr[-4000:]}")
    row = json.loads(result.stdout.strip().splitlines()[-1])
    row["load_before"], row["load_after"] = load_before, os.getloadavg()[0]
    row["process_seconds"] = time.perf_counter() - t0
    return row


def report(rows: dict[int, dict], out: Path, quick: bool) -> None:
    counts = sorted(rows)
    base = rows[counts[0]]
    lines = [
        "# Scaling with the device count (simulated CPU devices)",
        "",
        f"Run {datetime.date.today()} on {platform.processor() or platform.machine()} with "
        f"{os.cpu_count()} cores, {'`--quick` sizes' if quick else 'full sizes'}; "
        "`python benchmarks/bench_scaling.py`. Each device count runs in its own process "
        "with `XLA_FLAGS=--xla_force_host_platform_device_count=N`; simulated devices share "
        f"the machine's {os.cpu_count()} cores, so ideal scaling stops at "
        f"{os.cpu_count()} devices. Times in seconds: *first* includes compilation, "
        "*median* is over the later calls; speed-up = median at "
        f"{counts[0]} device(s) / median at N. Load: 1-minute load average before / after "
        "the process.",
        "",
        "| workload | devices | first (s) | median (s) | speed-up | load before / after |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for name in WORKLOADS:
        for n in counts:
            r = rows[n][name]
            load = f"{rows[n]['load_before']:.1f} / {rows[n]['load_after']:.1f}"
            if "skipped" in r:
                note = r["skipped"].replace("|", "/")
                lines.append(f"| {name} | {n} | - | - | - | {load} ({note}) |")
                continue
            speed = base[name]["median"] / r["median"] if "median" in base[name] else float("nan")
            lines.append(
                f"| {name} | {n} | {r['first']:.2f} | {r['median']:.3f} | {speed:.2f} | {load} |"
            )
    raw = {str(k): v for k, v in rows.items()}
    write_results("scaling", raw, "\n".join(lines) + "\n", dict(quick=quick), out)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 3.2), dpi=100)
    for name in WORKLOADS:
        if not all("median" in rows[n][name] for n in counts):
            continue
        ax.plot(
            counts,
            [base[name]["median"] / rows[n][name]["median"] for n in counts],
            "o-",
            label=name,
        )
    ax.plot(counts, [min(n, os.cpu_count() or 1) / counts[0] for n in counts], "k:", label="ideal")
    ax.set_xscale("log", base=2)
    ax.set_xticks(counts, [str(n) for n in counts])
    ax.set_xlabel("simulated CPU devices")
    ax.set_ylabel(f"speed-up over {counts[0]} device(s)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "scaling.png")
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--devices", default=None, help="device counts, e.g. 1,2,4,8")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, 1 and 2 devices")
    parser.add_argument("--out", type=Path, default=RESULTS, help="folder for the results")
    parser.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    size = QUICK if args.quick else FULL
    if args.worker is not None:
        print(json.dumps(worker(args.worker, size)))
        return
    default = "1,2" if args.quick else "1,2,4,8"
    counts = [int(c) for c in (args.devices or default).split(",")]
    rows = {}
    for n in counts:
        rows[n] = run_devices(n, args.quick)
        medians = {k: round(v.get("median", float("nan")), 3) for k, v in rows[n].items()
                   if isinstance(v, dict)}  # fmt: skip
        print(f"{n} device(s): {medians}", flush=True)
    report(rows, args.out, args.quick)
    print(f"wrote {args.out / 'scaling.md'} and {args.out / 'scaling.png'}")


if __name__ == "__main__":
    main()
