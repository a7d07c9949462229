"""Files written whole or not at all (`jaxcaustics.io.files`): a writer that fails
leaves the earlier file as it was and no temporary file beside it."""

import json

import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics.io import files


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_a_failed_write_leaves_the_earlier_file_and_nothing_else(tmp_path):
    path = tmp_path / "summary.json"
    files.write_json(path, {"run": 1})
    with pytest.raises(TypeError):  # `object()` is not JSON: fails after the file opened
        files.write_json(path, {"run": 2, "bad": object()})
    assert json.loads(path.read_text()) == {"run": 1}
    assert _listing(tmp_path) == ["summary.json"]


def test_the_temporary_file_keeps_the_suffix_a_writer_chooses_its_format_by(tmp_path):
    seen = []
    with files.written_whole(tmp_path / "plot.png") as tmp:
        seen.append(tmp)
        tmp.write_bytes(b"x")
    assert seen[0].suffix == ".png" and seen[0].parent == tmp_path
    assert _listing(tmp_path) == ["plot.png"]


@pytest.mark.parametrize("writer", ["png", "exr"])
def test_a_picture_that_fails_while_written_leaves_the_earlier_one(tmp_path, monkeypatch, writer):
    """The PNG and EXR writers wrote straight onto the file: an interrupt or a full disk
    mid-write left half a picture in place of the earlier one."""
    path = tmp_path / f"caustic.{writer}"
    earlier = np.linspace(0.0, 1.0, 64).reshape(8, 8)
    write = jc.write_png if writer == "png" else jc.io.write_exr
    write(path, earlier)
    before = path.read_bytes()

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    if writer == "png":
        import skimage.io

        monkeypatch.setattr(skimage.io, "imsave", full_disk)
    else:
        import OpenEXR

        monkeypatch.setattr(OpenEXR.File, "write", full_disk)
    with pytest.raises(OSError, match="No space"):
        write(path, 1.0 - earlier)
    assert path.read_bytes() == before and _listing(tmp_path) == [path.name]


def test_a_file_written_whole_has_the_permissions_open_would_give(tmp_path):
    """`mkstemp`'s owner-only mode is not left on a user's file (a design's files go to a
    workshop): the same mode as a file written with `open`."""
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    whole = tmp_path / "whole.json"
    files.write_json(whole, {"a": 1})
    assert whole.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777
