"""The ``jaxcaustics`` command: ``render water`` end to end, argument errors, --version."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics.cli.main import main

TINY = ["--size", "48x36"]  # 48 x 36 pixels over the default 4 x 3 m


def test_render_water_frames(tmp_path, capsys):
    out = tmp_path / "frames"
    assert main(["render", "water", *TINY, "--frames", "2", "--output", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "caustics_0000.exr",
        "caustics_0000.png",
        "caustics_0001.exr",
        "caustics_0001.png",
    ]
    frames = [jc.io.read_exr(out / f"caustics_{k:04d}.exr") for k in range(2)]
    for image in frames:
        assert image.shape == (36, 48) and image.dtype == np.float32
        assert np.all(np.isfinite(image)) and image.min() >= 0.0
        # Periodic sea, automatic window (no light missed), Fresnel off: every photon
        # lands in the image, so the mean relative irradiance is 1 up to float32 sums.
        assert image.mean() == pytest.approx(1.0, abs=1e-3)
        assert image.std() > 0.01  # the waves do focus light
    assert not np.array_equal(frames[0], frames[1])  # the sea moves between frames
    png = jc.read_image(out / "caustics_0000.png")
    assert png.shape == (36, 48) and png.max() > 0.5
    report = capsys.readouterr()
    assert "N = " in report.out and "M = " in report.out
    assert "missed flux" in report.out and "ms/frame" in report.out
    assert "caustics_0001.exr" in report.out
    assert "WARNING" not in report.err


def test_small_window_warns_about_missed_flux(tmp_path, capsys):
    argv = ["render", "water", "--size", "24x18", "--amplitude", "0.05", "--output", str(tmp_path)]
    assert main([*argv, "--samples-x", "1", "--channels-y", "0", "--exposure", "0.5"]) == 0
    report = capsys.readouterr()
    assert "N = 1" in report.out and "M = 0" in report.out
    assert "WARNING" in report.err and "--samples-x auto" in report.err
    assert jc.io.read_exr(tmp_path / "caustics_0000.exr").mean() < 0.99  # light was lost


# on request (slow), for the default run's 10-minute budget: dispersion and Fresnel
# are tested in test_twopass and test_effects; this runs them through the command line
@pytest.mark.slow
def test_dispersion_gives_colour_and_fresnel_loses_light(tmp_path):
    argv = ["render", "water", "--size", "24x18", "--output", str(tmp_path), "--quiet"]
    argv += ["--extent", "2x1.5", "--heightfield-size", "32x24", "--zenith", "0"]
    assert main([*argv, "--ior", "1.331,1.335,1.340", "--fresnel"]) == 0
    image = jc.io.read_exr(tmp_path / "caustics_0000.exr")
    assert image.shape == (18, 24, 3)
    # Fresnel reflects about 2% at near-normal incidence on water.
    assert np.all((image.mean(axis=(0, 1)) > 0.95) & (image.mean(axis=(0, 1)) < 0.995))
    assert jc.read_image(tmp_path / "caustics_0000.png", as_gray=False).shape == (18, 24, 3)


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["render"],
        ["render", "pool"],
        ["render", "water", "--size", "10"],
        ["render", "water", "--size", "1x10"],
        ["render", "water", "--extent", "4x-3"],
        ["render", "water", "--zenith", "95"],
        ["render", "water", "--depth", "0"],
        ["render", "water", "--amplitude", "nan"],
        ["render", "water", "--ior", "1.3,1.4"],
        ["render", "water", "--ior", "-1"],
        ["render", "water", "--samples-x", "6"],
        ["render", "water", "--channels-y", "3"],
        ["render", "water", "--frames", "0"],
        ["render", "water", "--bogus"],
        ["design", "--size", "0"],  # was an OverflowError traceback
        ["design", "--size", "12.5"],
    ],
)
def test_bad_arguments_exit_with_usage(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "error:" in capsys.readouterr().err


def test_errors_after_parsing_are_one_line(tmp_path, capsys, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert main(["render", "water", "--output", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert "cannot create the output directory" in err and "Traceback" not in err

    def bad_render(*args, **kwargs):
        raise ValueError("`heights` contains NaN or infinite values")

    monkeypatch.setattr(jc, "render", bad_render)
    assert main(["render", "water", *TINY, "--samples-x", "3", "--output", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "jaxcaustics: error: `heights` contains NaN or infinite values"


@pytest.mark.parametrize("target", ["data_dir", "file_hash", "stereo_motorcycle", "no_such"])
def test_a_design_target_that_is_not_a_picture_is_one_line(target, tmp_path, capsys):
    """Names in `skimage.data` that are not pictures (a folder name, a function of a
    file name, a tuple of frames) were a TypeError traceback."""
    assert main(["design", target, "--output", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "`TARGET`" in err and "Traceback" not in err


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"jaxcaustics {jc.__version__}"


def _console_script() -> list[str]:
    """The installed ``jaxcaustics`` script (next to this Python, or on PATH), else
    ``python -m jaxcaustics``."""
    local = Path(sys.executable).parent / "jaxcaustics"
    if local.exists():
        return [str(local)]
    found = shutil.which("jaxcaustics")
    return [found] if found else [sys.executable, "-m", "jaxcaustics"]


def test_console_script_renders(tmp_path):
    cmd = [*_console_script(), "render", "water", "--size", "16x12", "--output", str(tmp_path)]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "missed flux" in run.stdout
    assert jc.io.read_exr(tmp_path / "caustics_0000.exr").shape == (12, 16)
    run = subprocess.run(
        [sys.executable, "-m", "jaxcaustics", "--version"], capture_output=True, text=True
    )
    assert run.returncode == 0 and run.stdout.strip() == f"jaxcaustics {jc.__version__}"


ROOT = Path(__file__).resolve().parent.parent


def python_blocks(page: str) -> list[str]:
    """The ```python code blocks of `page` (a path from the repository root), in order."""
    text = (ROOT / page).read_text()
    return [block.split("```", 1)[0] for block in text.split("```python\n")[1:]]


def run_block(page: str, index: int) -> dict:
    """Run the `index`-th Python block of `page` in a fresh namespace and return it."""
    namespace: dict = {}
    exec(compile(python_blocks(page)[index], page, "exec"), namespace)
    return namespace


def test_readme_python_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = run_block("README.md", 0)
    assert namespace["image"].shape == (300, 400)
    assert float(namespace["stats"]["missed_flux_fraction"][0]) < 1e-6  # "(here none)"
    assert (tmp_path / "caustics.png").is_file()


def test_getting_started_sea_is_the_readme_example():
    """Getting started repeats the README's example (run above) word for word."""
    assert python_blocks("README.md")[0] in python_blocks("docs/getting-started.md")


def test_accuracy_guide_tolerance_example_runs(tmp_path, monkeypatch):
    """The `render(scene, tolerance=...)` example of docs/guides/accuracy.md (the README's
    sea)."""
    monkeypatch.chdir(tmp_path)
    namespace = run_block("docs/guides/accuracy.md", 0)
    choice = namespace["stats"]["choice"]
    assert choice.method == "twopass" and choice.expected_error * choice.margin <= 0.02
    assert namespace["image"].shape == (300, 400)


# 9 s (a lens and a glass ball rendered): on request, for the default run's time budget; the
# method's renders of both scene kinds are tested in test_triangles and
# test_triangles_reference
@pytest.mark.slow
def test_triangles_page_glass_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = run_block("docs/methods/triangles.md", 0)
    assert namespace["image"].shape == (128, 128)
    assert namespace["result"].image.shape == (64, 64)
    assert float(namespace["result"].image.max()) > 1.0  # the ball focuses light


@pytest.mark.slow
def test_design_guide_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = run_block("docs/guides/design.md", 0)
    assert (tmp_path / "lens" / "lens.stl").is_file()
    # the exported solid, rendered by the reference, is close to the target. Bound: the
    # 64 x 64 design's own error is about 0.05 (examples/design_lens.py: 0.049 at 32
    # photons per pixel side); verify_lens's default 512^2 photons (8 per pixel side) add
    # binning noise (0.062 there) and the flat facets of the solid add more
    assert namespace["check"].nominal < 0.1, namespace["check"]
