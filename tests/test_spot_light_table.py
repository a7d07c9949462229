"""CSL tables for a moving light (Liu et al. 2008, Sect. 4): directions, matching, triples,
interpolation, sharding, save/load.

Most tests use synthetic CSL sets on the 42-direction icosphere: light "A" exists for every
direction (axis along the light's travel), light "B" only where the light comes from above
(``s_z > 0.2``); slots are shuffled at some vertices and some frames are rotated by 90
degrees, so neither the matching nor the interpolation can rely on slot order or frames.
"""

import importlib.util
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _subprocess import run_python

from jaxcaustics.methods.spot_lights.frames import _canonicalise, _resample_images
from jaxcaustics.methods.spot_lights.light_table import _locate
from jaxcaustics.methods.spot_lights.lights import SpotLights
from jaxcaustics.methods.spot_lights.table import (
    SpotLightTable,
    build_spot_light_table,
    direction_edges,
    greedy_match,
    icosphere_directions,
    interpolate_in_face,
    interpolate_spot_lights,
    slerp,
)
from jaxcaustics.trace.optics import orthonormal_basis

N = 24
K = 3
CENTRE = np.array([0.1, -0.2, 0.3])
SIZE = 1.0


def unit(x):
    x = np.asarray(x, float)
    return x / np.linalg.norm(x)


def geometry(kind, s):
    """(origin, axis, alpha, beta, half_width) of light `kind` for vertex direction `s`."""
    d = -np.asarray(s)
    if kind == 0:
        return CENTRE + 0.7 * d, d, 1.5 + 0.3 * s[2], 0.8 + 0.2 * s[0], 0.4
    axis = unit(d + 0.6 * np.array([1.0, 0.0, 0.0]))
    return CENTRE + 0.3 * np.asarray(s) + [0.2, 0, 0], axis, 0.8, 0.1 + 0.05 * s[1], 0.3


def blob(kind, s, u, v):
    """The image of light `kind` at light-plane coordinates of its canonical frame."""
    amplitude = 1.0 + 0.3 * s[0] if kind == 0 else 0.5 + 0.2 * s[1]
    u0, v0, sigma = (0.08, -0.05, 0.07) if kind == 0 else (-0.04, 0.03, 0.05)
    return amplitude * np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * sigma**2))


def has_b(s):
    return s[2] > 0.2


def synthetic_sets(directions):
    """Stacked (V, K) light fields and the kind held by each slot (-1: empty)."""
    v_count = len(directions)
    fields = {
        "origin": np.zeros((v_count, K, 3)),
        "axis": np.tile([0.0, 0.0, 1.0], (v_count, K, 1)),
        "frame_u": np.tile([1.0, 0.0, 0.0], (v_count, K, 1)),
        "alpha": np.ones((v_count, K)),
        "beta": np.zeros((v_count, K)),
        "half_width": np.ones((v_count, K)),
        "image": np.zeros((v_count, K, N, N)),
        "active": np.zeros((v_count, K), bool),
    }
    kinds = np.full((v_count, K), -1)
    for vi, s in enumerate(directions):
        present = [0, 1] if has_b(s) else [0]
        if vi % 3 == 0:
            present = present[::-1]  # shuffled slots
        for slot, kind in enumerate(present):
            origin, axis, alpha, beta, w = geometry(kind, s)
            e_u, e_v = (np.asarray(e) for e in orthonormal_basis(jnp.asarray(axis)))
            g = (np.arange(N) + 0.5) / N * 2 * w - w
            u, v = np.meshgrid(g, g)  # rows along v, columns along u
            if vi % 4 == 1:  # frame rotated by 90 degrees: u' = v, v' = -u
                frame_u, image = e_v, blob(kind, s, -v, u)
            else:
                frame_u, image = e_u, blob(kind, s, u, v)
            for name, value in (
                ("origin", origin),
                ("axis", axis),
                ("frame_u", frame_u),
                ("alpha", alpha),
                ("beta", beta),
                ("half_width", w),
                ("image", image),
            ):
                fields[name][vi, slot] = value
            fields["active"][vi, slot] = True
            kinds[vi, slot] = kind
    return fields, kinds


