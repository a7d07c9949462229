"""Lens design for high-contrast pictures: target x start x light, judged independently.

Setting: Mitsuba 3's caustics tutorial (lens 2 x 2 m, index 1.5, blank 0.5 m, screen
7 m past the lens), 128 x 128 targets: scikit-image's ``camera`` and the three
high-contrast targets of `targets.py` (made before any tuning). Each row is one
`design_lens` call with its defaults but the start (float32, a fresh process: compilation
counted). The design is exported (`export_lens`), its height map read back from the EXR
(with the bicubic's boundary mode from its JSON sidecar) and rendered by the NumPy
reference (`reference.trace_lens`, 2048^2 photons); against the target, both at unit
mean: relative L2, 1 - SSIM (scikit-image), and the fraction of the flux on pixels where
the target is below 5% of its mean. Writes ``benchmarks/results/design_contrast.md``
(table), ``design_contrast.json`` (the environment and the raw rows, read back by
``--rows`` and ``--report-only``) and ``design_contrast.png``.

    python benchmarks/bench_design_contrast.py            # all rows (~10 min on 2 cores)
    python benchmarks/bench_design_contrast.py --rows silhouette-transport
    python benchmarks/bench_design_contrast.py --report-only
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import environment, judge, once, read_results, write_results  # noqa: E402

RESULTS = Path(__file__).parent / "results"
NAME = "design_contrast"
PHOTONS = 2048
SETTING = dict(width=2.0, height=2.0, thickness=0.5, screen_distance=7.0, ior=1.5)
TARGETS = ("camera", "silhouette", "lettering", "dots")
LIGHTS = {
    "collimated": None,
    "point": "point",  # 1.5 x the screen distance above the lens
    "tilted": "tilted",  # 20 degrees from vertical
}
ROWS = [f"{t}-transport" for t in TARGETS] + [f"{t}-poisson" for t in TARGETS]
ROWS += ["silhouette-transport-point", "silhouette-transport-tilted"]
RENDERS = Path(tempfile.gettempdir()) / "jaxcaustics_design_contrast"  # not committed


def target(name: str):
    import numpy as np
    import targets  # beside this script

    if name == "camera":
        from skimage import data

        from jaxcaustics.internal import area_average

        return area_average(data.camera().astype(float), (128, 128))
    return np.asarray(targets.TARGETS[name]())


def light(name: str | None):
    import numpy as np

    from jaxcaustics import DirectionalLight, PointLight

    if name == "point":
        top = SETTING["screen_distance"] + SETTING["thickness"]
        return PointLight(np.array([0.0, 0.0, top + 1.5 * SETTING["screen_distance"]]), 1.0)
    if name == "tilted":
        return DirectionalLight.from_angles(20.0)
    return None


def one(row: str) -> dict:
    """Design and judge `row` in this process."""
    import warnings

    import jax
    import numpy as np

    from jaxcaustics import HeightField, LensScene, design_lens, export_lens
    from jaxcaustics.io import read_exr
    from jaxcaustics.reference import trace_lens

    parts = row.split("-")
    name, start = parts[0], parts[1]
    light_name = parts[2] if len(parts) > 2 else None
    goal = target(name)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        total, d = once(
            lambda: design_lens(goal, **SETTING, light=light(light_name), start=start, throw=False)
        )
    with tempfile.TemporaryDirectory() as tmp:
        paths = export_lens(d.scene, tmp, formats=("stl",))
        z_mm = read_exr(paths["height_exr"]).astype(float)
        boundary = json.loads(paths["height_json"].read_text())["boundary"]
    heights = z_mm[1::2, 1::2] / 1000.0 - SETTING["thickness"]
    exported = LensScene(
        HeightField(heights, d.scene.surface.extent, boundary),
        d.scene.light,
        d.scene.receiver,
        SETTING["thickness"],
        SETTING["screen_distance"],
        ior=SETTING["ior"],
    )
    reference_s, image = once(trace_lens, exported, PHOTONS)
    levels = d.levels
    firsts = [lev.get("first_step_seconds", float("nan")) for lev in levels]
    compile_s = sum(s for s in firsts if s == s)  # the first call of each compiled solve
    RENDERS.mkdir(exist_ok=True)
    np.save(RENDERS / f"{row}.npy", image.astype(np.float32))
    return dict(
        row=row,
        target=name,
        start=start,
        light=light_name or "collimated",
        total_s=total,
        compile_s=compile_s,
        transport_s=levels[0]["seconds"] if levels[0].get("stage") == "transport" else 0.0,
        steps=sum(int(lev["steps"]) for lev in levels),
        predicted=d.predicted_error,
        predicted_dark=d.dark_flux,
        reference=judge(image, goal),
        reference_s=reference_s,
        warnings=[str(w.message)[:160] for w in caught if "design_lens" in str(w.message)],
        jax=jax.__version__,
    )


def report(rows: dict) -> str:
    lines = [
        "# Lens design for high-contrast targets (transport start against the Poisson start)",
        "",
        "Mitsuba 3 tutorial setting (lens 2 x 2 m, index 1.5, blank 0.5 m, screen 7 m away), "
        "128 x 128 targets, `design_lens` defaults but `start` (and the light), float32, "
        "2 CPU cores, one fresh process per row (compilation counted in `total s`; "
        "`transport s`: the transport, its compilation included; `first steps s`: the "
        "first call of each compiled solve (the landing fit and the image refinement, or "
        "the Poisson levels): their compilation plus one step). Judged by the NumPy reference "
        f"(`trace_lens`, {PHOTONS}^2 photons) on the exported height map read back from "
        "its EXR: relative L2 and 1 - SSIM at unit mean, and the flux fraction on pixels "
        "where the target is below 5% of its mean. `predicted`: the design's own "
        "forward model (caustic triangles). Regenerate: "
        "`python benchmarks/bench_design_contrast.py`.",
        "",
        "| target | start | light | total s | transport s | first steps s | steps | "
        "predicted L2 | reference L2 | 1 - SSIM | dark flux | warned |",
        "|---|---|---|--:|--:|--:|--:|--:|--:|--:|--:|---|",
    ]
    import os

    lines.insert(2, f"1-minute load average when the report was written: {os.getloadavg()[0]:.1f}.")
    lines.insert(3, "")
    for key in ROWS:
        r = rows.get(key)
        if r is None:
            continue
        ref = r["reference"]
        lines.append(
            f"| {r['target']} | {r['start']} | {r['light']} | {r['total_s']:.1f} | "
            f"{r['transport_s']:.1f} | {r['compile_s']:.1f} | {r['steps']} | "
            f"{r['predicted']:.3f} | {ref['l2']:.3f} | {ref['ssim']:.3f} | "
            f"{100 * ref['dark']:.2f}% | {'yes' if r['warnings'] else 'no'} |"
        )
    lines += ["", "![targets and reference renders](design_contrast.png)"]
    return "\n".join(lines) + "\n"


def figure(rows: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = [t for t in TARGETS if f"{t}-transport" in rows]
    fig, axes = plt.subplots(2, len(names), figsize=(2.2 * len(names), 4.6))
    axes = np.atleast_2d(axes).reshape(2, -1)
    for k, name in enumerate(names):
        path = RENDERS / f"{name}-transport.npy"
        goal = target(name)
        top = np.quantile(goal / goal.mean(), 0.999)
        axes[0, k].imshow(goal / goal.mean(), cmap="gray", vmin=0, vmax=top)
        axes[0, k].set_title(f"{name}: target", fontsize=8)
        if path.exists():
            img = np.load(path)
            axes[1, k].imshow(img / img.mean(), cmap="gray", vmin=0, vmax=top)
            r = rows[f"{name}-transport"]["reference"]
            axes[1, k].set_title(f"reference: L2 {r['l2']:.3f}", fontsize=8)
        for a in axes[:, k]:
            a.axis("off")
    fig.tight_layout()
    fig.savefig(RESULTS / "design_contrast.png", dpi=70)
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        print(json.dumps(one(args.one)))
        return
    stored = read_results(NAME) or {}
    rows = stored.get("rows", {})
    env = stored.get("environment") if args.report_only else environment()
    if not args.report_only:
        for row in args.rows.split(","):
            proc = subprocess.run(
                [sys.executable, __file__, "--one", row], capture_output=True, text=True
            )
            if proc.returncode != 0:
                print(proc.stderr[-2000:])
                continue
            rows[row] = json.loads(proc.stdout.strip().splitlines()[-1])
            r = rows[row]
            print(row, f"{r['total_s']:.1f} s", r["reference"], flush=True)
            write_results(NAME, rows, report(rows), env=env)
    write_results(NAME, rows, report(rows), env=env)
    figure(rows)


if __name__ == "__main__":
    main()
