"""`design_lens`: validation, a small design judged by the reference tracer, brightness
invariance, masks."""

import numpy as np
import pytest

import jaxcaustics._inverse.design as design_module
from jaxcaustics._inverse.design import design_lens
from jaxcaustics.reference import trace_lens

SPEC = dict(width=0.1, height=0.1, thickness=0.02, throw=0.5)
SMALL = dict(levels=(16,), max_steps=15)


def blob(n=16):
    """A smooth target: two Gaussian spots on a dim background."""
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    spots = np.exp(-((xx - 0.35) ** 2 + (yy - 0.4) ** 2) / 0.02)
    spots += 0.7 * np.exp(-((xx - 0.7) ** 2 + (yy - 0.65) ** 2) / 0.015)
    return 0.3 + spots


def rel_l2(image, target):
    a = image / image.mean()
    b = target / target.mean()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def blob_design():
    return design_lens(blob(), **SPEC, **SMALL)


# ----------------------------------------------------------------- bad specifications


@pytest.fixture
def no_optimisation(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("the optimisation started before the specification was checked")

    monkeypatch.setattr(design_module, "_run_level", forbidden)


@pytest.mark.parametrize(
    ("change", "name"),
    [
        (dict(thickness=-0.01), "thickness"),
        (dict(thickness=0.0), "thickness"),
        (dict(throw=0.0), "throw"),
        (dict(throw=-1.0), "throw"),
        (dict(width=0.0), "width"),
        (dict(height=float("nan")), "height"),
        (dict(ior=1.0), "ior"),
        (dict(regularization=-1.0), "regularization"),
        (dict(levels=()), "levels"),
        (dict(mask=np.ones((8, 8), bool)), "mask"),
        (dict(mask=np.zeros((16, 16), bool)), "mask"),
        # a weak lens this strong needs a relief deeper than the blank
        (dict(thickness=1e-5), "thickness"),
    ],
)
def test_bad_specifications_raise_before_optimisation(no_optimisation, change, name):
    spec = {**SPEC, **SMALL, **change}
    with pytest.raises(ValueError, match=f"`{name}`"):
        design_lens(blob(), **spec)


@pytest.mark.parametrize(
    "target",
    [np.full((16, 16), np.nan), np.zeros((16, 16)), -blob(), np.ones(16)],
    ids=["nan", "zeros", "negative", "1-d"],
)
def test_bad_targets_raise_before_optimisation(no_optimisation, target):
    with pytest.raises(ValueError, match="`target`"):
        design_lens(target, **SPEC, **SMALL)


# ----------------------------------------------------------------- designs


def test_small_design_matches_the_target_by_the_reference(blob_design):
    d = blob_design
    assert d.heights.shape == (16, 16)
    assert np.isclose(d.heights.max(), 0.0)
    assert SPEC["thickness"] + d.heights.min() > 0
    # the loss went down by orders of magnitude from the weak-lens start
    assert d.loss_history[-1] < 0.05 * d.loss_history[0]  # measured: 4.0 -> 0.05
    ref = trace_lens(d.scene, 512)
    flat = rel_l2(np.ones_like(ref), blob())
    error = rel_l2(ref, blob())
    # measured: 0.045 (the flat lens: 0.42); the forward model agrees with the reference
    assert error < 0.06, (error, flat)
    assert rel_l2(d.predicted, ref) < 0.03


def test_design_is_invariant_to_the_target_brightness(blob_design):
    brighter = design_lens(3.0 * blob(), **SPEC, **SMALL)
    np.testing.assert_allclose(brighter.heights, blob_design.heights, rtol=0, atol=1e-9)


def circle_design():
    n = 16
    x = (np.arange(n) + 0.5) / n - 0.5
    xx, yy = np.meshgrid(x, x)
    mask = xx**2 + yy**2 < 0.4**2
    d = design_lens(np.ones((n, n)), mask=mask, **SPEC, **SMALL)
    return mask, trace_lens(d.scene, 512)


@pytest.fixture(scope="module")
def circle():
    return circle_design()


def test_masked_target_moves_light_into_the_mask(circle):
    mask, ref = circle
    outside = ref[~mask].sum() / ref.sum()
    # the flat lens puts 1 - pi 0.4^2 = 50% of its light outside; measured: 14%
    assert outside < 0.2, outside


@pytest.mark.xfail(reason="the transport solve does not converge for a hard mask yet", strict=False)
def test_masked_target_keeps_the_outside_dark_and_the_inside_even(circle):
    mask, ref = circle
    # the floor (2% of the mean) is all that the design should leave outside: about 1%
    assert ref[~mask].sum() / ref.sum() < 0.03
    assert np.std(ref[mask] / ref[mask].mean()) < 0.15
