"""``jaxcaustics design``: from a target picture to a lens a workshop can mill.

The design runs in rounds (the transport start, or each level of the Poisson start, then
the refinement); after every round the heights are written to a checkpoint
(``design.ckpt`` in the output folder), so ``--resume`` continues an interrupted run
(Ctrl-C keeps the last checkpoint) and ends where an uninterrupted run ends. Outputs:
the solid as binary STL (millimetres; ``--formats`` adds OBJ or PLY), the height map
(16-bit PNG and EXR), the predicted caustic (PNG), the loss plot, the manufacturability
report, and ``design.json``, every parameter of the problem (element, index, outline, light, screen,
units, the target and how it was scaled), so that the folder alone is enough to verify
the part (``jaxcaustics verify FOLDER``); ``--verify`` also renders the exported solid
with the reference tracer (screen moved by 5%, the Sun's disc).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from ..inverse.design import design as design_element
from ..inverse.design import lens_problem
from ..inverse.export import export_lens
from ..inverse.problem import (
    Circle,
    DesignProblem,
    Ellipse,
    Mirror,
    Polygon,
    Rectangle,
    Screen,
    problem_to_dict,
)
from ..inverse.solvers import SOLVER_NAMES
from ..inverse.verify import default_photons, exported_error, verify_heights, verify_lens
from ..io.files import save_figure, write_json
from ..io.images import READ_EXTENSIONS, check_folder, read_image, write_exr, write_png
from ..scene.mirror import MirrorScene
from ..scene.scene import DirectionalLight, LensScene
from ..scene.sources import AreaLight, SunLight
from .flags import (
    MAX_PIXELS,
    MAX_SIDE,
    add_light_angles,
    folder,
    int_at_least,
    length,
    memory_size,
    number,
    output_folder,
    resume_checkpoint,
    spare_inputs,
    translate,
    with_flags,
)

_NOT_PICTURES = {"download_all", "data_dir", "file_hash", "lbp_frontal_face_cascade_filename"}


def _load_target(spec: str | None, size: int) -> np.ndarray:
    """The target picture as a float image: a file (PNG, EXR, ...) or a scikit-image
    bundled picture by name (default ``camera``), resized to `size` columns."""
    from skimage import data, transform

    name = "camera" if spec is None else spec
    if not name.strip():
        raise ValueError("`TARGET` is empty (an unset shell variable?): give a file or a name")
    not_a_picture = f"`TARGET` {name!r} is neither a file nor a scikit-image picture"
    # a file only when it is a file: a folder named like a bundled picture (the default
    # `camera` as `--output`) is not read as the target
    if Path(name).is_file():
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
    elif Path(name).exists():
        raise ValueError(f"`TARGET` {name!r} is a folder, not a picture")
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
        "--element",
        choices=("lens", "mirror"),
        default="lens",
        help="lens (refracting; default) or mirror (reflecting: the light must lean, "
        "--zenith, and the screen faces the reflected beam, --screen-distance from the mirror)",
    )
    design.add_argument(
        "--screen-normal",
        choices=("ground", "beam"),
        default=None,
        help="ground: the screen lies flat under the lens (a lens's default); beam: it faces "
        "the outgoing beam (a mirror's only choice)",
    )
    design.add_argument(
        "--outline",
        default="rectangle",
        metavar="OUTLINE",
        help="the blank's outline: rectangle (default), circle (--width across; a round "
        "lens in a round mount), ellipse (--width by --height), or FILE: a polygon's "
        "vertices, one 'x y' pair a line, star-shaped about the centre of their box, "
        "or a picture (PNG, JPEG, TIFF, EXR) white inside the outline; scaled to --width",
    )
    add_light_angles(design, zenith_deg=0.0, azimuth_deg=0.0)
    design.add_argument(
        "--light",
        type=_light_kind,
        default="collimated",
        metavar="LIGHT",
        help="collimated (default: a point at infinity), sun (the Sun's disc, 0.533 "
        "degrees across: the design pre-compensates its blur), or led:SIZE@DISTANCE (a "
        "square Lambertian die SIZE wide, DISTANCE from the top's centre against the "
        "light's direction, e.g. led:3mm@100mm)",
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
    design.add_argument(
        "--formats",
        type=mesh_formats,
        default=("stl",),
        metavar="LIST",
        help="mesh files of the solid, comma-separated among stl, obj, ply (default: stl, "
        "binary; the solid of a design with 1024^2 heights is 420 MB as STL)",
    )
    design.add_argument(
        "--memory-limit",
        type=memory_size,
        default=None,
        metavar="SIZE",
        help="memory the design may take, e.g. 8G or 512M (default: half of this machine's); "
        "a design estimated over it is refused before it starts",
    )
    design.add_argument("--output", type=folder, default=Path("design"), help="output folder")
    design.add_argument(
        "--resume", action="store_true", help="continue from the output folder's checkpoint"
    )
    design.add_argument(
        "--verify", action="store_true", help="render the exported solid with the reference"
    )
    design.set_defaults(func=with_flags(run_design, _DESIGN_FLAGS, _DESIGN_PHRASES))


def mesh_formats(text: str) -> tuple[str, ...]:
    """`--formats`: a comma-separated list of mesh formats (stl, obj, ply)."""
    formats = tuple(part.strip().lower() for part in text.split(",") if part.strip())
    unknown = [f for f in formats if f not in ("stl", "obj", "ply")]
    if not formats or unknown:
        raise argparse.ArgumentTypeError(
            f"expected stl, obj or ply (comma-separated), got {text!r}"
        )
    return tuple(dict.fromkeys(formats))


# the library's argument names of `design_lens` and `export_lens` -> the design's flags
_DESIGN_FLAGS = {
    "target": "TARGET",
    "width": "--width",
    "height": "--height",
    "thickness": "--thickness",
    "screen_distance": "--screen-distance",
    "ior": "--ior",
    "start": "--start",
    "levels": "--levels",
    "heights_shape": "--levels",
    "max_steps": "--steps",
    "max_relief": "--max-relief",
    "tool_radius_mm": "--tool-radius",
    "solver": "--solver",
    "memory_limit": "--memory-limit",
    "formats": "--formats",
}
# the files a design writes into `--output` (`export_lens`'s with name "lens")
_WRITTEN = [
    *(f"lens{ending}" for ending in (".stl", ".obj", "_height.png", "_height.json",
                                     "_height.exr", "_report.json", "_report.txt")),
    "predicted.png", "target.png", "target.exr", "loss.png", "design.json", "summary.json",
    "design.ckpt", "verification.json",
]  # fmt: skip
_DESIGN_PHRASES = {"the target's size": "`--size`"}


def _light_kind(text: str):
    """`--light`: ``"collimated"``, ``"sun"`` or ``(size, distance)`` of ``led:S@D``."""
    if text in ("collimated", "sun"):
        return text
    head, _, rest = text.partition(":")
    size, at, distance = rest.partition("@")
    if head != "led" or not at:
        raise argparse.ArgumentTypeError(
            f"expected collimated, sun or led:SIZE@DISTANCE (e.g. led:3mm@100mm), got {text!r}"
        )
    return length(size), length(distance)


def _light(args, problem):
    """The extended source of `--light`, along `--zenith` and `--azimuth`."""
    centre = DirectionalLight.from_angles(args.zenith, args.azimuth)
    if args.light == "sun":
        return SunLight(np.asarray(centre.direction))
    size, distance = args.light
    d = np.asarray(centre.direction, float)
    position = np.array([0.0, 0.0, problem.top]) - distance * d / np.linalg.norm(d)
    return AreaLight(position, size)


def _levels(text: str) -> list[int]:
    try:
        levels = [int(v) for v in text.split(",")]
    except ValueError as err:
        raise ValueError(f"`--levels` must be integers separated by commas, got {text!r}") from err
    if not levels or min(levels) < 4 or max(levels) > MAX_SIDE:
        raise ValueError(f"`--levels` must be integers in [4, {MAX_SIDE}], got {text!r}")
    return levels


def _settings(strategy) -> dict | None:
    """A strategy's settings as JSON-ready data (its class name as ``"kind"``)."""
    if strategy is None:
        return None
    fields = {f.name: getattr(strategy, f.name) for f in dataclasses.fields(strategy)}
    return {"kind": type(strategy).__name__, **{k: _plain(v) for k, v in fields.items()}}


