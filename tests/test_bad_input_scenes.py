"""Bad input to the scene constructors and scene-building helpers is refused at once.

Each case raises a `ValueError` (or `TypeError`) naming the argument in backticks, when
the object is built: before anything is compiled. One Hypothesis property draws bad
values for one field at a time and checks that a constructor either refuses them naming
the field or builds an object whose fields are all finite.
"""

import dataclasses
import math
import re

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import jaxcaustics as jc

E = (0.0, 1.0, 0.0, 1.0)
SUN = jc.DirectionalLight([0.0, 0.0, -1.0])
F32 = np.float32


def _field(**kw):
    return jc.HeightField(**{"heights": np.zeros((4, 4)), "extent": E, **kw})


def _receiver(**kw):
    return jc.PlaneReceiver(**{"extent": E, "shape": (4, 4), **kw})


def _water(**kw):
    return jc.WaterScene(**{"surface": _field(), "light": SUN, "receiver": _receiver(), **kw})


def _lens(**kw):
    surface = _field(boundary="clamp")
    return jc.LensScene(**{"surface": surface, "light": SUN, "receiver": _receiver(), **kw})


def _ball(z=1.0, radius=0.5):
    mesh = trimesh.creation.icosphere(1, radius=radius)
    mesh.apply_translation([0.0, 0.0, z])
    return jc.Mesh.from_trimesh(mesh)


BALL = _ball()


def _mesh_scene(**kw):
    return jc.MeshScene(**{"generator": BALL, "light": SUN, "receiver": _receiver(), **kw})


SPHERE = jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3)


def _ellipsoid_scene(**kw):
    return jc.EllipsoidScene(**{"generator": SPHERE, "light": SUN, "receiver": _receiver(), **kw})


class _FacesOnly:
    faces = np.array([[0, 1, 2]])


def _waves(**kw):
    return jc.wave_heights(**{"shape": (8, 8), "extent": E, **kw})


def _bump(**kw):
    return jc.internal.gaussian_bump(
        **{"shape": (8, 8), "extent": E, "sigma": 0.1, "amplitude": 0.01, **kw}
    )


def _sines(**kw):
    return jc.sine_sum(**{"shape": (8, 8), "extent": E, "terms": [(1, 0, 0.01, 0.0)], **kw})


def _sine_term(**kw):
    term = {"kx": 1, "ky": 0, "a": 0.01, "phase": 0.0, **kw}
    return _sines(terms=[tuple(term.values())])


