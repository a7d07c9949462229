"""Designs under the light people have: the Sun's disc and an LED's die, judged by the
reference on what was exported, under that source.

Each row designs the same lens twice, for the ideal light (collimated, or a point at
the die's centre) and for the extended source (`jc.SunLight`, `jc.AreaLight`), with
`jaxcaustics.design` defaults (float32, one fresh process per row, compilation
counted), exports both (`export_lens`), reads their height maps back from the EXR and
traces them with the NumPy reference under the source, sampled at two densities
(``photons^2`` photons shared over ``samples`` source samples): relative L2 and 1 - SSIM
at unit mean; the change between the densities bounds the judge's noise.

Settings (128 x 128 targets; index 1.5):

- ``mitsuba``: Mitsuba 3's caustics tutorial: a 2 x 2 lens (metres), 0.5 thick, the
  screen 7 away; the Sun straight overhead; ``camera``;
- ``quick250``, ``quick500``, ``quick1000``: the quickstart lens, 100 x 100 x 10 mm, the
  screen 250, 500, 1000 mm away; the Sun; ``camera``;
- ``letters500``: the quickstart lens at 500 mm, white lettering on black;
- ``led``: a 50 x 50 x 10 mm lens under a 3 mm square Lambertian die 100 mm above its
  top, the screen 300 mm below it; ``camera``.

Writes ``benchmarks/results/sources.md`` and ``sources.json``.

    python benchmarks/bench_sources.py                 # all rows (~35 min on 2 cores)
    python benchmarks/bench_sources.py --rows led
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from bench_outline import judge, target  # noqa: E402
from harness import once, rows_main  # noqa: E402

NAME = "sources"
JUDGES = ((2048, 64), (4096, 256))  # (photons per axis, source samples)
# rows whose blur spans 3.5 pixels or more: 64 samples over it moved the figure by 15%
FINE_JUDGES = {"led": ((4096, 256), (4096, 1024)), "quick1000": ((4096, 256), (4096, 1024))}
ROWS = ["mitsuba", "quick250", "quick500", "quick1000", "letters500", "led"]


def setting(row: str):
    """``(target name, width, thickness, screen distance, ideal light, source)``."""
    import jaxcaustics as jc

    sun = jc.SunLight()
    if row == "mitsuba":
        return "camera", 2.0, 0.5, 7.0, None, sun
    if row == "led":
        top = 0.3 + 0.01
        die = jc.AreaLight([0.0, 0.0, top + 0.1], 0.003)
        return "camera", 0.05, 0.01, 0.3, jc.PointLight([0.0, 0.0, top + 0.1]), die
    name = "lettering" if row.startswith("letters") else "camera"
    distance = int(row.removeprefix("letters").removeprefix("quick")) / 1000
    # at 250 mm the design's relief is 11.9 mm: over the 10 mm blank (refused by name)
    return name, 0.1, 0.015 if distance < 0.3 else 0.01, distance, None, sun


def exported_image(design, thickness, distance, source, photons, samples):
    """`design`'s exported height map traced by the reference under `source`."""
    import jaxcaustics as jc
    from jaxcaustics.reference import trace_lens

    with tempfile.TemporaryDirectory() as tmp:
        paths = jc.export_lens(design.scene, tmp, formats=("stl",))
        z_mm = jc.io.read_exr(paths["height_exr"]).astype(float)
        sidecar = json.loads(paths["height_json"].read_text())
    surface = jc.HeightField(
        z_mm[1::2, 1::2] / 1000.0 - thickness,
        design.scene.surface.extent,
        sidecar["boundary"],
    )
    scene = jc.LensScene(surface, source, design.scene.receiver, thickness, distance)
    return trace_lens(scene, photons, source_samples=samples)


def one(row: str) -> dict:
    """Design both lenses of `row`, export and judge them, in this process."""
    import warnings

    import jaxcaustics as jc

    name, width, thickness, distance, ideal, source = setting(row)
    wanted = target(name)
    out = dict(row=row, target=name)
    for kind, light in (("ideal", ideal), ("source", source)):
        problem = jc.DesignProblem(
            jc.Lens(thickness), jc.Rectangle(width, width), jc.Screen(distance), light
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            total, d = once(lambda p=problem: jc.design(p, wanted))
        judged = {}
        for photons, samples in FINE_JUDGES.get(row, JUDGES):
            seconds, image = once(exported_image, d, thickness, distance, source, photons, samples)
            judged[f"{photons}/{samples}"] = {**judge(image, wanted), "seconds": seconds}
        out[kind] = dict(
            total_s=total,
            predicted=d.predicted_error,
            blur_px=d.source_blur_px,
            reference=judged,
            warnings=[str(w.message)[:200] for w in caught if "design" in str(w.message)],
        )
    out["total_s"] = out["ideal"]["total_s"] + out["source"]["total_s"]
    out["reference"] = {k: out[k]["reference"] for k in ("ideal", "source")}
    return out


def report(rows: dict) -> str:
    lines = [
        "# Designs under the Sun and an LED's die (judged on the export, under the source)",
        "",
        "Each row: the lens designed for the ideal light (collimated; `led`: a point at "
        "the die's centre) and for the source (`jc.SunLight()`, the Sun's disc 0.533 "
        "degrees across, straight overhead; `led`: `jc.AreaLight`, a 3 mm square "
        "Lambertian die 100 mm above the lens's top). Settings: `mitsuba`, Mitsuba's "
        "tutorial (2 x 2 lens, 0.5 thick, screen 7 away); `quickD`, the quickstart lens "
        "(100 x 100 x 10 mm) with the screen D mm away; `letters500`, white lettering on "
        "black at 500 mm; `led`, a 50 x 50 x 10 mm lens, screen 300 mm below. 128 x 128 "
        "targets, `jaxcaustics.design` defaults, float32, 2 CPU cores, one fresh process "
        "per row (`s`: design time, compilation included). Judged by the NumPy reference "
        "on the exported height map (EXR) under the source at the finer `judge` (photons per "
        "axis / source samples); `noise`: the change of the L2 from the coarser one. "
        "`blur px`: the source's blur on the screen (radius, pixels). `quick250`'s blank is "
        "15 mm thick (the 10 mm one is too thin for its relief, 11.9 mm). "
        "Regenerate: `python benchmarks/bench_sources.py`.",
        "",
        "| setting | target | judge | blur px | ideal: s | L2 | 1 - SSIM | noise | "
        "for the source: s | predicted L2 | L2 | 1 - SSIM | noise | ratio of L2 |",
        "|---|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for key in ROWS:
        r = rows.get(key)
        if r is None:
            continue
        a, b = r["ideal"], r["source"]
        coarse, fine = a["reference"]  # as measured, coarser first
        fa, ca = a["reference"][fine], a["reference"][coarse]
        fb, cb = b["reference"][fine], b["reference"][coarse]
        lines.append(
            f"| {key} | {r['target']} | {fine} | {b['blur_px']:.2f} | {a['total_s']:.1f} | "
            f"{fa['l2']:.4f} | {fa['ssim']:.3f} | {abs(fa['l2'] - ca['l2']):.4f} | "
            f"{b['total_s']:.1f} | {b['predicted']:.3f} | {fb['l2']:.4f} | {fb['ssim']:.3f} "
            f"| {abs(fb['l2'] - cb['l2']):.4f} | {fb['l2'] / fa['l2']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    rows_main(NAME, __file__, ROWS, one, report, __doc__, argv)


if __name__ == "__main__":
    main()