def _plain(value):
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return repr(value)  # a solver object


def _on_the_ground(scene) -> bool:
    """A lens over the ground screen (the exported solid can be traced there)."""
    return not isinstance(scene, MirrorScene) and scene.screen_pose is None


def _screen(args: argparse.Namespace, screen: Screen) -> Screen:
    """`--screen-normal` on the screen (`--element mirror` allows only the beam)."""
    if args.element == "mirror" and args.screen_normal == "ground":
        raise ValueError("`--screen-normal` ground: a mirror's screen faces the reflected beam")
    if args.screen_normal == "beam" or args.element == "mirror":
        return Screen(screen.distance, screen.extent, normal="beam")
    return screen


def _outline(spec: str, width: float, height: float):
    """`--outline`: a name, or a file of polygon vertices scaled to `width`."""
    if spec == "rectangle":
        return Rectangle(width, height)
    if spec == "circle":
        return Circle(width)
    if spec == "ellipse":
        return Ellipse(width, height)
    if not Path(spec).is_file():
        raise ValueError(
            f"`--outline` {spec!r} is neither rectangle, circle, ellipse nor a file of vertices"
            " or a picture"
        )
    if Path(spec).suffix.lower() in READ_EXTENSIONS:  # a picture: white inside the blank
        try:
            mask = np.asarray(read_image(spec), float) > 0.5  # as the target: row 0, y_min
            shape = Polygon.from_mask(mask, 1.0)
        except (ValueError, OSError) as err:
            raise ValueError(f"`--outline` {spec!r}: {err}") from err
        return Polygon(np.asarray(shape.vertices) * (width / shape.width))
    try:
        vertices = np.loadtxt(spec, ndmin=2)
    except ValueError as err:
        raise ValueError(f"`--outline` {spec!r}: not 'x y' pairs, one a line ({err})") from err
    if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3:
        raise ValueError(f"`--outline` {spec!r}: needs 3 or more 'x y' lines")
    span = float(np.ptp(vertices[:, 0]))
    if not span > 0:
        raise ValueError(f"`--outline` {spec!r}: the vertices span no width")
    try:
        return Polygon(vertices * (width / span))
    except ValueError as err:
        raise ValueError(f"`--outline` {spec!r}: {err}") from err