CASES = [
    # HeightField
    ("heights", lambda: _field(heights="abc")),
    ("heights", lambda: _field(heights=None)),
    ("heights", lambda: _field(heights=np.ones((3, 3), bool))),
    ("heights", lambda: _field(heights=np.zeros((3, 3)) + 1j)),
    ("heights", lambda: _field(heights=np.full((3, 3), np.nan))),
    ("heights", lambda: _field(heights=np.zeros(4))),
    ("heights", lambda: _field(heights=np.zeros((1, 1)))),
    ("heights", lambda: _field(heights=[[0.0, 1.0], [2.0]])),
    ("extent", lambda: _field(extent=["0", "1", "0", "1"])),
    ("extent", lambda: _field(extent=[True, False, False, True])),
    ("extent", lambda: _field(extent=(1, 0, 0, 1))),
    ("extent", lambda: _field(extent=(0, 1, 0))),
    ("extent", lambda: _field(extent=np.array([-3e38, 3e38, 0, 1], F32))),  # width overflows
    ("boundary", lambda: _field(boundary="PERIODIC")),
    ("boundary", lambda: _field(boundary=np.array("periodic"))),
    ("boundary", lambda: _field(boundary=None)),
    ("rotation", lambda: _field(rotation="0.1")),
    ("rotation", lambda: _field(rotation=True)),
    ("rotation", lambda: _field(rotation=1j)),
    ("rotation", lambda: _field(rotation=np.nan)),
    ("rotation", lambda: _field(rotation=[0.1, 0.2])),
    ("rotation", lambda: _field(rotation=10**400)),
    ("rotation", lambda: _field(heights=np.zeros((4, 4), F32), rotation=1e300)),
    # DirectionalLight
    ("direction", lambda: jc.DirectionalLight("down")),
    ("direction", lambda: jc.DirectionalLight([0, 0, 0])),
    ("direction", lambda: jc.DirectionalLight([0, 0, 1])),
    ("direction", lambda: jc.DirectionalLight([1, 0, 0])),
    ("direction", lambda: jc.DirectionalLight([0, -1])),
    ("direction", lambda: jc.DirectionalLight(np.array([1e20, 0, -1e20], F32))),
    ("direction", lambda: jc.DirectionalLight(np.array([0, 0, -1e-30], F32))),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles("30")),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(None)),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(True)),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(np.bool_(True))),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(90.0)),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(-1.0)),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(np.nan)),
    ("zenith_deg", lambda: jc.DirectionalLight.from_angles(89.99999999)),
    ("azimuth_deg", lambda: jc.DirectionalLight.from_angles(10.0, "0")),
    ("azimuth_deg", lambda: jc.DirectionalLight.from_angles(10.0, True)),
    ("azimuth_deg", lambda: jc.DirectionalLight.from_angles(10.0, np.nan)),
    ("azimuth_deg", lambda: jc.DirectionalLight.from_angles(10.0, np.inf)),
    ("azimuth_deg", lambda: jc.DirectionalLight.from_angles(10.0, 1j)),
    # PointLight
    ("position", lambda: jc.PointLight("abc")),
    ("position", lambda: jc.PointLight([0.0, 0.0, -1.0])),  # below the receiver
    ("position", lambda: jc.PointLight([0.0, 0.0, 0.0])),
    ("intensity", lambda: jc.PointLight([0.0, 0.0, 1.0], "1")),
    ("intensity", lambda: jc.PointLight([0.0, 0.0, 1.0], True)),
    ("intensity", lambda: jc.PointLight([0.0, 0.0, 1.0], 1j)),
    ("intensity", lambda: jc.PointLight([0.0, 0.0, 1.0], np.inf)),
    # PlaneReceiver
    ("shape", lambda: _receiver(shape="44")),
    ("shape", lambda: _receiver(shape=4)),
    ("shape", lambda: _receiver(shape=(4.0, 4))),
    ("shape", lambda: _receiver(shape=(True, True))),
    ("shape", lambda: _receiver(shape=(0, 4))),
    ("shape", lambda: _receiver(shape=(4, 4, 4))),
    ("shape", lambda: _receiver(shape={4, 5})),
    ("shape", lambda: _receiver(shape=(10**6, 10**6))),  # a runaway image
    ("extent", lambda: _receiver(extent=(0, 1j, 0, 1))),
    # WaterScene
    ("surface", lambda: _water(surface=np.zeros((4, 4)))),
    ("light", lambda: _water(light=jc.PointLight([0.0, 0.0, 5.0]))),
    ("receiver", lambda: _water(receiver="x")),
    ("rest_depth", lambda: _water(rest_depth="1")),
    ("rest_depth", lambda: _water(rest_depth=True)),
    ("rest_depth", lambda: _water(rest_depth=0.0)),
    ("rest_depth", lambda: _water(rest_depth=[1.0, 2.0])),
    ("surface", lambda: _water(surface=_field(heights=np.full((4, 4), -2.0)))),  # below floor
    ("ior", lambda: _water(ior="1.3")),
    ("ior", lambda: _water(ior=np.array(True))),
    ("ior", lambda: _water(ior=[1.3, True])),
    ("ior", lambda: _water(ior={1.3, 1.4})),
    ("ior", lambda: _water(ior={1.3: 1})),
    ("ior", lambda: _water(ior=[[1.3]])),
    ("ior", lambda: _water(ior=1e300)),
    ("ior", lambda: _water(ior=1e-300)),
    ("ior", lambda: _water(ior=10**400)),
    ("ior", lambda: _water(ior=1.3 + 0j)),
    ("ior", lambda: _water(ior=(1.3,) * 100_000)),  # a runaway number of channels
    ("fresnel", lambda: _water(fresnel="False")),
    ("fresnel", lambda: _water(fresnel=None)),
    ("fresnel", lambda: _water(fresnel=2)),
    # LensScene
    ("thickness", lambda: _lens(thickness="0.01")),
    ("thickness", lambda: _lens(thickness=np.nan)),
    ("screen_distance", lambda: _lens(screen_distance=-1.0)),
    ("screen_distance", lambda: _lens(screen_distance=np.bool_(True))),
    ("ior", lambda: _lens(ior=1e300)),
    ("fresnel", lambda: _lens(fresnel=0.5)),
    ("surface", lambda: _lens(surface=_field(heights=np.full((4, 4), -0.02)))),
    ("light", lambda: _lens(light=jc.PointLight([0.0, 0.0, 0.505]))),  # inside the lens
    # Mesh
    ("faces", lambda: jc.Mesh(BALL.vertices, [[0, 1], [1, 2, 3]])),
    ("faces", lambda: jc.Mesh(BALL.vertices, np.ones((3, 3), bool))),
    ("faces", lambda: jc.Mesh(BALL.vertices, "abc")),
    ("vertices", lambda: jc.Mesh(np.full((3, 3), "1"), [[0, 1, 2]])),
    ("mesh", lambda: jc.Mesh.from_trimesh(_FacesOnly())),
    ("mesh", lambda: jc.Mesh.from_trimesh(trimesh.Trimesh(np.full((3, 3), np.nan), [[0, 1, 2]]))),
    ("path", lambda: jc.Mesh.load(None)),
    ("path", lambda: jc.Mesh.load(3)),
    # MeshScene
    ("material", lambda: _mesh_scene(material=np.array("mirror"))),
    ("normals", lambda: _mesh_scene(normals=None)),
    ("interfaces", lambda: _mesh_scene(interfaces=10**9)),  # a runaway loop
    ("interfaces", lambda: _mesh_scene(interfaces=True)),
    ("interfaces", lambda: _mesh_scene(interfaces=2.0)),
    ("interfaces", lambda: _mesh_scene(interfaces="2")),
    ("fresnel", lambda: _mesh_scene(fresnel="False")),
    ("occluders", lambda: _mesh_scene(occluders=None)),
    ("occluders", lambda: _mesh_scene(occluders=_ball(3.0, 0.1))),
    ("ior", lambda: _mesh_scene(ior=1e300)),
    ("generator", lambda: _mesh_scene(generator=jc.Mesh(BALL.vertices, BALL.faces[:, ::-1]))),
    ("generator", lambda: _mesh_scene(generator=_ball(z=0.2))),  # below the screen
    ("light", lambda: _mesh_scene(light=jc.PointLight([0.0, 0.0, 1.0]))),  # inside it
    ("light", lambda: _mesh_scene(light=jc.PointLight([0.0, 0.0, 0.3]))),  # below it
    # Ellipsoid, EllipsoidScene
    ("radii", lambda: jc.Ellipsoid([0, 0, 1.0], [0.0, 0.1, 0.1])),
    ("radii", lambda: jc.Ellipsoid([0, 0, 1.0], [-0.1, 0.1, 0.1])),
    ("radii", lambda: jc.Ellipsoid([0, 0, 1.0], np.full(3, 1e-30, F32))),  # 1/r^2 overflows
    ("center", lambda: jc.Ellipsoid("abc", [0.1] * 3)),
    ("rotation", lambda: jc.Ellipsoid([0, 0, 1.0], [0.1] * 3, np.eye(3) * 2)),
    ("radius", lambda: jc.Ellipsoid.sphere([0, 0, 1.0], True)),
    ("subdivisions", lambda: SPHERE.to_mesh(20)),  # 20 * 4**20 faces
    ("subdivisions", lambda: SPHERE.to_mesh(True)),
    ("interfaces", lambda: _ellipsoid_scene(interfaces=10**9)),
    ("fresnel", lambda: _ellipsoid_scene(fresnel="yes")),
    ("occluders", lambda: _ellipsoid_scene(occluders=SPHERE)),
    ("occluders", lambda: _ellipsoid_scene(occluders=None)),
    ("occluders", lambda: _ellipsoid_scene(occluders=[jc.Ellipsoid.sphere([0, 0, 1.2], 0.2)])),
    ("generator", lambda: _ellipsoid_scene(generator=jc.Ellipsoid.sphere([0, 0, 0.1], 0.2))),
    ("light", lambda: _ellipsoid_scene(light=jc.PointLight([0.0, 0.0, 5.0]))),
    # shading
    ("albedo", lambda: jc.Lambertian("0.5")),
    ("albedo", lambda: jc.Lambertian(True)),
    ("albedo", lambda: jc.Lambertian(np.nan)),
    ("albedo", lambda: jc.Lambertian(-0.1)),
    ("albedo", lambda: jc.Lambertian(2.0)),
    ("albedo", lambda: jc.Lambertian(0.5j)),
    ("eye", lambda: jc.Glossy("abc")),
    ("eye", lambda: jc.Glossy([0.0, 1.0])),
    ("eye", lambda: jc.Glossy([0.0, 0.0, np.nan])),
    ("albedo", lambda: jc.Glossy([0.0, 0.0, 1.0], albedo=None)),
    ("specular", lambda: jc.Glossy([0.0, 0.0, 1.0], specular=2.0)),
    ("shininess", lambda: jc.Glossy([0.0, 0.0, 1.0], shininess=-1.0)),
    ("shininess", lambda: jc.Glossy([0.0, 0.0, 1.0], shininess=1e300)),
    # waves
    ("shape", lambda: _waves(shape=(True, True))),
    ("shape", lambda: _waves(shape=("8", "8"))),
    ("shape", lambda: _waves(shape=(10**6, 10**6))),  # a runaway allocation
    ("shape", lambda: _bump(shape=(10**6, 10**6))),
    ("shape", lambda: _sines(shape=(10**6, 10**6))),
    ("extent", lambda: _waves(extent=["0", "1", "0", "1"])),
    ("extent", lambda: _waves(extent=[False, True, False, True])),
    ("extent", lambda: _waves(extent=(0, 1j, 0, 1))),
    ("extent", lambda: _waves(extent=(-3e38, 3e38, 0, 1))),
    ("time", lambda: _waves(time="1")),
    ("time", lambda: _waves(time=True)),
    ("time", lambda: _waves(time=1j)),
    ("time", lambda: _waves(time=10**400)),
    ("amplitude", lambda: _waves(amplitude="0.1")),
    ("depth", lambda: _waves(depth=np.bool_(True))),
    ("direction", lambda: _waves(direction="0.5")),
    ("direction", lambda: _waves(direction=True)),
    ("direction_spread", lambda: _waves(direction_spread="1")),
    ("wavelength_range", lambda: _waves(wavelength_range=("0.1", "1"))),
    ("wavelength_range", lambda: _waves(wavelength_range=(True, True))),
    ("center", lambda: _bump(center=("0.5", "0.5"))),
    ("center", lambda: _bump(center=(True, False))),
    ("center", lambda: _bump(center=(0.5j, 0.5))),
    ("extent", lambda: _bump(extent=[False, True, False, True])),
    ("extent", lambda: _bump(extent=["0", "1", "0", "1"])),
    ("sigma", lambda: _bump(sigma=True)),
    ("sigma", lambda: _bump(sigma="0.1")),
    ("extent", lambda: _sines(extent=["0", "1", "0", "1"])),
    ("terms[0]", lambda: _sine_term(kx="1")),
    ("terms[0]", lambda: _sine_term(kx=True)),
    ("terms[0]", lambda: _sine_term(kx=1e300)),
    ("terms[0]", lambda: _sine_term(ky=1j)),
    ("terms[0] amplitude", lambda: _sine_term(a=True)),
    ("terms[0] amplitude", lambda: _sine_term(a="0.1")),
    # stack_scenes, unstack_scenes
    ("scenes", lambda: jc.devices.stack_scenes(None)),
    ("scenes", lambda: jc.devices.stack_scenes(3)),
    ("scenes", lambda: jc.devices.stack_scenes(_water())),
    ("scenes", lambda: jc.devices.stack_scenes([])),
    ("scenes", lambda: jc.devices.stack_scenes([_water(), _water(ior=1.5)])),
    ("scenes", lambda: jc.devices.unstack_scenes(_water())),
    ("scenes", lambda: jc.devices.unstack_scenes(None)),
]


