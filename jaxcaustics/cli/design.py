"""``jaxcaustics design``: from a target picture to a lens a workshop can mill.

The design runs level by level (coarse to fine); after every level the heights are
written to a checkpoint (``design.ckpt`` in the output folder), so ``--resume``
continues an interrupted run (Ctrl-C keeps the last checkpoint) and ends where an
uninterrupted run ends. Outputs: the solid as STL and OBJ (millimetres), the height map
(16-bit PNG and EXR), the predicted caustic (PNG), the loss plot and the
manufacturability report; ``--verify`` also renders the exported solid with the
reference tracer (screen moved by 5%, the Sun's disc).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import reference
from ..inverse.checkpoint import run_rounds
from ..inverse.design import design_lens
from ..inverse.export import export_lens
from ..inverse.numerics import resample_corners
from ..inverse.poisson_levels import default_levels
from ..inverse.sequence import frame_paths, load_frames, recover_sequence
from ..inverse.solvers import SOLVER_NAMES
from ..inverse.transport_start import transport_shape
from ..inverse.verify import verify_lens
from ..io.images import check_folder, read_image, write_exr, write_png
from ..scene.scene import DirectionalLight, HeightField, PlaneReceiver, WaterScene
from ..scene.waves import wave_heights

UNITS = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
# most pixels of a design target, a recovered grid or a rendered map (4096^2)
MAX_PIXELS = 1 << 24
MAX_SIDE = 4096  # most pixels along a side (`--size` of design, `--heights`)
MAX_BUILT_IN = 512  # most height samples per side of recover's built-in sea (traced first)


def length(text: str) -> float:
    """A length with a unit (``100mm``, ``0.5m``, ``50cm``; a bare number is millimetres),
    in metres."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm|cm|m)?\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected a length such as 100mm or 0.5m, got {text!r}")
    value = float(match.group(1)) * UNITS[match.group(2) or "mm"]
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"a length must be positive and finite, got {text!r}")
    return value


def int_at_least(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer of at least `minimum` (and at most `maximum`)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum}, got {value}")
        return value

    return parse


def number(
    minimum: float | None = None, *, strict: bool = False, not_equal: float | None = None
) -> Callable[[str], float]:
    """An argparse type: a finite number (``>= minimum``, ``> minimum`` if `strict`; not
    `not_equal`)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if minimum is not None and (value <= minimum if strict else value < minimum):
            raise argparse.ArgumentTypeError(
                f"must be {'>' if strict else '>='} {minimum:g}, got {text!r}"
            )
        if value == not_equal:
            raise argparse.ArgumentTypeError(f"must not be {not_equal:g}, got {text!r}")
        return value

    return parse


def zenith(text: str) -> float:
    """An argparse type: the light's angle from vertical, degrees in ``[0, 90)``."""
    value = number(0.0)(text)
    if value >= 90.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 90) degrees, got {text!r}")
    return value


def output_folder(path: Path) -> Path:
    """`--output`, created (with its parents) if missing, else a `ValueError` naming it."""

    try:
        check_folder(path, "--output")
        path.mkdir(parents=True, exist_ok=True)
    except (ValueError, OSError) as err:
        raise ValueError(f"cannot create the output directory {str(path)!r}: {err}") from err
    return path


def resume_checkpoint(checkpoint: Path, resume: bool) -> None:
    """`--resume` needs the checkpoint that an earlier run left in `--output`."""
    if resume and not checkpoint.is_file():
        raise ValueError(
            f"`--resume`: no checkpoint at {checkpoint} (run without --resume to start, or "
            "give the --output of the run to continue)"
        )


def with_flags(run: Callable[[argparse.Namespace], int], flags: dict[str, str]):
    """`run`, its `ValueError`s naming the command's flags instead of the library's
    arguments (`flags`: argument -> flag), e.g. `levels` -> `--levels`."""

    def wrapped(args: argparse.Namespace) -> int:
        try:
            return run(args)
        except ValueError as err:
            text = str(err)
            for name, flag in flags.items():
                text = text.replace(f"`{name}`", f"`{flag}`")
            raise ValueError(text) from err

    return wrapped


# names in `skimage.data` that are not pictures (or would download several)
_NOT_PICTURES = {"download_all", "data_dir", "file_hash", "lbp_frontal_face_cascade_filename"}


