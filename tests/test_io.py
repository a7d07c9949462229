"""Image file I/O: EXR round trips, tone-mapped and linear 16-bit PNGs, errors."""

import struct
import zlib

import numpy as np
import pytest
import skimage.io
import tifffile

from jaxcaustics.io.images import (
    _read_png_16bit,
    read_exr,
    read_image,
    write_exr,
    write_png,
    write_png_linear16,
)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC (to build test files by hand)."""
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def _png_header(path):
    """(width, height, bit depth, colour type) from a PNG's IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">IIBB", data[16:26])


@pytest.fixture
def rng():
    return np.random.default_rng(0)


# --------------------------------------------------------------------------- EXR


def test_exr_round_trip_one_channel(tmp_path, rng):
    img = rng.normal(size=(7, 5)).astype(np.float32) * 1e3
    path = tmp_path / "sub" / "dir" / "y.exr"  # parent directories are created
    write_exr(path, img)
    out = read_exr(path)
    assert out.dtype == np.float32 and out.shape == (7, 5)
    np.testing.assert_array_equal(out, img)


def test_exr_round_trip_rgb(tmp_path, rng):
    img = rng.random((6, 9, 3)).astype(np.float32)
    write_exr(str(tmp_path / "rgb.exr"), img)
    out = read_exr(tmp_path / "rgb.exr")
    assert out.dtype == np.float32 and out.shape == (6, 9, 3)
    np.testing.assert_array_equal(out, img)  # R, G, B order kept (EXR stores B, G, R)


def test_exr_round_trip_many_channels_and_names(tmp_path, rng):
    img = rng.random((4, 3, 5)).astype(np.float32)
    write_exr(tmp_path / "c.exr", img)
    np.testing.assert_array_equal(read_exr(tmp_path / "c.exr"), img)
    # Custom names in an order that is not alphabetical come back in that order.
    two = rng.random((4, 3, 2))
    write_exr(tmp_path / "za.exr", two, channel_names=["Z", "A"])
    np.testing.assert_array_equal(read_exr(tmp_path / "za.exr"), two.astype(np.float32))
    one = rng.random((4, 3, 1)).astype(np.float32)
    write_exr(tmp_path / "one.exr", one)
    assert read_exr(tmp_path / "one.exr").shape == (4, 3, 1)


def test_exr_float64_input_and_read_image(tmp_path):
    img = np.linspace(0.0, 5.0, 12).reshape(3, 4)  # float64, values above 1 kept
    write_exr(tmp_path / "d.exr", img)
    np.testing.assert_array_equal(read_image(tmp_path / "d.exr"), img.astype(np.float32))
    rgb = np.stack([img, 2 * img, 3 * img], axis=-1)
    write_exr(tmp_path / "rgb.exr", rgb)
    gray = read_image(tmp_path / "rgb.exr", as_gray=True)
    np.testing.assert_allclose(gray, rgb @ [0.2125, 0.7154, 0.0721], rtol=1e-6)
    assert read_image(tmp_path / "rgb.exr", as_gray=False).shape == (3, 4, 3)


