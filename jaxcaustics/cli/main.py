"""The ``jaxcaustics`` command.

::

    jaxcaustics render water [options]   # caustics of an animated procedural sea
    jaxcaustics --version

Subcommands are registered in `_COMMANDS`: each entry adds its parser to the top-level
subparsers and sets ``func`` (called with the parsed arguments, returns an exit code),
so later commands (``design``, ``recover``) slot in beside ``render``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

import jaxcaustics as jc
from jaxcaustics import __version__
from jaxcaustics.methods.twopass import MAX_AUTO_HALF_WINDOW

from .design import add_design
from .flags import (
    MAX_PIXELS,
    add_light_angles,
    folder,
    int_at_least,
    number,
    output_folder,
    with_flags,
)
from .recover import add_recover
from .verify import add_verify

# Above this missed-flux fraction the image is visibly too dark: warn.
MISSED_FLUX_WARNING = 0.01
# the most frames, Newton steps and samples per pixel side `render water` takes (more
# runs for hours: each frame is a render, each step and sample multiplies its work)
MAX_FRAMES = 100_000
MAX_HIT_ITERATIONS = 64
MAX_SUPERSAMPLE = 16


class CLIError(Exception):
    """A user error found after parsing (reported without a traceback, exit code 2)."""


# --------------------------------------------------------------------------- argument types


def _size(text: str) -> tuple[int, int]:
    """``"COLSxROWS"`` -> ``(rows, cols)``."""
    parts = text.lower().replace("*", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected COLSxROWS in pixels, e.g. 400x300, got {text!r}"
        ) from None
    if cols < 2 or rows < 2:
        raise argparse.ArgumentTypeError(f"need at least 2x2 pixels, got {text!r}")
    if rows * cols > MAX_PIXELS:
        raise argparse.ArgumentTypeError(f"at most {MAX_PIXELS} pixels (4096x4096), got {text!r}")
    return rows, cols


def _extent(text: str) -> tuple[float, float]:
    """``"WIDTHxHEIGHT"`` in metres -> ``(width, height)``."""
    parts = text.lower().replace("*", "x").split("x")
    try:
        width, height = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT in metres, e.g. 4x3, got {text!r}"
        ) from None
    if not (math.isfinite(width) and math.isfinite(height) and width > 0 and height > 0):
        raise argparse.ArgumentTypeError(f"width and height must be positive, got {text!r}")
    return width, height


def _window(parity: str) -> Callable[[str], int | str]:
    """An odd (N) or even (M) window size, or ``"auto"``."""

    def parse(text: str) -> int | str:
        if text.lower() == "auto":
            return "auto"
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected an integer or 'auto', got {text!r}"
            ) from None
        if parity == "odd" and (value < 1 or value % 2 != 1):
            raise argparse.ArgumentTypeError(f"must be an odd integer >= 1 or 'auto', got {value}")
        if parity == "even" and (value < 0 or value % 2 != 0):
            raise argparse.ArgumentTypeError(f"must be an even integer >= 0 or 'auto', got {value}")
        return value

    return parse


def _ior(text: str) -> float | tuple[float, float, float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected one number or three comma-separated numbers (R,G,B), got {text!r}"
        ) from None
    if len(values) not in (1, 3):
        raise argparse.ArgumentTypeError(
            f"expected one index of refraction or three (R,G,B), got {len(values)}"
        )
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"indices of refraction must be positive, got {text!r}")
    return values[0] if len(values) == 1 else (values[0], values[1], values[2])


# --------------------------------------------------------------------------- render water


def _add_render(subparsers) -> None:
    render = subparsers.add_parser(
        "render",
        help="render caustic images of a scene",
        description="Render caustic images of a scene.",
    )
    scenes = render.add_subparsers(dest="scene", metavar="SCENE", required=True)
    water = scenes.add_parser(
        "water",
        help="an animated procedural sea over a flat ground (two-pass method)",
        description=(
            "Render the caustics that an animated procedural sea (jaxcaustics.wave_heights, "
            "periodic over the extent) casts on the flat ground below it, with Yuksel & "
            "Keyser's two-pass method. Writes, per frame, a tone-mapped PNG and a linear "
            "OpenEXR of the irradiance relative to a horizontal plane (flat water = 1.0): "
            "DIR/caustics_0000.png and DIR/caustics_0000.exr, ..."
        ),
    )
    g = water.add_argument_group("caustic map and surface")
    g.add_argument(
        "--size",
        type=_size,
        default=(300, 400),
        metavar="COLSxROWS",
        help="caustic-map size in pixels (default: 400x300)",
    )
    g.add_argument(
        "--extent",
        type=_extent,
        default=None,
        metavar="WxH",
        help="size of the patch of ground and sea in metres (also the period of the sea); "
        "default: 4 m wide, with the height that makes the pixels square (4x3 for 400x300)",
    )
    g.add_argument(
        "--heightfield-size",
        type=_size,
        default=None,
        metavar="COLSxROWS",
        help="resolution of the water height field (bicubic between samples; need not "
        "match the map); default: the same as --size",
    )
    g.add_argument(
        "--depth",
        type=number(0.0, strict=True),
        default=1.0,
        metavar="M",
        help="rest depth of the water above the ground, metres (default: %(default)s)",
    )
    g.add_argument(
        "--amplitude",
        type=number(0.0),
        default=0.02,
        metavar="M",
        help="RMS wave height, metres (default: %(default)s)",
    )
    g.add_argument(
        "--seed",
        type=int_at_least(0),
        default=0,
        help="seed of the wave set (default: %(default)s)",
    )

    g = water.add_argument_group("light and optics")
    add_light_angles(g, zenith_deg=20.0, azimuth_deg=30.0)
    g.add_argument(
        "--ior",
        type=_ior,
        default=1.333,
        metavar="N[,N,N]",
        help="index of refraction of the water; three comma-separated values (R,G,B, e.g. "
        "1.331,1.335,1.340) render dispersion as a colour image (default: %(default)s)",
    )
    g.add_argument(
        "--fresnel",
        action="store_true",
        help="multiply by the Fresnel transmittance of the surface",
    )

    g = water.add_argument_group("two-pass method")
    g.add_argument(
        "--samples-x",
        type=_window("odd"),
        default="auto",
        metavar="N|auto",
        help="N, samples along x gathered per pixel (odd). 'auto' (default) sizes the "
        "window from the largest ray displacement over all frames, so no light is lost: "
        "the paper's N=7, M=6 only hold the light that lands within 3 pixels, which at "
        "the default scene misses about 20%% of it. Pass 7 and 6 for the paper's setting",
    )
    g.add_argument(
        "--channels-y",
        type=_window("even"),
        default="auto",
        metavar="M|auto",
        help="M, so that M+1 neighbouring pixels along y are reached (even); 'auto' as "
        "for --samples-x",
    )
    g.add_argument(
        "--hit-iterations",
        type=int_at_least(0, MAX_HIT_ITERATIONS),
        default=3,
        metavar="K",
        help="Newton steps to find where each light ray meets the moving surface "
        "(default: %(default)s)",
    )
    g.add_argument(
        "--supersample",
        type=int_at_least(1, MAX_SUPERSAMPLE),
        default=4,
        metavar="S",
        help="S x S samples per caustic-map pixel; 1 is the paper's method (fastest, with a "
        "faint pixel-grid ripple where the light is stretched), 4 removes the ripple at "
        "about 16x the cost of the gather (default: %(default)s)",
    )

    g = water.add_argument_group("animation and output")
    g.add_argument(
        "--frames",
        type=int_at_least(1, MAX_FRAMES),
        default=1,
        metavar="K",
        help="number of frames (default: %(default)s)",
    )
    g.add_argument(
        "--dt",
        type=number(),
        default=0.05,
        metavar="S",
        help="seconds of simulated time between frames (default: %(default)s)",
    )
    g.add_argument(
        "--start-time",
        type=number(),
        default=0.0,
        metavar="S",
        help="simulated time of the first frame, seconds (default: %(default)s)",
    )
    g.add_argument(
        "--exposure",
        type=number(0.0, strict=True),
        default=None,
        help="PNG scale factor before clipping to white (relative irradiance 1/EXPOSURE "
        "is white); default: chosen from the first frame (its 99.5th percentile) and kept "
        "for all frames so the animation does not flicker",
    )
    g.add_argument(
        "--output",
        type=folder,
        default=Path("out"),
        metavar="DIR",
        help="output directory, created if needed (default: %(default)s)",
    )
    g.add_argument("--quiet", action="store_true", help="print only warnings and errors")
    water.set_defaults(
        func=with_flags(
            _render_water,
            {name: f"--{name}" for name in ("depth", "amplitude", "extent", "ior", "exposure")},
        )
    )


def _render_water(args: argparse.Namespace) -> int:
    import jax
    from tqdm import tqdm

    rows, cols = args.size
    if args.extent is None:
        width = 4.0
        height = width * rows / cols
    else:
        width, height = args.extent
    extent = (0.0, width, 0.0, height)
    hf_rows, hf_cols = args.heightfield_size or args.size
    say = (lambda *a, **k: None) if args.quiet else print
    times = [args.start_time + k * args.dt for k in range(args.frames)]
    if not math.isfinite(times[-1]):
        raise CLIError(f"`--dt` {args.dt:g}: the last frame's time {times[-1]} is not finite")
    for flag, value, most in (
        ("--samples-x", args.samples_x, 2 * cols + 1),
        ("--channels-y", args.channels_y, 2 * rows),
    ):
        if value != "auto" and value > most:
            raise CLIError(
                f"`{flag}` {value} reaches past the {cols}x{rows} pixels ({most} already "
                "reaches every pixel)"
            )

    light = jc.DirectionalLight.from_angles(args.zenith, args.azimuth)
    receiver = jc.PlaneReceiver(extent, (rows, cols))

    def scene_at(t: float):
        heights = jc.wave_heights(
            (hf_rows, hf_cols),
            extent,
            t,
            amplitude=args.amplitude,
            depth=args.depth,
            seed=args.seed,
        )
        low = float(np.min(heights))
        if args.depth + low <= 0:  # the scene's own error names `surface` and `rest_depth`
            raise CLIError(
                f"`--amplitude` {args.amplitude:g} m: the sea's deepest trough ({low:.3g} m at "
                f"t = {t:g} s) reaches the ground `--depth` {args.depth:g} m below: lower "
                "--amplitude or raise --depth"
            )
        surface = jc.HeightField(heights, extent, boundary="periodic")
        return jc.WaterScene(
            surface, light, receiver, args.depth, ior=args.ior, fresnel=args.fresnel
        )

    ior_text = (
        f"{args.ior:g}" if isinstance(args.ior, float) else ",".join(f"{v:g}" for v in args.ior)
    )
    say("jaxcaustics render water")
    say(
        f"  caustic map  {cols}x{rows} px over {width:g} x {height:g} m "
        f"({1000 * width / cols:.3g} x {1000 * height / rows:.3g} mm pixels)"
    )
    say(
        f"  sea          {hf_cols}x{hf_rows} height samples, RMS {args.amplitude:g} m, "
        f"rest depth {args.depth:g} m, seed {args.seed}, periodic"
    )
    say(
        f"  light        zenith {args.zenith:g} deg, azimuth {args.azimuth:g} deg; "
        f"ior {ior_text}; Fresnel {'on' if args.fresnel else 'off'}"
    )
    if args.frames == 1:
        say(f"  frames       1 at t = {times[0]:g} s")
    else:
        say(f"  frames       {args.frames} at t = {times[0]:g} s + k * {args.dt:g} s")

    output_folder(args.output)

    # The window: 'auto' is the largest over all frames (cheap pre-pass per frame), so
    # that every frame uses the same N, M and the render compiles once.
    n, m = args.samples_x, args.channels_y
    if n == "auto" or m == "auto":
        auto_n, auto_m = 1, 0
        for t in times:
            fn, fm = jc.internal.auto_window(scene_at(t), args.hit_iterations, args.supersample)
            auto_n, auto_m = max(auto_n, fn), max(auto_m, fm)
        # no wider than the receiver (a window past every pixel was refused naming
        # `samples_x`, on a tiny --extent)
        n = min(auto_n, 2 * cols + 1) if n == "auto" else n
        m = min(auto_m, 2 * rows) if m == "auto" else m
    if n * (m + 1) > 1000:
        print(
            f"note: a large window (N = {n}, M = {m}) takes long to compile; light moves "
            "many pixels in this scene",
            file=sys.stderr,
        )
    say(
        f"  two-pass     N = {n} samples along x ({args.samples_x}), "
        f"M = {m} channels along y ({args.channels_y}), hit iterations {args.hit_iterations}, "
        f"supersample {args.supersample}"
    )

    def render(scene):
        with warnings.catch_warnings():  # missed light: said below, in the flags' words
            warnings.filterwarnings("ignore", message="render: method 'twopass' missed")
            image, stats = jc.render(
                scene,
                "twopass",
                return_stats=True,
                samples_x=n,
                channels_y=m,
                hit_iterations=args.hit_iterations,
                supersample=args.supersample,
            )
        image = jax.block_until_ready(image)
        return np.asarray(image), np.asarray(stats["missed_flux_fraction"])

    start = time.perf_counter()
    render(scene_at(times[0]))  # compile (and run once)
    compile_s = time.perf_counter() - start

    exposure = args.exposure
    render_s: list[float] = []
    missed = []
    written: list[Path] = []
    for k, t in enumerate(tqdm(times, desc="frames", unit="frame", disable=None)):
        scene = scene_at(t)
        start = time.perf_counter()
        image, missed_k = render(scene)
        render_s.append(time.perf_counter() - start)
        missed.append(missed_k)
        if exposure is None:
            high = float(np.percentile(image, 99.5))
            exposure = 1.0 / high if high > 0 else 1.0
        png = args.output / f"caustics_{k:04d}.png"
        exr = args.output / f"caustics_{k:04d}.exr"
        jc.write_png(png, image, exposure=exposure)
        jc.io.write_exr(exr, image)
        written += [png, exr]

    missed_arr = np.asarray(missed)  # (frames, channels)
    worst = float(missed_arr.max())
    say(
        f"  render       {1000 * np.mean(render_s):.1f} ms/frame after "
        f"{compile_s:.1f} s to compile and run the first"
    )
    per_channel = ", ".join(f"{100 * v:.3g}%" for v in missed_arr.max(axis=0))
    say(f"  missed flux  {per_channel} (largest over frames, per channel)")
    say(f"  exposure     {exposure:.4g} (relative irradiance {1 / exposure:.3g} is white)")
    if worst > MISSED_FLUX_WARNING:
        if args.samples_x == "auto" and args.channels_y == "auto":
            advice = (
                f"The waves move light further than the largest automatic window "
                f"({MAX_AUTO_HALF_WINDOW} pixels): use larger pixels (a smaller --size "
                "or a larger --extent) or less --amplitude or --depth."
            )
        else:
            advice = (
                "Use --samples-x auto --channels-y auto (or a larger window), or less "
                "--amplitude or --depth."
            )
        print(
            f"WARNING: up to {100 * worst:.1f}% of the light lands outside the N = {n}, "
            f"M = {m} window and is missing from the images (they are darker than they "
            f"should be). {advice}",
            file=sys.stderr,
        )
    if len(written) <= 4:
        say("  wrote        " + ", ".join(str(p) for p in written))
    else:
        say(
            f"  wrote        {len(written)} files: {written[0]} ... {written[-1]} "
            f"(PNG tone-mapped, EXR linear)"
        )
    return 0


# --------------------------------------------------------------------------- main

# Each entry adds one top-level subcommand to the subparsers it is given.
_COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    _add_render,
    add_design,
    add_recover,
    add_verify,
]


def build_parser() -> argparse.ArgumentParser:

    parser = argparse.ArgumentParser(
        prog="jaxcaustics",
        description="Differentiable caustics in JAX: render caustic images from the command line.",
        epilog="Run 'jaxcaustics render water --help' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in _COMMANDS:
        add(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``jaxcaustics`` console script; returns the exit code.

    Argument errors exit through argparse (`SystemExit` with code 2 and a usage
    message); errors the library finds in the values (`ValueError`, exit 2), file-system
    errors and a solver's failures (`OSError`, `RuntimeError`, exit 1) are printed as one
    line instead of a traceback.
    """
    parser = build_parser()
    args = parser.parse_args(argv)

    shown: set[str] = set()

    def show_warning(message, category, filename, lineno, file=None, line=None):
        if str(message) not in shown:  # e.g. the same aliasing warning every frame
            shown.add(str(message))
            print(f"{parser.prog}: warning: {message}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return int(args.func(args))
    except (CLIError, ValueError) as err:
        print(f"{parser.prog}: error: {err}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError) as err:  # a file system's, a solver's (with `throw`)
        print(f"{parser.prog}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
