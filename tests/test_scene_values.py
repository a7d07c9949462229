"""A scene changed after it was built (``eqx.tree_at``, or traced under ``jax.jit``) is
checked where a method starts rendering: a NaN field, an upward light or impossible
geometry is an error naming the field, never an all-black image (issue 20)."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc

RECEIVER = jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (8, 8))
DOWN = jc.DirectionalLight([0.0, 0.0, -1.0])


def water():
    heights = 0.01 * np.sin(np.linspace(0, 2 * np.pi, 64)).reshape(8, 8)
    return jc.WaterScene(jc.HeightField(heights, (-1.0, 1.0, -1.0, 1.0)), DOWN, RECEIVER, 0.5)


def lens(light=DOWN):
    surface = jc.HeightField(np.zeros((8, 8)), (-0.05, 0.05, -0.05, 0.05), boundary="clamp")
    return jc.LensScene(surface, light, RECEIVER)


def sphere_mesh():
    mesh = trimesh.creation.icosphere(1, radius=0.3)
    mesh.apply_translation([0.0, 0.0, 1.0])
    return jc.Mesh.from_trimesh(mesh)


def mesh_scene(light=DOWN):
    return jc.MeshScene(sphere_mesh(), light, RECEIVER)


def ellipsoid_scene():
    return jc.EllipsoidScene(jc.Ellipsoid((0.0, 0.0, 1.0), (0.3, 0.3, 0.3)), DOWN, RECEIVER)


UP = jnp.array([0.0, 0.0, 1.0])
SCENES = {"twopass": water, "triangles": lens, "caustics_mapping": mesh_scene,
          "adaptive": mesh_scene, "spot_lights": ellipsoid_scene}  # fmt: skip


@pytest.mark.parametrize("method", sorted(SCENES))
@pytest.mark.parametrize(
    "change, field",
    [
        (lambda s: eqx.tree_at(lambda s: s.light.direction, s, UP), "scene.light.direction"),
        (
            lambda s: eqx.tree_at(lambda s: s.light.direction, s, jnp.array([0.0, jnp.nan, -1])),
            "scene.light.direction",
        ),
        (
            lambda s: eqx.tree_at(lambda s: s.receiver.extent, s, jnp.array([1.0, -1, -1, 1])),
            "scene.receiver.extent",
        ),
    ],
)
def test_every_method_refuses_a_changed_light_or_receiver(method, change, field):
    scene = change(SCENES[method]())
    with pytest.raises(ValueError, match="`" + re.escape(field) + "`"):
        jc.render(scene, method)


@pytest.mark.parametrize(
    "make, where, value, match",
    [
        (water, lambda s: s.surface.heights, jnp.full((8, 8), jnp.nan), "scene.surface.heights"),
        (water, lambda s: s.surface.heights, jnp.full((8, 8), -0.6), "scene.surface"),
        (water, lambda s: s.rest_depth, jnp.array(-0.5), "scene.rest_depth"),
        (water, lambda s: s.surface.extent, jnp.array([0.0, 0, 0, 1]), "scene.surface.extent"),
        (lens, lambda s: s.screen_distance, jnp.array(0.0), "scene.screen_distance"),
        (lens, lambda s: s.thickness, jnp.array(-0.01), "scene.thickness"),
        (lens, lambda s: s.surface.heights, jnp.full((8, 8), -0.02), "scene.surface"),
        (
            lambda: lens(jc.PointLight([0.0, 0.0, 2.0])),
            lambda s: s.light.position,
            jnp.array([0.0, 0.0, 0.2]),
            "scene.light",
        ),
        (
            lambda: lens(jc.PointLight([0.0, 0.0, 2.0])),
            lambda s: s.light.intensity,
            jnp.array(-1.0),
            "scene.light.intensity",
        ),
        (
            mesh_scene,
            lambda s: s.generator.faces,
            jnp.asarray(sphere_mesh().faces)[:, ::-1],
            "scene.generator",
        ),
        (
            mesh_scene,
            lambda s: s.generator.vertices,
            sphere_mesh().vertices - jnp.array([0.0, 0.0, 1.0]),
            "scene.generator",
        ),
        (
            lambda: mesh_scene(jc.PointLight([0.0, 0.0, 3.0])),
            lambda s: s.light.position,
            jnp.array([0.0, 0.0, 1.0]),
            "scene.light",
        ),
        (
            ellipsoid_scene,
            lambda s: s.generator.radii,
            jnp.array([0.3, -0.3, 0.3]),
            "scene.generator.radii",
        ),
        (
            ellipsoid_scene,
            lambda s: s.generator.center,
            jnp.array([0.0, 0.0, 0.1]),
            "scene.generator",
        ),
    ],
)
def test_impossible_geometry_set_after_building_is_refused(make, where, value, match):
    scene = eqx.tree_at(where, make(), value)
    with pytest.raises(ValueError, match="`" + re.escape(match)):
        jc.render(scene)


def test_under_jit_a_nan_or_an_upward_light_is_an_error_not_a_black_image():
    scene = water()

    @eqx.filter_jit
    def image(heights, direction):
        changed = eqx.tree_at(lambda s: (s.surface.heights, s.light.direction), scene,
                              (heights, direction))  # fmt: skip
        return jc.render(changed, jc.TwoPass.paper())  # a fixed window under jit

    good = image(scene.surface.heights, scene.light.direction)
    assert float(jnp.mean(good)) == pytest.approx(1.0, abs=0.05)
    with pytest.raises(Exception, match=r"`scene\.surface\.heights` contains NaN"):
        jax.block_until_ready(image(jnp.full((8, 8), jnp.nan), scene.light.direction))
    with pytest.raises(Exception, match=r"`scene\.light\.direction` .* must point down"):
        jax.block_until_ready(image(scene.surface.heights, UP))


def test_a_batch_with_one_bad_scene_is_an_error():
    good = water()
    bad = eqx.tree_at(lambda s: s.rest_depth, good, jnp.array(jnp.nan))
    stacked = jc.devices.stack_scenes([good, good])
    stacked = eqx.tree_at(
        lambda s: s.rest_depth, stacked, jnp.stack([good.rest_depth, bad.rest_depth])
    )
    with pytest.raises(Exception, match=r"`scene\.rest_depth` contains NaN"):
        jax.block_until_ready(jc.render_batch(stacked, "twopass"))


def test_gradients_pass_through_the_checks():
    scene = water()

    def loss(heights):
        image = jc.render(eqx.tree_at(lambda s: s.surface.heights, scene, heights))
        return jnp.sum(image**2)

    grad = jax.grad(loss)(scene.surface.heights)
    assert bool(jnp.all(jnp.isfinite(grad))) and float(jnp.max(jnp.abs(grad))) > 0