def synthetic_tracks(directions, faces, fields, kinds):
    """Exact tracking: each light's geometry formula evaluated at the other end."""
    edges = direction_edges(faces)
    origin = np.zeros((len(edges), 2, K, 3))
    axis = np.zeros((len(edges), 2, K, 3))
    for e, ends in enumerate(edges):
        for side in range(2):
            src, dst = ends[side], ends[1 - side]
            for slot in range(K):
                kind = kinds[src, slot]
                if kind < 0:
                    origin[e, side, slot] = fields["origin"][src, slot]
                    axis[e, side, slot] = fields["axis"][src, slot]
                else:
                    o, a, *_ = geometry(kind, directions[dst])
                    origin[e, side, slot], axis[e, side, slot] = o, a
    return origin, axis


def stacked(fields):
    from jaxcaustics.methods.spot_lights.light_table import _stacked_spot_lights

    return _stacked_spot_lights(fields)


@pytest.fixture(scope="module")
def synthetic():
    directions, faces = icosphere_directions(1)
    fields, kinds = synthetic_sets(directions)
    moved_origin, moved_axis = synthetic_tracks(directions, faces, fields, kinds)
    table = build_spot_light_table(
        directions, faces, stacked(fields), moved_origin, moved_axis, centre=CENTRE, size=SIZE
    )
    return table, kinds


def lit(lights):
    """The active lights as NumPy dicts."""
    mask = np.asarray(lights.active)
    return {
        name: np.asarray(getattr(lights, name))[mask]
        for name in ("origin", "axis", "frame_u", "alpha", "beta", "half_width", "image")
    }


def light_field(lights, decimals=9):
    """Geometry -> summed image of the active lights (lights at one geometry add)."""
    field = {}
    data = lit(lights)
    for k in range(len(data["alpha"])):
        key = tuple(
            np.round(
                np.concatenate(
                    [
                        data["origin"][k],
                        data["axis"][k],
                        data["frame_u"][k],
                        [data["alpha"][k], data["beta"][k], data["half_width"][k]],
                    ]
                ),
                decimals,
            )
        )
        field[key] = field.get(key, 0.0) + data["image"][k]
    return field


def total_power(lights):
    return float(np.sum(np.where(np.asarray(lights.active), np.asarray(lights.power()), 0.0)))


# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("subdivisions, v, f", [(0, 12, 20), (1, 42, 80), (2, 162, 320)])
def test_icosphere_directions(subdivisions, v, f):
    directions, faces = icosphere_directions(subdivisions)
    assert directions.shape == (v, 3) and faces.shape == (f, 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    tri = directions[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("fk,fk->f", normal, tri.sum(1)) > 0)
    edges = direction_edges(faces)
    assert len(edges) == v + f - 2 and np.all(edges[:, 0] < edges[:, 1])
    with pytest.raises(ValueError, match="subdivisions"):
        icosphere_directions(-1)


def test_slerp_and_locate():
    a, b = unit([1.0, 0.2, 0.1]), unit([0.3, 1.0, -0.2])
    mid = np.asarray(slerp(jnp.asarray(a), jnp.asarray(b), 0.5))
    np.testing.assert_allclose(mid, unit(a + b), atol=1e-12)
    directions, faces = icosphere_directions(1)
    rng = np.random.default_rng(1)
    locate = jax.jit(_locate)
    for s in rng.normal(size=(20, 3)):
        s = unit(s)
        face, w = locate(jnp.asarray(directions), jnp.asarray(faces), jnp.asarray(s))
        w = np.asarray(w)
        assert np.all(w >= 0) and abs(w.sum() - 1) < 1e-12
        hit = w @ directions[faces[int(face)]]
        np.testing.assert_allclose(unit(hit), s, atol=1e-12)


def test_greedy_match():
    d = np.array([[0.1, 0.05, np.inf], [0.2, 0.3, 0.9], [np.inf, np.inf, np.inf]])
    p0, p1 = greedy_match(d, threshold=0.5)
    assert p0.tolist() == [1, 0, -1] and p1.tolist() == [1, 0, -1]


def test_resample_rotates_light_plane():
    """A blob at in-plane offset q of a source light lands at R q in the target plane."""
    axis_src = unit([0.0, 0.2, -1.0])
    axis_dst = unit([0.3, -0.1, -1.0])
    e_u, e_v = (np.asarray(e) for e in orthonormal_basis(jnp.asarray(axis_src)))
    n, w = 64, 0.5
    g = (np.arange(n) + 0.5) / n * 2 * w - w
    u, v = np.meshgrid(g, g)
    image = np.exp(-((u - 0.15) ** 2 + (v + 0.1) ** 2) / (2 * 0.03**2))
    source = SpotLights([[0.0, 0, 0]], [axis_src], [e_u], [1.0], [0.0], [w], [image])
    f_u, f_v = (np.asarray(e) for e in orthonormal_basis(jnp.asarray(axis_dst)))
    out = np.asarray(
        jax.jit(_resample_images)(
            source, jnp.asarray([axis_dst]), jnp.asarray([f_u]), jnp.asarray([w])
        )
    )[0]
    q = 0.15 * e_u - 0.1 * e_v
    c = np.cross(axis_src, axis_dst)
    rq = q + np.cross(c, q) + np.cross(c, np.cross(c, q)) / (1 + axis_src @ axis_dst)
    centroid = np.array([np.sum(out * u), np.sum(out * v)]) / np.sum(out)
    np.testing.assert_allclose(centroid, [rq @ f_u, rq @ f_v], atol=2e-3)
    np.testing.assert_allclose(out.sum(), image.sum(), rtol=1e-3)


def test_canonical_frames_rotate_images_exactly():
    """A light whose frame is the canonical one turned by 90 degrees gets its image turned
    back: an exact permutation of the pixels."""
    axis = unit([0.2, -0.3, -1.0])
    e_u, e_v = (np.asarray(e) for e in orthonormal_basis(jnp.asarray(axis)))
    image = np.random.default_rng(0).random((8, 8))
    light = SpotLights([[0.0, 0, 0]], [axis], [e_v], [1.0], [0.0], [0.5], [image])
    canonical = _canonicalise(light)
    np.testing.assert_allclose(np.asarray(canonical.frame_u[0]), e_u, atol=1e-12)
    # canonical (u, v) -> rotated frame (u' = v, v' = -u): new[i, j] = old[N-1-j, i]
    np.testing.assert_allclose(np.asarray(canonical.image[0]), image[::-1].T, atol=1e-12)
    same = _canonicalise(SpotLights([[0.0, 0, 0]], [axis], [e_u], [1.0], [0.0], [0.5], [image]))
    np.testing.assert_array_equal(np.asarray(same.image[0]), image)


def test_matching_follows_tracks(synthetic):
    table, kinds = synthetic
    directions = np.asarray(table.directions)
    for e, (a, b) in enumerate(np.asarray(table.edges)):
        rows = [tuple(r) for r in np.asarray(table.edge_match[e]) if r[0] != -2]
        for i, j in rows:
            ka = kinds[a, i] if i >= 0 else -1
            kb = kinds[b, j] if j >= 0 else -1
            if i >= 0 and j >= 0:
                assert ka == kb  # never A with B
            elif i >= 0:
                assert ka == 1 and not has_b(directions[b])
            else:
                assert kb == 1 and not has_b(directions[a])
        assert len(rows) == max(np.sum(kinds[a] >= 0), np.sum(kinds[b] >= 0))


def test_every_light_painted_once_per_face(synthetic):
    table, kinds = synthetic
    faces = np.asarray(table.faces)
    slot = np.asarray(table.triple_slot)
    paint = np.asarray(table.corner_paint)
    active = np.asarray(table.triple_active)
    assert np.all(paint[slot < 0] == 0) and np.all(paint[~active] == 0)
    for f, face in enumerate(faces):
        for i, v in enumerate(face):
            for s in np.flatnonzero(kinds[v] >= 0):
                painted = paint[f, :, i][active[f] & (slot[f, :, i] == s)]
                assert painted.sum() == 1.0
    # triples where all three pairwise matches agree are merged: A makes one triple per face
    one_triple = [
        np.sum(active[f])
        for f, face in enumerate(faces)
        if not any(has_b(np.asarray(table.directions)[v]) for v in face)
    ]
    assert one_triple and set(one_triple) == {1}


@pytest.mark.parametrize("vertex", [0, 1, 5, 13])
def test_exact_at_vertex(synthetic, vertex):
    table, kinds = synthetic
    s = np.asarray(table.directions[vertex])
    lights = interpolate_spot_lights(table, -s)
    got = lit(lights)
    want = lit(table.lights[vertex])
    assert len(got["alpha"]) == len(want["alpha"]) == np.sum(kinds[vertex] >= 0)
    order_got, order_want = np.argsort(got["alpha"]), np.argsort(want["alpha"])
    for name in got:
        np.testing.assert_allclose(
            got[name][order_got], want[name][order_want], atol=1e-9, err_msg=name
        )


def edge_point(table, edge, t):
    a, b = np.asarray(table.edges[edge])
    return unit((1 - t) * np.asarray(table.directions[a]) + t * np.asarray(table.directions[b]))


def faces_of_edge(table, edge):
    a, b = np.asarray(table.edges[edge])
    faces = np.asarray(table.faces)
    return [f for f in range(len(faces)) if a in faces[f] and b in faces[f]]


def weights_on_edge(table, face, edge, t):
    a, b = np.asarray(table.edges[edge])
    face_vertices = list(np.asarray(table.faces[face]))
    w = np.zeros(3)
    w[face_vertices.index(a)], w[face_vertices.index(b)] = 1 - t, t
    return jnp.asarray(w)


def boundary_edges(table):
    """Edges with B at one end only, and edges with B at both ends."""
    d = np.asarray(table.directions)
    edges = np.asarray(table.edges)
    one = [e for e, (a, b) in enumerate(edges) if has_b(d[a]) != has_b(d[b])]
    both = [e for e, (a, b) in enumerate(edges) if has_b(d[a]) and has_b(d[b])]
    return one, both


def test_continuity_across_edges(synthetic):
    """On an edge both faces give the same light field (same geometries, same summed
    images), and it matches `interpolate_spot_lights` there."""
    table, _ = synthetic
    one, both = boundary_edges(table)
    for edge in (one[0], one[3], both[0], 0):
        f0, f1 = faces_of_edge(table, edge)
        t = 0.37
        lights0 = interpolate_in_face(table, f0, weights_on_edge(table, f0, edge, t))
        field0 = light_field(lights0)
        field1 = light_field(interpolate_in_face(table, f1, weights_on_edge(table, f1, edge, t)))
        assert field0.keys() == field1.keys()
        for key in field0:
            np.testing.assert_allclose(field0[key], field1[key], atol=1e-9)
        auto = interpolate_spot_lights(table, -edge_point(table, edge, t))
        np.testing.assert_allclose(total_power(auto), total_power(lights0), rtol=1e-9)
        assert light_field(auto).keys() == field0.keys()


def test_continuous_near_edge(synthetic):
    """Directions just either side of an edge give nearly the same lights."""
    table, _ = synthetic
    one, _ = boundary_edges(table)
    edge = one[1]
    f0, f1 = faces_of_edge(table, edge)
    on_edge = edge_point(table, edge, 0.6)
    results = []
    for f in (f0, f1):
        third = [v for v in np.asarray(table.faces[f]) if v not in np.asarray(table.edges[edge])]
        s = unit(on_edge + 1e-7 * np.asarray(table.directions[third[0]]))
        results.append(interpolate_spot_lights(table, -s))
    p0, p1 = total_power(results[0]), total_power(results[1])
    assert abs(p0 - p1) < 1e-5 * p0
    image0 = sum(lit(results[0])["image"]).sum()
    image1 = sum(lit(results[1])["image"]).sum()
    np.testing.assert_allclose(image0, image1, rtol=1e-5)


def test_power_between_corners(synthetic):
    table, _ = synthetic
    rng = np.random.default_rng(3)
    faces = np.asarray(table.faces)
    corner_power = [total_power(table.lights[v]) for v in range(len(table.directions))]
    one, _ = boundary_edges(table)
    chosen = [faces_of_edge(table, one[0])[0], faces_of_edge(table, one[2])[1], 0, 7]
    for f in chosen:
        w = rng.dirichlet(np.ones(3))
        s = unit(w @ np.asarray(table.directions[faces[f]]))
        p = total_power(interpolate_spot_lights(table, -s))
        corners = [corner_power[v] for v in faces[f]]
        assert min(corners) * 0.99 <= p <= max(corners) * 1.01


def test_interpolate_under_vmap_and_errors(synthetic):
    table, _ = synthetic
    directions = -np.asarray(table.directions)[[2, 9]] + 0.01
    batched = jax.vmap(lambda d: interpolate_spot_lights(table, d))(jnp.asarray(directions))
    for k, d in enumerate(directions):
        single = interpolate_spot_lights(table, d)
        np.testing.assert_allclose(
            np.asarray(batched.image[k]), np.asarray(single.image), atol=1e-12
        )
    with pytest.raises(ValueError, match="direction"):
        interpolate_spot_lights(table, [0.0, 1.0])
    with pytest.raises(ValueError, match="direction"):
        interpolate_spot_lights(table, [0.0, 0.0, 0.0])


def test_build_errors():
    directions, faces = icosphere_directions(0)
    fields, kinds = synthetic_sets(directions)
    moved = synthetic_tracks(directions, faces, fields, kinds)
    with pytest.raises(ValueError, match="moved_axis"):
        build_spot_light_table(
            directions, faces, stacked(fields), moved[0], moved[1][:, :1], centre=CENTRE, size=SIZE
        )
    with pytest.raises(ValueError, match="size"):
        build_spot_light_table(directions, faces, stacked(fields), *moved, centre=CENTRE, size=0.0)


def test_save_load_round_trip(synthetic, tmp_path):
    table, _ = synthetic
    path = tmp_path / "table.npz"
    table.save(path)
    loaded = SpotLightTable.load(path)
    for a, b in zip(jax.tree.leaves(table), jax.tree.leaves(loaded), strict=True):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="path"):
        SpotLightTable.load(tmp_path / "missing.npz")


