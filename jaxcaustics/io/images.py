"""Image files: linear EXR for data, tone-mapped PNG for display.

NumPy in, NumPy out (JAX arrays are accepted as input and converted). Arrays follow the
library's convention ``[row, col] = [y, x]``, with row 0 the *first* row of the file
(the top of the picture when viewed).

- `write_exr` / `read_exr`: lossless float32 OpenEXR (ZIP compression), for
  irradiance maps, height maps and anything else that must round-trip exactly.
- `write_png`: a tone-mapped 8- or 16-bit PNG for looking at (not for data).
- `write_png_linear16`: a 16-bit PNG holding a data map scaled linearly from
  ``[vmin, vmax]`` to ``0..65535`` (e.g. a height map for a CNC or a 3-D printer).
- `read_image`: PNG / JPEG / TIFF as floats in ``[0, 1]``, or EXR as linear floats.

16-bit PNGs go through imagecodecs, every other format through Pillow, tifffile and
OpenEXR; what a file holds is read from its header first (`probe.py`). See the design
notes (``docs/design-notes.md``).

Bad input raises `ValueError` naming the argument; a missing file raises
`FileNotFoundError` and an unreadable or corrupt file a `ValueError`, both with the path.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import imagecodecs
import numpy as np

from .._checks import check_bool
from .files import written_whole
from .probe import check_picture, read_tiff_page

__all__ = ["read_exr", "read_image", "write_exr", "write_png", "write_png_linear16"]

_EXR_LAYOUT_KEY = "jaxcaustics_layout"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
READ_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")
# Rec. 709 luminance weights (the same as `skimage.color.rgb2gray`).
_LUMA = np.array([0.2125, 0.7154, 0.0721])


# --------------------------------------------------------------------------- checks


def _as_path(path, suffixes: tuple[str, ...], *, name: str = "path") -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"`{name}` must be a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if p.suffix.lower() not in suffixes:
        allowed = suffixes[0] if len(suffixes) == 1 else "one of " + ", ".join(suffixes)
        raise ValueError(
            f"`{name}` must end in {allowed}, got {str(p)!r} (unknown extension {p.suffix!r})"
        )
    return p


def check_folder(folder, name: str) -> Path:
    """`folder` as a `Path` if it is a directory this process can write in, or one it
    can create (its nearest existing ancestor is a writable directory), else a
    `ValueError` naming `name`. Creates nothing (a probe file is removed at once)."""
    if not isinstance(folder, (str, os.PathLike)):
        raise ValueError(f"`{name}` must be a str or os.PathLike, got {type(folder).__name__}")
    d = Path(folder)
    if d.exists() and not d.is_dir():
        raise ValueError(f"`{name}` {str(d)!r} exists and is not a directory")
    existing = next(p for p in (d, *d.parents) if p.exists())
    if not existing.is_dir():
        raise ValueError(f"`{name}` {str(d)!r}: {str(existing)!r} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        raise ValueError(
            f"`{name}` {str(d)!r}: cannot write in {str(existing)!r} ({err.strerror or err})"
        ) from err
    return d


def _prepare_output(p: Path) -> None:
    if p.is_dir():
        raise ValueError(f"`path` {str(p)!r} is a directory")
    check_folder(p.parent, "path")
    p.parent.mkdir(parents=True, exist_ok=True)


def _check_input_file(p: Path) -> None:
    if not p.exists():
        raise FileNotFoundError(f"`path`: no such file: {str(p)!r}")
    if not p.is_file():
        raise ValueError(f"`path` {str(p)!r} is not a regular file")


def _as_image(image, name: str, *, ndims: tuple[int, ...] = (2, 3)) -> np.ndarray:
    """Converts to a float64 NumPy array and checks ndim, size and finiteness."""
    try:
        arr = np.asarray(image)
    except Exception as err:  # noqa: BLE001 - re-raised with the argument's name
        raise ValueError(f"`{name}` must be array-like, got {type(image).__name__}") from err
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.integer)
        or np.issubdtype(arr.dtype, np.floating)
        or arr.dtype == bool
    ):
        raise ValueError(f"`{name}` must hold real numbers, got dtype {arr.dtype}")
    if arr.ndim not in ndims:
        want = " or ".join(f"{d}-D" for d in ndims)
        raise ValueError(f"`{name}` must be {want}, got shape {arr.shape} ({arr.ndim}-D)")
    if arr.size == 0 or (arr.ndim == 3 and arr.shape[2] == 0):
        raise ValueError(f"`{name}` is empty (shape {arr.shape})")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"`{name}` contains NaN or infinite values")
    return arr


def _check_optional_scalar(value, name: str, *, positive: bool) -> float | None:
    if value is None:
        return None
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"`{name}` must be a number or None, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`{name}` must be a number or None, got {value!r}") from err
    if not math.isfinite(v):
        raise ValueError(f"`{name}` must be finite, got {v}")
    if positive and not v > 0:
        raise ValueError(f"`{name}` must be positive, got {v}")
    return v


# --------------------------------------------------------------------------- EXR


def _default_channel_names(arr: np.ndarray) -> list[str]:
    if arr.ndim == 2:
        return ["Y"]
    if arr.shape[2] == 3:
        return ["R", "G", "B"]
    return [f"C{i}" for i in range(arr.shape[2])]


def write_exr(path, image, *, channel_names: Sequence[str] | None = None) -> None:
    """Writes a linear float32 OpenEXR file (ZIP compression, lossless).

    The channel order and the array's dimensionality are stored in a header attribute,
    so `read_exr` returns exactly the array written (as float32).

    **Arguments:**

    - `path`: output file, a `str` or `os.PathLike`; must end in ``.exr``. Parent
      directories are created.
    - `image`: array-like of shape ``(rows, cols)`` or ``(rows, cols, C)``: linear values
      (any unit; e.g. relative irradiance or metres), indexed ``[y, x]``, row 0 at the top
      of the picture. Stored as float32: values must be finite and within the float32
      range.
    - `channel_names`: optional sequence of str, one distinct name per channel. Defaults:
      ``"Y"`` for a 2-D image; ``"R", "G", "B"`` for 3 channels; ``"C0" .. "C{C-1}"``
      otherwise.

    **Raises:** `ValueError` for a bad `path` extension, an empty, non-numeric, non-finite
    or wrongly shaped `image`, or bad `channel_names`.
    """
    import OpenEXR

    p = _as_path(path, (".exr",))
    arr = _as_image(image, "image")
    with np.errstate(over="ignore"):
        arr32 = arr.astype(np.float32)
    if not np.all(np.isfinite(arr32)):
        raise ValueError("`image` has values outside the float32 range")
    if channel_names is None:
        names = _default_channel_names(arr)
    else:
        if isinstance(channel_names, str):
            raise ValueError("`channel_names` must be a sequence of str, not a single str")
        names = list(channel_names)
        n_channels = 1 if arr.ndim == 2 else arr.shape[2]
        if len(names) != n_channels:
            raise ValueError(
                f"`channel_names` must give {n_channels} names for an image of shape "
                f"{arr.shape}, got {len(names)}"
            )
        if not all(isinstance(n, str) and n for n in names):
            raise ValueError(f"`channel_names` must be non-empty strings, got {names!r}")
        if len(set(names)) != len(names):
            raise ValueError(f"`channel_names` must be distinct, got {names!r}")
    planes = [arr32] if arr.ndim == 2 else [arr32[:, :, i] for i in range(arr.shape[2])]
    # The OpenEXR bindings need C-contiguous planes (strided views are misread).
    channels = {n: np.ascontiguousarray(plane) for n, plane in zip(names, planes, strict=True)}
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        _EXR_LAYOUT_KEY: json.dumps({"channels": names, "ndim": arr.ndim}),
    }
    _prepare_output(p)
    with written_whole(p) as tmp, OpenEXR.File(header, channels) as f:
        f.write(str(tmp))


def _exr_channel_order(names: list[str], header: dict) -> tuple[list[str], int]:
    """The channel order and ndim to return: ours if written by `write_exr`, else a
    conventional order (Y; R,G,B; R,G,B,A; otherwise sorted by name)."""
    layout = header.get(_EXR_LAYOUT_KEY)
    if isinstance(layout, str):
        try:
            info = json.loads(layout)
            order, ndim = list(info["channels"]), int(info["ndim"])
            if sorted(order) == sorted(names) and (ndim == 3 or len(order) == 1):
                return order, ndim
        except (ValueError, KeyError, TypeError):
            pass  # a foreign or damaged attribute: fall back to the conventions
    if len(names) == 1:
        return names, 2
    for conventional in (["R", "G", "B"], ["R", "G", "B", "A"]):
        if sorted(names) == sorted(conventional):
            return conventional, 3
    return sorted(names), 3


def read_exr(path) -> np.ndarray:
    """Reads an OpenEXR file (first part) as float32.

    **Arguments:**

    - `path`: an ``.exr`` file, a `str` or `os.PathLike`.

    **Returns:** a float32 `numpy.ndarray` of shape ``(rows, cols)`` or
    ``(rows, cols, C)``. A single-channel file (e.g. ``"Y"``) gives a 2-D array. A file
    written by `write_exr` comes back with the shape and channel order it was written
    with. For other files: ``R, G, B`` (and ``A``) channels in that order, otherwise the
    channels sorted by name. Half and uint channels are converted to float32.

    **Raises:** `FileNotFoundError` if `path` does not exist; `ValueError` if `path` does
    not end in ``.exr`` or is not a readable OpenEXR image.
    """
    import OpenEXR

    p = _as_path(path, (".exr",))
    _check_input_file(p)
    if not OpenEXR.isOpenExrFile(str(p)):
        raise ValueError(f"`path` {str(p)!r} is not an OpenEXR file")
    try:
        with OpenEXR.File(str(p), separate_channels=True) as f:
            # Copies: the bindings clear the header and may free pixels on exit.
            header = dict(f.header())
            planes = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    except Exception as err:  # noqa: BLE001 - the bindings raise several types
        raise ValueError(f"`path` {str(p)!r} is not a readable OpenEXR image: {err}") from err
    if not planes:
        raise ValueError(f"`path` {str(p)!r} holds no image channels")
    shapes = {plane.shape for plane in planes.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(
            f"`path` {str(p)!r}: channels have different or non-2-D shapes "
            f"({sorted(shapes)}); subsampled or deep images are not supported"
        )
    order, ndim = _exr_channel_order(list(planes), header)
    if ndim == 2:
        return planes[order[0]].astype(np.float32)
    return np.stack([planes[n].astype(np.float32) for n in order], axis=-1)


# --------------------------------------------------------------------------- PNG


def _write_png_uint16_rgb(p: Path, q: np.ndarray) -> None:
    """A 16-bit RGB PNG, by imagecodecs (libpng): Pillow, under scikit-image, cannot
    write these."""
    p.write_bytes(imagecodecs.png_encode(q))


def _save_png(p: Path, q: np.ndarray) -> None:
    """Saves a uint8 / uint16 array of shape (rows, cols) or (rows, cols, 3)."""
    _prepare_output(p)
    with written_whole(p) as tmp:
        if q.dtype == np.uint16 and q.ndim == 3:
            _write_png_uint16_rgb(tmp, q)
        else:
            import skimage.io

            skimage.io.imsave(str(tmp), q, check_contrast=False)


def _read_png_16bit(p: Path) -> np.ndarray | None:
    """A 16-bit PNG (gray, gray + alpha, RGB, RGBA) as uint16, by imagecodecs (Pillow
    truncates the colour ones to 8 bits, and gray + alpha to 8-bit RGBA); None for any
    other PNG (Pillow reads those fully)."""
    data = p.read_bytes()
    if data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR" or len(data) < 26:
        return None
    if data[24] != 16:
        return None
    return np.asarray(imagecodecs.png_decode(data))


def write_png(path, image, *, exposure=None, gamma=2.2, bit_depth: int = 8) -> None:
    """Writes a tone-mapped PNG for display.

    The image is scaled so that a robust high value maps to white: ``image * exposure``
    if `exposure` is given, otherwise ``image / percentile(image, 99.5)`` (over all
    channels together, so colours keep their ratios; the maximum is used when that
    percentile is 0, and an all-zero image stays black). The result is clipped to
    ``[0, 1]``, gamma-encoded as ``v ** (1 / gamma)`` and quantised to `bit_depth` bits.

    **Arguments:**

    - `path`: output file, a `str` or `os.PathLike`; must end in ``.png``. Parent
      directories are created.
    - `image`: array-like of shape ``(rows, cols)``, ``(rows, cols, 1)`` or
      ``(rows, cols, 3)``: linear, non-negative, finite values (e.g. relative
      irradiance), indexed ``[y, x]``, row 0 at the top. 2-D and single-channel images are
      written as grayscale, 3 channels as RGB. Any other channel count raises a
      `ValueError` (pick or combine the channels you want to show first).
    - `exposure`: optional positive float factor applied before clipping; replaces the
      automatic scale. Default None (the automatic scale).
    - `gamma`: display gamma (a float, > 0); 1 writes linear values; default 2.2.
    - `bit_depth`: bits per sample, 8 or 16; the file holds uint8 or uint16 samples
      accordingly; default 8.

    **Raises:** `ValueError` for a bad `path` extension, a bad `image` (empty, wrong
    shape, NaN, infinite or negative values), or bad `exposure`, `gamma` or `bit_depth`.
    """
    p = _as_path(path, (".png",))
    arr = _as_image(image, "image")
    if arr.ndim == 3:
        if arr.shape[2] == 1:
            arr = arr[:, :, 0]
        elif arr.shape[2] != 3:
            raise ValueError(
                f"`image` must have 1 or 3 channels to be shown, got shape {arr.shape}; "
                "select or combine channels first"
            )
    if np.any(arr < 0):
        raise ValueError(f"`image` has negative values (min {arr.min()}); cannot tone-map")
    exposure = _check_optional_scalar(exposure, "exposure", positive=True)
    gamma_value = _check_optional_scalar(gamma, "gamma", positive=True)
    if gamma_value is None:
        raise ValueError("`gamma` must be a positive number, got None")
    whole = isinstance(bit_depth, (int, np.integer)) and not isinstance(bit_depth, bool)
    if not whole or bit_depth not in (8, 16):
        raise ValueError(f"`bit_depth` must be 8 or 16, got {bit_depth!r}")
    if exposure is None:
        high = float(np.percentile(arr, 99.5))
        if high <= 0:
            high = float(arr.max())
        scale = 1.0 / high if high > 0 else 1.0
    else:
        scale = exposure
    encoded = np.clip(arr * scale, 0.0, 1.0) ** (1.0 / gamma_value)
    top = 255 if bit_depth == 8 else 65535
    q = np.rint(encoded * top).astype(np.uint8 if bit_depth == 8 else np.uint16)
    _save_png(p, q)


def write_png_linear16(path, array, *, vmin=None, vmax=None) -> tuple[float, float]:
    """Writes a 2-D data map as a 16-bit grayscale PNG, linearly scaled.

    ``vmin`` maps to 0 and ``vmax`` to 65535; values outside ``[vmin, vmax]`` are
    clipped. Recover the data as ``vmin + read_image(path) * (vmax - vmin)`` (to within
    ``(vmax - vmin) / 65535 / 2``). If ``vmin == vmax`` every pixel is 0.

    **Arguments:**

    - `path`: output file, a `str` or `os.PathLike`; must end in ``.png``. Parent
      directories are created.
    - `array`: array-like of shape ``(rows, cols)``: finite values in any unit (e.g. a
      height map in metres), indexed ``[y, x]``.
    - `vmin`, `vmax`: optional floats, the data range to encode; default the minimum and
      maximum of `array`.

    **Returns:** ``(vmin, vmax)``, a tuple of floats: the range used, in the unit of
    `array`.

    **Raises:** `ValueError` for a bad `path` extension, a bad `array` (not 2-D, empty,
    NaN or infinite) or non-finite `vmin` / `vmax`, or ``vmin > vmax``.
    """
    p = _as_path(path, (".png",))
    arr = _as_image(array, "array", ndims=(2,))
    lo = _check_optional_scalar(vmin, "vmin", positive=False)
    hi = _check_optional_scalar(vmax, "vmax", positive=False)
    lo = float(arr.min()) if lo is None else lo
    hi = float(arr.max()) if hi is None else hi
    if lo > hi:
        raise ValueError(f"`vmin` ({lo}) must not exceed `vmax` ({hi})")
    if hi > lo:
        unit = np.clip((arr - lo) / (hi - lo), 0.0, 1.0)
    else:
        unit = np.zeros_like(arr)
    q = np.rint(unit * 65535).astype(np.uint16)
    _save_png(p, q)
    return lo, hi


# --------------------------------------------------------------------------- reading


def _to_gray(img: np.ndarray, p: Path, *, exr: bool) -> np.ndarray:
    if img.ndim == 2:
        return img
    c = img.shape[2]
    if c == 1 or (c == 2 and not exr):  # gray, gray + alpha (EXR: unknown channels)
        return img[:, :, 0]
    if c in (3, 4):  # RGB, RGBA: alpha dropped
        return img[:, :, :3] @ _LUMA.astype(img.dtype)
    raise ValueError(
        f"`as_gray`: cannot convert {c} channels of {str(p)!r} to gray; use as_gray=False"
    )


def read_image(path, *, as_gray: bool = True) -> np.ndarray:
    """Reads an image file as float32.

    **Arguments:**

    - `path`: a ``.png``, ``.jpg`` / ``.jpeg``, ``.tif`` / ``.tiff`` or ``.exr`` file, a
      `str` or `os.PathLike`.
    - `as_gray`: a bool; default True. If True, return a 2-D array: RGB(A) is converted to
      luminance with the Rec. 709 weights (``0.2125 R + 0.7154 G + 0.0721 B``; alpha is
      dropped), gray + alpha keeps the gray; an EXR must have one channel, or R, G, B (and
      A) by name. If False, the channels are returned as stored.

    **Returns:** a float32 `numpy.ndarray` of shape ``(rows, cols)`` or
    ``(rows, cols, C)``. Unsigned integer images (8- or 16-bit PNG, JPEG, TIFF) are scaled
    to ``[0, 1]`` (by 255 or 65535; signed integer TIFFs to ``[-1, 1]``); floating-point
    TIFF values unchanged; EXR values linear, as `read_exr`.

    **Raises:** `FileNotFoundError` if `path` does not exist; `ValueError` for an unknown
    extension, an unreadable or corrupt file, or one that is not a single picture
    (`jaxcaustics.io.probe.check_picture`, from the header, before any pixel is decoded):
    several pages or frames, over 8192^2 pixels, or (with `as_gray`) channels that are not
    gray, gray + alpha, RGB or RGBA (an EXR's by name: Y, or R, G, B and A).
    """
    p = _as_path(path, READ_EXTENSIONS)
    as_gray = check_bool(as_gray, "as_gray")
    _check_input_file(p)
    check_picture(p, as_gray=as_gray)  # from its header: one picture, sized, its channels
    if p.suffix.lower() == ".exr":
        img = read_exr(p)
    else:
        import imageio.v3 as iio
        import skimage.io
        import skimage.util

        try:
            raw = _read_png_16bit(p) if p.suffix.lower() == ".png" else None
            if raw is None and p.suffix.lower() in (".tif", ".tiff"):
                raw = read_tiff_page(p)  # (scikit-image's reader turned a 3 x 1 x 2 round)
            elif raw is None:
                # Pillow explicitly: imageio would otherwise try every legacy plugin on
                # a corrupt file.
                raw = iio.imread(p, plugin="pillow")
            raw = np.asarray(raw)
            if raw.dtype == object or raw.size == 0:
                raise ValueError(f"decoded to an unusable array (dtype {raw.dtype})")
            img = skimage.util.img_as_float(raw)
        except Exception as err:  # noqa: BLE001 - decoders raise many types
            raise ValueError(f"`path` {str(p)!r} is not a readable image: {err}") from err
        if img.ndim not in (2, 3):
            raise ValueError(
                f"`path` {str(p)!r} decoded to shape {img.shape}; expected a single image"
            )
    if as_gray:
        img = _to_gray(img, p, exr=p.suffix.lower() == ".exr")
    return np.asarray(img, dtype=np.float32)
