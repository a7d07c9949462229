"""Lens design at print resolution: target size x picture, time, memory and quality.

Setting: the quickstart's (lens 100 x 100 mm, index 1.5, blank 10 mm, screen 500 mm
below, collimated light from straight above). Each row is one `design` with its
defaults (float32) in a fresh process: `total s` counts everything, compilation
included; `compile s` is the first call of each compiled solve (compilation plus one
step); `peak GB` is the process's peak resident memory. The design is judged on what a
workshop receives: the exported solid (its top sampled as `export_lens` writes it) traced
exactly by its flat facets (`reference.trace_solid_facets`, no photon noise), against
the target at unit mean: relative L2, 1 - SSIM (scikit-image) and the fraction of the
flux on pixels where the target is below 5% of its mean. Writes
``benchmarks/results/resolution.md`` and ``resolution.json``.

    python benchmarks/bench_resolution.py                      # all rows (~20 min, 2 cores)
    python benchmarks/bench_resolution.py --rows camera-256,silhouette-512
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import judge, once, rows_main  # noqa: E402

NAME = "resolution"
PICTURES = ("camera", "silhouette", "lettering")
SIZES = (128, 256, 512, 1024)
ROWS = [f"{p}-{s}" for p in PICTURES for s in SIZES]


def target(name: str, size: int):
    import numpy as np

    if name == "camera":
        # the quickstart's picture, resized as `jaxcaustics design --size` resizes it
        # (scikit-image's `resize`, anti-aliased; bilinear above the photograph's 512
        # pixels, where a box average would make a target of 2 x 2 blocks at 1024)
        from skimage import data, transform

        return transform.resize(data.camera().astype(float), (size, size), anti_aliasing=True)
    import targets  # beside this script

    return np.asarray(targets.TARGETS[name](size))


def one(row: str) -> dict:
    """Design and judge `row` in this process."""
    import os
    import resource
    import warnings

    import jax

    import jaxcaustics as jc
    from jaxcaustics import reference
    from jaxcaustics.internal import exported_image

    load = os.getloadavg()[0]  # other work on the machine slows the row down
    name, size = row.rsplit("-", 1)
    goal = target(name, int(size))
    problem = jc.DesignProblem(
        jc.Lens(thickness=0.01), jc.Rectangle(0.1, 0.1), jc.Screen(distance=0.5)
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        total, d = once(lambda: jc.design(problem, goal, throw=False))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: kB
    judge_s, image = once(lambda: exported_image(d.scene))
    # the height map as a mill cuts it (the bicubic surface), traced by triangles of
    # vertices: 8 per pixel side (4 at 1024 pixels: 8193^2 is over the reference's limit)
    per_pixel = 8 if int(size) <= 512 else 4
    vertices = per_pixel * max(d.target.shape) + 1
    heights_s, smooth = once(lambda: reference.trace_lens_triangles(d.scene, vertices))
    firsts = [lev.get("first_step_seconds", float("nan")) for lev in d.levels]
    return dict(
        row=row,
        target=name,
        size=int(size),
        heights=list(d.heights.shape),
        total_s=total,
        compile_s=sum(s for s in firsts if s == s),
        transport_s=sum(lev["seconds"] for lev in d.levels if lev.get("stage") == "transport"),
        predict_s=d.timings.get("predict", float("nan")),
        peak_gb=peak / 1e9,
        predicted=d.predicted_error,
        reference=judge(image, d.target),
        judge_s=judge_s,
        heights_judged=judge(smooth, d.target),
        heights_vertices=vertices,
        heights_judge_s=heights_s,
        load=load,
        warnings=[str(w.message)[:160] for w in caught],
        jax=jax.__version__,
    )


def report(rows: dict) -> str:
    import os

    lines = [
        "# Lens design at print resolution",
        "",
        f"1-minute load average when the report was written: {os.getloadavg()[0]:.1f}; "
        "`load`: when the row started (2 cores: above 2, other work shared them).",
        "",
        "Quickstart setting (100 mm lens, index 1.5, 10 mm blank, screen 500 mm), `design` "
        "defaults, float32, 2 CPU cores, one fresh process per row. The camera is resized "
        "as `jaxcaustics design --size` resizes it (scikit-image's anti-aliased `resize`: "
        "bilinear at 1024 pixels, from its 512); the silhouette (scikit-image's 328 x 400 "
        "`horse`) and the lettering (drawn at 512 pixels) are box-averaged "
        "(`benchmarks/targets.py`). `total s`: the design, "
        "compilation included (not the export); `compile s`: the first call of each "
        "compiled solve; `transport s`: the optimal transport; `peak GB`: the process's "
        "peak resident memory. Judged on the exported solid's facets (exact, "
        "`reference.trace_solid_facets`): relative L2 and 1 - SSIM at unit mean, and the "
        "flux on pixels where the target is below 5% of its mean. `predicted`: the design's "
        "own forward model. `heights L2`, `heights 1 - SSIM`: the height map as a mill cuts "
        "it (the bicubic surface, not the STL's flat facets), traced by triangles of "
        "vertices spread over the pixels by area (`reference.trace_lens_triangles`, 8 "
        "vertices per pixel side, 4 at 1024 pixels; `-`: a row from before that judge). "
        "Regenerate: `python benchmarks/bench_resolution.py`.",
        "",
        "| picture | size | heights | total s | compile s | transport s | peak GB | "
        "predicted L2 | solid L2 | 1 - SSIM | dark flux | judged in s | heights L2 | "
        "heights 1 - SSIM | load |",
        "|---|--:|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for key in ROWS:
        r = rows.get(key)
        if r is None:
            continue
        ref = r["reference"]
        smooth = r.get("heights_judged")
        load = f"{r['load']:.1f}" if "load" in r else "-"
        by_heights = f"{smooth['l2']:.3f} | {smooth['ssim']:.3f}" if smooth is not None else "- | -"
        lines.append(
            f"| {r['target']} | {r['size']} | {r['heights'][0]}^2 | {r['total_s']:.1f} | "
            f"{r['compile_s']:.1f} | {r['transport_s']:.1f} | {r['peak_gb']:.2f} | "
            f"{r['predicted']:.3f} | {ref['l2']:.3f} | {ref['ssim']:.3f} | "
            f"{100 * ref['dark']:.2f}% | {r['judge_s']:.0f} | {by_heights} | {load} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    rows_main(NAME, __file__, ROWS, one, report, __doc__)
