"""The triangle search: the bounding volume hierarchy finds what brute force finds.

`nearest_hits` searches meshes of more than `BRUTE_FORCE_FACES` triangles with a tree
(`build_hierarchy`, walked front to back without a stack, lanes refilled as rays end).
The tree must change nothing but the time: the same nearest hit (ray parameter and
triangle index, ties to the lower index) for every ray, under `jit` and `vmap`, with
traced vertices, and the same rendered images and gradients.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics.trace import intersect as _intersect
from jaxcaustics.trace.intersect import (
    BRUTE_FORCE_FACES,
    LEAF_FACES,
    build_hierarchy,
    nearest_hits,
    search_bytes,
)


def _blob(subdivisions=3, z=1.0, dtype=np.float64):
    """A bumpy icosphere (1280 faces at 3 subdivisions: above the brute-force limit)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(sphere.vertices)
    r = 0.3 * (1 + 0.1 * v[:, 0] * v[:, 1] + 0.08 * np.sin(3 * v[:, 2]))
    return jc.Mesh(np.asarray(v * r[:, None] + [0.0, 0.0, z], dtype), np.asarray(sphere.faces))


def _rays(count, dtype, seed=0):
    """Rays from above, from inside the blob and along the axes (zero direction
    components), most of them aimed at the blob, some past it."""
    rng = np.random.default_rng(seed)
    origins = np.concatenate(
        [
            rng.normal(size=(count, 3)) * 0.2 + [0.0, 0.0, 2.0],
            rng.normal(size=(count, 3)) * 0.05 + [0.0, 0.0, 1.0],
        ]
    )
    aim = rng.normal(size=(2 * count, 3)) * 0.4 + [0.0, 0.0, 1.0]
    directions = aim - origins
    directions[:8] = [[0.0, 0.0, -1.0]] * 4 + [[1.0, 0.0, 0.0]] * 2 + [[0.0, -1.0, 0.0]] * 2
    origins[4:8] = [0.0, 0.0, 1.0]
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return jnp.asarray(origins, dtype), jnp.asarray(directions, dtype)


def _assert_same_hits(found, origins, directions, triangles, t_min, exclude=None):
    """`found` ``(t, index)`` is the nearest hit by brute force: misses agree, ``t`` to
    rounding (the tree stores each triangle's edges, brute force subtracts them anew, and
    XLA fuses the two differently: ``t``, a ratio of triple products, then differs by up
    to about 10 units in the last place; 100 allowed), and the triangle
    is the brute force's, or one it hits at that same distance (a ray through a shared
    vertex or edge meets several triangles at once)."""
    t, index = (np.asarray(a) for a in found)
    every = np.array(_intersect.ray_triangle_distances(origins, directions, triangles, t_min))
    if exclude is not None:
        skip = np.asarray(exclude)
        every[np.arange(len(every))[skip >= 0], skip[skip >= 0]] = np.inf
    nearest = every.min(axis=1)
    hit = np.isfinite(nearest)
    rtol = 100 * np.finfo(every.dtype).eps
    np.testing.assert_array_equal(np.isfinite(t), hit)
    np.testing.assert_allclose(t[hit], nearest[hit], rtol=rtol)
    same = index == every.argmin(axis=1)
    tied = np.isclose(every[np.arange(len(every)), index], nearest, rtol=rtol, atol=0)
    assert np.all((same | tied)[hit])
    assert np.all(index[~hit] == 0)
    return hit


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_tree_finds_the_brute_force_hits(dtype):
    mesh = _blob(dtype=dtype)
    triangles = mesh.vertices[mesh.faces]
    assert triangles.shape[0] > BRUTE_FORCE_FACES  # the tree is used
    origins, directions = _rays(400, dtype)
    rng = np.random.default_rng(1)
    exclude = jnp.asarray(rng.integers(-1, triangles.shape[0], origins.shape[0]), jnp.int32)
    t_min = 1e-6
    # lanes: fewer than the rays, so lanes are refilled
    found = jax.jit(nearest_hits, static_argnums=4)(
        origins, directions, triangles, t_min, 64, exclude
    )
    hit = _assert_same_hits(found, origins, directions, triangles, t_min, exclude)
    assert 0.3 < hit.mean() < 1.0  # hits and misses both tested


