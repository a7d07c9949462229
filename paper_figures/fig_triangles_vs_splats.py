"""Umenhoffer, Patow & Szirmay-Kalos, Figures 1 and 9: caustic triangles against splats.

"Caustic Triangles on the GPU" (2008) shows, in Figure 9, (a) its 128 x 128 photon hit
location image, (b) the photon hits drawn as points and (c) the caustics drawn as caustic
triangles; in Figure 1, the problems of photon splatting: a too small splat leaves a dot
pattern, a too large one blurs, and a manually tuned size sits in between. This script
draws both figures as one, on one caustic generator, with numbers:

(a) the photon hit location image (128 x 128 photons: hit x in red, hit y in green,
    over the screen's extent; photons that miss the glass or are lost are black);
(b) the hits as points on the screen;
(c) caustic triangles (``jaxcaustics.caustic_triangles``, exact reconstruction: each
    triangle spreads its flux uniformly over its exact overlap with the pixels);
(d-f) Gaussian splatting of the same photons (`splat_photons`) with a too small radius,
    the tuned one (the sigma minimising the error against the reference, searched over a
    geometric sweep) and a too large one;
(g) the reference: `jaxcaustics.reference.trace_mesh` (NumPy, float64) with many more
    photons, binned into the pixels;
(h) the error of splatting against its radius, with that of the caustic triangles.

Every reconstruction is titled with its relative L1 error against the reference,
``sum |blur(x) - blur(ref)| / sum |blur(ref)|`` after a Gaussian blur of 1 pixel (as in
``tests/test_triangles_reference.py``: the blur removes the reference's own aliasing,
a regular photon grid binned into pixels, not the methods' errors, which live at the
scale of the photon grid's cells). The unblurred error is printed too.

The caustic generator: a glass torus (index 1.5, smooth normals, up to 4 interfaces, so
internal reflections are followed) lying 0.6 m over the screen ``z = 0``, lit by
directional light 30 degrees off the vertical. Its caustic has a bright cusp and soft
wings: the very uneven photon density the paper points to, where no single splat size
fits (dots in the wings, blur in the cusp) while triangles adapt.

What differs from the paper: no layered distance maps, cube-map caustic storage or GPU
rasterisation. Photons are traced exactly through the triangle mesh; the receiver is the
plane under the object and the caustic is shown as irradiance on it (the light that went
through the glass only; no direct light, shadow or camera view); the paper's (c) uses
Gouraud-shaded triangles, here the exact, flux-conserving reconstruction; splats are
normalised Gaussians with sigma in screen pixels rather than screen-space sprites; and
the "manually tuned" splat of Figure 1 is the one that minimises the error against the
reference, the best a user could do.

Writes, to ``--output`` (default ``paper_figures/output/``):

- ``fig_triangles_vs_splats.png``: the figure;
- ``fig_triangles_vs_splats.json``: the errors (method, sigma, relative L1, blurred and
  not) and the settings.

Run ``python paper_figures/fig_triangles_vs_splats.py`` (about a minute or two on 2 CPU
cores: the photon tracing of 128^2 photons through the mesh dominates), or ``--quick``
for a small smoke test (48^2 photons, a coarser torus, a small screen and reference).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.colors as mcolors  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker as mticker  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402
from jaxcaustics.internal import splat_photons  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "output"
NAME = "fig_triangles_vs_splats"

# The scene: a glass torus over the screen z = 0, oblique directional light.
MAJOR_RADIUS, MINOR_RADIUS = 0.5, 0.2  # metres
HEIGHT = 0.6  # centre of the torus above the screen, metres
ZENITH, AZIMUTH = 30.0, 0.0  # degrees
IOR = 1.5
INTERFACES = 4
SCREEN = (-0.55, 1.45, -1.0, 1.0)  # x_min, x_max, y_min, y_max, metres

# Full run and --quick: photon grid, mesh sections (major, minor), screen pixels,
# reference photons per axis.
FULL = dict(photons=128, sections=(40, 16), pixels=256, reference=1536)
QUICK = dict(photons=48, sections=(24, 10), pixels=96, reference=512)

BLUR = 1.0  # pixels, of the error measure
# Splat radii swept (pixels): 0.2 .. 8 in steps of 40^(1/16) (--quick: 40^(1/8)); the too
# small and too large radii are a quarter and four times the tuned one (steps of 40^(6/16)
# = 3.99, and of 40^(3/8)).
SIGMAS = tuple(float(s) for s in np.geomspace(0.2, 8.0, 17))
QUICK_SIGMAS = SIGMAS[::2]


def torus_scene(sections=FULL["sections"], pixels=FULL["pixels"]) -> jc.MeshScene:
    """The glass torus over the screen (`sections`: its mesh's major and minor sections)."""
    mesh = trimesh.creation.torus(
        MAJOR_RADIUS, MINOR_RADIUS, major_sections=sections[0], minor_sections=sections[1]
    )
    mesh.apply_translation([0.0, 0.0, HEIGHT])
    return jc.MeshScene(
        jc.Mesh.from_trimesh(mesh),
        jc.DirectionalLight.from_angles(ZENITH, AZIMUTH),
        jc.PlaneReceiver(SCREEN, (pixels, pixels)),
        ior=IOR,
        interfaces=INTERFACES,
    )


def hit_location_image(photons: jc.internal.Photons, extent) -> np.ndarray:
    """The photon hit location image as RGB: x in red, y in green (0..1 over `extent`),
    invalid photons black. Row 0 is the first row of the emission grid."""
    x0, x1, y0, y1 = extent
    pos = np.asarray(photons.position[0])
    valid = np.asarray(photons.valid[0])
    rgb = np.zeros(valid.shape + (3,))
    rgb[..., 0] = np.clip((pos[..., 0] - x0) / (x1 - x0), 0.0, 1.0)
    rgb[..., 1] = np.clip((pos[..., 1] - y0) / (y1 - y0), 0.0, 1.0)
    rgb[..., 2] = 0.25
    return np.where(valid[..., None], rgb, 0.0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--photons",
        type=int,
        default=None,
        help=f"photons per axis of the hit location image (default: {FULL['photons']}, as "
        f"in the paper; --quick: {QUICK['photons']})",
    )
    parser.add_argument(
        "--size",
        type=int,
        default=None,
        metavar="PIXELS",
        help=f"screen pixels per axis (default: {FULL['pixels']}; --quick: {QUICK['pixels']})",
    )
    parser.add_argument(
        "--reference",
        type=int,
        default=None,
        metavar="N",
        help=f"reference photons per axis (default: {FULL['reference']}; --quick: "
        f"{QUICK['reference']})",
    )
    parser.add_argument("--dpi", type=int, default=110, help="resolution of the figure")
    parser.add_argument(
        "--quick", action="store_true", help="small grid, torus, screen and reference"
    )
    parser.add_argument("--output", "--out", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    args = parser.parse_args(argv)
    settings = dict(QUICK if args.quick else FULL)
    for key, value in (
        ("photons", args.photons),
        ("pixels", args.size),
        ("reference", args.reference),
    ):
        if value is not None:
            settings[key] = value
    n, pixels = settings["photons"], settings["pixels"]
    scene = torus_scene(settings["sections"], pixels)
    faces = int(scene.generator.faces.shape[0])

    start = time.perf_counter()
    truth = reference.trace_mesh(scene, settings["reference"])
    ref_s = time.perf_counter() - start
    print(
        f"reference: {settings['reference']}^2 photons through {faces} faces, "
        f"{pixels}x{pixels} pixels: {ref_s:.1f} s"
    )

    start = time.perf_counter()
    result = jc.internal.caustic_triangles(scene, photons=n)
    triangles = np.asarray(result.image)
    tri_s = time.perf_counter() - start
    photons = result.photons
    missed = float(result.missed_flux_fraction[0])
    valid = int(np.asarray(photons.valid).sum())
    print(
        f"caustic triangles: {n}^2 photons ({valid} valid), {tri_s:.1f} s (with "
        f"compilation), missed flux {100 * missed:.2f}%"
    )

    start = time.perf_counter()
    sigmas = QUICK_SIGMAS if args.quick else SIGMAS
    splats = {s: np.asarray(splat_photons(photons, scene.receiver, s)[0]) for s in sigmas}
    sweep = {
        s: (jc.image_error(img, truth), jc.image_error(img, truth, 0.0))
        for s, img in splats.items()
    }
    best = min(range(len(sigmas)), key=lambda k: sweep[sigmas[k]][0])
    step = 3 if args.quick else 6  # a factor of about 4
    tuned = sigmas[best]
    small, large = sigmas[max(best - step, 0)], sigmas[min(best + step, len(sigmas) - 1)]
    print(f"splats: {len(sweep)} radii, {time.perf_counter() - start:.1f} s")

    rows = [
        ("caustic triangles", None, triangles),
        ("splats, too small", small, splats[small]),
        ("splats, tuned", tuned, splats[tuned]),
        ("splats, too large", large, splats[large]),
    ]
    table = [
        dict(
            method=method,
            sigma=sigma,
            rel_l1=jc.image_error(image, truth),
            rel_l1_unblurred=jc.image_error(image, truth, 0.0),
        )
        for method, sigma, image in rows
    ]
    print(f"\n{'method':<20} {'sigma (px)':>10} {'rel L1':>8} {'unblurred':>10}")
    for row in table:
        sigma = "-" if row["sigma"] is None else f"{row['sigma']:.3g}"
        errors = f"{row['rel_l1']:>8.4f} {row['rel_l1_unblurred']:>10.4f}"
        print(f"{row['method']:<20} {sigma:>10} {errors}")
    print()

    args.output.mkdir(parents=True, exist_ok=True)
    summary = dict(
        settings=dict(settings, faces=faces, blur_px=BLUR, sigmas_px=list(sigmas)),
        missed_flux_fraction=missed,
        errors=table,
        sweep=[dict(sigma=s, rel_l1=e[0], rel_l1_unblurred=e[1]) for s, e in sorted(sweep.items())],
    )
    json_path = args.output / f"{NAME}.json"
    json_path.write_text(json.dumps(summary, indent=2) + "\n")

    # -- the figure
    extent = SCREEN
    white = float(np.percentile(truth, 99.8))
    norm = mcolors.PowerNorm(gamma=0.5, vmin=0.0, vmax=white)
    fig, axes = plt.subplots(2, 4, figsize=(17, 9.4), constrained_layout=True)
    axes = axes.ravel()

    axes[0].imshow(hit_location_image(photons, extent), origin="lower", interpolation="nearest")
    axes[0].set_title(f"(a) photon hit location image, {n}x{n}\n(R = hit x, G = hit y)")
    axes[0].set_xlabel("photon column")
    axes[0].set_ylabel("photon row")

    pos = np.asarray(photons.position[0])[np.asarray(photons.valid[0])]
    axes[1].set_facecolor("black")
    axes[1].scatter(pos[:, 0], pos[:, 1], s=0.15 if n > 64 else 1.0, c="white", lw=0)
    axes[1].set_xlim(extent[0], extent[1])
    axes[1].set_ylim(extent[2], extent[3])
    axes[1].set_aspect("equal")
    axes[1].set_title(f"(b) photon hits as points ({valid} valid)")

    panels = [
        (2, f"(c) caustic triangles\nrel. L1 {table[0]['rel_l1']:.4f}", triangles),
        (
            3,
            f"(d) splats, too small, σ = {small:.2g} px\nrel. L1 {table[1]['rel_l1']:.4f}",
            splats[small],
        ),
        (
            4,
            f"(e) splats, tuned, σ = {tuned:.2g} px\nrel. L1 {table[2]['rel_l1']:.4f}",
            splats[tuned],
        ),
        (
            5,
            f"(f) splats, too large, σ = {large:.2g} px\nrel. L1 {table[3]['rel_l1']:.4f}",
            splats[large],
        ),
        (6, f"(g) reference, {settings['reference']}^2 photons", truth),
    ]
    for k, title, image in panels:
        shown = axes[k].imshow(
            image, origin="lower", extent=extent, cmap="gray", norm=norm, interpolation="nearest"
        )
        axes[k].set_title(title)
    for k in range(1, 7):
        axes[k].set_xlabel("x (m)")
        axes[k].set_ylabel("y (m)")
        axes[k].xaxis.set_major_locator(mticker.MultipleLocator(0.5))
    cax = axes[6].inset_axes([0.04, 0.06, 0.035, 0.38])
    bar = fig.colorbar(shown, cax=cax)
    bar.set_label("irradiance (light = 1)", color="white", fontsize=8)
    bar.ax.tick_params(colors="white", labelsize=7)

    ax = axes[7]
    radii = sorted(sweep)
    errors = [sweep[s][0] for s in radii] + [table[0]["rel_l1"]]
    lo, hi = 0.8 * min(errors), 1.25 * max(errors)
    ax.plot(radii, errors[:-1], "o-", label="Gaussian splats")
    ax.axhline(table[0]["rel_l1"], color="C3", label="caustic triangles")
    for sigma, mark in ((small, "d"), (tuned, "e"), (large, "f")):
        ax.annotate(
            f"({mark})",
            (sigma, sweep[sigma][0]),
            textcoords="offset points",
            xytext=(0, 8),
            ha="center",
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(mticker.FormatStrFormatter("%g"))
        axis.set_minor_formatter(mticker.NullFormatter())
    ax.set_xticks([t for t in (0.2, 0.5, 1, 2, 5, 10) if radii[0] <= t <= radii[-1]])
    ax.set_yticks([t for t in (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0) if lo <= t <= hi])
    ax.set_xlabel("splat radius σ (pixels)")
    ax.set_ylabel(f"rel. L1 error (after a {BLUR:g}-pixel blur)")
    ax.set_ylim(lo, hi)
    ax.set_title(f"(h) splat error against its radius\n({n}x{n} photons)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()

    fig.suptitle(
        f"Caustic triangles vs photon splats: glass torus (n = {IOR:g}), light at "
        f"{ZENITH:g}° zenith, {pixels}x{pixels}-pixel screen"
    )
    png = args.output / f"{NAME}.png"
    fig.savefig(png, dpi=args.dpi)
    plt.close(fig)
    print(f"wrote {png}")
    print(f"wrote {json_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