@pytest.mark.parametrize(
    ("image", "kwargs", "match"),
    [
        (np.zeros((0, 4)), {}, "`image` is empty"),
        (np.zeros((3, 4, 0)), {}, "`image` is empty"),
        (np.zeros(5), {}, "`image` must be 2-D or 3-D"),
        (np.zeros((2, 2, 2, 2)), {}, "`image` must be 2-D or 3-D"),
        (np.array([[1.0, np.nan]]), {}, "`image` contains NaN"),
        (np.array([[1.0, np.inf]]), {}, "`image` contains NaN or infinite"),
        (np.array([[1e300]]), {}, "`image` has values outside the float32"),
        (np.array([["a"]]), {}, "`image` must hold real numbers"),
        (np.zeros((2, 2, 2)), {"channel_names": ["A"]}, "`channel_names` must give 2"),
        (np.zeros((2, 2, 2)), {"channel_names": ["A", "A"]}, "`channel_names` must be distinct"),
        (np.zeros((2, 2, 2)), {"channel_names": "AB"}, "`channel_names` must be a sequence"),
        (np.zeros((2, 2, 2)), {"channel_names": ["A", ""]}, "`channel_names` must be non-empty"),
    ],
)
def test_write_exr_bad_input(tmp_path, image, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_exr(tmp_path / "x.exr", image, **kwargs)
    assert not (tmp_path / "x.exr").exists()


def test_exr_bad_paths(tmp_path):
    with pytest.raises(ValueError, match=r"`path` must end in \.exr"):
        write_exr(tmp_path / "x.png", np.zeros((2, 2)))
    with pytest.raises(ValueError, match="`path` must be a str"):
        write_exr(3, np.zeros((2, 2)))
    with pytest.raises(FileNotFoundError, match="missing.exr"):
        read_exr(tmp_path / "missing.exr")
    (tmp_path / "d.exr").mkdir()
    with pytest.raises(ValueError, match=r"d\.exr.*is a directory"):
        write_exr(tmp_path / "d.exr", np.zeros((2, 2)))


def test_corrupt_exr(tmp_path, rng):
    bad = tmp_path / "x.exr"
    bad.write_bytes(rng.bytes(2000))
    with pytest.raises(ValueError, match=r"x\.exr.*not an OpenEXR file"):
        read_exr(bad)
    with pytest.raises(ValueError, match=r"x\.exr"):
        read_image(bad)
    # A valid header followed by truncated pixel data.
    good = tmp_path / "good.exr"
    write_exr(good, rng.random((64, 64)))
    data = good.read_bytes()
    cut = tmp_path / "cut.exr"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut\.exr.*not a readable OpenEXR image"):
        read_exr(cut)


# --------------------------------------------------------------------------- tone-mapped PNG


@pytest.mark.parametrize(("bit_depth", "dtype"), [(8, np.uint8), (16, np.uint16)])
def test_write_png_gray_ramp(tmp_path, bit_depth, dtype):
    ramp = np.tile(np.linspace(0.0, 3.0, 200), (4, 1))  # (4, 200)
    path = tmp_path / "out" / "ramp.png"
    write_png(path, ramp, bit_depth=bit_depth)
    assert _png_header(path)[2:] == (bit_depth, 0)  # grayscale
    raw = skimage.io.imread(path)
    assert raw.dtype == dtype and raw.shape == (4, 200)
    top = np.iinfo(dtype).max
    assert raw[0, 0] == 0 and raw[0, -1] == top  # the 99.5th percentile and above are white
    assert np.all(np.diff(raw[0].astype(np.int64)) >= 0)  # monotone
    # Below the clipping point: the gamma curve (v / high) ** (1 / 2.2).
    high = np.percentile(ramp, 99.5)
    expected = np.rint(np.clip(ramp[0] / high, 0, 1) ** (1 / 2.2) * top)
    np.testing.assert_array_equal(raw[0], expected)


def test_write_png_rgb_8_and_16(tmp_path, rng):
    img = rng.random((5, 6, 3))
    write_png(tmp_path / "a.png", img, exposure=1.0, gamma=1.0)
    raw8 = skimage.io.imread(tmp_path / "a.png")
    assert raw8.dtype == np.uint8 and raw8.shape == (5, 6, 3)
    np.testing.assert_array_equal(raw8, np.rint(img * 255))
    write_png(tmp_path / "b.png", img, exposure=1.0, gamma=1.0, bit_depth=16)
    assert _png_header(tmp_path / "b.png")[2:] == (16, 2)  # 16-bit RGB really written
    raw16 = _read_png_16bit(tmp_path / "b.png")
    assert raw16.dtype == np.uint16
    np.testing.assert_array_equal(raw16, np.rint(img * 65535))
    # read_image keeps all 16 bits (Pillow alone would truncate RGB to 8).
    np.testing.assert_allclose(read_image(tmp_path / "b.png", as_gray=False), img, atol=1e-5)
    # An independent decoder agrees on the high bytes.
    np.testing.assert_array_equal(skimage.io.imread(tmp_path / "b.png"), raw16 >> 8)


def test_write_png_exposure_single_channel_and_black(tmp_path):
    img = np.full((3, 3, 1), 0.5)
    write_png(tmp_path / "e.png", img, exposure=4.0)  # 0.5 * 4 clips to white
    raw = skimage.io.imread(tmp_path / "e.png")
    assert raw.shape == (3, 3) and np.all(raw == 255)
    write_png(tmp_path / "z.png", np.zeros((3, 3)))  # all black stays black
    assert np.all(skimage.io.imread(tmp_path / "z.png") == 0)


@pytest.mark.parametrize(
    ("image", "kwargs", "match"),
    [
        (-np.ones((3, 3)), {}, "`image` has negative values"),
        (np.array([[0.0, np.nan]]), {}, "`image` contains NaN"),
        (np.array([[0.0, -np.inf]]), {}, "`image` contains NaN or infinite"),
        (np.zeros((0, 3)), {}, "`image` is empty"),
        (np.zeros(3), {}, "`image` must be 2-D or 3-D"),
        (np.zeros((3, 3, 2)), {}, "`image` must have 1 or 3 channels"),
        (np.zeros((3, 3, 4)), {}, "`image` must have 1 or 3 channels"),
        (np.ones((3, 3)), {"bit_depth": 12}, "`bit_depth` must be 8 or 16"),
        (np.ones((3, 3)), {"exposure": 0.0}, "`exposure` must be positive"),
        (np.ones((3, 3)), {"exposure": np.nan}, "`exposure` must be finite"),
        (np.ones((3, 3)), {"gamma": -1.0}, "`gamma` must be positive"),
        (np.ones((3, 3)), {"gamma": None}, "`gamma` must be a positive number"),
    ],
)
def test_write_png_bad_input(tmp_path, image, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_png(tmp_path / "x.png", image, **kwargs)
    assert not (tmp_path / "x.png").exists()


def test_write_png_bad_extension(tmp_path):
    with pytest.raises(ValueError, match=r"`path` must end in \.png.*'\.jpg'"):
        write_png(tmp_path / "x.jpg", np.ones((2, 2)))


# --------------------------------------------------------------------------- linear 16-bit


def test_png_linear16_round_trip(tmp_path, rng):
    heights = rng.normal(scale=0.01, size=(9, 11))
    path = tmp_path / "h.png"
    vmin, vmax = write_png_linear16(path, heights)
    assert (vmin, vmax) == (heights.min(), heights.max())
    assert _png_header(path)[2:] == (16, 0)
    assert skimage.io.imread(path).dtype == np.uint16
    back = vmin + read_image(path).astype(np.float64) * (vmax - vmin)
    step = (vmax - vmin) / 65535
    assert np.max(np.abs(back - heights)) <= 0.5 * step * (1 + 1e-3)


def test_png_linear16_explicit_range_clips_and_constant(tmp_path):
    arr = np.array([[-1.0, 0.0, 0.5, 1.0, 2.0]])
    assert write_png_linear16(tmp_path / "a.png", arr, vmin=0.0, vmax=1.0) == (0.0, 1.0)
    raw = skimage.io.imread(tmp_path / "a.png")
    np.testing.assert_array_equal(raw, [[0, 0, 32768, 65535, 65535]])
    assert write_png_linear16(tmp_path / "c.png", np.full((2, 2), 3.0)) == (3.0, 3.0)
    assert np.all(skimage.io.imread(tmp_path / "c.png") == 0)


@pytest.mark.parametrize(
    ("array", "kwargs", "match"),
    [
        (np.zeros((2, 2, 3)), {}, "`array` must be 2-D"),
        (np.zeros((0, 2)), {}, "`array` is empty"),
        (np.array([[0.0, np.nan]]), {}, "`array` contains NaN"),
        (np.ones((2, 2)), {"vmin": 1.0, "vmax": 0.0}, "`vmin`.*must not exceed `vmax`"),
        (np.ones((2, 2)), {"vmax": np.inf}, "`vmax` must be finite"),
        (np.ones((2, 2)), {"vmin": "low"}, "`vmin` must be a number"),
    ],
)
def test_png_linear16_bad_input(tmp_path, array, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_png_linear16(tmp_path / "x.png", array, **kwargs)


# --------------------------------------------------------------------------- reading


def test_read_image_png_gray_and_rgb(tmp_path):
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[..., 0] = 255
    rgb[1, :, 1] = 51
    skimage.io.imsave(tmp_path / "c.png", rgb, check_contrast=False)
    full = read_image(tmp_path / "c.png", as_gray=False)
    assert full.dtype == np.float32 and full.shape == (2, 3, 3)
    np.testing.assert_allclose(full, rgb / 255.0, atol=1e-7)
    gray = read_image(tmp_path / "c.png")
    assert gray.shape == (2, 3)
    np.testing.assert_allclose(gray, (rgb / 255.0) @ [0.2125, 0.7154, 0.0721], atol=1e-6)
    rgba = np.concatenate([rgb, np.full((2, 3, 1), 7, np.uint8)], axis=-1)
    skimage.io.imsave(tmp_path / "a.png", rgba, check_contrast=False)
    np.testing.assert_allclose(read_image(tmp_path / "a.png"), gray, atol=1e-6)  # alpha dropped


def test_read_image_tiff_and_jpeg(tmp_path):
    ramp = np.linspace(0, 65535, 20).astype(np.uint16).reshape(5, 4)
    # gray, said so: scikit-image's imsave writes an array whose last side is 3 or 4 as
    # one row of RGB(A) pixels, which is what its header then says
    tifffile.imwrite(tmp_path / "r.tif", ramp, photometric="minisblack")
    np.testing.assert_allclose(read_image(tmp_path / "r.tif"), ramp / 65535.0, atol=1e-7)
    flat = np.full((8, 8), 128, np.uint8)
    skimage.io.imsave(tmp_path / "f.jpg", flat, check_contrast=False)
    np.testing.assert_allclose(read_image(tmp_path / "f.jpg"), 128 / 255.0, atol=2 / 255)


def test_read_png_16bit_all_filters(tmp_path, rng):
    """The 16-bit colour decoder (imagecodecs) against a file written by hand, using
    every PNG filter type."""
    q = rng.integers(0, 65536, size=(7, 5, 4)).astype(np.uint16)  # RGBA
    rows, cols, ch = q.shape
    bpp = 2 * ch
    raw = q.astype(">u2").view(np.uint8).reshape(rows, cols * bpp).astype(np.int64)
    lines, zero = [], np.zeros(bpp, np.int64)
    for i in range(rows):
        x = raw[i]
        up = raw[i - 1] if i else np.zeros_like(x)
        left = np.concatenate([zero, x[:-bpp]])
        up_left = np.concatenate([zero, up[:-bpp]])
        pa, pb, pc = abs(up - up_left), abs(left - up_left), abs(left + up - 2 * up_left)
        paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, up_left))
        kind = i % 5
        pred = [0 * x, left, up, (left + up) // 2, paeth][kind]
        lines.append(bytes([kind]) + ((x - pred) % 256).astype(np.uint8).tobytes())
    ihdr = struct.pack(">IIBBBBB", cols, rows, 16, 6, 0, 0, 0)
    png = (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", ihdr)
        + _png_chunk(b"IDAT", zlib.compress(b"".join(lines)))
        + _png_chunk(b"IEND", b"")
    )
    (tmp_path / "f.png").write_bytes(png)
    np.testing.assert_array_equal(_read_png_16bit(tmp_path / "f.png"), q)
    np.testing.assert_array_equal(skimage.io.imread(tmp_path / "f.png"), q >> 8)


def test_read_image_errors(tmp_path, rng):
    with pytest.raises(FileNotFoundError, match=r"nope\.png"):
        read_image(tmp_path / "nope.png")
    with pytest.raises(ValueError, match=r"`path` must end in .*'\.bmp'"):
        read_image(tmp_path / "x.bmp")
    bad = tmp_path / "bad.png"
    bad.write_bytes(rng.bytes(500))
    with pytest.raises(ValueError, match=r"bad\.png.*not a readable image"):
        read_image(bad)
    fake = tmp_path / "fake.jpg"
    fake.write_bytes(b"not a jpeg at all")
    with pytest.raises(ValueError, match=r"fake\.jpg.*not a readable image"):
        read_image(fake)
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(ValueError, match=r"dir\.png.*not a regular file"):
        read_image(tmp_path / "dir.png")
    for c in (2, 5):
        write_exr(tmp_path / f"m{c}.exr", rng.random((2, 2, c)))
        # refused from the header, naming the file and its channels
        with pytest.raises(ValueError, match=rf"m{c}\.exr.*{c} channel.*not a picture's"):
            read_image(tmp_path / f"m{c}.exr")
        assert read_image(tmp_path / f"m{c}.exr", as_gray=False).shape == (2, 2, c)


def test_read_image_keeps_16_bits_of_a_large_colour_png(tmp_path, rng):
    """A 512 x 512 16-bit RGB PNG round trip keeps every bit (the decoder is compiled:
    the hand-written one it replaced looped over the pixels of each filtered row)."""
    img = rng.integers(0, 65536, size=(512, 512, 3)).astype(np.uint16)
    write_png(tmp_path / "big.png", img / 65535.0, exposure=1.0, gamma=1.0, bit_depth=16)
    assert _png_header(tmp_path / "big.png")[2:] == (16, 2)
    np.testing.assert_array_equal(_read_png_16bit(tmp_path / "big.png"), img)
    back = read_image(tmp_path / "big.png", as_gray=False)
    np.testing.assert_allclose(back, img / 65535.0, atol=1e-7)