@pytest.mark.parametrize(
    ("name", "make"), CASES, ids=[f"{k}-{name}" for k, (name, _) in enumerate(CASES)]
)
def test_bad_input_is_refused_naming_the_argument(name, make):
    with pytest.raises((ValueError, TypeError), match=f"`{re.escape(name)}"):
        make()


def test_valid_neighbours_still_build():
    """Values next to the refused ones: NumPy ints and floats, touching solids, a
    one-channel list of indices, a mirror wound either way, a generator of scenes."""
    assert _mesh_scene(interfaces=np.int64(2)).interfaces == 2
    assert _ellipsoid_scene(interfaces=np.int32(3)).interfaces == 3
    assert _water(ior=np.float32(1.5)).ior == pytest.approx(1.5)
    assert _water(ior=[1.3]).ior == (1.3,)
    assert _receiver(shape=np.array([3, 5])).shape == (3, 5)
    assert jc.DirectionalLight.from_angles(np.float32(30.0), np.int64(45)) is not None
    touching = jc.Ellipsoid.sphere([0.0, 0.0, 1.5], 0.2)  # 0.5 apart, radii 0.3 + 0.2
    assert len(_ellipsoid_scene(occluders=[touching]).occluders) == 1
    inside_out = jc.Mesh(BALL.vertices, BALL.faces[:, ::-1])
    assert _mesh_scene(generator=inside_out, material="mirror").material == "mirror"
    assert jc.Glossy([0.0, 0.0, 1.0], 0.0, 1.0, 0.0).shininess == 0.0
    assert jc.Lambertian(np.float64(0.5)).albedo == 0.5
    assert (
        len(jc.devices.unstack_scenes(jc.devices.stack_scenes(w for w in [_water(), _water()])))
        == 2
    )


