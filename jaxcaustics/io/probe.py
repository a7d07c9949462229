"""What an image file holds, read from its header before anything is decoded: its size,
its channels and its pages (`probe_image`), and whether that is a picture
`read_image` takes (`check_picture`).

A picture is one image (one page, one frame) of at most `MAX_READ_PIXELS` pixels, with
1 (gray), 2 (gray + alpha), 3 (RGB) or 4 (RGBA) channels; an EXR's channels must say
so by name (``Y`` or any single channel; ``R, G, B`` and ``A``). Anything else is a
`ValueError` naming the file and what it holds: a stack of frames, a depth / id / mask
EXR, a header that declares gigapixels (refused before its pixels are decoded).

The headers are read by the decoders' own lazy openers (Pillow's `Image.open`,
tifffile's `TiffFile`, OpenEXR's ``header_only``), which read no pixels; PNG's ``IHDR``
is read directly, as Pillow does.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from pathlib import Path

import numpy as np

MAX_READ_PIXELS = 8192 * 8192  # a 24-megapixel photo passes; 20000^2 does not
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour types -> channels as decoded (a palette: RGB, or RGBA with transparency)
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}
_PIL_CHANNELS = {"1": 1, "L": 1, "P": 3, "I": 1, "F": 1, "LA": 2, "RGB": 3, "RGBA": 4}
_PIL_CHANNELS |= {"I;16": 1, "I;16B": 1, "I;16L": 1, "PA": 4}  # CMYK, YCbCr, ...: 0
_EXR_COLOUR = (["R", "G", "B"], ["R", "G", "B", "A"])
_TIFF_PLANE = "YXS"  # tifffile's axes of one picture: rows, columns, samples


@dataclasses.dataclass(frozen=True)
class ImageHeader:
    """What `probe_image` found: ``rows x cols`` pixels, `channels` per pixel (their
    `names` for an EXR), `pages` (frames, pages or parts)."""

    rows: int
    cols: int
    channels: int
    pages: int = 1
    names: tuple[str, ...] = ()
    mode: str = ""  # Pillow's, where it read the header

    def describe(self) -> str:
        names = f" ({', '.join(self.names)})" if self.names else ""
        names += f" (mode {self.mode})" if self.mode else ""
        pages = f", {self.pages} pages" if self.pages != 1 else ""
        return f"{self.cols} x {self.rows} pixels, {self.channels} channel(s){names}{pages}"


def probe_image(p: Path) -> ImageHeader:
    """The header of the image file `p` (PNG, JPEG, TIFF or EXR), no pixels decoded;
    a `ValueError` naming `p` if it cannot be read."""
    suffix = p.suffix.lower()
    try:
        if suffix == ".png":
            with open(p, "rb") as f:
                head = f.read(26)
            if head[:8] == _PNG_SIGNATURE and head[12:16] == b"IHDR" and len(head) == 26:
                cols, rows = struct.unpack(">II", head[16:24])
                return ImageHeader(rows, cols, _PNG_CHANNELS.get(head[25], 0))
            raise ValueError("not a PNG file (no PNG signature and IHDR)")
        if suffix in (".tif", ".tiff"):
            return _probe_tiff(p)
        if suffix == ".exr":
            return _probe_exr(p)
        import PIL.Image

        with PIL.Image.open(p) as im:
            cols, rows = im.size
            # (a JPEG's further frames, a phone's MPO, are previews and depth maps of
            # the one picture, which is decoded: one page)
            return ImageHeader(rows, cols, _PIL_CHANNELS.get(im.mode, 0), 1, (), im.mode)
    except ValueError as err:
        raise ValueError(f"`path` {str(p)!r} is not a readable image: {err}") from err
    except Exception as err:  # noqa: BLE001 - the decoders raise many types
        raise ValueError(f"`path` {str(p)!r} is not a readable image: {err}") from err


def _probe_tiff(p: Path) -> ImageHeader:
    import tifffile

    with tifffile.TiffFile(p) as tif:
        series = tif.series[0]
        size = dict(zip(series.axes, (int(n) for n in series.shape), strict=True))
        stacked = math.prod(n for a, n in size.items() if a not in _TIFF_PLANE)
        pages = max(len(tif.pages), stacked)
    return ImageHeader(size.get("Y", 1), size.get("X", 1), size.get("S", 1), pages)


def read_tiff_page(p: Path):
    """The picture of the TIFF `p` as ``(rows, cols)`` or ``(rows, cols, channels)``,
    laid out by its first series' axes (tifffile: ``Y`` rows, ``X`` columns, ``S``
    samples), so that no axis of size 1 is squeezed or taken for another (scikit-image's
    reader turned a 3 x 1 x 2 image into 2 x 3); other axes must be of size 1
    (`check_picture` refuses stacks first)."""
    import tifffile

    with tifffile.TiffFile(p) as tif:
        series = tif.series[0]
        data, axes = np.asarray(series.asarray()), series.axes
    for axis in _TIFF_PLANE:
        if axis not in axes:
            data, axes = data[..., None], axes + axis
    data = np.moveaxis(data, [axes.index(a) for a in _TIFF_PLANE], [-3, -2, -1])
    data = data.reshape(*data.shape[-3:])
    return data[..., 0] if data.shape[-1] == 1 else data


def _probe_exr(p: Path) -> ImageHeader:
    import OpenEXR

    if not OpenEXR.isOpenExrFile(str(p)):
        raise ValueError("not an OpenEXR file")
    with OpenEXR.File(str(p), header_only=True) as f:
        header = f.header()
        (x0, y0), (x1, y1) = header["dataWindow"]
        names = tuple(str(c.name) for c in header["channels"])
    return ImageHeader(int(y1 - y0 + 1), int(x1 - x0 + 1), len(names), 1, names)


def check_picture(p: Path, *, as_gray: bool) -> ImageHeader:
    """`probe_image(p)`, or a `ValueError` naming `p` and what it holds when it is not
    one picture `read_image` takes: several pages, over `MAX_READ_PIXELS`, no pixels,
    or (for `as_gray`) channels that are not a picture's."""
    header = probe_image(p)
    found = f"`path` {str(p)!r} holds {header.describe()}"
    if header.pages > 1:
        raise ValueError(f"{found}: a stack of frames, not one picture (one image a file)")
    if header.rows < 1 or header.cols < 1:
        raise ValueError(f"{found}: no pixels")
    if header.rows * header.cols > MAX_READ_PIXELS:
        raise ValueError(
            f"{found}: over {MAX_READ_PIXELS} pixels (8192^2), not decoded; resize it first"
        )
    if not as_gray:
        return header
    if header.names:
        colour = sorted(header.names) in (sorted(c) for c in _EXR_COLOUR)
        if len(header.names) != 1 and not colour:
            raise ValueError(
                f"{found}: not a picture's channels (Y, or R, G, B and A): read it with "
                "as_gray=False, or `read_exr`"
            )
    elif not 1 <= header.channels <= 4:
        raise ValueError(f"{found}: a picture has 1 (gray), 2 (gray + alpha), 3 (RGB) or 4 (RGBA)")
    return header