def _load_target(spec: str | None, size: int) -> np.ndarray:
    """The target picture as a float image: a file (PNG, EXR, ...) or a scikit-image
    bundled picture by name (default ``camera``), resized to `size` columns."""
    from skimage import data, transform

    name = spec or "camera"
    not_a_picture = f"`TARGET` {name!r} is neither a file nor a scikit-image picture"
    if Path(name).exists():
        try:
            image = np.asarray(read_image(name), float)
        except ValueError as err:
            raise ValueError(f"`TARGET` {name!r}: {err}") from err
    elif name in getattr(data, "__all__", ()) and name not in _NOT_PICTURES:
        try:
            image = np.asarray(getattr(data, name)(), float)
        except Exception as err:  # not callable, a tuple of images, a download refused
            raise ValueError(f"{not_a_picture} ({type(err).__name__}: {err})") from err
        colour = image.ndim == 3 and image.shape[-1] in (3, 4)
        if not (image.ndim == 2 or colour) or min(image.shape[:2]) < 2:
            raise ValueError(f"{not_a_picture} (its data has shape {image.shape})")
    else:
        raise ValueError(not_a_picture)
    if image.ndim == 3:
        image = image[..., :3].mean(axis=-1)
    if not (np.all(np.isfinite(image)) and image.min() >= 0 and image.max() > 0):
        raise ValueError(f"`TARGET` {name!r} must be finite, non-negative and not all black")
    rows = max(4, round(size * image.shape[0] / image.shape[1]))
    if rows * size > MAX_PIXELS:
        raise ValueError(
            f"`--size` {size}: the {image.shape[1]} x {image.shape[0]} picture would be "
            f"{size} x {rows} pixels, over {MAX_PIXELS}"
        )
    return transform.resize(image, (rows, size), anti_aliasing=True)


