"""`read_image` takes one picture and refuses anything else by the file's name, from its
header: stacks of frames, channel sets that are not a picture's, gigapixel headers."""

import struct
import zlib

import imagecodecs
import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from jaxcaustics.io.images import read_image, write_exr

EXR_NAMES = ["Y", "R", "G", "B", "A", "Z", "depth", "id", "mask"]


def _write(path, kind, data, pages, names):
    """`data` ``(pages, rows, cols, channels)`` written as `kind`."""
    if kind.startswith("png"):
        page = data[0, ..., 0] if data.shape[-1] == 1 else data[0]
        path.write_bytes(imagecodecs.png_encode(page))
    elif kind.startswith("tiff"):
        with tifffile.TiffWriter(path) as tif:
            for page in data:
                rgb = page.shape[-1] in (3, 4)
                tif.write(
                    page if page.shape[-1] > 1 else page[..., 0],
                    photometric="rgb" if rgb else "minisblack",
                    planarconfig="contig",
                    extrasamples=("unassalpha",) if page.shape[-1] == 4 else None,
                )
    else:
        write_exr(path, data[0], channel_names=names)


def _expected(kind, data):
    if kind.endswith("8"):
        return data[0] / 255.0
    if kind.endswith("16"):
        return data[0] / 65535.0
    return data[0].astype(np.float32)


@st.composite
def pictures(draw):
    kind = draw(st.sampled_from(["png8", "png16", "tiff8", "tiff16", "tifff", "exr"]))
    channels = draw(st.integers(1, 4 if kind.startswith("png") else 5))
    pages = draw(st.integers(1, 3)) if kind.startswith("tiff") else 1
    rows, cols = draw(st.integers(1, 9)), draw(st.integers(1, 9))
    names = None
    if kind == "exr":
        names = draw(st.lists(st.sampled_from(EXR_NAMES), min_size=channels,
                              max_size=channels, unique=True))  # fmt: skip
    dtype = np.uint8 if kind.endswith("8") else np.uint16 if kind.endswith("16") else np.float32
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    shape = (pages, rows, cols, channels)
    if dtype is np.float32:
        data = rng.uniform(0.0, 4.0, shape).astype(np.float32)
    else:
        data = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    return kind, data, names


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(picture=pictures(), as_gray=st.booleans())
@example(  # found by Hypothesis: a 3 x 1 TIFF of two samples was read as 2 x 3
    picture=("tiff8", np.arange(6, dtype=np.uint8).reshape(1, 3, 1, 2), None), as_gray=False
)
def test_a_file_is_read_as_written_or_refused_naming_it(tmp_path, picture, as_gray):
    kind, data, names = picture
    pages, rows, cols, channels = data.shape
    path = tmp_path / ("image." + {"p": "png", "t": "tiff", "e": "exr"}[kind[0]])
    _write(path, kind, data, pages, names)
    if kind == "exr":
        picture_channels = channels == 1 or sorted(names) in (["B", "G", "R"], ["A", "B", "G", "R"])
    else:
        picture_channels = channels <= 4
    ok = pages == 1 and (picture_channels or not as_gray)
    if not ok:
        with pytest.raises(ValueError, match=str(path)):
            read_image(path, as_gray=as_gray)
        return
    image = read_image(path, as_gray=as_gray)
    want = _expected(kind, data)
    if as_gray:
        assert image.shape == (rows, cols)
        if channels <= 2:  # gray (+ alpha): the gray itself
            np.testing.assert_allclose(image, want[..., 0], rtol=1e-6, atol=1e-6)
        return
    if kind == "exr" and channels > 1:  # stored in `write_exr`'s order, which it keeps
        np.testing.assert_allclose(image, want, rtol=1e-6)
        return
    np.testing.assert_allclose(np.squeeze(image), np.squeeze(want), rtol=1e-6, atol=1e-6)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def test_a_gigapixel_header_is_refused_before_decoding(tmp_path):
    """A 16-bit PNG that declares 20000 x 20000 pixels (3.2 GB decoded) and holds a few
    bytes: refused from its header, naming the file and the size it declares."""
    ihdr = struct.pack(">IIBBBBB", 20000, 20000, 16, 0, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr)
    data += _chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + _chunk(b"IEND", b"")
    path = tmp_path / "huge.png"
    path.write_bytes(data)
    with pytest.raises(ValueError, match=r"huge\.png.*20000 x 20000 pixels.*not decoded"):
        read_image(path)


def test_data_channels_and_stacks_are_not_pictures(tmp_path):
    path = tmp_path / "buffers.exr"
    write_exr(path, np.ones((4, 5, 3), np.float32), channel_names=["depth", "id", "mask"])
    with pytest.raises(ValueError, match=r"depth, id, mask.*not a picture's channels"):
        read_image(path)
    assert read_image(path, as_gray=False).shape == (4, 5, 3)  # as data, it reads
    stack = tmp_path / "frames.tif"
    tifffile.imwrite(stack, np.zeros((3, 8, 8), np.uint8), photometric="minisblack")
    with pytest.raises(ValueError, match=r"frames\.tif.*3 pages.*stack of frames"):
        read_image(stack)
