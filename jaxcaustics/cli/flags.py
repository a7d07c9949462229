"""The command line's shared flag parsers and checks: lengths with units, bounded
numbers, the output folder, `--resume`, and errors that name the flag."""

from __future__ import annotations

import argparse
import math
import re
import warnings
from collections.abc import Callable
from pathlib import Path

from ..io.images import check_folder

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


BYTES = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def memory_size(text: str) -> int:
    """A memory size in bytes (``12G``, ``512M``, ``8GiB``, ``16GB``; binary units, a
    bare number is bytes)."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kKmMgGtT]?)(?:i?[bB])?\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected a size such as 12G or 512M, got {text!r}")
    value = int(float(match.group(1)) * BYTES[match.group(2).lower()])
    if value < 1:
        raise argparse.ArgumentTypeError(f"a memory size must be at least 1 byte, got {text!r}")
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


def folder(text: str) -> Path:
    """An argparse type for `--output`: a folder's name; an empty one (an unset shell
    variable, which `Path` reads as the current folder) is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError(
            "an empty folder name (an unset shell variable?) would write into the current "
            "folder: name one ('.' for the current folder)"
        )
    return Path(text)


def output_folder(path: Path) -> Path:
    """`--output`, created (with its parents) if missing, else a `ValueError` naming it."""
    try:
        check_folder(path, "--output")
        path.mkdir(parents=True, exist_ok=True)
    except (ValueError, OSError) as err:
        raise ValueError(f"cannot create the output directory {str(path)!r}: {err}") from err
    return path


def spare_inputs(folder: Path, written: list[str], inputs: list) -> None:
    """A `ValueError` naming `--output` when the command would write one of the files
    `written` (names in `folder`) over one of its `inputs` (a picture named
    ``target.png`` in the output folder was read, then overwritten)."""
    for name in written:
        path = folder / name
        for source in inputs:
            if path.is_file() and Path(source).is_file() and path.samefile(source):
                raise ValueError(
                    f"`--output` {str(folder)!r}: the command writes its {name} there, over "
                    f"the input {str(source)!r}: choose another folder, or move the input"
                )


def resume_checkpoint(checkpoint: Path, resume: bool) -> None:
    """`--resume` needs the checkpoint that an earlier run left in `--output`."""
    if resume and not checkpoint.is_file():
        raise ValueError(
            f"`--resume`: no checkpoint at {checkpoint} (run without --resume to start, or "
            "give the --output of the run to continue)"
        )


def translate(text: str, flags: dict[str, str], phrases: dict[str, str] | None = None) -> str:
    """`text` with the library's argument names (in backticks) replaced by the command's
    flags (`flags`: argument -> flag) and the plain `phrases` by theirs; a flag named
    twice in a row (two arguments, one flag) is named once."""
    for name, flag in flags.items():
        text = text.replace(f"`{name}`", f"`{flag}`")
    for phrase, said in (phrases or {}).items():
        text = text.replace(phrase, said)
    return re.sub(r"(`[^`]+`)(,| or|, or) \1", r"\1", text)


def with_flags(
    run: Callable[[argparse.Namespace], int],
    flags: dict[str, str],
    phrases: dict[str, str] | None = None,
):
    """`run`, its errors (`ValueError`, `RuntimeError`) and warnings naming the command's
    flags instead of the library's arguments (`flags`: argument -> flag, e.g. `levels`
    -> `--levels`; `phrases`: plain text -> the command's words)."""

    def wrapped(args: argparse.Namespace) -> int:
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            text = translate(str(message), flags, phrases)
            shown(text, category, filename, lineno, file, line)

        with warnings.catch_warnings():
            warnings.showwarning = show
            try:
                return run(args)
            except ValueError as err:
                raise ValueError(translate(str(err), flags, phrases)) from err
            except RuntimeError as err:
                raise RuntimeError(translate(str(err), flags, phrases)) from err

    return wrapped


# names in `skimage.data` that are not pictures (or would download several)


def add_light_angles(parser, *, zenith_deg: float, azimuth_deg: float) -> None:
    """`--zenith` and `--azimuth` of a collimated light, with these defaults (degrees)."""
    parser.add_argument(
        "--zenith",
        type=zenith,
        default=zenith_deg,
        metavar="DEG",
        help="angle of the light from vertical, degrees, in [0, 90) (default: %(default)s)",
    )
    parser.add_argument(
        "--azimuth",
        type=number(),
        default=azimuth_deg,
        metavar="DEG",
        help="direction the light travels towards, degrees from +x towards +y "
        "(default: %(default)s)",
    )
