"""Smoke tests of the paper-figure scripts (``--quick``: tiny sizes, seconds)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import jaxcaustics as jc

FIGURES = Path(__file__).resolve().parent.parent / "paper_figures"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"paper_figure_{name}", FIGURES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _assert_picture(path: Path, min_shape=(8, 8)):
    assert path.is_file() and path.stat().st_size > 500
    image = jc.read_image(path)
    assert image.shape[0] >= min_shape[0] and image.shape[1] >= min_shape[1]
    assert image.std() > 0.02  # not blank: caustics (or axes and colour bars) are drawn


def test_fig2_quick(tmp_path, capsys):
    assert _load("fig2_caustics_map").main(["--quick", "--output", str(tmp_path)]) == 0
    caustics = jc.read_image(tmp_path / "fig2_caustics_map.png")
    assert caustics.shape == (60, 80)
    _assert_picture(tmp_path / "fig2_caustics_map.png")
    _assert_picture(tmp_path / "fig2_height_and_caustics.png", min_shape=(200, 400))
    out = capsys.readouterr().out
    assert "N = 7, M = 6" in out and "WARNING" not in out
    assert str(tmp_path / "fig2_caustics_map.png") in out


def test_fig7_quick(tmp_path, capsys):
    assert _load("fig7_animated_frames").main(["--quick", "--output", str(tmp_path)]) == 0
    frames = [jc.read_image(tmp_path / f"fig7_frame_{k:04d}.png") for k in range(2)]
    assert all(f.shape == (30, 40) for f in frames)
    assert not np.array_equal(frames[0], frames[1])  # the water moved
    for k in range(2):
        _assert_picture(tmp_path / f"fig7_frame_{k:04d}.png")
    _assert_picture(tmp_path / "fig7_animated_frames.png", min_shape=(200, 400))
    out = capsys.readouterr().out
    assert "ms per frame" in out and "WARNING" not in out


@pytest.mark.parametrize("name", ["fig2_caustics_map", "fig7_animated_frames"])
def test_help(name, capsys):
    with pytest.raises(SystemExit) as exc:
        _load(name).main(["--help"])
    assert exc.value.code == 0
    assert "--quick" in capsys.readouterr().out
