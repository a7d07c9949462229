"""Shared test configuration.

Float64 is on for the whole session (finite-difference checks need it); tests of
float32 behaviour build their scenes from float32 arrays explicitly (see `make_scene`).
"""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)


def make_scene(
    heights,
    extent=(0.0, 1.0, 0.0, 1.0),
    *,
    zenith=0.0,
    azimuth=0.0,
    depth=0.5,
    shape=None,
    receiver_extent=None,
    boundary="periodic",
    dtype=np.float64,
    **scene_kwargs,
):
    """A `WaterScene` whose arrays are all of `dtype` (so float32 really is float32)."""
    import jaxcaustics as jc

    heights = np.asarray(heights, dtype=dtype)
    shape = heights.shape if shape is None else shape
    light = jc.DirectionalLight.from_angles(zenith, azimuth)
    return jc.WaterScene(
        jc.HeightField(heights, np.asarray(extent, dtype), boundary),
        jc.DirectionalLight(np.asarray(light.direction, dtype)),
        jc.PlaneReceiver(np.asarray(receiver_extent or extent, dtype), shape),
        np.asarray(depth, dtype),
        **scene_kwargs,
    )


@pytest.fixture
def rng():
    return np.random.default_rng(0)
