"""Design a caustic lens that projects a picture, export it for milling, and check it.

The target is scikit-image's bundled ``camera`` picture, area-averaged to ``--size``
pixels square. `design_lens` computes the top surface of a 100 mm x 100 mm glass lens
(index 1.5), milled into a 10 mm thick blank, whose caustic on a screen 500 mm below its
flat bottom face is that picture (collimated light from straight above). The design is
then

- exported for fabrication (`export_lens`: STL and OBJ solids, height maps, and a
  manufacturability report, all in millimetres),
- rendered independently by the NumPy reference photon tracer and compared with the
  target (relative L2 error, both images scaled to unit mean),
- drawn: target | reference render of the design | heights (mm).

Run: ``python examples/design_lens.py`` (about a minute on a 2-core CPU; the first solver
step of each level compiles). Options: ``--size 32`` (faster), ``--output DIR`` (default:
a new temporary folder), ``--photons`` (reference photons per pixel along each axis; with
fewer than the default 32 the reference's pixel binning adds to the error it reports).
"""

import argparse
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window
import matplotlib.pyplot as plt  # noqa: E402
from skimage import data  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics.reference import trace_lens  # noqa: E402


def area_average(image, n):
    """The centre square of `image`, averaged down to ``n x n`` pixels (whole blocks)."""
    s = min(image.shape[:2]) // n * n
    r0, c0 = (image.shape[0] - s) // 2, (image.shape[1] - s) // 2
    square = image[r0 : r0 + s, c0 : c0 + s]
    return square.reshape(n, s // n, n, s // n, *image.shape[2:]).mean(axis=(1, 3))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64, help="target pixels per side")
    parser.add_argument("--photons", type=int, default=32, help="per pixel per axis")
    parser.add_argument("--output", type=Path, default=None, help="output folder")
    args = parser.parse_args(argv)
    out = args.output or Path(tempfile.mkdtemp(prefix="design_lens_"))
    out.mkdir(parents=True, exist_ok=True)

    target = area_average(data.camera().astype(float) / 255.0, args.size)

    # 1. Design (lengths in metres). The default heights grids go from 32 samples to
    #    twice the target's pixels, coarse to fine.
    design = jc.design_lens(
        target, width=0.1, height=0.1, thickness=0.01, screen_distance=0.5, ior=1.5
    )
    print(f"designed in {design.timings['total']:.1f} s: {design.timings}")
    for level in design.levels:
        print(
            f"  heights {level['shape']}: {level['steps']} steps, loss {level['loss']:.3g}, "
            f"{level['seconds']:.1f} s ({level['first_step_seconds']:.1f} s first step)"
        )
    print(f"relief {design.relief * 1e3:.2f} mm")

    # 2. Export for fabrication: solids, height maps and the manufacturability report.
    t0 = time.perf_counter()
    paths = jc.export_lens(design.scene, out, formats=("stl", "obj"))
    export_s = time.perf_counter() - t0
    print(paths["report_txt"].read_text().rstrip())

    # 3. Check with the independent NumPy reference tracer.
    t0 = time.perf_counter()
    render = trace_lens(design.scene, args.photons * args.size)
    render_s = time.perf_counter() - t0
    error = jc.relative_l2(render, target)
    predicted = jc.relative_l2(design.predicted, target)
    print(f"relative L2 error vs the target: reference {error:.3f}, design's own {predicted:.3f}")

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.6))
    panels = (
        (target, "target", "gray"),
        (render, "reference render of the design", "gray"),
        (design.heights * 1e3, "heights (mm)", "viridis"),
    )
    for ax, (image, title, cmap) in zip(axes, panels, strict=True):
        shown = ax.imshow(image, cmap=cmap)
        ax.set_title(title)
        ax.set_axis_off()
    fig.colorbar(shown, ax=axes[2], shrink=0.8)
    fig.tight_layout()
    fig.savefig(out / "design_lens.png", dpi=80)
    plt.close(fig)
    print(f"wrote {out}")
    return {
        "relative_l2": error,
        "predicted_relative_l2": predicted,
        "relief_mm": design.relief * 1e3,
        "design_seconds": design.timings["total"],
        "export_seconds": export_s,
        "render_seconds": render_s,
    }


if __name__ == "__main__":
    main()
