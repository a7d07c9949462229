"""Shared test configuration.

Float64 is on for the whole session (finite-difference checks need it); tests of
float32 behaviour build their scenes from float32 arrays explicitly (see `make_scene`).
"""

from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

# Every compiled program keeps a few hundred memory mappings, and Linux allows a process
# 65,530 (`vm.max_map_count`): past it, XLA fails with "LLVM compilation error: Cannot
# allocate memory". A worker of the default run reached about 39,000; past 40,000 the
# compiled programs are dropped between test files.
_MAPS = Path("/proc/self/maps")
_MAX_MAPS = 40_000


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    yield
    if _MAPS.exists():
        with _MAPS.open() as maps:
            if sum(1 for _ in maps) > _MAX_MAPS:
                jax.clear_caches()


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