SHARDING_SCRIPT = textwrap.dedent(
    """
    import os, sys
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    from jaxcaustics.methods.spot_lights.table import map_sharded

    assert len(jax.devices()) == 4, jax.devices()
    seen = set()

    def fn(shared, item):
        return {"y": jnp.sin(item["x"] @ shared) * item["t"], "n": jnp.sum(item["x"] ** 2)}

    shared = np.linspace(-1.0, 1.0, 12).reshape(3, 4)
    batch = {"x": np.random.default_rng(0).normal(size=(10, 3)), "t": np.arange(10.0)}
    direct = jax.vmap(fn, in_axes=(None, 0))(shared, batch)
    for mode in ("map", "vmap"):  # per device item by item, or vectorised under sharding
        sharded = map_sharded(fn, shared, batch, chunk=6, per_device=mode)
        single = map_sharded(fn, shared, batch, devices=jax.devices()[:1], chunk=3)
        for key in ("y", "n"):
            np.testing.assert_allclose(sharded[key], single[key], rtol=1e-12, atol=1e-14)
            np.testing.assert_allclose(sharded[key], direct[key], rtol=1e-12, atol=1e-14)
    # a chunk really is split across the four devices
    from jax.sharding import Mesh, NamedSharding, PartitionSpec
    mesh = Mesh(np.asarray(jax.devices()), ("directions",))
    x = jax.device_put(np.zeros((8, 3)), NamedSharding(mesh, PartitionSpec("directions")))
    assert len(x.addressable_shards) == 4 and x.addressable_shards[0].data.shape == (2, 3)
    if len(sys.argv) > 1:
        from jaxcaustics.scene.ellipsoid import Ellipsoid, EllipsoidScene
        import jaxcaustics as jc
        scene = EllipsoidScene(
            Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
            jc.DirectionalLight([0.0, 0.0, -1.0]),
            jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], (32, 32)),
            ior=1.5,
        )
        from jaxcaustics.methods.spot_lights.exit_rays import trace_exit_rays
        from jaxcaustics.methods.spot_lights.table import (
            icosphere_directions,
            precompute_spot_lights,
        )

        # the tracer (continuous in its inputs) agrees to rounding
        def trace(sc, d):
            rays = trace_exit_rays(sc, 24, direction=d)
            return rays.origin, rays.direction, rays.energy

        directions = -icosphere_directions(0)[0]
        sharded = map_sharded(trace, scene, directions, chunk=8)
        single = map_sharded(trace, scene, directions, devices=jax.devices()[:1], chunk=4)
        for u, v in zip(sharded, single):
            np.testing.assert_allclose(u, v, rtol=1e-10, atol=1e-12)
        # the whole precomputation: the same lights, matches and triples; the fit's
        # Levenberg-Marquardt stops where its tolerance allows, which differs by ~1e-4 (alpha,
        # beta) between differently partitioned or batched programs
        kw = dict(subdivisions=0, rays_per_axis=24, tracking_steps=2, max_lights=4,
                  resolution=16, progress=False)
        a = precompute_spot_lights(scene, **kw)
        b = precompute_spot_lights(scene, devices=jax.devices()[:1], **kw)
        for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
            u, v = np.asarray(u), np.asarray(v)
            if np.issubdtype(u.dtype, np.floating):
                np.testing.assert_allclose(u, v, rtol=2e-3, atol=2e-3)
            else:
                np.testing.assert_array_equal(u, v)
    print("OK")
    """
)


