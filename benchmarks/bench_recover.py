"""Water recovery from caustics the model did not render: smooth seas, three lights.

Each row: a 1 m x 1 m periodic sea of three swells, 0.5 m deep, 128 x 128 heights and
pixels; its caustic rendered by the NumPy reference (`reference.trace_water`, 16^2
photons a pixel); `recover_surface` with its defaults (float32, the transport start,
no image-space solve) in a fresh process, so that the time includes JAX's start-up and
every compilation. Judged by the heights (relative RMS, means removed) and by the
reference's caustic of the recovered heights against the target (`jc.image_error`:
relative L1 after a 1-pixel Gaussian blur). The 80-degree sea has a quarter of the
amplitude (the full one folds under grazing light: peak irradiance 35x the mean).

    python benchmarks/bench_recover.py        # three rows, about 3 minutes on 2 cores
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
OUT = RESULTS / "recover.md"
CASES = ((0.0, 1.0), (30.0, 1.0), (80.0, 0.25))  # (zenith, amplitude scale)

ONE = """
import json, sys, time
import numpy as np
start = time.perf_counter()
import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics._inverse.recover import recover_surface
import_s = time.perf_counter() - start
zenith, scale = float(sys.argv[1]), float(sys.argv[2])
extent = (0.0, 1.0, 0.0, 1.0)
terms = [(3, 1, 0.004 * scale, 0.3), (-2, 3, 0.0035 * scale, 1.1), (1, -4, 0.003 * scale, 2.0)]
truth = np.asarray(jc.sine_sum((128, 128), extent, terms=terms), float)
light = jc.DirectionalLight.from_angles(zenith)
def caustic(h):
    receiver = jc.PlaneReceiver(extent, (128, 128))
    scene = jc.WaterScene(jc.HeightField(h, extent), light, receiver, 0.5)
    return reference.trace_water(scene, photons_per_axis=16)
target = caustic(truth)
t0 = time.perf_counter()
r = recover_surface(target, extent=extent, rest_depth=0.5, light=light)
seconds = time.perf_counter() - t0
t = truth - truth.mean()
print(json.dumps({
    "zenith": zenith, "peak": float(target.max()), "seconds": seconds,
    "import_s": import_s,
    "height_error": float(np.linalg.norm(r.heights - t) / np.linalg.norm(t)),
    "caustic_error": jc.image_error(caustic(r.heights), target),
    "stages": [(s["stage"], s["steps"], round(s["seconds"], 2)) for s in r.stages],
}))
"""


def main() -> None:
    rows = []
    for zenith, scale in CASES:
        out = subprocess.run(
            [sys.executable, "-c", ONE, str(zenith), str(scale)],
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
        "| light (deg) | peak / mean | height error | caustic error | time (s) |"
        " stages (steps, s) |",
        "|--:|--:|--:|--:|--:|---|",
    ]
    for r in rows:
        stages = "; ".join(f"{name} {steps}, {s}" for name, steps, s in r["stages"])
        lines.append(
            f"| {r['zenith']:.0f} | {r['peak']:.2f} | {r['height_error']:.4f} |"
            f" {r['caustic_error']:.4f} | {r['seconds']:.1f} | {stages} |"
        )
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
