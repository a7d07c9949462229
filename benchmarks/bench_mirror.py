"""Caustic mirrors, and a lens whose screen faces the refracted beam: judged by the
reference on what was exported.

Settings (128 x 128 targets: scikit-image's ``camera`` and the bright ``silhouette`` on
black of `targets.py`; 100 x 100 mm blank, 10 mm thick; `jaxcaustics.design` defaults,
the transport start and the image refinement, float32, one fresh process per row,
compilation counted):

- ``mirror``: a `Mirror`, collimated light 30 degrees from its normal, the screen 1 m
  away facing the reflected beam;
- ``mirror-point``: the same under a point light 1 m from the mirror's centre, 30 degrees
  from its normal;
- ``lens-beam``: a `Lens` (index 1.5) under light 30 degrees from vertical, the screen
  500 mm from its bottom face, facing the refracted beam.

The design is exported (`export_lens`, the blank `--thickness`); its height map is read
back from the EXR and traced by the NumPy reference (`trace_mirror`, `trace_lens`) at
4096^2 and 8192^2 photons: relative L2 and 1 - SSIM at unit mean, the flux fraction on
pixels where the target is below 5% of its mean; the two photon counts' difference
bounds the reference's noise. Writes ``benchmarks/results/mirror.md`` and
``mirror.json``.

    python benchmarks/bench_mirror.py              # all rows (~12 min on 2 cores)
    python benchmarks/bench_mirror.py --rows mirror-camera
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from bench_outline import judge, target  # noqa: E402
from harness import once, rows_main  # noqa: E402

NAME = "mirror"
PHOTONS = (4096, 8192)
THICKNESS = 0.01
SETTINGS = ("mirror", "mirror-point", "lens-beam")
ROWS = [f"{s}-{t}" for s in SETTINGS for t in ("camera", "silhouette")]


def problem(setting: str):
    import numpy as np

    import jaxcaustics as jc

    sun = jc.DirectionalLight.from_angles(30.0)
    blank = jc.Rectangle(0.1, 0.1)
    if setting == "lens-beam":
        return jc.DesignProblem(jc.Lens(THICKNESS), blank, jc.Screen(0.5, normal="beam"), sun)
    if setting == "mirror-point":
        at = np.radians(30.0)
        lamp = jc.PointLight(np.array([-np.sin(at), 0.0, np.cos(at)]))
        return jc.DesignProblem(jc.Mirror(THICKNESS), blank, jc.Screen(1.0), lamp)
    return jc.DesignProblem(jc.Mirror(THICKNESS), blank, jc.Screen(1.0), sun)


def goal(name: str):
    import numpy as np

    if name == "camera":
        return target("camera")
    import targets  # beside this script

    return np.asarray(targets.silhouette())


def one(row: str) -> dict:
    """Design, export and judge `row` in this process."""
    import warnings

    import jaxcaustics as jc
    from jaxcaustics.reference import trace_lens, trace_mirror

    setting, name = row.rsplit("-", 1)
    wanted = goal(name)
    prob = problem(setting)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        total, d = once(lambda: jc.design(prob, wanted))
    mirror = isinstance(d.scene, jc.MirrorScene)
    with tempfile.TemporaryDirectory() as tmp:
        paths = jc.export_lens(
            d.scene, tmp, thickness=THICKNESS if mirror else None, formats=("stl",)
        )
        z_mm = jc.io.read_exr(paths["height_exr"]).astype(float)
        sidecar = json.loads(paths["height_json"].read_text())
    surface = jc.HeightField(
        z_mm[1::2, 1::2] / 1000.0 - THICKNESS, prob.outline.extent, sidecar["boundary"]
    )
    if mirror:
        exported = jc.MirrorScene(surface, d.scene.light, d.scene.receiver, d.scene.screen_pose)
        trace = trace_mirror
    else:
        exported = jc.LensScene(
            surface,
            d.scene.light,
            d.scene.receiver,
            THICKNESS,
            0.5,
            screen_pose=d.scene.screen_pose,
        )
        trace = trace_lens
    judged = {}
    for photons in PHOTONS:
        seconds, image = once(trace, exported, photons)
        judged[str(photons)] = {**judge(image, wanted), "seconds": seconds}
    levels = {r["stage"]: r for r in d.levels}
    fit = levels.get("landing fit", {})
    return dict(
        row=row,
        setting=setting,
        target=name,
        total_s=total,
        predicted=d.predicted_error,
        reference=judged,
        fit_rms_pixels=fit.get("rms_pixels"),
        stretch=fit.get("stretch"),
        warnings=[str(w.message)[:160] for w in caught if "design" in str(w.message)],
    )


def report(rows: dict) -> str:
    fine, coarse = (str(p) for p in PHOTONS[::-1])
    lines = [
        "# Caustic mirrors and a screen facing the beam (judged on the export)",
        "",
        "100 x 100 mm blank, 10 mm thick; `mirror`: collimated light 30 degrees from the "
        "mirror's normal, screen 1 m away facing the reflected beam; `mirror-point`: a point "
        "light 1 m away at 30 degrees; `lens-beam`: a lens (index 1.5) under light 30 "
        "degrees from vertical, screen 500 mm from its bottom face facing the refracted "
        "beam. 128 x 128 targets, `jaxcaustics.design` defaults, float32, 2 CPU cores, one "
        "fresh process per row (`total s`: compilation included). Judged by the NumPy "
        f"reference on the exported height map (EXR) at {fine}^2 photons; `noise`: the "
        f"change of the L2 from {coarse}^2 to {fine}^2 photons; `fit px`: the landing fit's "
        "RMS misplacement (pixels); `stretch`: the transport's stretch along x. "
        "Regenerate: `python benchmarks/bench_mirror.py`.",
        "",
        "| setting | target | total s | predicted L2 | reference L2 | noise | 1 - SSIM | "
        "dark flux | fit px | stretch | warned |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|---|",
    ]
    for key in ROWS:
        r = rows.get(key)
        if r is None:
            continue
        ref, other = r["reference"][fine], r["reference"][coarse]
        lines.append(
            f"| {r['setting']} | {r['target']} | {r['total_s']:.1f} | {r['predicted']:.3f} | "
            f"{ref['l2']:.4f} | {abs(other['l2'] - ref['l2']):.4f} | {ref['ssim']:.3f} | "
            f"{100 * ref['dark']:.2f}% | {r['fit_rms_pixels']:.3f} | {r['stretch']:.3f} | "
            f"{'yes' if r['warnings'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    rows_main(NAME, __file__, ROWS, one, report, __doc__, argv)


if __name__ == "__main__":
    main()