def describe_folder(out: Path, design, start, finish, *, source: str, max_relief) -> None:
    """Write ``design.json`` and ``target.exr`` into the design folder `out` (where
    `export_lens` wrote ``lens_height.exr``): every parameter of `design`'s problem, its
    strategies, the target and how it was scaled, so that the folder alone is enough to
    verify the part (`jaxcaustics verify`)."""
    target = np.asarray(design.target)
    write_exr(out / "target.exr", target)
    write_json(
        out / "design.json",
        {
            "problem": problem_to_dict(design.problem),
            "start": _settings(start),
            "finish": _settings(finish),
            "max_relief": max_relief,
            "target": {
                "source": source,
                "scaled": f"luminance (the mean of R, G, B), resized to {target.shape[1]} "
                "columns with anti-aliasing; unit mean in the design",
                "file": "target.exr",
                "shape": list(target.shape),
            },
            "screen": {"extent": list(map(float, design.scene.receiver.extent))},
            "heights": {
                "file": "lens_height.exr",
                "units": "millimetres above the bottom face",
                "samples": "the design's own heights at the odd rows and columns",
                "boundary": design.scene.surface.boundary,
            },
        },
    )


def run_design(args: argparse.Namespace) -> int:
    check_folder(args.output, "--output")  # created once the rest is known good
    target = _load_target(args.target, args.size)
    height = args.height or args.width * target.shape[0] / target.shape[1]
    outline = _outline(args.outline, args.width, height)
    height = outline.height
    problem, start, finish = lens_problem(
        width=args.width,
        height=height,
        thickness=args.thickness,
        screen_distance=args.screen_distance,
        ior=args.ior,
        start=args.start,
        levels=None if args.levels is None else _levels(args.levels),
        max_steps=args.steps,
        solver=args.solver,
        light=DirectionalLight.from_angles(args.zenith, args.azimuth),
    )
    problem = DesignProblem(
        Mirror(args.thickness) if args.element == "mirror" else problem.element,
        outline,
        _screen(args, problem.screen),
        problem.light,
    )
    if args.light != "collimated":
        light = _light(args, problem)
        problem = DesignProblem(problem.element, problem.outline, problem.screen, light)
    inputs = [Path(p) for p in (args.target, args.outline) if p and Path(p).is_file()]
    spare_inputs(args.output, _WRITTEN, inputs)
    out = output_folder(args.output)
    checkpoint = out / "design.ckpt"
    resume_checkpoint(checkpoint, args.resume)
    losses: list[float] = []

    def step_done(info):
        losses.append(float(info["loss"]) / info.get("residuals", 1))

    began = time.perf_counter()
    try:
        design = design_element(
            problem,
            target,
            start=start,
            finish=finish,
            max_relief=args.max_relief,
            throw=False,
            callback=step_done,
            checkpoint=checkpoint,
            resume=args.resume,
            progress=True,
            memory_limit=args.memory_limit,
        )
    except KeyboardInterrupt as stop:
        print(f"{stop or 'design interrupted'}; rerun with --resume")
        return 130
    seconds = time.perf_counter() - began

    # a mirror's blank: its face milled into the top of a block `--thickness` thick
    mirror = isinstance(design.scene, MirrorScene)
    paths = export_lens(
        design.scene,
        out,
        thickness=args.thickness if mirror else None,
        tool_radius_mm=args.tool_radius * 1000,
        formats=args.formats,
    )
    write_png(out / "predicted.png", design.predicted)
    write_png(out / "target.png", target)
    _loss_plot(losses, out / "loss.png")
    describe_folder(
        out, design, start, finish, source=args.target or "camera", max_relief=args.max_relief
    )
    # the design's error as exported: the solid's facets traced exactly (parallel light
    # onto the ground; None otherwise)
    began_judging = time.perf_counter()
    exported = None if mirror else exported_error(design.scene, design.target)
    judging = time.perf_counter() - began_judging
    summary = {
        "start": args.start,
        "solver": args.solver,
        "steps_per_level": args.steps,
        "levels": [list(r["shape"]) for r in design.levels],
        "seconds": seconds,
        "predicted_error": design.predicted_error,
        "exported_error": exported,
        "dark_flux": design.dark_flux,
        "converged": design.converged,
        "warnings": design.warnings,
        "final_loss": float(design.loss_history[-1]) if design.loss_history else None,
        "relief_mm": 1000 * design.relief,
        "files": {k: str(v) for k, v in paths.items()},
    }
    if args.verify and not _on_the_ground(design.scene):
        photons = default_photons(design.scene.light, design.target.shape)
        error, _ = verify_heights(design.scene, design.target, photons_per_axis=photons)
        print(f"verification: the heights traced by the reference miss the target by {error:.4f}")
        summary["verification"] = {"heights": error}
    elif args.verify:
        assert isinstance(design.scene, LensScene)  # (for mypy: `_on_the_ground`)
        photons = default_photons(design.scene.light, design.target.shape)
        report = verify_lens(design.scene, design.target, photons_per_axis=photons)
        print(report)
        summary["verification"] = {
            "nominal": report.nominal,
            "screen_near": report.screen_near,
            "screen_far": report.screen_far,
            "sun": report.sun,
        }
    write_json(out / "summary.json", summary)
    print(
        f"designed in {seconds:.1f} s; relief {1000 * design.relief:.2f} mm; predicted error "
        f"{design.predicted_error:.3f} (relative L2), {100 * design.dark_flux:.1f}% of the "
        "flux on dark pixels"
    )
    if exported is not None:
        print(
            f"the exported solid misses the target by {exported:.3f} (relative L2; its facets "
            f"traced exactly, {judging:.0f} s)"
        )
    if design.source_blur_px is not None:
        print(
            f"the source blurs each point of the caustic over {design.source_blur_px:.1f} "
            "pixels (radius) on the screen; the design pre-compensates where it can"
        )
    for note in design.warnings:  # again, after the progress bar, in the flags' words
        print(f"warning: {translate(note, _DESIGN_FLAGS, _DESIGN_PHRASES)}")
    print((out / "lens_report.txt").read_text() if (out / "lens_report.txt").exists() else "")
    meshes = ", ".join(f"lens.{fmt}" for fmt in args.formats)
    print(f"wrote {out}/ ({meshes}, height maps, design.json, predicted.png, loss.png)")
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
    save_figure(fig, path, dpi=80)
    plt.close(fig)
