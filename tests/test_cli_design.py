"""``jaxcaustics design``: units, outputs, checkpoints and resume."""

import argparse

import numpy as np
import pytest
import trimesh

from jaxcaustics import read_exr
from jaxcaustics._cli import main
from jaxcaustics._cli_inverse import length

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
    # the Poisson start's coarse-to-fine levels are the rounds that are checkpointed (the
    # transport start is one round)
    args = [*ARGS, "--start", "poisson"]
    straight = tmp_path / "straight"
    assert main([*args, "--output", str(straight)]) == 0
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
    assert main([*args, "--output", str(resumed)]) == 130  # interrupted, checkpoint kept
    assert (resumed / "design.ckpt.npz").is_file() and not (resumed / "lens.stl").exists()
    assert main([*args, "--output", str(resumed), "--resume"]) == 0
    np.testing.assert_array_equal(
        read_exr(resumed / "lens_height.exr"), read_exr(straight / "lens_height.exr")
    )


def test_recover_rejects_bad_levels(tmp_path):
    assert main(["recover", "--levels", "1,2", "--output", str(tmp_path)]) == 2
    assert main(["recover", "--levels", "4,x", "--output", str(tmp_path)]) == 2


@pytest.mark.slow  # about 30 s, mostly compilation
def test_recover_without_target_recovers_the_built_in_sea(tmp_path):
    out = tmp_path / "recover"
    assert (
        main(
            ["recover", "--heights", "16", "--levels", "2,1", "--steps", "30", "--output", str(out)]
        )
        == 0
    )
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert summary["height_error"] < 1.0  # measured 0.41 after 2 x 30 steps
    assert read_exr(out / "heights.exr").shape == (16, 16)
