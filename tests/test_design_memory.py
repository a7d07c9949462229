"""A design's memory: estimated before anything is compiled and kept under
`memory_limit` (by default half of the machine's), its predicted caustic traced in bands
of photon rows when the photons do not fit at once (the same image and the same gradient
as one trace)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcaustics as jc
import jaxcaustics.inverse.design as design_module
from jaxcaustics.inverse import lens_setup
from jaxcaustics.inverse.prediction import predict_caustic
from jaxcaustics.methods.triangles.method import band_bytes, caustic_triangles

PROBLEM = jc.DesignProblem(jc.Lens(thickness=0.02), jc.Rectangle(0.1, 0.1), jc.Screen(distance=0.5))


def blob(n=16):
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    return 0.3 + np.exp(-((xx - 0.35) ** 2 + (yy - 0.4) ** 2) / 0.02)


def bump(shape):
    """A smooth relief of a few tenths of a millimetre: a caustic with bright and dim
    regions."""
    y, x = (np.linspace(-1.0, 1.0, n) for n in shape)
    xx, yy = np.meshgrid(x, y)
    return -3e-4 * np.exp(-((xx - 0.2) ** 2 + (yy + 0.1) ** 2) / 0.3)


def test_the_predicted_caustic_in_bands_is_the_one_trace():
    setup = lens_setup.prepare(PROBLEM, blob(), jc.TransportStart(grid=24), None)
    h = bump(setup.shapes[-1])
    whole, missed, window, _ = predict_caustic(setup, h)
    n = 4 * 16 + 1
    # room for 8 photon rows at a time, not for the 65^2 photons at once
    small = 2 * 8 * band_bytes(n, 1, jnp.result_type(float))
    assert band_bytes(n * n, 1, jnp.result_type(float)) > small // 2
    banded, banded_missed, banded_window, _ = predict_caustic(
        dataclasses.replace(setup, memory_limit=small), h
    )
    assert banded_window == 16 and window <= 16
    scale = float(np.abs(whole).max())
    assert scale > 0 and float(np.std(whole / whole.mean())) > 0.05  # not a flat image
    # the same triangles, drawn in another order (float64 here)
    np.testing.assert_allclose(banded, whole, rtol=0, atol=1e-10 * scale)
    assert abs(banded_missed - missed) < 1e-10


def test_banded_triangles_have_the_one_band_gradient():
    """What the design's finish differentiates: the gradient of an image misfit with
    respect to the heights, in bands (a checkpointed scan) and at once."""
    setup = lens_setup.prepare(PROBLEM, blob(8), jc.TransportStart(grid=8), None)
    h0 = jnp.asarray(bump(setup.shapes[-1]))
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(8, 8)))
    n = 17
    limit = 2 * 4 * band_bytes(n, 1, jnp.float64)  # four photon rows a band

    def misfit(h, memory_limit):
        scene = setup.element_scene(h)
        result = caustic_triangles(scene, photons=n, window=4, memory_limit=memory_limit)
        assert result.stats["bands"] == (1 if memory_limit is None else 6)
        image = result.image
        return jnp.sum(weights * image / jnp.mean(image))

    gradient = jax.jit(jax.grad(misfit), static_argnums=1)  # jitted: 6 s, eagerly 11 s
    whole = gradient(h0, None)
    banded = gradient(h0, limit)
    assert float(jnp.max(jnp.abs(whole))) > 0
    np.testing.assert_allclose(banded, whole, rtol=1e-8, atol=1e-8 * float(jnp.abs(whole).max()))


@pytest.fixture
def no_work(monkeypatch):
    """The design's work fails the test: a refusal must come before it."""

    def started(*args, **kwargs):
        raise AssertionError("the design started before its memory was checked")

    monkeypatch.setattr(design_module, "_solve", started)


def test_a_design_over_its_memory_limit_is_refused_with_the_estimate_and_knob(no_work):
    grid = (512, 512)
    needed = lens_setup.design_memory(grid, 1, 0)
    assert needed == (1 << 30) + 1300 * 512 * 512  # the fixed part and 1.3 kB a sample
    with pytest.raises(ValueError) as err:
        jc.design(
            PROBLEM,
            blob(),
            start=jc.TransportStart(grid=512),
            finish=None,
            memory_limit=needed - 1,
        )
    text = str(err.value)
    assert f"{needed / 2**30:.1f} GiB" in text and "(512, 512)" in text
    assert "`memory_limit`" in text and "`levels` or `heights_shape`" in text


def test_memory_limit_is_checked_and_defaults_to_half_the_machine(no_work, monkeypatch):
    pages = {"SC_PAGE_SIZE": 4096, "SC_PHYS_PAGES": (6 << 30) // 4096}
    monkeypatch.setattr(lens_setup.os, "sysconf", lambda name: pages[name])
    assert lens_setup.check_design_memory_limit(None) == 3 << 30
    for bad in (0, -1, 2.5, "8G", 1 << 20):
        with pytest.raises(ValueError, match="memory_limit"):
            jc.design(PROBLEM, blob(), memory_limit=bad)


def test_the_cli_reads_memory_sizes():
    import argparse

    from jaxcaustics.cli.flags import memory_size

    assert memory_size("12G") == 12 << 30
    assert memory_size("512M") == 512 << 20
    assert memory_size("8GiB") == memory_size("8gb") == 8 << 30
    assert memory_size("1.5G") == 3 << 29
    assert memory_size("4096") == 4096
    for bad in ("", "G", "12X", "-1G", "0"):
        with pytest.raises(argparse.ArgumentTypeError):
            memory_size(bad)


def test_the_cli_names_memory_limit(tmp_path, capsys):
    from jaxcaustics.cli.main import main

    code = main(["design", "--size", "16", "--memory-limit", "1M", "--output", str(tmp_path)])
    out = capsys.readouterr()
    assert code != 0
    text = out.out + out.err
    assert "--memory-limit" in text and "Traceback" not in text


def test_a_grid_below_four_samples_a_pixel_is_reported():
    """A 512-pixel target on black on its default grid (1024^2, two a pixel side) loses
    fine detail: the design says so (`LensDesign.warnings`); a photograph there is
    finished by the image refinement, and is reported below two a side."""
    from types import SimpleNamespace

    from jaxcaustics.inverse.design import _design_warnings

    photo, black = np.ones((8, 8)), np.zeros((8, 8))
    black[2:5, 2:5] = 1.0

    def notes(grid, target, goal):
        setup = SimpleNamespace(
            shapes=[grid], target_shape=target, start=jc.TransportStart(), warn_error=0.15,
            goal=goal,
        )  # fmt: skip
        return _design_warnings(setup, [], 0.05, 0.0)

    (note,) = notes((1024, 1024), (512, 512), black)
    assert "2 samples per target pixel side" in note and "`ImageRefinement(steps" in note
    assert notes((1024, 1024), (512, 512), photo) == []  # refined
    (note,) = notes((1024, 1024), (1024, 1024), photo)
    assert "1 samples per target pixel side; below 2" in note
    assert notes((1024, 1024), (256, 256), black) == []  # four a side
    assert notes((128, 128), (128, 128), black) == []  # small targets: as asked
