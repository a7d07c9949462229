"""``jaxcaustics verify FOLDER``: the exported part of a design folder traced by the NumPy
reference, from the folder alone (its ``design.json``, height map and target).

The lens is rebuilt from what was exported (``lens_height.exr``: millimetres above the
bottom face, the design's own samples at its odd rows and columns) and the problem the
folder describes (index, thickness, outline, light, screen); `verify_lens` traces its
solid at the nominal screen, the screen moved by 5% each way, and under the Sun's disc.
The figures are printed and written to ``verification.json`` in the folder.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..inverse.problem import Mirror, problem_from_dict
from ..inverse.screen_geometry import screen_pose
from ..inverse.verify import MAX_PHOTONS_PER_AXIS, default_photons, verify_heights, verify_lens
from ..io.files import write_json
from ..io.images import read_exr
from ..scene.mirror import MirrorScene
from ..scene.scene import HeightField, LensScene, PlaneReceiver
from .flags import int_at_least


def add_verify(subparsers) -> None:
    verify = subparsers.add_parser(
        "verify",
        help="trace a design folder's exported lens with the reference",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    verify.add_argument("folder", type=Path, metavar="FOLDER", help="a `design` output folder")
    verify.add_argument(
        "--photons",
        type=int_at_least(16, MAX_PHOTONS_PER_AXIS),
        default=None,
        help="the reference's photons per axis, for a design under a point light or an LED "
        "(default: 8 per target pixel side; 32 under an LED, whose samples share them); "
        "under parallel light (no Fresnel) the solid's facets are followed exactly instead",
    )
    verify.set_defaults(func=run_verify)


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ValueError(f"`FOLDER`: cannot read {path.name}: {err}") from err


def exported_lens(folder: Path) -> tuple[LensScene | MirrorScene, np.ndarray]:
    """The element a design folder exported (a `LensScene` or `MirrorScene`), its target ``(rows,
    cols)``; a `ValueError` naming `FOLDER` when the folder does not describe a design."""
    folder = Path(folder)
    described = folder / "design.json"
    if not described.is_file():
        raise ValueError(f"`FOLDER` {str(folder)!r} has no design.json: not a design folder")
    spec = _read_json(described)
    try:
        problem = problem_from_dict(spec.get("problem"))
        heights_file = folder / spec["heights"]["file"]
        boundary = spec["heights"]["boundary"]
        target = np.asarray(read_exr(folder / spec["target"]["file"]), float)
        extent = np.asarray(spec["screen"]["extent"], float)
        z_mm = np.asarray(read_exr(heights_file), float)
    except (KeyError, TypeError) as err:
        raise ValueError(f"`FOLDER`: design.json lacks {err}") from err
    except ValueError as err:
        raise ValueError(f"`FOLDER` {str(folder)!r}: {err}") from err
    if target.ndim == 3:  # an EXR read as channels: the target is one
        target = target[..., 0]
    if z_mm.ndim != 2 or z_mm.shape[0] % 2 == 0 or z_mm.shape[1] % 2 == 0:
        raise ValueError(
            f"`FOLDER`: {heights_file.name} of shape {z_mm.shape} is not the design's "
            "height map (2 rows + 1 by 2 cols + 1 vertices)"
        )
    thickness = problem.element.thickness
    heights = z_mm[1::2, 1::2] / 1000.0 - thickness  # metres above the rest plane
    surface = HeightField(heights, problem.outline.extent, boundary)
    receiver = PlaneReceiver(extent, target.shape)
    pose = screen_pose(problem)
    if isinstance(problem.element, Mirror):
        assert pose is not None  # (for mypy: a mirror's screen always has a pose)
        mirror = MirrorScene(
            surface, problem.light, receiver, pose, outline=problem.outline.lens_outline
        )
        return mirror, target
    scene = LensScene(
        surface,
        problem.light,
        receiver,
        thickness,
        problem.screen.distance,
        ior=problem.element.ior,
        outline=problem.outline.lens_outline,
        screen_pose=pose,
    )
    return scene, target


def run_verify(args: argparse.Namespace) -> int:
    scene, target = exported_lens(args.folder)
    photons = args.photons or default_photons(scene.light, target.shape)
    figures: dict = {"photons_per_axis": photons}
    if isinstance(scene, MirrorScene) or scene.screen_pose is not None:
        error, _ = verify_heights(scene, target, photons_per_axis=photons)
        print(f"the exported heights traced by the reference miss the target by {error:.4f}")
        figures["heights"] = error
    else:
        report = verify_lens(scene, target, photons_per_axis=photons)
        print(report)
        figures |= {
            "nominal": report.nominal,
            "screen_near": report.screen_near,
            "screen_far": report.screen_far,
            "sun": report.sun,
            "screen_shift": report.screen_shift,
        }
    path = Path(args.folder) / "verification.json"
    write_json(path, figures)
    print(f"wrote {path}")
    return 0
