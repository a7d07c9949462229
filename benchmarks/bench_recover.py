"""Water recovery from caustics the model did not render: smooth seas, three lights.

Each row: a 1 m x 1 m periodic sea of three swells, 0.5 m deep, 128 x 128 heights and
pixels; its caustic rendered by the NumPy reference (`reference.trace_water`, 16^2
photons a pixel); `recover_surface` with its defaults (float32, the transport start,
no image-space solve) in a fresh process, so that the time includes JAX's start-up and
every compilation. Judged by the heights (relative RMS, means removed) and by the
reference's caustic of the recovered heights against the target (`jc.image_error`:
relative L1 after a 1-pixel Gaussian blur). The 80-degree sea has a quarter of the
amplitude (the full one folds under grazing light: peak irradiance 35x the mean).
The "photo" rows see the same caustic through a 1-pixel Gaussian blur with 2% Gaussian
noise, the blur given to `recover_surface` (``blur=1``).

The video: 16 frames, 0.1 s apart, of `wave_heights` (128^2, 2 mm RMS over waves of
0.25-1 m, light 30 degrees off vertical), traced by the reference and recovered by
`recover_sequence` in one fresh process: per-frame time and height error.

Folding seas: the 32^2 sea of `tests/test_water_start.py` (three swells, light 30
degrees off vertical, azimuth 20) with its relief scaled until rays cross, recovered
with the start alone (``fold_fit=False``) and with the fold fit (``fold_fit=True``,
`jaxcaustics.inverse.water_refine`), both judged as above.

Writes ``benchmarks/results/recover.md`` and ``recover.json`` (the environment and the
raw rows).

    python benchmarks/bench_recover.py        # about 20 minutes on 2 cores
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import write_results  # noqa: E402

# (zenith, amplitude scale, photo: blurred and noisy)
CASES = tuple(
    (z, a, photo) for photo in (False, True) for z, a in ((0.0, 1.0), (30.0, 1.0), (80.0, 0.25))
)

ONE = """
import json, sys, time
import numpy as np
start = time.perf_counter()
import jaxcaustics as jc
from jaxcaustics import recover_surface, reference
import_s = time.perf_counter() - start
zenith, scale, photo = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3] == "True"
extent = (0.0, 1.0, 0.0, 1.0)
terms = [(3, 1, 0.004 * scale, 0.3), (-2, 3, 0.0035 * scale, 1.1), (1, -4, 0.003 * scale, 2.0)]
truth = np.asarray(jc.sine_sum((128, 128), extent, terms=terms), float)
light = jc.DirectionalLight.from_angles(zenith)
def caustic(h):
    receiver = jc.PlaneReceiver(extent, (128, 128))
    scene = jc.WaterScene(jc.HeightField(h, extent), light, receiver, 0.5)
    return reference.trace_water(scene, photons_per_axis=16)
target = caustic(truth)
seen = target
if photo:
    from scipy.ndimage import gaussian_filter
    rng = np.random.default_rng(1)
    noise = 1 + 0.02 * rng.standard_normal(target.shape)
    seen = gaussian_filter(target, 1.0, mode="wrap") * noise
t0 = time.perf_counter()
r = recover_surface(seen, extent=extent, rest_depth=0.5, light=light, blur=1.0 if photo else 0.0)
seconds = time.perf_counter() - t0
t = truth - truth.mean()
print(json.dumps({
    "zenith": zenith, "photo": photo, "peak": float(target.max()), "seconds": seconds,
    "import_s": import_s,
    "height_error": float(np.linalg.norm(r.heights - t) / np.linalg.norm(t)),
    "caustic_error": jc.image_error(caustic(r.heights), target),
    "stages": [(s["stage"], s["steps"], round(s["seconds"], 2)) for s in r.stages],
}))
"""


VIDEO = """
import json, time
import numpy as np
import jaxcaustics as jc
from jaxcaustics import reference
extent = (0.0, 1.0, 0.0, 1.0)
light = jc.DirectionalLight.from_angles(30.0)
truths, frames = [], []
for k in range(16):
    h = np.asarray(jc.wave_heights((128, 128), extent, 0.1 * k, amplitude=0.002, depth=0.5,
                                   wavelength_range=(0.25, 1.0), num_waves=8, seed=3), float)
    receiver = jc.PlaneReceiver(extent, (128, 128))
    scene = jc.WaterScene(jc.HeightField(h, extent), light, receiver, 0.5)
    truths.append(h - h.mean())
    frames.append(reference.trace_water(scene, photons_per_axis=16))
r = jc.recover_sequence(frames, extent=extent, rest_depth=0.5, light=light, progress=False)
print(json.dumps({
    "peak": float(max(f.max() for f in frames)),
    "seconds": r.seconds.tolist(), "warm": r.warm.tolist(), "misfit": r.misfit.tolist(),
    "height_error": [
        float(np.linalg.norm(h - t) / np.linalg.norm(t)) for h, t in zip(r.heights, truths)
    ],
}))
"""


FOLDS = """
import json, time, warnings
import numpy as np
import jaxcaustics as jc
from jaxcaustics import recover_surface, reference
extent, n = (0.0, 1.0, 0.0, 1.0), 32
terms = ((1, 0, 0.008, 0.3), (1, 1, 0.006, 1.1), (0, 2, 0.003, 2.0))
light = jc.DirectionalLight.from_angles(30.0, 20.0)
def caustic(h):
    scene = jc.WaterScene(jc.HeightField(h, extent), light, jc.PlaneReceiver(extent, (n, n)), 0.5)
    return reference.trace_water(scene, photons_per_axis=16)
