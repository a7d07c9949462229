"""``jaxcaustics recover``: a water surface from a caustic photo, or from the frames of a
video of a pool floor."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from .. import reference
from ..inverse.sequence import frame_paths, load_frames, recover_sequence
from ..inverse.solvers import SOLVER_NAMES
from ..io.files import save_figure, write_json
from ..io.images import write_exr, write_png
from ..scene.scene import DirectionalLight, HeightField, PlaneReceiver, WaterScene
from ..scene.waves import wave_heights
from .flags import (
    MAX_BUILT_IN,
    MAX_SIDE,
    folder,
    int_at_least,
    number,
    output_folder,
    resume_checkpoint,
    spare_inputs,
    with_flags,
    zenith,
)


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
    recover.add_argument("--output", type=folder, default=Path("recover"), help="output folder")
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
    "solver": "--solver",
}


_SEA_WAVELENGTHS = (0.3, 1.0)  # the built-in sea's waves, metres


def _built_in_sea(args, extent, light) -> tuple[np.ndarray, np.ndarray]:
    """The CLI's demonstration: a 64^2 sea and its caustic traced by the reference."""

    n = args.heights or 64
    try:
        truth = np.asarray(
            wave_heights(
                (n, n),
                extent,
                amplitude=0.003,
                depth=args.depth,
                wavelength_range=_SEA_WAVELENGTHS,
                num_waves=8,
                seed=3,
            ),
            float,
        )
    except ValueError as err:  # it named `num_waves` and `wavelength_range`
        low, high = _SEA_WAVELENGTHS
        raise ValueError(
            f"`--size` {extent[1]:g},{extent[3]:g} m: the built-in sea's waves, {low:g} to "
            f"{high:g} m long and periodic over the floor, do not fit on it (give a floor of "
            "a metre or more, or a TARGET)"
        ) from err
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
    save_figure(fig, path, dpi=80)
    plt.close(fig)


def _written(count: int) -> list[str]:
    """The files a recovery of `count` frames writes into `--output`."""
    tags = [""] if count == 1 else [f"_{k:04d}" for k in range(count)]
    names = ("heights{}.exr", "recovered_caustic{}.png", "target{}.png", "residual{}.png")
    return [n.format(t) for t in tags for n in names] + ["summary.json", "recover.ckpt"]


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
        if not name.strip():  # `Path` would read it as the current folder
            raise ValueError("`TARGET` is empty (an unset shell variable?): give a file or folder")
        if not Path(name).exists():
            raise ValueError(f"`TARGET` {name!r}: no such file or folder")
    frames: list = []
    if len(args.target) == 1 and Path(args.target[0]).is_dir():
        frames = frame_paths(args.target[0])
    elif args.target:
        frames = [Path(t) for t in args.target]
    spare_inputs(args.output, _written(max(len(frames), 1)), frames)
    out = output_folder(args.output)
    checkpoint = out / "recover.ckpt"
    resume_checkpoint(checkpoint, args.resume)
    extent = (0.0, args.size[0], 0.0, args.size[1])
    light = DirectionalLight.from_angles(args.zenith, args.azimuth)
    truth = None
    if not args.target:
        truth, built_in = _built_in_sea(args, extent, light)
        frames = [built_in]
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
        tag = "" if single else f"_{k:04d}"  # as `_written` says
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
    write_json(out / "summary.json", summary)
    for key, value in summary.items():
        print(f"{key}: {value}")
    names = "heights, recovered_caustic, target, residual" + ("" if single else " per frame")
    print(f"wrote {out}/ ({names}; summary.json)")
    return 0
