"""``jaxcaustics design``: units, outputs, checkpoints and resume."""

import argparse

import numpy as np
import pytest
import trimesh

from jaxcaustics import read_exr
from jaxcaustics._cli import main
from jaxcaustics._cli_design import length

ARGS = ["design", "--size", "16", "--levels", "8,16", "--steps", "3", "--width", "80mm"]


def test_lengths_take_units():
    assert length("100mm") == pytest.approx(0.1)
    assert length("0.5m") == pytest.approx(0.5)
    assert length("50cm") == pytest.approx(0.5)
    assert length("20") == pytest.approx(0.02)  # bare numbers are millimetres
    for bad in ("-1mm", "0mm", "ten", "5in"):
        with pytest.raises(argparse.ArgumentTypeError):
            length(bad)


def test_bad_specifications_fail_before_designing(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["design", "--thickness", "-2mm", "--output", str(tmp_path)])
    assert exit_info.value.code == 2
    assert main(["design", "no-such-picture", "--output", str(tmp_path)]) == 2
    assert "TARGET" in capsys.readouterr().err
    assert main(["design", "--levels", "8,x", "--output", str(tmp_path)]) == 2


@pytest.mark.slow  # two small designs, about a minute (mostly compilation)
def test_design_writes_a_millable_lens_and_resumes_to_the_same_result(tmp_path, monkeypatch):
    straight = tmp_path / "straight"
    assert main([*ARGS, "--output", str(straight)]) == 0
    solid = trimesh.load(straight / "lens.stl")
    assert solid.is_watertight
    assert solid.extents[0] == pytest.approx(80.0, rel=1e-6)  # millimetres
    for name in (
        "lens.obj",
        "lens_height.png",
        "lens_height.exr",
        "predicted.png",
        "loss.png",
        "lens_report.txt",
        "summary.json",
    ):
        assert (straight / name).is_file()

    import jaxcaustics._inverse.design as design_module

    original = design_module.design_lens
    calls = {"n": 0}

    def ctrl_c_in_level_two(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    resumed = tmp_path / "resumed"
    monkeypatch.setattr(design_module, "design_lens", ctrl_c_in_level_two)
    assert main([*ARGS, "--output", str(resumed)]) == 130  # interrupted, checkpoint kept
    assert (resumed / "design.ckpt.npz").is_file() and not (resumed / "lens.stl").exists()
    assert main([*ARGS, "--output", str(resumed), "--resume"]) == 0
    np.testing.assert_array_equal(
        read_exr(resumed / "lens_height.exr"), read_exr(straight / "lens_height.exr")
    )
