"""`throw` means raising everywhere (as in Optimistix); the lens-to-screen distance is
`screen_distance`. The old keywords still work, with a `DeprecationWarning`."""

import numpy as np
import pytest

import jaxcaustics as jc

TARGET = np.ones((8, 8))
SPEC = dict(width=0.1, height=0.1, thickness=0.01)


def _lens(**kw):
    return jc.LensScene(
        jc.HeightField(np.zeros((4, 4)), (0, 0.1, 0, 0.1), "clamp"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver((0, 0.1, 0, 0.1), (4, 4)),
        thickness=0.01,
        **kw,
    )


def test_lens_scene_old_keyword_and_attribute():
    with pytest.warns(DeprecationWarning, match="`throw` is deprecated, pass `screen_distance`"):
        old = _lens(throw=0.3)
    assert float(old.screen_distance) == float(_lens(screen_distance=0.3).screen_distance)
    with pytest.warns(DeprecationWarning, match="read `screen_distance`"):
        assert float(old.throw) == float(old.screen_distance)
    with pytest.raises(ValueError, match="pass `screen_distance` only"):
        _lens(throw=0.3, screen_distance=0.3)


def test_design_lens_old_keywords_reach_the_checks():
    # the old distance goes where `screen_distance` goes: its check names it
    with pytest.warns(DeprecationWarning, match="`throw` is deprecated"):
        with pytest.raises(ValueError, match="screen_distance"):
            jc.design_lens(TARGET, throw=-1.0, **SPEC)
    with pytest.warns(DeprecationWarning, match="`throw_errors` is deprecated, pass `throw`"):
        with pytest.raises(ValueError, match="`throw`"):
            jc.design_lens(TARGET, screen_distance=0.5, throw_errors="no", **SPEC)
    with pytest.raises(ValueError, match="`screen_distance` is required"):
        jc.design_lens(TARGET, **SPEC)
    with pytest.raises(ValueError, match="pass `screen_distance` only"):
        jc.design_lens(TARGET, throw=0.5, screen_distance=0.5, **SPEC)


def test_design_variants_old_keyword():
    with pytest.warns(DeprecationWarning, match="`throws` is deprecated"):
        with pytest.raises(ValueError, match=r"screen_distances\[1\]"):
            jc.design_lens_variants(TARGET, throws=[0.5, -1.0], **SPEC)