def add_design(subparsers) -> None:
    design = subparsers.add_parser(
        "design",
        help="design a caustic lens for a target picture",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    design.add_argument(
        "target",
        nargs="?",
        default=None,
        metavar="TARGET",
        help="target picture: a file, or a scikit-image picture name (default: camera)",
    )
    design.add_argument("--width", type=length, default=0.1, help="lens width (default 100mm)")
    design.add_argument(
        "--height", type=length, default=None, help="lens height (default: the target's aspect)"
    )
    design.add_argument(
        "--thickness", type=length, default=0.01, help="blank thickness (default 10mm)"
    )
    design.add_argument(
        "--screen-distance",
        "--throw",  # its old name
        dest="screen_distance",
        type=length,
        default=0.5,
        help="lens to screen distance (default 500mm; --throw is its old name)",
    )
    design.add_argument(
        "--ior", type=number(1.0, strict=True), default=1.5, help="index of refraction (1.5)"
    )
    design.add_argument(
        "--size",
        type=int_at_least(2, MAX_SIDE),
        default=128,
        help=f"target columns (default 128, at most {MAX_SIDE})",
    )
    design.add_argument(
        "--levels",
        default=None,
        help="height-grid sizes, coarse to fine (default: 32, 64, ... up to twice --size; "
        f"at most {MAX_SIDE})",
    )
    design.add_argument(
        "--steps", type=int_at_least(1), default=40, help="solver steps per level (40)"
    )
    design.add_argument(
        "--start",
        default="transport",
        choices=("transport", "poisson"),
        help="transport: optimal transport then the landing fit (default; black stays "
        "black); poisson: the weak-lens start and the irradiance solve coarse to fine",
    )
    design.add_argument(
        "--solver",
        default="levenberg_marquardt",
        choices=SOLVER_NAMES,
        help="the Poisson start's solver",
    )
    design.add_argument(
        "--max-relief",
        type=length,
        default=None,
        help="deepest relief the blank allows; deeper designs are folded into Fresnel zones",
    )
    design.add_argument(
        "--tool-radius", type=length, default=0.001, help="ball-end mill radius (1mm)"
    )
    design.add_argument("--output", type=Path, default=Path("design"), help="output folder")
    design.add_argument(
        "--resume", action="store_true", help="continue from the output folder's checkpoint"
    )
    design.add_argument(
        "--verify", action="store_true", help="render the exported solid with the reference"
    )
    design.set_defaults(func=with_flags(run_design, _DESIGN_FLAGS))


# the library's argument names of `design_lens` and `export_lens` -> the design's flags
_DESIGN_FLAGS = {
    "target": "TARGET",
    "width": "--width",
    "height": "--height",
    "thickness": "--thickness",
    "screen_distance": "--screen-distance",
    "ior": "--ior",
    "levels": "--levels",
    "heights_shape": "--levels",
    "max_steps": "--steps",
    "max_relief": "--max-relief",
    "tool_radius_mm": "--tool-radius",
}


def _levels(text: str) -> list[int]:
    try:
        levels = [int(v) for v in text.split(",")]
    except ValueError as err:
        raise ValueError(f"`--levels` must be integers separated by commas, got {text!r}") from err
    if not levels or min(levels) < 4 or max(levels) > MAX_SIDE:
        raise ValueError(f"`--levels` must be integers in [4, {MAX_SIDE}], got {text!r}")
    return levels


def _run_levels(
    rounds, shape, out: Path, label: str, resume: bool, live: bool = False
) -> int | None:
    """Run the coarse-to-fine rounds (state: heights on the final grid and the loss) with
    a checkpoint in `out`; returns an exit code when the command should stop (Ctrl-C,
    or a checkpoint of a finished run), else None."""
    import jax.numpy as jnp

    checkpoint = out / f"{label}.ckpt"  # `run_design` checked it is there with --resume
    _, done, interrupted = run_rounds(
        rounds,
        {"heights": jnp.zeros(shape), "loss": jnp.asarray(np.inf)},
        checkpoint=checkpoint,
        resume=resume,
        describe=lambda s: f"loss {float(s['loss']):.4g}",
        label=label,
        live=live,
    )
    if interrupted:
        print(f"interrupted after {done} of {len(rounds)} levels; rerun with --resume")
        return 130
    return None


def run_design(args: argparse.Namespace) -> int:
    import jax.numpy as jnp

    out = output_folder(args.output)
    resume_checkpoint(out / "design.ckpt", args.resume)
    target = _load_target(args.target, args.size)
    height = args.height or args.width * target.shape[0] / target.shape[1]
    if args.start == "transport":  # one level: the heights grid of the landing fit
        given = None if args.levels is None else _levels(args.levels)[-1]
        levels = [given or max(transport_shape(target.shape, args.width, height))]
    else:
        levels = list(default_levels(target.shape)) if args.levels is None else _levels(args.levels)
    spec = dict(
        width=args.width,
        height=height,
        thickness=args.thickness,
        screen_distance=args.screen_distance,
        ior=args.ior,
    )
    final_shape = (max(4, round(levels[-1] * height / args.width)), levels[-1])
    losses: list[float] = []
    designs: dict[int, object] = {}

    def level_round(k: int):
        def step_done(info, report):
            losses.append(float(info["loss"]) / info.get("residuals", 1))
            rows, cols = info["shape"]
            report(f"{rows}x{cols} step {info['step']}/{args.steps} loss {info['loss']:.4g}")

        def run(state, report):
            initial = None if k == 0 else np.asarray(state["heights"])
            design = design_lens(
                target,
                levels=(levels[k],),
                max_steps=args.steps,
                solver=args.solver,
                start=args.start,
                max_relief=args.max_relief if k == len(levels) - 1 else None,
                initial=initial,
                throw=False,
                callback=lambda info: step_done(info, report),
                **spec,
            )
            designs[k] = design
            fine = resample_corners(
                np.asarray(design.heights), final_shape, design.scene.surface.boundary
            )
            return {"heights": jnp.asarray(fine), "loss": jnp.asarray(design.loss_history[-1])}

        return run

    start = time.perf_counter()
    code = _run_levels(
        [level_round(k) for k in range(len(levels))],
        final_shape,
        out,
        "design",
        args.resume,
        live=True,
    )
    if code is not None or len(levels) - 1 not in designs:
        return code or 0
    design = designs[len(levels) - 1]
    seconds = time.perf_counter() - start

    paths = export_lens(design.scene, out, tool_radius_mm=args.tool_radius * 1000)
    write_png(out / "predicted.png", design.predicted)
    write_png(out / "target.png", target)
    _loss_plot(losses, out / "loss.png")
    summary = {
        "levels": levels,
        "steps_per_level": args.steps,
        "start": args.start,
        "solver": args.solver,
        "seconds": seconds,
        "predicted_error": design.predicted_error,
        "dark_flux": design.dark_flux,
        "converged": design.converged,
        "warnings": design.warnings,
        "final_loss": float(design.loss_history[-1]) if design.loss_history else None,
        "relief_mm": 1000 * design.relief,
        "files": {k: str(v) for k, v in paths.items()},
    }
    if args.verify:
        photons = 8 * max(design.target.shape)  # 64 photons per pixel on average
        report = verify_lens(design.scene, design.target, photons_per_axis=photons)
        print(report)
        summary["verification"] = {
            "nominal": report.nominal,
            "screen_near": report.screen_near,
            "screen_far": report.screen_far,
            "sun": report.sun,
        }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(
        f"designed in {seconds:.1f} s; relief {1000 * design.relief:.2f} mm; predicted error "
        f"{design.predicted_error:.3f} (relative L2), {100 * design.dark_flux:.1f}% of the "
        "flux on dark pixels"
    )
    for note in design.warnings:
        print(f"warning: {note}")
    print((out / "lens_report.txt").read_text() if (out / "lens_report.txt").exists() else "")
    print(f"wrote {out}/ (lens.stl, lens.obj, height maps, predicted.png, loss.png, reports)")
    return 0


def _loss_plot(losses: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2))
    if losses:
        ax.semilogy(np.arange(1, len(losses) + 1), losses)
    ax.set_xlabel("solver step (all levels)")
    ax.set_ylabel("loss per residual")
    ax.set_title("lens design")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _pair(text: str) -> tuple[float, float]:
    """Two positive lengths ``W,H`` in metres."""
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected two numbers A,B, got {text!r}") from err
    if not all(math.isfinite(v) and v > 0 for v in (a, b)):
        raise argparse.ArgumentTypeError(f"expected two positive numbers, got {text!r}")
    return a, b


