"""Caustic spot lights as a rendering method: a glass sphere against the reference."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics import reference


def sphere_scene(zenith=20.0, azimuth=0.0, shape=(48, 48), occluders=()):
    """A glass ball (radius 0.3 m, n = 1.5, centre 1 m up) over a 2 x 2 m floor."""
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight.from_angles(zenith, azimuth),
        jc.PlaneReceiver((-1.2, 0.8, -1.0, 1.0), shape),
        ior=1.5,
        occluders=occluders,
    )


def test_render_dispatches_and_checks_the_scene():
    scene = sphere_scene(shape=(8, 8))
    lights = jc.internal.SpotLights(
        [[0.0, 0.0, 1.0]],
        [[0.0, 0.0, -1.0]],
        [[1.0, 0.0, 0.0]],
        [0.5],
        [0.0],
        [0.3],
        np.ones((1, 8, 8)),
    )
    image, stats = jc.render(scene, lights=lights, samples=1, return_stats=True)
    assert image.shape == (8, 8) and float(jnp.sum(image)) > 0
    assert int(stats["lights"][0]) == 1
    mesh = jc.MeshScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3).to_mesh(1),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (8, 8)),
        occluders=[jc.Ellipsoid.sphere([0.0, 0.0, 0.5], 0.1).to_mesh(1)],
    )
    with pytest.raises(ValueError, match="occluders"):
        jc.internal.spot_lights(mesh)
    with pytest.raises(ValueError, match="lights"):
        jc.internal.spot_lights(scene, lights=lights, max_lights=3)
    with pytest.raises(ValueError, match="scene"):
        jc.internal.spot_lights(object())


@pytest.mark.slow
def test_sphere_caustic_agrees_with_the_reference_at_a_fitted_direction():
    """The lights fitted for this very light direction. Tolerance 0.08 in relative L1
    after a 1-pixel blur (48 x 48 pixels of 4 cm; reference 1024^2 photons, its own
    error about 0.01): the spot lights model each bundle by a radially symmetric focus
    law and a 64^2 light-plane image splatted with 3-ray-spacing splats, which smears
    the sharp rim of the ball's caustic by a few centimetres (Liu et al. report visual,
    not numerical, agreement). Measured: 0.057 (60-degree bundles)."""
    scene = sphere_scene()
    result = jc.internal.spot_lights(scene, rays_per_axis=128, max_lights=8)
    ref = reference.trace_ellipsoid(scene, 1024)
    error = jc.image_error(result.image, ref)
    assert error < 0.08, error
    assert float(result.missed_flux_fraction[0]) <= 0.05 + 1e-9


@pytest.mark.slow
def test_sphere_caustic_from_interpolated_lights_agrees_with_the_reference():
    """A table over the 42 directions of a once-subdivided icosahedron (64^2 rays, 5
    tracking steps), rendered at a vertex direction and at the centre of a face (the
    farthest from its three precomputed directions, 10 degrees). Same tolerance and
    justification as the fitted direction (0.08); interpolating may cost at most 0.02
    more than a fit for that very direction (measured: 0.064 against 0.057)."""
    scene = sphere_scene()
    table = jc.precompute_spot_lights(
        scene, subdivisions=1, rays_per_axis=64, tracking_steps=5, max_lights=4, progress=False
    )
    vertices = np.asarray(table.directions)
    faces = np.asarray(table.faces)
    travel = -vertices  # light travels away from the vertex direction
    zenith = np.degrees(np.arccos(np.clip(-travel[:, 2], -1.0, 1.0)))
    at_vertex = travel[int(np.argmin(np.abs(zenith - 20.0)))]
    centres = vertices[faces].mean(axis=1)
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    face_zenith = np.degrees(np.arccos(np.clip(centres[:, 2], -1.0, 1.0)))
    between = -centres[int(np.argmin(np.abs(face_zenith - 25.0)))]
    for direction in (at_vertex, between):
        lit = jc.EllipsoidScene(
            scene.generator, jc.DirectionalLight(direction), scene.receiver, ior=1.5
        )
        lights = jc.internal.interpolate_spot_lights(table, jnp.asarray(direction))
        image = jc.internal.spot_lights(lit, lights=lights).image
        ref = reference.trace_ellipsoid(lit, 1024)
        direct = jc.internal.spot_lights(lit, rays_per_axis=64, max_lights=4).image
        error, direct_error = jc.image_error(image, ref), jc.image_error(direct, ref)
        assert error < 0.08, (direction, error)
        assert error < direct_error + 0.02, (direction, error, direct_error)


@pytest.mark.slow
def test_mesh_made_with_trimesh_against_the_mesh_reference():
    """The same ball as a trimesh icosphere (642 vertices, smooth normals) in a
    MeshScene: rays traced through the mesh, lights fitted, image against the mesh
    reference. Tolerance 0.1 (the sphere's 0.08 plus the mesh tracer's 48^2-ray grid:
    coarser splats; measured 0.052)."""
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    ball.apply_translation([0.0, 0.0, 1.0])
    scene = jc.MeshScene(
        jc.Mesh.from_trimesh(ball),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1.2, 0.8, -1.0, 1.0), (48, 48)),
        ior=1.5,
    )
    result = jc.internal.spot_lights(scene, rays_per_axis=48, max_lights=4)
    ref = reference.trace_mesh(scene, 512)
    error = jc.image_error(result.image, ref)
    assert error < 0.1, error


def test_a_scene_the_method_does_not_model_is_rendered_with_a_warning():
    """Spot lights need an object that focuses rays near points (`support` says so); a
    long rod rendered with them anyway says so instead of passing silently (it was 0.85
    off the reference, without a word)."""
    import warnings

    lights = jc.internal.SpotLights(
        [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]], [[1.0, 0.0, 0.0]],
        [0.5], [0.0], [0.3], np.ones((1, 8, 8)),
    )  # fmt: skip
    rod = jc.EllipsoidScene(
        jc.Ellipsoid((0.0, 0.0, 1.0), (0.8, 0.1, 0.1)),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (8, 8)),
        ior=1.5,
    )
    assert jc.internal.method_support("spot_lights", rod) is not None
    with pytest.warns(UserWarning, match="'spot_lights' does not model this scene.*elongated"):
        jc.render(rod, "spot_lights", lights=lights, samples=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a sphere is modelled: no word
        jc.render(sphere_scene(shape=(8, 8)), "spot_lights", lights=lights, samples=1)
