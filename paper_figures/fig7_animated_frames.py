"""Yuksel & Keyser, Figure 7: frames of an animated water surface and its caustics.

The paper shows frames of its real-time water simulation with a 400 x 300 caustics map,
N = 7 and M = 6. Here: a strip of frames of an animated procedural sea
(`jaxcaustics.wave_heights`, gravity waves that move by the water-wave dispersion
relation) over a 2 x 1.5 m patch of ground under 0.5 m of water, 1 mm RMS ripples with
wavelengths of 10-30 cm; the height field above and its caustics map below, one column
per frame. Each frame's map is compiled once and re-rendered per frame (same shapes), and
the script prints the time per frame after compilation and the missed-flux fraction.

Writes, to ``--output`` (default ``paper_figures/output/``):

- ``fig7_frame_0000.png`` ...: each caustics map, one pixel per map pixel (linear grey
  scale, the same white level for all frames);
- ``fig7_animated_frames.png``: the strip.

Run ``python paper_figures/fig7_animated_frames.py`` (about 10 s on 2 CPU cores), or with
``--quick`` for a tiny smoke test.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fig2_caustics_map import DEFAULT_OUTPUT, EXTENT  # noqa: E402
from fig2_caustics_map import water_scene as fig2_scene  # noqa: E402

# The scene of fig2_caustics_map.py with 1 mm ripples: at 400 x 300 pixels (5 mm) light
# still lands within 3 pixels of where flat water sends it, so N = 7, M = 6 hold it.
AMPLITUDE = 0.001  # RMS wave height, metres


def water_scene(shape, time_s: float, *, seed: int = 0):
    """The water scene at `time_s` seconds: heights and caustic map share the extent."""
    return fig2_scene(shape, time_s, seed=seed, amplitude=AMPLITUDE)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=4, help="frames in the strip (default: 4)")
    parser.add_argument(
        "--dt", type=float, default=0.1, help="seconds between frames (default: 0.1)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the waves")
    parser.add_argument("--dpi", type=int, default=100, help="resolution of the figure")
    parser.add_argument("--quick", action="store_true", help="tiny size, 2 frames: smoke test")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    shape = (30, 40) if args.quick else (300, 400)
    frames = 2 if args.quick else args.frames
    rows, cols = shape
    times = [k * args.dt for k in range(frames)]

    def render(scene):
        image, stats = jc.render(scene, jc.TwoPass.paper(), return_stats=True)
        return np.asarray(image), float(stats["missed_flux_fraction"][0])

    start = time.perf_counter()
    render(water_scene(shape, times[0], seed=args.seed))
    compile_s = time.perf_counter() - start

    heights, images, missed, seconds = [], [], [], []
    for t in times:
        scene = water_scene(shape, t, seed=args.seed)
        start = time.perf_counter()
        image, missed_t = render(scene)
        seconds.append(time.perf_counter() - start)
        heights.append(1000.0 * np.asarray(scene.surface.heights))
        images.append(image)
        missed.append(missed_t)
    print(
        f"{frames} frames, caustics map {cols}x{rows}, N = 7, M = 6: "
        f"{1000 * np.mean(seconds):.1f} ms per frame after {compile_s:.1f} s to compile; "
        f"missed flux at most {100 * max(missed):.3g}%"
    )
    if max(missed) > 0.01:
        print("WARNING: over 1% of the light falls outside the 7 x 7 window")

    args.output.mkdir(parents=True, exist_ok=True)
    white = float(np.percentile(np.stack(images), 99.9))
    written = []
    for k, image in enumerate(images):
        path = args.output / f"fig7_frame_{k:04d}.png"
        jc.write_png(path, image, exposure=1.0 / white, gamma=1.0)
        written.append(path)

    h_lim = max(float(np.abs(h).max()) for h in heights)
    fig, axes = plt.subplots(
        2, frames, figsize=(3.2 * frames + 1.2, 5.2), squeeze=False, constrained_layout=True
    )
    for k, t in enumerate(times):
        top = axes[0, k].imshow(
            heights[k], origin="lower", extent=EXTENT, cmap="viridis", vmin=-h_lim, vmax=h_lim
        )
        bottom = axes[1, k].imshow(
            images[k], origin="lower", extent=EXTENT, cmap="gray", vmin=0.0, vmax=white
        )
        axes[0, k].set_title(f"t = {t:.2f} s")
        axes[1, k].set_xlabel("x (m)")
        for ax in axes[:, k]:
            ax.tick_params(labelsize=7)
            if k > 0:
                ax.set_yticklabels([])
    axes[0, 0].set_ylabel("height field\ny (m)")
    axes[1, 0].set_ylabel("caustics map\ny (m)")
    fig.colorbar(top, ax=axes[0, :], label="height (mm)", shrink=0.9)
    fig.colorbar(bottom, ax=axes[1, :], label="relative irradiance", shrink=0.9)
    fig.suptitle(f"animated water: caustics map {cols}x{rows}, N = 7, M = 6")
    strip = args.output / "fig7_animated_frames.png"
    fig.savefig(strip, dpi=args.dpi)
    plt.close(fig)
    written.append(strip)
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