@pytest.mark.slow  # 15 s (the default run's budget); the tree against brute force and
# under traced vertices without vmap stay in the default run
def test_the_tree_follows_traced_vertices_under_vmap():
    """Two meshes at once (a batch of scenes): one tree each, built under `vmap`."""
    a, b = _blob(), _blob(z=1.2)
    b = jc.Mesh(b.vertices * jnp.asarray([1.3, 0.8, 1.0]), b.faces)
    triangles = jnp.stack([a.vertices[a.faces], b.vertices[b.faces]])
    origins, directions = _rays(200, np.float64, seed=2)
    search = jax.vmap(lambda tri: nearest_hits(origins, directions, tri, 1e-9, 128))
    t, index = search(triangles)
    for k in range(2):
        _assert_same_hits((t[k], index[k]), origins, directions, triangles[k], 1e-9)
    assert not np.array_equal(np.asarray(t[0]), np.asarray(t[1]))  # two trees, not one


def test_every_triangle_sits_in_one_leaf_inside_every_box_above_it():
    mesh = _blob()
    triangles = np.asarray(mesh.vertices[mesh.faces])
    tree = build_hierarchy(mesh.vertices[mesh.faces])
    leaves = np.asarray(tree.leaves)
    assert leaves.shape[1] == LEAF_FACES
    real = leaves[leaves < len(triangles)]
    np.testing.assert_array_equal(np.sort(real), np.arange(len(triangles)))
    boxes = np.asarray(tree.boxes)
    first_leaf = leaves.shape[0]
    for slot, faces in enumerate(leaves):
        node = first_leaf + slot
        for face in faces[faces < len(triangles)]:
            k = node
            while k >= 1:  # the leaf and each of its ancestors hold the triangle
                assert np.all(boxes[k, :3] <= triangles[face].min(0))
                assert np.all(boxes[k, 3:] >= triangles[face].max(0))
                k //= 2


def _scene(mesh):
    return jc.MeshScene(
        mesh,
        jc.DirectionalLight.from_angles(15.0, 30.0),
        jc.PlaneReceiver((-0.6, 0.6, -0.6, 0.6), (24, 24)),
        ior=1.5,
    )


# 20-30 s (a brute-force render and its gradient): on request, for the default run's time
# budget; the tree's hits equal brute force's in the default run
# (test_the_tree_finds_the_brute_force_hits)
@pytest.mark.slow
def test_a_render_and_its_gradient_do_not_change_with_the_tree(monkeypatch):
    scene = _scene(_blob())

    def loss(vertices):
        s = jc.MeshScene(
            jc.Mesh(vertices, scene.generator.faces), scene.light, scene.receiver, ior=1.5
        )
        image = jc.render(s, "triangles", photons=33, window=12)
        return jnp.sum(image * jnp.linspace(0.0, 1.0, image.size).reshape(image.shape))

    vertices = scene.generator.vertices
    with_tree = jax.value_and_grad(loss)(vertices)
    monkeypatch.setattr(_intersect, "BRUTE_FORCE_FACES", 10**9)
    searched = []  # the brute-force search traced (not a cached compilation of the tree's)
    brute_search = _intersect.ray_triangle_distances
    monkeypatch.setattr(
        _intersect,
        "ray_triangle_distances",
        lambda *a, **k: searched.append(1) or brute_search(*a, **k),
    )
    brute = jax.value_and_grad(loss)(vertices)
    assert searched
    assert float(brute[0]) > 0
    np.testing.assert_allclose(float(with_tree[0]), float(brute[0]), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(with_tree[1]), np.asarray(brute[1]), rtol=0, atol=1e-9)
    assert np.abs(np.asarray(brute[1])).max() > 1e-3  # the gradient is not trivially zero


def test_the_tree_search_memory_does_not_grow_with_rays_times_faces():
    small, large = search_bytes(4096, 10**4), search_bytes(4096, 10**5)
    assert large < 11 * small  # linear in the faces, not in rays x faces
    assert search_bytes(4096, BRUTE_FORCE_FACES) == 8 * 4096 * BRUTE_FORCE_FACES * 16