def add_recover(subparsers) -> None:
    recover = subparsers.add_parser(
        "recover",
        help="recover a water surface from a photograph (or video frames) of its caustic",
        description=(
            "Recover the water height field whose caustic on the pool floor is TARGET (a "
            "PNG, JPEG, TIFF or EXR, scaled so that its mean is flat water's irradiance). "
            "Several TARGETs, or a folder of them, are frames of a video: recovered in "
            "order, each warm-started from the one before, with a checkpoint after every "
            "frame (--resume continues; Ctrl-C keeps the frames done). Without TARGET, "
            "the caustic of a built-in sea is traced by the NumPy reference and recovered, "
            "and the recovered heights are compared with the true ones. Writes the "
            "heights (EXR), the recovered caustic, the target and the residual map "
            "(recovered minus target) per frame, and summary.json."
        ),
    )
    recover.add_argument("target", nargs="*", metavar="TARGET")
    recover.add_argument("--size", default="1,1", type=_pair, help="floor area W,H in metres")
    recover.add_argument(
        "--depth", type=number(0.0, strict=True), default=0.5, help="rest depth, metres (0.5)"
    )
    recover.add_argument(
        "--zenith", type=zenith, default=20.0, help="light zenith, degrees in [0, 90)"
    )
    recover.add_argument("--azimuth", type=number(), default=0.0, help="light azimuth, degrees")
    recover.add_argument(
        "--ior",
        type=number(0.0, strict=True, not_equal=1.0),
        default=1.333,
        help="water's index (1.333)",
    )
    recover.add_argument(
        "--boundary", default="periodic", choices=("periodic", "clamp"), help="surface edges"
    )
    recover.add_argument(
        "--blur",
        type=number(0.0),
        default=0.0,
        help="camera blur, Gaussian PSF sigma in pixels (0)",
    )
    recover.add_argument(
        "--gamma",
        type=number(0.0, strict=True),
        default=1.0,
        help="decode file values v as v**GAMMA (2.2 for an sRGB photograph; 1: linear data)",
    )
    recover.add_argument(
        "--heights",
        type=int_at_least(2, MAX_SIDE),
        default=None,
        help=f"height samples per axis (the target's; the built-in sea: 64, at most "
        f"{MAX_BUILT_IN})",
    )
    recover.add_argument(
        "--solver",
        default="none",
        choices=("none", *SOLVER_NAMES),
        help="image-space refinement after the transport start (none)",
    )
    recover.add_argument(
        "--levels", default="1", help="coarse-to-fine factors of the --solver, e.g. 4,2,1"
    )
    recover.add_argument(
        "--steps", type=int_at_least(1), default=50, help="solver steps per level (50)"
    )
    recover.add_argument("--output", type=Path, default=Path("recover"), help="output folder")
    recover.add_argument("--resume", action="store_true", help="continue from the checkpoint")
    recover.set_defaults(func=with_flags(run_recover, _RECOVER_FLAGS))


# the library's argument names of `recover_surface` / `recover_sequence` -> recover's flags
_RECOVER_FLAGS = {
    "target": "TARGET",
    "frames": "TARGET",
    "extent": "--size",
    "rest_depth": "--depth",
    "ior": "--ior",
    "blur": "--blur",
    "heights_shape": "--heights",
    "coarse_to_fine": "--levels",
    "max_steps": "--steps",
}


