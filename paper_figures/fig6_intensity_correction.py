"""Liu, Dong, Bao & Peng, Figure 6: caustic spot lights with and without intensity correction.

"Caustic spot light for rendering caustics" (2008), Section 2.3: the light-plane image of
a caustic spot light (CSL) gives the power leaving each bit of the plane; where the
spot light's rays converge or diverge on their way to a point ``x`` the beam's cross
section shrinks or grows, so the intensity at ``x`` is the image value divided by the
area ratio ``sigma = |h(r) h'(r) / r|`` (Eq. 4). Their Fig. 6 shows a caustic rendered
with (left) and without (right) that correction and says only that the correction "can
greatly improve the rendering quality". This script gives the numbers.

Scene: a glass ball (index 1.5, radius 0.3 m, centre 1 m above the floor ``z = 0``, two
interfaces, no Fresnel) lit by a directional light 20 degrees from the vertical
(travelling towards +x); the receiver is a 2 x 2 m square of the floor centred under
the ball's shifted image (``x`` from -0.64 to 1.36 m), 128 x 128 pixels (``--height``
and ``--size`` change the ball's height and the receiver's side). The ball's caustic
surface runs along its axis from the marginal rays' crossing (about 0.30 m past the
centre) to the paraxial focus (0.45 m), so with the floor 1 m below the centre (1.06 m
along the light) it sees the beam spreading past the focus: a bright blob, brightest
(about half the light's irradiance) under the axis, in a dim halo of the steep marginal
rays (and about 18% of the light misses the 2 m square).

- CSLs: `jaxcaustics.spot_lights` with ``rays_per_axis = 256`` (its defaults otherwise:
  up to 16 lights, 95% of the energy, 64^2 light-plane images, 2 x 2 samples per pixel);
  then the same fitted lights rendered again with ``intensity_correction=False``.
- Reference: `jaxcaustics.reference.trace_ellipsoid`, 2048^2 photons (and 1024^2, to
  show its own error).
- Without the correction each light's image value is carried unchanged along its rays,
  so the floor's level depends on where the fit put the light plane: a plane where the
  bundle is wider than on the floor makes it too bright, a narrower one too dark.
- Error: relative L1 ``sum |blur(img) - blur(ref)| / sum blur(ref)``, both images blurred
  by a Gaussian of sigma 1 pixel (zero outside the receiver).

Writes to ``--output`` (default ``paper_figures/output/``):

- ``fig6_intensity_correction.png``: reference, with correction, without correction (one
  grey scale), and the profiles along the row through the ball's axis;
- ``fig6_intensity_correction.md``: the table (also printed).

Run ``python paper_figures/fig6_intensity_correction.py`` (under a minute on 2 CPU
cores, most of it jit compilation of the fit) or ``--quick`` (32^2 pixels, 64^2 rays,
256^2 photons).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.ndimage import gaussian_filter  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "output"
NAME = "fig6_intensity_correction"

IOR = 1.5
RADIUS = 0.3  # metres
HEIGHT = 1.0  # centre above the floor, metres
ZENITH = 20.0  # degrees
SIZE = 2.0  # side of the square receiver, metres
BLUR = 1.0  # pixels

FULL = dict(pixels=128, rays_per_axis=256, reference=2048)
QUICK = dict(pixels=32, rays_per_axis=64, reference=256)


def extent(height: float = HEIGHT, size: float = SIZE, zenith: float = ZENITH) -> tuple:
    """The square receiver of side `size` centred where the ball's axis along the light
    (travelling towards +x) meets the floor."""
    shift = height * math.tan(math.radians(zenith))
    return (shift - size / 2, shift + size / 2, -size / 2, size / 2)


def sphere_scene(
    pixels: int, height: float = HEIGHT, size: float = SIZE, zenith: float = ZENITH
) -> jc.EllipsoidScene:
    """The glass ball, centre `height` m up, over the `size` x `size` m receiver
    (`pixels` per side)."""
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, height], RADIUS),
        jc.DirectionalLight.from_angles(zenith),
        jc.PlaneReceiver(extent(height, size, zenith), (pixels, pixels)),
        ior=IOR,
    )


def blur(image, sigma: float = BLUR) -> np.ndarray:
    """Gaussian blur of `sigma` pixels, zero outside the image."""
    image = np.asarray(image, np.float64)
    return gaussian_filter(image, sigma, mode="constant") if sigma > 0 else image


def run(quick: bool = False, height: float = HEIGHT, size: float = SIZE) -> tuple[dict, dict]:
    settings = dict(QUICK if quick else FULL, height=height, size=size)
    scene = sphere_scene(settings["pixels"], height, size)

    start = time.perf_counter()
    truth = np.asarray(reference.trace_ellipsoid(scene, settings["reference"]), np.float64)
    ref_s = time.perf_counter() - start
    coarse = np.asarray(reference.trace_ellipsoid(scene, settings["reference"] // 2), np.float64)

    start = time.perf_counter()
    fitted = jc.internal.spot_lights(scene, rays_per_axis=settings["rays_per_axis"])
    corrected = np.asarray(fitted.image, np.float64)
    fit_s = time.perf_counter() - start
    lights = fitted.lights[0]

    start = time.perf_counter()
    plain = np.asarray(
        jc.internal.spot_lights(scene, lights=lights, intensity_correction=False).image, np.float64
    )
    plain_s = time.perf_counter() - start

    results = dict(
        settings=settings,
        lights=int(fitted.stats["lights"][0]),
        missed_flux_fraction=float(fitted.missed_flux_fraction[0]),
        error_corrected=jc.image_error(corrected, truth),
        error_uncorrected=jc.image_error(plain, truth),
        error_corrected_unblurred=jc.image_error(corrected, truth, 0.0),
        error_uncorrected_unblurred=jc.image_error(plain, truth, 0.0),
        error_reference_half=jc.image_error(coarse, truth),
        flux_corrected=float(corrected.sum() / truth.sum()),
        flux_uncorrected=float(plain.sum() / truth.sum()),
        reference_seconds=ref_s,
        fit_render_seconds=fit_s,
        render_uncorrected_seconds=plain_s,
    )
    images = dict(reference=truth, corrected=corrected, uncorrected=plain)
    return results, images


def markdown(r: dict) -> str:
    s = r["settings"]
    lines = [
        "# Liu et al., Fig. 6: CSL intensity correction (Eq. 4) on a glass ball",
        "",
        f"Glass ball n = {IOR}, radius {RADIUS} m, centre {s['height']:g} m up; directional "
        f"light {ZENITH:g} deg from vertical; receiver {s['size']:g} x {s['size']:g} m, "
        f"{s['pixels']}^2 pixels. CSLs: "
        f"`spot_lights`, {s['rays_per_axis']}^2 traced rays, {r['lights']} lights, missed "
        f"flux {100 * r['missed_flux_fraction']:.1f}%. Reference: `trace_ellipsoid`, "
        f"{s['reference']}^2 photons. Error: relative L1 sum|blur(img) - blur(ref)| / "
        f"sum blur(ref), Gaussian blur sigma = {BLUR:g} px on both images (zero outside the "
        "receiver), and without the blur. Flux: image sum / reference sum.",
        "",
        "| image | rel. L1 (1 px blur) | rel. L1 (no blur) | flux ratio | time (s) |",
        "|---|---:|---:|---:|---:|",
        f"| CSLs with intensity correction | {r['error_corrected']:.4f} | "
        f"{r['error_corrected_unblurred']:.4f} | {r['flux_corrected']:.3f} | "
        f"{r['fit_render_seconds']:.1f} (trace + fit + render, jit included) |",
        f"| CSLs without intensity correction | {r['error_uncorrected']:.4f} | "
        f"{r['error_uncorrected_unblurred']:.4f} | {r['flux_uncorrected']:.3f} | "
        f"{r['render_uncorrected_seconds']:.1f} (render, same lights) |",
        f"| reference, {s['reference'] // 2}^2 photons | {r['error_reference_half']:.4f} | | | |",
        f"| reference, {s['reference']}^2 photons | 0 | 0 | 1 | {r['reference_seconds']:.1f} |",
    ]
    return "\n".join(lines) + "\n"


def figure(r: dict, images: dict, path: Path, dpi: int = 110) -> None:
    truth = images["reference"]
    box = extent(r["settings"]["height"], r["settings"]["size"])
    white = float(np.percentile(truth, 99.8)) or 1.0
    panels = [
        ("reference", truth, f"reference ({r['settings']['reference']}^2 photons)"),
        (
            "corrected",
            images["corrected"],
            f"CSLs, with correction\nrel. L1 = {r['error_corrected']:.3f}",
        ),
        (
            "uncorrected",
            images["uncorrected"],
            f"CSLs, without correction\nrel. L1 = {r['error_uncorrected']:.3f}",
        ),
    ]
    fig, axes = plt.subplots(1, 4, figsize=(15.5, 4.2), constrained_layout=True)
    for ax, (_, image, title) in zip(axes[:3], panels, strict=True):
        shown = ax.imshow(image, origin="lower", extent=box, cmap="gray", vmin=0, vmax=white)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (m)")
    axes[0].set_ylabel("y (m)")
    fig.colorbar(shown, ax=axes[:3], shrink=0.85, label="irradiance / light's (clipped)")
    rows = truth.shape[0]
    xs = np.linspace(box[0], box[1], truth.shape[1], endpoint=False)
    xs += 0.5 * (box[1] - box[0]) / truth.shape[1]
    mid = rows // 2
    for key, image, _ in panels:
        band = blur(image)[mid - 1 : mid + 1].mean(axis=0)  # the two rows about y = 0
        axes[3].plot(xs, band, lw=1.0, label=key)
    axes[3].set_title(f"row through the axis (y = 0), {BLUR:g} px blur", fontsize=9)
    axes[3].set_xlabel("x (m)")
    axes[3].legend(fontsize=8)
    fig.suptitle(
        f"Liu et al. Fig. 6: glass ball n = {IOR}, light {ZENITH:g} deg; relative L1 after a "
        f"Gaussian blur of {BLUR:g} px (both images, zero outside)",
        fontsize=10,
    )
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (a test)")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    parser.add_argument(
        "--height", type=float, default=HEIGHT, help=f"ball centre above the floor, m ({HEIGHT})"
    )
    parser.add_argument("--size", type=float, default=SIZE, help=f"receiver side, m ({SIZE})")
    parser.add_argument("--dpi", type=int, default=110)
    args = parser.parse_args(argv)
    if args.height < RADIUS:
        parser.error(f"--height must be at least the radius, {RADIUS} m")
    start = time.perf_counter()
    results, images = run(args.quick, args.height, args.size)
    args.output.mkdir(parents=True, exist_ok=True)
    text = markdown(results)
    (args.output / f"{NAME}.md").write_text(text)
    figure(results, images, args.output / f"{NAME}.png", args.dpi)
    print(text)
    print(f"total {time.perf_counter() - start:.1f} s")
    results["markdown"] = text
    results["files"] = [args.output / f"{NAME}.{e}" for e in ("md", "png")]
    return results


if __name__ == "__main__":
    main()
