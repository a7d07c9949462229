"""`method_for`: the one call that fixes a method's scene-sized knobs, so that `render`
composes with `jit`, `vmap` and `grad`."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcaustics as jc

EXTENT = (0.0, 1.0, 0.0, 1.0)


def _sea(seed=0, amplitude=0.002):
    heights = jc.wave_heights((32, 32), EXTENT, amplitude=amplitude, depth=0.5, seed=seed)
    return jc.WaterScene(
        jc.HeightField(heights, EXTENT),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(EXTENT, (32, 32)),
        rest_depth=0.5,
    )


def _lens():
    x = np.linspace(-1, 1, 24)
    bump = 0.001 * np.exp(-(x[:, None] ** 2 + x[None, :] ** 2) / 0.2)
    return jc.LensScene(
        jc.HeightField(bump, (0.0, 0.1, 0.0, 0.1), "clamp"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver((0.0, 0.1, 0.0, 0.1), (24, 24)),
        thickness=0.01,
        screen_distance=0.3,
    )


def test_defaults_under_jit_say_what_to_call():
    with pytest.raises(ValueError, match="method_for"):
        jax.jit(jc.render)(_sea())


def test_water_under_jit_and_vmap_matches_the_eager_render():
    seas = [_sea(0), _sea(1, amplitude=0.004)]
    method = jc.method_for(seas)
    assert isinstance(method.samples_x, int) and isinstance(method.channels_y, int)
    # sized for the rougher sea: at least its own window
    own = jc.method_for(seas[1])
    assert method.samples_x >= own.samples_x and method.channels_y >= own.channels_y
    eager = [np.asarray(jc.render(s, method)) for s in seas]
    jitted = jax.jit(lambda s: jc.render(s, method))(seas[0])
    np.testing.assert_allclose(np.asarray(jitted), eager[0], rtol=1e-5, atol=1e-6)
    batch = jc.devices.stack_scenes(seas)
    mapped = jax.vmap(lambda s: jc.render(s, method))(batch)
    np.testing.assert_allclose(np.asarray(mapped), np.stack(eager), rtol=1e-5, atol=1e-6)


def test_lens_under_jit_and_grad():
    lens = _lens()
    method = jc.method_for(lens, "triangles", photons=25)
    assert isinstance(method, jc.CausticTriangles) and isinstance(method.window, int)

    def centre(h):
        scene = eqx.tree_at(lambda s: s.surface.heights, lens, h)
        return jnp.sum(jc.render(scene, method)[8:16, 8:16])

    heights = jnp.asarray(lens.surface.heights)
    value, grad = jax.jit(jax.value_and_grad(centre))(heights)
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))
    assert float(jnp.abs(grad).max()) > 0
    np.testing.assert_allclose(float(value), float(centre(heights)), rtol=1e-5)


def test_bad_calls_name_the_argument():
    with pytest.raises(ValueError, match="`scenes` is empty"):
        jc.method_for([])
    with pytest.raises(ValueError, match="`method`"):
        jc.method_for(_sea(), "triangles")
    with pytest.raises(ValueError, match="concrete"):
        jax.jit(lambda s: jc.method_for(s).samples_x)(_sea())
    with pytest.raises(ValueError, match="not a knob"):
        jc.method_for(_sea(), "twopass", photons=3)
