"""Round lenses against square ones: target x outline, judged by the reference on what
was exported.

Setting: the quickstart's lens (100 mm blank, 10 mm thick, index 1.5, screen 500 mm below,
collimated light straight down), 128 x 128 targets: scikit-image's ``camera`` and the
white ``lettering`` on black of `targets.py`. Each row is one `jaxcaustics.design` call
with its defaults (the transport start and the image refinement) in a fresh process
(float32; compilation counted), for a `Rectangle` (100 x 100 mm) or a `Circle` (100 mm
across) outline. The design is exported (`export_lens`); its height map is read back from
the EXR (the bicubic's boundary and the outline from its JSON sidecar) and traced by the
NumPy reference (`reference.trace_lens`) at 4096^2 and 8192^2 photons: relative L2 and
1 - SSIM at unit mean, the flux fraction on pixels where the target is below 5% of its
mean; the two photon counts' difference bounds the reference's own noise. The round STL
is checked to be watertight. Writes ``benchmarks/results/outline.md`` and
``outline.json``.

    python benchmarks/bench_outline.py              # all rows (~5 min on 2 cores)
    python benchmarks/bench_outline.py --rows camera-circle
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import once, rows_main  # noqa: E402

NAME = "outline"
PHOTONS = (4096, 8192)
THICKNESS, SCREEN = 0.01, 0.5
ROWS = [f"{t}-{o}" for t in ("camera", "lettering") for o in ("rectangle", "circle")]


def target(name: str):
    import numpy as np

    if name == "camera":
        from skimage import data

        from jaxcaustics.internal import area_average

        return area_average(data.camera().astype(float), (128, 128))
    import targets  # beside this script

    return np.asarray(targets.lettering())


def judge(image, goal) -> dict:
    import numpy as np
    from skimage.metrics import structural_similarity

    a, b = image / image.mean(), goal / goal.mean()
    return dict(
        l2=float(np.linalg.norm(a - b) / np.linalg.norm(b)),
        ssim=float(1 - structural_similarity(a, b, data_range=float(b.max()))),
        dark=float(a[b < 0.05].sum() / a.sum()),
    )


def one(row: str) -> dict:
    """Design, export and judge `row` in this process."""
    import warnings

    import trimesh

    import jaxcaustics as jc
    from jaxcaustics.reference import trace_lens

    name, outline_name = row.split("-")
    goal = target(name)
    outline = jc.Circle(0.1) if outline_name == "circle" else jc.Rectangle(0.1, 0.1)
    problem = jc.DesignProblem(jc.Lens(THICKNESS), outline, jc.Screen(SCREEN))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        total, d = once(lambda: jc.design(problem, goal))
    with tempfile.TemporaryDirectory() as tmp:
        paths = jc.export_lens(d.scene, tmp, formats=("stl",))
        solid = trimesh.load(paths["stl"])
        z_mm = jc.io.read_exr(paths["height_exr"]).astype(float)
        sidecar = json.loads(paths["height_json"].read_text())
    exported = jc.LensScene(
        jc.HeightField(z_mm[1::2, 1::2] / 1000.0 - THICKNESS, outline.extent, sidecar["boundary"]),
        d.scene.light,
        d.scene.receiver,
        THICKNESS,
        SCREEN,
        outline=sidecar["outline"],
    )
    judged = {}
    for photons in PHOTONS:
        seconds, image = once(trace_lens, exported, photons)
        judged[str(photons)] = {**judge(image, goal), "seconds": seconds}
    return dict(
        row=row,
        target=name,
        outline=outline_name,
        total_s=total,
        predicted=d.predicted_error,
        reference=judged,
        watertight=bool(solid.is_watertight and solid.is_volume),
        extents_mm=[float(v) for v in solid.extents],
        warnings=[str(w.message)[:160] for w in caught if "design" in str(w.message)],
    )


def report(rows: dict) -> str:
    fine, coarse = (str(p) for p in PHOTONS[::-1])
    lines = [
        "# Round lenses against square ones (the quickstart's lens, judged on its export)",
        "",
        "100 mm blank, 10 mm thick, index 1.5, screen 500 mm, collimated light, 128 x 128 "
        "targets, `jaxcaustics.design` defaults, float32, 2 CPU cores, one fresh process "
        "per row (`total s`: compilation included). Judged by the NumPy reference on the "
        f"exported height map (EXR) at {fine}^2 photons; `noise`: the change of the L2 "
        f"from {coarse}^2 to {fine}^2 photons. Regenerate: "
        "`python benchmarks/bench_outline.py`.",
        "",
        "| target | outline | total s | predicted L2 | reference L2 | noise | 1 - SSIM | "
        "dark flux | solid | warned |",
        "|---|---|--:|--:|--:|--:|--:|--:|---|---|",
    ]
    for key in ROWS:
        r = rows.get(key)
        if r is None:
            continue
        ref, other = r["reference"][fine], r["reference"][coarse]
        solid = "watertight" if r["watertight"] else "NOT watertight"
        size = " x ".join(f"{v:.1f}" for v in r["extents_mm"])
        lines.append(
            f"| {r['target']} | {r['outline']} | {r['total_s']:.1f} | {r['predicted']:.3f} | "
            f"{ref['l2']:.4f} | {abs(other['l2'] - ref['l2']):.4f} | {ref['ssim']:.3f} | "
            f"{100 * ref['dark']:.2f}% | {solid}, {size} mm | "
            f"{'yes' if r['warnings'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    rows_main(NAME, __file__, ROWS, one, report, __doc__, argv)


if __name__ == "__main__":
    main()