def _built_in_sea(args, extent, light) -> tuple[np.ndarray, np.ndarray]:
    """The CLI's demonstration: a 64^2 sea and its caustic traced by the reference."""

    n = args.heights or 64
    truth = np.asarray(
        wave_heights(
            (n, n),
            extent,
            amplitude=0.003,
            depth=args.depth,
            wavelength_range=(0.3, 1.0),
            num_waves=8,
            seed=3,
        ),
        float,
    )
    scene = WaterScene(
        HeightField(truth, extent),
        light,
        PlaneReceiver(extent, (n, n)),
        args.depth,
        ior=args.ior,
    )
    return truth, reference.trace_water(scene, photons_per_axis=16)


def _write_residual(path: Path, residual: np.ndarray) -> None:
    """The residual map (recovered minus target, relative to flat water) as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.6, 4))
    limit = max(float(np.abs(residual).max()), 1e-12)
    shown = ax.imshow(residual, origin="lower", cmap="RdBu_r", vmin=-limit, vmax=limit)
    fig.colorbar(shown, ax=ax, label="recovered - target")
    ax.set_title("where the recovery does not fit")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def run_recover(args: argparse.Namespace) -> int:

    try:
        factors = tuple(int(v) for v in args.levels.split(","))
    except ValueError as err:
        raise ValueError(f"`--levels` must be integers such as 4,2,1, got {args.levels!r}") from err
    if factors[-1] != 1 or any(a <= b for a, b in zip(factors, factors[1:], strict=False)):
        raise ValueError(f"`--levels` must decrease strictly to 1, got {args.levels!r}")
    if not args.target and (args.heights or 64) > MAX_BUILT_IN:
        raise ValueError(
            f"`--heights` {args.heights}: the built-in sea (no TARGET) is at most "
            f"{MAX_BUILT_IN} samples a side (its caustic is traced by the reference first)"
        )
    for name in args.target:
        if not Path(name).exists():
            raise ValueError(f"`TARGET` {name!r}: no such file or folder")
    out = output_folder(args.output)
    checkpoint = out / "recover.ckpt"
    resume_checkpoint(checkpoint, args.resume)
    extent = (0.0, args.size[0], 0.0, args.size[1])
    light = DirectionalLight.from_angles(args.zenith, args.azimuth)
    truth = None
    if not args.target:
        truth, built_in = _built_in_sea(args, extent, light)
        frames: list = [built_in]
    elif len(args.target) == 1 and Path(args.target[0]).is_dir():
        frames = frame_paths(args.target[0])
    else:
        frames = [Path(t) for t in args.target]
    targets = load_frames(frames, args.ior)  # read and checked once, scaled to unit mean
    if args.gamma != 1 and args.target:
        targets = [t**args.gamma / np.mean(t**args.gamma) for t in targets]
    shape = None if args.heights is None else (args.heights, args.heights)
    start = time.perf_counter()
    result = recover_sequence(
        targets,
        checkpoint=checkpoint,
        resume=args.resume,
        extent=extent,
        rest_depth=args.depth,
        light=light,
        ior=args.ior,
        boundary=args.boundary,
        blur=args.blur,
        heights_shape=shape,
        solver=None if args.solver == "none" else args.solver,
        coarse_to_fine=factors,
        max_steps=args.steps,
        throw=False,
    )
    if result.interrupted:
        print(f"interrupted after {result.done} of {len(frames)} frames; rerun with --resume")
        return 130
    single = len(frames) == 1
    for k in range(len(frames)):
        tag = "" if single else f"_{k:04d}"
        write_exr(out / f"heights{tag}.exr", result.heights[k])
        write_png(out / f"recovered_caustic{tag}.png", result.images[k])
        write_png(out / f"target{tag}.png", targets[k])
        _write_residual(out / f"residual{tag}.png", result.images[k] - targets[k])
    summary = {
        "seconds": time.perf_counter() - start,
        "frames": len(frames),
        "solver": args.solver,
        "image_error": result.image_error.tolist(),
        "misfit": result.misfit.tolist(),
        "warm": result.warm.tolist(),
        "seconds_per_frame": result.seconds.tolist(),
    }
    if truth is not None:
        t = truth - truth.mean()
        summary["height_error"] = float(np.linalg.norm(result.heights[0] - t) / np.linalg.norm(t))
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    for key, value in summary.items():
        print(f"{key}: {value}")
    names = "heights, recovered_caustic, target, residual" + ("" if single else " per frame")
    print(f"wrote {out}/ ({names}; summary.json)")
    return 0