def run_sharding_script(tmp_path, *args):
    assert "OK" in run_python(tmp_path, SHARDING_SCRIPT, *args)


def test_map_sharded_agrees_with_single_device(tmp_path):
    run_sharding_script(tmp_path)


HAVE_TRACER = all(
    importlib.util.find_spec(f"jaxcaustics.{name}") is not None
    for name in ("_ellipsoid", "_spot_light_fit")
)
needs_tracer = pytest.mark.skipif(not HAVE_TRACER, reason="needs _ellipsoid and _spot_light_fit")


@pytest.mark.slow
@needs_tracer
def test_precompute_sharded_agrees_with_single_device(tmp_path):
    run_sharding_script(tmp_path, "precompute")


@pytest.mark.slow
@needs_tracer
def test_precompute_glass_sphere(tmp_path):
    import jaxcaustics as jc
    from jaxcaustics.methods.spot_lights.table import precompute_spot_lights
    from jaxcaustics.scene.ellipsoid import Ellipsoid, EllipsoidScene

    scene = EllipsoidScene(
        Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight([0.0, 0.0, -1.0]),
        jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], (32, 32)),
        ior=1.5,
    )
    table = precompute_spot_lights(
        scene,
        subdivisions=1,
        rays_per_axis=48,
        tracking_steps=4,
        max_lights=4,
        resolution=24,
        progress=False,
    )
    assert table.directions.shape == (42, 3)
    active = np.asarray(table.lights.active)
    assert np.all(active.any(axis=1))
    # the main light: the most powerful of every direction, its axis along the light
    power = np.where(active, np.asarray(table.lights.power()), 0.0)
    main = np.argmax(power, axis=1)
    axes = np.asarray(table.lights.axis)[np.arange(42), main]
    assert np.all(np.einsum("vk,vk->v", axes, -np.asarray(table.directions)) > 0.95)
    for vertex in (0, 17):
        got = lit(interpolate_spot_lights(table, -np.asarray(table.directions[vertex])))
        want = lit(table.lights[vertex])
        order_got, order_want = np.argsort(got["alpha"]), np.argsort(want["alpha"])
        for name in got:
            np.testing.assert_allclose(
                got[name][order_got], want[name][order_want], atol=1e-8, err_msg=name
            )
    table.save(tmp_path / "sphere.npz")
    loaded = SpotLightTable.load(tmp_path / "sphere.npz")
    np.testing.assert_array_equal(np.asarray(loaded.triple_slot), np.asarray(table.triple_slot))
