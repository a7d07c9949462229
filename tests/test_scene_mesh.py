"""Lens and mesh scenes: validation before compilation, mesh loading, effects."""

import numpy as np
import pytest
import trimesh

import jaxcaustics as jc

APERTURE = (0.0, 0.1, 0.0, 0.1)


def _lens(**over):
    kw = dict(
        surface=jc.HeightField(np.zeros((8, 8)), APERTURE, "clamp"),
        light=jc.DirectionalLight.from_angles(10.0),
        receiver=jc.PlaneReceiver(APERTURE, (8, 8)),
        thickness=0.01,
        screen_distance=0.3,
    )
    kw.update(over)
    return jc.LensScene(**kw)


def _sphere(z=1.0, radius=0.5):
    mesh = trimesh.creation.icosphere(1, radius=radius)
    mesh.apply_translation([0.0, 0.0, z])
    return jc.Mesh.from_trimesh(mesh)


def _inside_out(mesh):
    return jc.Mesh(mesh.vertices, np.asarray(mesh.faces)[:, ::-1])


def test_a_closed_mesh_knows_its_signed_volume():
    sphere = _sphere(radius=0.5)  # trimesh's volume of the same icosphere (translation-free)
    expected = trimesh.creation.icosphere(1, radius=0.5).volume
    assert sphere.signed_volume() == pytest.approx(expected, rel=1e-9)
    assert _inside_out(sphere).signed_volume() == pytest.approx(-sphere.signed_volume())
    beside = _mesh_scene(light=jc.PointLight([2.0, 0.0, 1.0]))  # beside it, level: allowed
    assert isinstance(beside.light, jc.PointLight)


def _mesh_scene(**over):
    kw = dict(
        generator=_sphere(),
        light=jc.DirectionalLight.from_angles(0.0),
        receiver=jc.PlaneReceiver((-1, 1, -1, 1), (8, 8)),
    )
    kw.update(over)
    generator, light, receiver = kw.pop("generator"), kw.pop("light"), kw.pop("receiver")
    return jc.MeshScene(generator, light, receiver, **kw)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: _lens(thickness=0.0), "thickness"),
        (lambda: _lens(screen_distance=-1.0), "screen_distance"),
        (lambda: _lens(ior=()), "ior"),
        (lambda: _lens(light="sun"), "light"),
        (lambda: _lens(surface=np.zeros((4, 4))), "surface"),
        (lambda: _lens(surface=jc.HeightField(np.full((4, 4), -0.02), APERTURE)), "surface"),
        (lambda: _lens(light=jc.PointLight([0.05, 0.05, 0.2])), "light"),
        (lambda: jc.PointLight([0.0, 0.0]), "position"),
        (lambda: jc.PointLight([0.0, 0.0, np.nan]), "position"),
        (lambda: jc.PointLight([0.0, 0.0, 1.0], intensity=0.0), "intensity"),
        (lambda: jc.Mesh(np.zeros((3, 3)), np.zeros((0, 3), int)), "faces"),
        (lambda: jc.Mesh(np.zeros((3, 2)), [[0, 1, 2]]), "vertices"),
        (lambda: jc.Mesh(np.zeros((3, 3)), [[0, 1, 3]]), "faces"),
        (lambda: jc.Mesh(np.zeros((3, 3)), [[0, 1, -1]]), "faces"),
        (lambda: jc.Mesh(np.zeros((3, 3)), [[0.0, 1.0, 2.0]]), "faces"),
        (lambda: jc.Mesh(np.full((3, 3), np.nan), [[0, 1, 2]]), "vertices"),
        (lambda: jc.Mesh.from_trimesh(trimesh.Trimesh()), "mesh"),
        (
            lambda: _mesh_scene(generator=jc.Mesh(_sphere().vertices, _sphere().faces[:-1])),
            "watertight",
        ),
        (lambda: _mesh_scene(generator=_sphere(z=0.2)), "generator"),
        (lambda: _mesh_scene(material="glass"), "material"),
        (lambda: _mesh_scene(normals="phong"), "normals"),
        (lambda: _mesh_scene(interfaces=0), "interfaces"),
        (lambda: _mesh_scene(occluders=[np.zeros((3, 3))]), "occluders"),
        # faces wound inwards pass the watertight check (once an all-zero image)
        (lambda: _mesh_scene(generator=_inside_out(_sphere())), "inside out"),
        # a point light inside or below the glass (once an all-zero image)
        (lambda: _mesh_scene(light=jc.PointLight([0.0, 0.0, 1.1])), "light"),
        (lambda: _mesh_scene(light=jc.PointLight([0.0, 0.0, 0.4])), "light"),
    ],
)
def test_bad_input_names_the_argument(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_an_open_mirror_is_allowed():
    half = jc.Mesh(_sphere().vertices, _sphere().faces[:-1])
    scene = _mesh_scene(generator=half, material="mirror")
    assert scene.effects.reflection and not scene.effects.refraction


def test_load_reads_obj_stl_ply_and_rejects_bad_files(tmp_path):
    mesh = trimesh.creation.icosphere(1)
    for ext in ("obj", "stl", "ply"):
        path = tmp_path / f"ball.{ext}"
        mesh.export(path)
        loaded = jc.Mesh.load(path)
        assert loaded.faces.shape == (80, 3) and loaded.is_watertight()
    with pytest.raises(ValueError, match="path"):
        jc.Mesh.load(tmp_path / "missing.obj")
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"\x00\x01 this is not a mesh")
    with pytest.raises(ValueError, match="path"):
        jc.Mesh.load(garbage)
    empty = tmp_path / "empty.obj"
    empty.write_text("# no faces\nv 0 0 0\n")
    with pytest.raises(ValueError, match="path"):
        jc.Mesh.load(empty)


def test_effects_follow_the_scene():
    occluder = jc.Mesh.from_trimesh(trimesh.creation.box((0.2, 0.2, 0.2)))
    occluder = jc.Mesh(np.asarray(occluder.vertices) + [0.5, 0.5, 0.2], occluder.faces)
    scene = _mesh_scene(fresnel=True, interfaces=4, occluders=[occluder], ior=(1.4, 1.5))
    e = scene.effects
    assert (e.refraction, e.fresnel, e.occlusion, e.interfaces, e.dispersion_channels) == (
        True,
        True,
        True,
        4,
        2,
    )
    assert not _mesh_scene().effects.occlusion
    lens = _lens(fresnel=False).effects
    assert lens.interfaces == 2 and not lens.fresnel
