"""Yuksel & Keyser, Figure 2: the caustics map of one frame of a water height field.

The paper's map is 800 x 600 pixels, computed with N = 7 samples along x and M = 6
channels along y. Here the water is an animated procedural sea (`jaxcaustics.wave_heights`)
over a 2 x 1.5 m patch of flat ground, 0.5 m deep, with small ripples (0.5 mm RMS,
wavelengths 10-30 cm): the kind of smooth, low-frequency surface the paper targets, for
which a 7 x 7 pixel window holds (nearly) all the light. The script prints the missed-flux
fraction to show it.

Writes, to ``--output`` (default ``paper_figures/output/``):

- ``fig2_caustics_map.png``: the caustics map itself, one pixel per map pixel (linear
  grey scale, white at the 99.9th percentile);
- ``fig2_height_and_caustics.png``: the height field next to the caustics map, in metres,
  with colour bars.

Run ``python paper_figures/fig2_caustics_map.py`` (about 10 s on 2 CPU cores), or with
``--quick`` for a tiny smoke test.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "output"

# The scene (shared in spirit with fig7_animated_frames.py).
EXTENT = (0.0, 2.0, 0.0, 1.5)  # metres: x_min, x_max, y_min, y_max
DEPTH = 0.5  # rest depth, metres
AMPLITUDE = 0.0005  # RMS wave height, metres
WAVELENGTHS = (0.1, 0.3)  # metres
NUM_WAVES = 32
ZENITH, AZIMUTH = 20.0, 30.0  # degrees
IOR = 1.333


def water_scene(shape, time_s: float, *, seed: int = 0, amplitude: float = AMPLITUDE):
    """The water scene at `time_s` seconds: heights and caustic map share the extent."""
    heights = jc.wave_heights(
        shape,
        EXTENT,
        time_s,
        amplitude=amplitude,
        depth=DEPTH,
        wavelength_range=WAVELENGTHS,
        num_waves=NUM_WAVES,
        seed=seed,
    )
    return jc.WaterScene(
        jc.HeightField(heights, EXTENT, boundary="periodic"),
        jc.DirectionalLight.from_angles(ZENITH, AZIMUTH),
        jc.PlaneReceiver(EXTENT, shape),
        DEPTH,
        ior=IOR,
    )


def _size(text: str) -> tuple[int, int]:
    """``"COLSxROWS"`` -> ``(rows, cols)``, as the CLI's ``--size``."""
    cols, _, rows = text.lower().partition("x")
    if not (cols.isdigit() and rows.isdigit()) or min(int(cols), int(rows)) < 2:
        raise argparse.ArgumentTypeError(
            f"expected COLSxROWS of at least 2x2 pixels, e.g. 800x600, got {text!r}"
        )
    return int(rows), int(cols)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--size",
        type=_size,
        default=(600, 800),
        metavar="COLSxROWS",
        help="caustics map size (default: 800x600, as in the paper)",
    )
    parser.add_argument("--time", type=float, default=0.0, help="time of the frame, s")
    parser.add_argument("--seed", type=int, default=0, help="seed of the waves")
    parser.add_argument(
        "--amplitude",
        type=float,
        default=AMPLITUDE,
        help=f"RMS wave height, m (default: {AMPLITUDE}; the window holds the light "
        "while it moves at most 3 pixels, so a smaller --size allows larger waves)",
    )
    parser.add_argument("--dpi", type=int, default=100, help="resolution of the figure")
    parser.add_argument("--quick", action="store_true", help="tiny size, for a smoke test")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    args = parser.parse_args(argv)
    shape = (60, 80) if args.quick else args.size
    rows, cols = shape

    scene = water_scene(shape, args.time, seed=args.seed, amplitude=args.amplitude)
    start = time.perf_counter()
    image, stats = jc.render(scene, jc.TwoPass.paper(), return_stats=True)
    image = np.asarray(image)
    seconds = time.perf_counter() - start
    missed = float(stats["missed_flux_fraction"][0])
    print(
        f"caustics map {cols}x{rows}, N = 7, M = 6: {seconds:.1f} s (with compilation), "
        f"missed flux {100 * missed:.3g}%, irradiance mean {image.mean():.4f}, "
        f"range {image.min():.3f} .. {image.max():.3f}"
    )
    if missed > 0.01:
        print("WARNING: over 1% of the light falls outside the 7 x 7 window")

    args.output.mkdir(parents=True, exist_ok=True)
    white = float(np.percentile(image, 99.9))
    map_png = args.output / "fig2_caustics_map.png"
    jc.write_png(map_png, image, exposure=1.0 / white, gamma=1.0)

    heights_mm = 1000.0 * np.asarray(scene.surface.heights)
    x0, x1, y0, y1 = EXTENT
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    shown = axes[0].imshow(
        heights_mm, origin="lower", extent=EXTENT, cmap="viridis", interpolation="antialiased"
    )
    fig.colorbar(shown, ax=axes[0], label="height above rest level (mm)", shrink=0.9)
    axes[0].set_title(f"water height field, t = {args.time:g} s (rest depth {DEPTH:g} m)")
    shown = axes[1].imshow(
        image,
        origin="lower",
        extent=EXTENT,
        cmap="gray",
        vmin=0.0,
        vmax=white,
        interpolation="antialiased",
    )
    fig.colorbar(shown, ax=axes[1], label="relative irradiance (flat water = 1)", shrink=0.9)
    axes[1].set_title(f"caustics map {cols}x{rows}, N = 7, M = 6")
    for ax in axes:
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
    figure_png = args.output / "fig2_height_and_caustics.png"
    fig.savefig(figure_png, dpi=args.dpi)
    plt.close(fig)
    print(f"wrote {map_png}")
    print(f"wrote {figure_png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
