"""Methods as Equinox modules: one place for each method's knobs, support and "auto" sizing,
and one image layout for every method."""

import dataclasses
import inspect

import equinox as eqx
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics.methods.registry import METHODS

APERTURE = (0.0, 0.1, 0.0, 0.1)
FUNCTIONS = {
    jc.TwoPass: jc.internal.two_pass,
    jc.CausticTriangles: jc.internal.caustic_triangles,
    jc.CausticsMapping: jc.internal.caustics_mapping,
    jc.AdaptiveCausticMap: jc.internal.adaptive_caustic_map,
    jc.SpotLightMethod: jc.internal.spot_lights,
}


def water(ior=1.33, shape=(8, 8)):
    heights = 0.002 * np.sin(np.linspace(0, 2 * np.pi, shape[1], endpoint=False))[None, :]
    surface = jc.HeightField(np.repeat(heights, shape[0], axis=0), (0, 1, 0, 1))
    return jc.WaterScene(
        surface,
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((0, 1, 0, 1), shape),
        ior=ior,
    )


def lens(ior=1.5):
    x = np.linspace(-1, 1, 8)
    bump = 1e-3 * np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / 0.3)
    return jc.LensScene(
        jc.HeightField(bump, APERTURE, "clamp"),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(APERTURE, (8, 8)),
        thickness=0.01,
        screen_distance=0.3,
        ior=ior,
    )


def ball_mesh(ior=1.5):
    mesh = trimesh.creation.icosphere(1, radius=0.3)
    mesh.apply_translation([0.0, 0.0, 1.0])
    return jc.MeshScene(
        jc.Mesh.from_trimesh(mesh),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
        ior=ior,
    )


def ellipsoid(ior=1.5):
    return jc.EllipsoidScene(
        jc.Ellipsoid((0.0, 0.0, 1.0), (0.3, 0.3, 0.3)),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
        ior=ior,
    )


# small, fast settings of each method, with a scene it renders
CASES = [
    (jc.TwoPass(samples_x=5, channels_y=4), water),
    (jc.CausticTriangles(photons=9), lens),
    (jc.CausticsMapping(photons=16), ball_mesh),
    (jc.AdaptiveCausticMap(photons=16, base=8, check_from=8), ball_mesh),
    (jc.SpotLightMethod(rays_per_axis=16, max_gain=100.0), ellipsoid),
]
IDS = [type(m).__name__ for m, _ in CASES]
# 16^2 rays leave some light out of the fitted spot lights: `render` warns of it, which is
# not what these tests are about
pytestmark = pytest.mark.filterwarnings("ignore:render. method 'spot_lights' missed")


def test_every_method_is_registered_under_its_name_with_its_function():
    assert {cls.name: cls for cls in FUNCTIONS} == METHODS
    assert all(issubclass(cls, jc.Method) for cls in METHODS.values())


@pytest.mark.parametrize("cls", list(FUNCTIONS), ids=lambda c: c.__name__)
def test_the_functions_defaults_are_the_modules(cls):
    """The knobs' defaults are written once, on the module; the function reads them."""
    parameters = inspect.signature(FUNCTIONS[cls]).parameters
    for field in dataclasses.fields(cls):
        if field.name == "fit":  # spot lights: the fit's keywords, as **fit_knobs
            assert parameters["fit_knobs"].kind is inspect.Parameter.VAR_KEYWORD
            continue
        default = field.default if field.default is not dataclasses.MISSING else None
        assert parameters[field.name].default == default, field.name


@pytest.mark.parametrize(("method", "make"), CASES, ids=IDS)
def test_an_instance_renders_as_its_name_and_knobs(method, make):
    scene = make()
    by_instance, stats = jc.render(scene, method, return_stats=True)
    by_name = jc.render(scene, method.name, **method.knobs())
    np.testing.assert_array_equal(np.asarray(by_instance), np.asarray(by_name))
    assert np.asarray(by_instance).max() > 0.0  # light arrives
    assert stats["missed_flux_fraction"].shape == (1,)
    assert method.support(scene) is None


@pytest.mark.parametrize(("method", "make"), CASES, ids=IDS)
def test_one_channel_layout_for_every_method(method, make):
    """A scalar index gives ``(rows, cols)``; a sequence of indices, even of one, gives
    ``(rows, cols, channels)``: spot lights gave ``(rows, cols)`` for ``ior=(1.5,)``."""
    scalar = method(make(ior=1.5))
    one = method(make(ior=(1.5,)))
    assert isinstance(scalar, jc.RenderResult)
    assert scalar.image.shape == (8, 8)
    assert one.image.shape == (8, 8, 1)
    np.testing.assert_allclose(np.asarray(one.image[..., 0]), np.asarray(scalar.image), 1e-6)


def test_a_method_instance_goes_through_jit_with_its_knobs_static():
    scene = water()
    method = jc.TwoPass(samples_x=5, channels_y=4)
    jitted = eqx.filter_jit(lambda s, m: m(s).image)(scene, method)
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(jc.render(scene, method)), 1e-6)


def test_auto_knobs_are_sized_for_the_scenes():
    scenes = [water(), water(shape=(8, 8))]
    sized = jc.TwoPass(samples_x="auto", channels_y="auto").sized_for(scenes)
    assert (sized.samples_x, sized.channels_y) == jc.internal.auto_window(scenes[0])
    fixed = jc.TwoPass(samples_x=5, channels_y=4)
    assert not fixed.needs_sizing() and fixed.sized_for(scenes) is fixed


def test_knobs_are_refused_by_name_and_not_beside_an_instance():
    with pytest.raises(ValueError, match="`photons` is not a knob of method 'twopass'"):
        jc.render(water(), "twopass", photons=9)
    with pytest.raises(ValueError, match="set \\['samples_x'\\] on it"):
        jc.render(water(), jc.TwoPass(), samples_x=5)
    with pytest.raises(ValueError, match="`method` must be one of"):
        jc.render(water(), "two_pass")
    with pytest.raises(ValueError, match="`method` must be"):
        jc.render(water(), 3)
    # spot lights take the fit's keywords as knobs of their own
    method = jc.SpotLightMethod.from_knobs(rays_per_axis=16, max_lights=4)
    assert method.fit == {"max_lights": 4} and method.knobs()["max_lights"] == 4
    with pytest.raises(ValueError, match="`max_light` is not a knob"):
        jc.SpotLightMethod.from_knobs(max_light=4)


def test_support_is_the_methods_own():
    assert jc.TwoPass().support(lens()) is not None
    assert jc.CausticTriangles().support(water()) is not None
    occluded = jc.MeshScene(
        ball_mesh().generator,
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
        occluders=(ball_mesh().generator,),
    )
    assert "occlusion" in jc.CausticsMapping().support(occluded)
    assert jc.CausticTriangles().support(occluded) is None
    for name, cls in METHODS.items():
        for scene in (water(), lens(), ball_mesh(), ellipsoid()):
            assert jc.internal.method_support(name, scene) == cls().support(scene)