rows = []
for scale in (1.0, 4.0, 8.0, 16.0):
    truth = scale * np.asarray(jc.sine_sum((n, n), extent, terms=terms), float)
    target = caustic(truth)
    t = truth - truth.mean()
    row = {"scale": scale, "peak": float(target.max())}
    for fold_fit in (False, True):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = recover_surface(target, extent=extent, rest_depth=0.5, light=light,
                                fold_fit=fold_fit)
        key = "fold" if fold_fit else "start"
        row[key] = {
            "seconds": time.perf_counter() - t0,
            "misfit": r.stages[2]["rms"],
            "height_error": float(np.linalg.norm(r.heights - t) / np.linalg.norm(t)),
            "caustic_error": jc.image_error(caustic(r.heights), target),
        }
    rows.append(row)
    print(json.dumps(row), flush=True)
print(json.dumps(rows))
"""


def fold_lines() -> tuple[list[str], list[dict]]:
    out = subprocess.run(
        [sys.executable, "-c", FOLDS], check=True, capture_output=True, text=True
    ).stdout
    rows = json.loads(out.strip().splitlines()[-1])
    lines = [
        "",
        "## Folding seas (32 x 32, float32): the start alone and with the fold fit",
        "",
        "Relief: the smooth sea's times the scale. The start's irradiance misfit above",
        "0.02 is where `recover_surface` warns and (by default) runs the fold fit. Time:",
        "each call, the first of the process paying the start's compilation.",
        "",
        "| relief | peak / mean | start misfit | start: height, caustic error | time (s) |"
        " fold fit: height, caustic error | time (s) |",
        "|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for r in rows:
        a, b = r["start"], r["fold"]
        lines.append(
            f"| {r['scale']:g}x | {r['peak']:.1f} | {a['misfit']:.4f} |"
            f" {a['height_error']:.3f}, {a['caustic_error']:.4f} | {a['seconds']:.1f} |"
            f" {b['height_error']:.3f}, {b['caustic_error']:.4f} | {b['seconds']:.1f} |"
        )
    return lines, rows


def video_lines() -> tuple[list[str], dict]:
    out = subprocess.run(
        [sys.executable, "-c", VIDEO], check=True, capture_output=True, text=True
    ).stdout
    v = json.loads(out.strip().splitlines()[-1])
    print(v)
    later = v["seconds"][1:]
    lines = [
        "",
        "## A video: 16 frames by `recover_sequence` (128 x 128, float32)",
        "",
        f"Peak irradiance {v['peak']:.2f} x the mean. The first frame (cold start) took"
        f" {v['seconds'][0]:.1f} s, compilation included; the 15 later ones (warm-started"
        f" from the frame before) {min(later):.2f}-{max(later):.2f} s each (median"
        f" {sorted(later)[len(later) // 2]:.2f} s).",
        "",
        "| frame | height error | irradiance misfit | warm | time (s) |",
        "|--:|--:|--:|:-:|--:|",
    ]
    for k, (e, m, w, t) in enumerate(
        zip(v["height_error"], v["misfit"], v["warm"], v["seconds"], strict=True)
    ):
        lines.append(f"| {k} | {e:.4f} | {m:.4f} | {'yes' if w else 'no'} | {t:.2f} |")
    return lines, v


def main() -> None:
    rows = []
    for zenith, scale, photo in CASES:
        out = subprocess.run(
            [sys.executable, "-c", ONE, str(zenith), str(scale), str(photo)],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
        print(rows[-1])
    lines = [
        "# Water recovery from the reference's caustics (128 x 128, float32)",
        "",
        "`python benchmarks/bench_recover.py`; see its docstring for the setting. Time: the",
        "`recover_surface` call in a fresh process, compilation included (importing the",
        "package took a further 2-4 s).",
        "",
        "| light (deg) | target | peak / mean | height error | caustic error | time (s) |"
        " stages (steps, s) |",
        "|--:|---|--:|--:|--:|--:|---|",
    ]
    for r in rows:
        stages = "; ".join(f"{name} {steps}, {s}" for name, steps, s in r["stages"])
        lines.append(
            f"| {r['zenith']:.0f} | {'photo' if r['photo'] else 'clean'} | {r['peak']:.2f} |"
            f" {r['height_error']:.4f} |"
            f" {r['caustic_error']:.4f} | {r['seconds']:.1f} | {stages} |"
        )
    folds, fold_rows = fold_lines()
    video, frames = video_lines()
    raw = dict(seas=rows, folds=fold_rows, video=frames)
    text = "\n".join(lines + folds + video) + "\n"
    print(f"wrote {write_results('recover', raw, text)}")


if __name__ == "__main__":
    main()