# --------------------------------------------------------------------------- property

_BAD = st.one_of(
    st.text(max_size=4),
    st.none(),
    st.booleans(),
    st.sampled_from([np.nan, np.inf, -np.inf, -1.0, 0.0, 1e300, -1e300, 10**400, np.bool_(True)]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**30), 10**30),
    st.complex_numbers(allow_nan=True, allow_infinity=True),
    st.lists(st.floats(), max_size=5),
    st.lists(st.integers(-(10**12), 10**12), max_size=3),
    st.lists(st.lists(st.floats(), min_size=1, max_size=3), min_size=1, max_size=3),
    hnp.arrays(
        st.sampled_from([np.float64, np.float32, np.int64, np.complex128, np.bool_]),
        hnp.array_shapes(min_dims=0, max_dims=3, max_side=4),
    ),
)

# Each constructor with valid values for every field.
_VALID = {
    jc.HeightField: lambda: dict(
        heights=np.zeros((3, 3)), extent=E, boundary="clamp", rotation=0.1
    ),
    jc.DirectionalLight: lambda: dict(direction=[0.1, 0.0, -1.0]),
    jc.PointLight: lambda: dict(position=[0.0, 0.0, 2.0], intensity=1.0),
    jc.PlaneReceiver: lambda: dict(extent=E, shape=(3, 3)),
    jc.WaterScene: lambda: dict(
        surface=_field(), light=SUN, receiver=_receiver(), rest_depth=1.0, ior=1.33, fresnel=False
    ),
    jc.LensScene: lambda: dict(
        surface=_field(),
        light=SUN,
        receiver=_receiver(),
        thickness=0.01,
        screen_distance=0.5,
        ior=(1.5, 1.6),
        fresnel=True,
    ),
    jc.Ellipsoid: lambda: dict(center=[0.0, 0.0, 1.0], radii=[0.1, 0.2, 0.3], rotation=np.eye(3)),
    jc.Mesh: lambda: dict(vertices=np.asarray(BALL.vertices), faces=np.asarray(BALL.faces)),
}
_FIELDS = [(kind, name) for kind, valid in _VALID.items() for name in valid()]


def _finite(value) -> bool:
    """Every number in `value` (a module's fields, recursively) is finite."""
    if dataclasses.is_dataclass(value):
        return all(_finite(getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, tuple):
        return all(_finite(v) for v in value)
    if isinstance(value, float):
        return math.isfinite(value)
    if hasattr(value, "dtype"):
        return bool(np.all(np.isfinite(np.asarray(value))))
    return True


@settings(max_examples=300, deadline=None)
@given(field=st.sampled_from(_FIELDS), bad=_BAD)
def test_a_bad_field_is_refused_by_name_or_gives_finite_fields(field, bad):
    kind, name = field
    kwargs = {**_VALID[kind](), name: bad}
    try:
        built = kind(**kwargs)
    except (ValueError, TypeError) as err:
        assert f"`{name}" in str(err), f"{kind.__name__}({name}={bad!r}): {err}"
        return
    assert _finite(built), f"{kind.__name__}({name}={bad!r}) built non-finite fields"
