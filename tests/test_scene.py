"""Scene types: validation before compilation, effects, pytree behaviour."""

import jax
import numpy as np
import pytest

import jaxcaustics as jc

EXT = (0.0, 1.0, 0.0, 1.0)


def _scene(**over):
    kw = dict(
        surface=jc.HeightField(np.zeros((8, 8)), EXT),
        light=jc.DirectionalLight.from_angles(20.0),
        receiver=jc.PlaneReceiver(EXT, (8, 8)),
        rest_depth=1.0,
    )
    kw.update(over)
    return jc.WaterScene(**kw)


def _dip(depth):
    h = np.zeros((8, 8))
    h[3, 4] = -depth
    return h


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: jc.HeightField(np.zeros(8), EXT), "heights"),
        (lambda: jc.HeightField(np.zeros((2, 3, 4)), EXT), "heights"),
        (lambda: jc.HeightField(np.full((4, 4), np.nan), EXT), "heights"),
        (lambda: jc.HeightField(np.zeros((4, 4)), (0, 1, 0)), "extent"),
        (lambda: jc.HeightField(np.zeros((4, 4)), (1, 0, 0, 1)), "extent"),
        (lambda: jc.HeightField(np.zeros((4, 4)), EXT, boundary="mirror"), "boundary"),
        (lambda: jc.HeightField([["a", "b"], ["c", "d"]], EXT), "heights"),
        (lambda: jc.DirectionalLight([0.0, 0.0, 0.0]), "direction"),
        (lambda: jc.DirectionalLight([0.0, 0.2, 1.0]), "direction"),
        (lambda: jc.DirectionalLight([1.0, 0.0, 0.0]), "direction"),
        (lambda: jc.DirectionalLight([0.0, 0.0, np.nan]), "direction"),
        (lambda: jc.DirectionalLight.from_angles(95.0), "zenith_deg"),
        (lambda: jc.PlaneReceiver(EXT, (0, 8)), "shape"),
        (lambda: jc.PlaneReceiver(EXT, (8,)), "shape"),
        (lambda: _scene(rest_depth=0.0), "rest_depth"),
        (lambda: _scene(rest_depth=-1.0), "rest_depth"),
        (lambda: _scene(rest_depth=np.nan), "rest_depth"),
        (lambda: _scene(ior=-1.333), "ior"),
        (lambda: _scene(ior=()), "ior"),
        (lambda: _scene(surface=np.zeros((8, 8))), "surface"),
        # strings where numbers are meant, fractions where integers are, complex values
        (lambda: _scene(ior="15"), "ior"),  # once two channels, 1.0 and 5.0
        (lambda: _scene(ior=("1.33", 1.34)), "ior"),
        (lambda: _scene(ior=True), "ior"),
        (lambda: jc.PlaneReceiver(EXT, (8.7, 8.2)), "shape"),  # once (8, 8)
        (lambda: jc.PlaneReceiver(EXT, "88"), "shape"),
        (lambda: jc.PlaneReceiver(EXT, 8), "shape"),
        (lambda: jc.HeightField(np.zeros((4, 4)) + 1e-3j, EXT), "heights"),
        # impossible geometry: the water surface reaches the ground
        (lambda: _scene(surface=jc.HeightField(np.full((8, 8), -1.0), EXT)), "surface"),
        (lambda: _scene(rest_depth=0.1, surface=jc.HeightField(_dip(0.2), EXT)), "surface"),
    ],
)
def test_bad_input_names_the_argument(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_render_rejects_bad_knobs():
    scene = _scene()
    with pytest.raises(ValueError, match="samples_x"):
        jc.render(scene, samples_x=4)
    with pytest.raises(ValueError, match="channels_y"):
        jc.render(scene, channels_y=3)
    with pytest.raises(ValueError, match="hit_iterations"):
        jc.render(scene, hit_iterations=-1)
    with pytest.raises(ValueError, match="supersample"):
        jc.render(scene, supersample=0)
    with pytest.raises(ValueError, match="method"):
        jc.render(scene, method="raytrace")
    # a window past every pixel of the 8 x 8 receiver (samples_x=100001 once compiled on
    # for minutes); 17 and 16 reach every pixel and still render
    with pytest.raises(ValueError, match="samples_x"):
        jc.render(scene, samples_x=100001)
    with pytest.raises(ValueError, match="channels_y"):
        jc.render(scene, samples_x=7, channels_y=18)
    assert np.all(np.isfinite(np.asarray(jc.render(scene, samples_x=17, channels_y=16))))


def test_effects_describe_what_is_traced():
    fx = _scene().effects
    assert fx.refraction and not fx.fresnel and not fx.total_internal_reflection
    assert fx.dispersion_channels == 1 and fx.interfaces == 1 and not fx.occlusion
    fx = _scene(ior=(1.33, 1.34, 0.9), fresnel=True).effects
    assert fx.fresnel and fx.total_internal_reflection and fx.dispersion_channels == 3


def test_scene_is_a_pytree_with_static_configuration():
    scene = _scene(ior=(1.33, 1.34), fresnel=True)
    leaves = jax.tree_util.tree_leaves(scene)
    # heights, surface extent, surface rotation, light direction, receiver extent, rest depth
    assert len(leaves) == 6
    rebuilt = jax.tree_util.tree_map(lambda x: x * 1, scene)
    assert rebuilt.ior == (1.33, 1.34) and rebuilt.fresnel and rebuilt.receiver.shape == (8, 8)


@pytest.mark.parametrize(
    "rotation", [np.nan, np.inf, [0.1, 0.2], np.zeros((1,)), "a", True, object()]
)
def test_bad_rotation_names_the_argument(rotation):
    with pytest.raises(ValueError, match="rotation"):
        jc.HeightField(np.zeros((4, 4)), EXT, rotation=rotation)


def test_rotation_is_a_float_leaf_in_the_dtype_of_the_heights():
    field = jc.HeightField(np.zeros((4, 4), np.float32), EXT)
    assert field.rotation.shape == () and field.rotation.dtype == np.float32
    assert float(field.rotation) == 0.0
    field = jc.HeightField(np.zeros((4, 4)), EXT, "clamp", rotation=1)  # an int is fine
    assert field.rotation.dtype == np.float64 and float(field.rotation) == 1.0
    field = jc.HeightField(np.zeros((4, 4)), EXT, rotation=np.float32(0.5))  # an array: kept
    assert field.rotation.dtype == np.float32
    traced = jax.jit(lambda a: jc.HeightField(np.zeros((4, 4)), EXT, rotation=a).rotation)
    assert float(traced(0.25)) == 0.25


def test_the_two_forms_of_the_catmull_rom_weights_agree():
    """`_weights_by_product` (the heights' tangent) restates `catmull_rom`'s polynomials
    as a matrix: the weights and their slopes agree."""
    from jaxcaustics.scene import surface

    t = np.linspace(0.0, 1.0, 11)
    w, dw = surface._weights_by_product(jax.numpy.asarray(t))
    expected_w, expected_dw, _ = surface.catmull_rom(t)
    np.testing.assert_allclose(np.asarray(w), np.stack(expected_w, -1), atol=1e-6)
    np.testing.assert_allclose(np.asarray(dw), np.stack(expected_dw, -1), atol=1e-6)
