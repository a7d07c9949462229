"""Layered distance maps, tracing in them, and light cube maps (Umenhoffer et al.)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxcaustics import Mesh
from jaxcaustics.methods.triangles import cube_faces
from jaxcaustics.methods.triangles import distance_map as dm

CENTER = np.array([0.0, 0.0, 1.0])
BOX_HALF, BOX_TOP = 0.2, 0.3  # box [-0.2, 0.2]^2 x [0, 0.3] standing on the receiver


# test helpers (they served only the tests in the package)


def direction_to_texel(directions, resolution: int):
    """Face and pixel coordinates of directions on an ``R x R`` cube map.

    **Returns:** ``(face, x, y)``: the face (`direction_face`) and the pixel coordinates
    on it, in ``[0, R]`` (texel ``(i, j)`` = ``(floor(y), floor(x))``, clipped to
    ``R - 1`` on the far edges).
    """
    face = dm.direction_face(directions)
    x, y, _ = dm.face_coordinates(directions, face, resolution)
    return face, x, y


def format_tracing_table(table: dict[str, np.ndarray]) -> str:
    """`tracing_error_table` as plain text: one row per (steps, iterations)."""
    lines = [
        f"{'steps':>5} {'secant':>6} {'median m':>10} {'p95 m':>10} {'max m':>10}"
        f" {'missed':>7} {'false':>7}"
    ]
    for i, n in enumerate(table["linear_steps"]):
        for j, it in enumerate(table["secant_iterations"]):
            lines.append(
                f"{n:>5d} {it:>6d} {table['median'][i, j]:>10.2e} {table['p95'][i, j]:>10.2e}"
                f" {table['max'][i, j]:>10.2e} {table['missed'][i, j]:>7.4f}"
                f" {table['false'][i, j]:>7.4f}"
            )
    return "\n".join(lines)


def _box():
    box = trimesh.creation.box(extents=(2 * BOX_HALF, 2 * BOX_HALF, BOX_TOP))
    box.apply_translation((0.0, 0.0, BOX_TOP / 2))
    return Mesh.from_trimesh(box)


@pytest.fixture(scope="module")
def box_scene():
    occluders = (_box(),)
    return occluders, dm.build_distance_map(CENTER, occluders, resolution=32, layers=2)


def _grid_triangles(x0, x1, y0, y1, z, nx, ny):
    """Triangles tiling the rectangle [x0, x1] x [y0, y1] at height z."""
    xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
    p = np.stack([*np.meshgrid(xs, ys, indexing="ij"), np.full((nx + 1, ny + 1), z)], -1)
    tris = []
    for i in range(nx):
        for j in range(ny):
            a, b, c, d = p[i, j], p[i + 1, j], p[i + 1, j + 1], p[i, j + 1]
            tris += [[a, b, c], [a, c, d]]
    return np.asarray(tris)


# --------------------------------------------------------------------------------------
# cube-map geometry
# --------------------------------------------------------------------------------------


def test_face_frames_are_right_handed():
    for n, u, v in cube_faces._FRAMES:
        np.testing.assert_array_equal(np.cross(u, v), n)


def test_direction_to_texel_face_choice_and_round_trip(rng):
    r = 16
    assert [int(dm.direction_face(jnp.asarray(d))) for d in np.eye(3)] == [0, 2, 4]
    assert [int(dm.direction_face(-jnp.asarray(d))) for d in np.eye(3)] == [1, 3, 5]
    assert int(dm.direction_face(jnp.array([0.5, -0.9, 0.1]))) == 3
    # texel centre directions map back to their own texel centres
    w = dm.texel_directions(r)
    face, x, y = direction_to_texel(w * 3.7, r)  # any length
    f_exp, i_exp, j_exp = np.meshgrid(np.arange(6), np.arange(r), np.arange(r), indexing="ij")
    np.testing.assert_array_equal(face, f_exp)
    np.testing.assert_allclose(x, j_exp + 0.5, atol=1e-12)
    np.testing.assert_allclose(y, i_exp + 0.5, atol=1e-12)
    # random directions: the face is the largest component, the projection lands inside
    d = rng.normal(size=(500, 3))
    face, x, y = direction_to_texel(jnp.asarray(d), r)
    axis = np.argmax(np.abs(d), axis=1)
    np.testing.assert_array_equal(face, 2 * axis + (d[np.arange(500), axis] < 0))
    assert np.all((x >= 0) & (x <= r) & (y >= 0) & (y <= r))
    # and back: the texel-space point, lifted to a direction, is parallel to d
    frames = cube_faces._FRAMES[np.asarray(face)]
    u, v = 2 * np.asarray(x) / r - 1, 2 * np.asarray(y) / r - 1
    back = frames[:, 0] + u[:, None] * frames[:, 1] + v[:, None] * frames[:, 2]
    np.testing.assert_allclose(np.cross(back, d), 0.0, atol=1e-12)
    assert np.all(np.sum(back * d, axis=1) > 0)


def test_face_coordinates_convention_and_spill():
    r = 8
    # -z face: U = +y (columns), V = +x (rows); d = (a, b, -1) -> u = b, v = a
    x, y, depth = dm.face_coordinates(jnp.array([0.25, -0.5, -2.0]), 5, r)
    np.testing.assert_allclose([x, y, depth], [(-0.25 + 1) * 4, (0.125 + 1) * 4, 2.0])
    # a direction just past the -z / +x seam still projects onto -z, outside its image,
    # and the straight edge through it stays straight (gnomonic projection)
    d = jnp.array([[1.1, 0.0, -1.0], [0.9, 0.3, -1.0], [1.3, -0.3, -1.0]])
    assert int(dm.direction_face(d[0])) == 0
    x, y, depth = dm.face_coordinates(d, 5, r)
    assert float(y[0]) > r and np.all(np.asarray(depth) > 0)
    p = np.stack([x, y], -1)
    (ax, ay), (bx, by) = p[1] - p[0], p[2] - p[0]
    cross = ax * by - ay * bx
    assert abs(cross) < 1e-12  # the three directions lie on one plane through c
    # behind the face: depth <= 0, finite coordinates
    x, y, depth = dm.face_coordinates(jnp.array([0.0, 1.0, 1.0]), 5, r)
    assert float(depth) < 0 and np.isfinite([x, y]).all()


# --------------------------------------------------------------------------------------
# distance maps
# --------------------------------------------------------------------------------------


def test_distance_map_of_the_plane():
    r, h = 16, 0.7
    c = np.array([0.1, -0.2, h])
    dmap = dm.build_distance_map(c, (), resolution=r, layers=2)
    w = np.asarray(dm.texel_directions(r))
    down = w[..., 2] < 0
    expected = np.where(down, h / np.where(down, -w[..., 2], 1.0), np.inf)
    d0 = np.asarray(dmap.distance[0])
    np.testing.assert_array_equal(np.isinf(d0), ~down)
    np.testing.assert_allclose(d0[down], expected[down], rtol=1e-12)
    np.testing.assert_array_equal(dmap.material[0], np.where(down, 1, 0))
    assert np.all(np.asarray(dmap.normal[0])[down] == [0.0, 0.0, 1.0])
    assert np.all(np.isinf(dmap.distance[1])) and np.all(dmap.material[1] == 0)


def test_distance_map_with_a_box(box_scene):
    _, dmap = box_scene
    w = np.asarray(dm.texel_directions(dmap.resolution))
    down = w[..., 2] < -1e-9
    t_top = np.where(down, (CENTER[2] - BOX_TOP) / np.where(down, -w[..., 2], 1), np.inf)
    t_plane = np.where(down, CENTER[2] / np.where(down, -w[..., 2], 1), np.inf)
    top_xy = np.abs(CENTER[:2] + w[..., :2] * t_top[..., None]).max(-1)
    plane_xy = np.abs(CENTER[:2] + w[..., :2] * t_plane[..., None]).max(-1)
    on_top = down & (top_xy < BOX_HALF - 1e-6)
    clear = down & (top_xy > BOX_HALF + 1e-6) & (plane_xy > BOX_HALF)
    assert on_top.sum() > 20 and clear.sum() > 1000
    d, m = np.asarray(dmap.distance), np.asarray(dmap.material)
    # layer 0 sees the box top, layer 1 the plane behind it
    np.testing.assert_array_equal(m[0][on_top], 2)
    np.testing.assert_allclose(d[0][on_top], t_top[on_top], rtol=1e-12)
    assert np.all(np.asarray(dmap.normal[0])[on_top] == [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(m[1][on_top], 1)
    np.testing.assert_allclose(d[1][on_top], t_plane[on_top], rtol=1e-12)
    # elsewhere: the plane, nothing behind it
    np.testing.assert_array_equal(m[0][clear], 1)
    np.testing.assert_allclose(d[0][clear], t_plane[clear], rtol=1e-12)
    assert np.all(m[1][clear] == 0) and np.all(np.isinf(d[1][clear]))
    # a floating box: culled, the plane is behind its top; unculled, its bottom face is
    lifted = (Mesh(np.asarray(_box().vertices) + [0.0, 0.0, 0.1], _box().faces),)
    culled = dm.build_distance_map(CENTER, lifted, resolution=8)
    full = dm.build_distance_map(CENTER, lifted, resolution=8, cull_back_faces=False)
    seen = np.asarray(culled.material[0]) == 2
    assert seen.sum() == 4
    assert np.all(np.asarray(culled.material[1])[seen] == 1)
    assert np.all(np.asarray(full.material[1])[seen] == 2)
    np.testing.assert_allclose(np.asarray(full.normal[1])[seen], [[0, 0, 1.0]] * 4)  # faces c


# --------------------------------------------------------------------------------------
# tracing
# --------------------------------------------------------------------------------------


def _rays(n, seed=0, spread=0.03):
    """Rays leaving a small object around the centre, going down."""
    rng = np.random.default_rng(seed)
    o = CENTER + rng.normal(size=(n, 3)) * spread
    d = rng.normal(size=(n, 3))
    d[:, 2] = -np.abs(d[:, 2]) - 0.3
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


# on request (slow), for the default run's 10-minute budget: tracing through the maps
# against exact hits is tested below (exact plane hits, clean misses, the box edge)
@pytest.mark.slow
def test_tracing_error_table(box_scene):
    occluders, dmap = box_scene
    o, d = _rays(400)
    table = dm.tracing_error_table(dmap, o, d, occluders)
    print("\n" + format_tracing_table(table))
    med, p95 = table["median"], table["p95"]
    # secant iterations: the linear search alone is off by about a step, one secant step
    # lands on the planar facets (exact up to rounding), more never hurt
    assert np.all(med[:, 0] > 1e-3) and np.all(med[:, 1:] < 1e-12)
    assert np.all(np.diff(med, axis=1) <= 1e-15)
    assert np.all(np.diff(p95, axis=1) <= 1e-12)
    # the linear search alone improves with more steps
    assert np.all(np.diff(med[:, 0]) < 0)
    # defaults (32 steps, 4 iterations): bound on the bulk; the tail is silhouette texels
    i, j = list(table["linear_steps"]).index(32), list(table["secant_iterations"]).index(4)
    assert p95[i, j] < 1e-9
    assert table["missed"][i, j] <= 0.01 and table["false"][i, j] <= 0.03


def test_trace_plane_hits_are_exact_and_misses_are_clean(box_scene):
    _, dmap = box_scene
    # origins beside the box, aimed at the open plane (one far out), and rays going up
    o = np.array([[0.5, 0.4, 0.9], [-0.6, 0.1, 1.1], [0.3, 0.0, 1.0]] + [[0.0, 0.0, 1.0]] * 2)
    d = np.array(
        [[0.3, 0.2, -1.0], [-0.2, -0.5, -1.0], [5.0, 1.0, -1.0], [0.1, 0.2, 1.0], [0, 0, 1.0]]
    )
    hit = dm.trace_distance_map(dmap, o, d)
    np.testing.assert_array_equal(hit.found, [True, True, True, False, False])
    np.testing.assert_array_equal(hit.material, [1, 1, 1, 0, 0])
    np.testing.assert_array_equal(hit.layer, [0, 0, 0, -1, -1])
    t = -o[:3, 2] / d[:3, 2]
    np.testing.assert_allclose(hit.point[:3], o[:3] + d[:3] * t[:, None], atol=1e-12)
    assert np.all(np.isfinite(hit.point)) and np.all(np.isinf(hit.distance[3:]))
    # a finite search range: the far ray (parameter 1) is out of reach of 0.95
    near = dm.trace_distance_map(dmap, o, d, max_distance=0.95)
    np.testing.assert_array_equal(near.found, [True, False, False, False, False])
    np.testing.assert_allclose(near.point[0], hit.point[0], atol=1e-12)


def test_ray_past_the_box_edge_finds_the_plane_behind(box_scene):
    """Rays from an offset origin pass beside the box, then enter the region hidden
    behind its top edge (seen from the centre), where layer 0 holds the box top: the
    sign change there is a jump, not a hit; the plane is found in layer 1."""
    _, dmap = box_scene
    shadow = BOX_HALF * CENTER[2] / (CENTER[2] - BOX_TOP)  # edge of the box's shadow
    ys = np.linspace(-0.1, 0.1, 5)
    targets = np.stack([np.full(5, 0.5 * (BOX_HALF + shadow)), ys, np.zeros(5)], -1)
    o = np.stack([np.full(5, 0.3), ys, np.full(5, 1.0)], -1)
    d = targets - o
    # they do miss the box (x > BOX_HALF at the top's height) and end in its shadow
    assert np.all(o[:, 0] + d[:, 0] * (1 - BOX_TOP) > BOX_HALF)
    assert np.all(targets[:, 0] < shadow)
    hit = dm.trace_distance_map(dmap, o, d)
    assert np.all(hit.found)
    np.testing.assert_array_equal(hit.material, 1)
    np.testing.assert_array_equal(hit.layer, 1)
    np.testing.assert_allclose(hit.point, targets, atol=1e-9)
    # accepting every sign change (no crossing check) gives the false hit at the edge
    naive = dm.trace_distance_map(dmap, o, d, tolerance=1e9)
    assert np.all(np.asarray(naive.layer) == 0)
    assert np.all(np.linalg.norm(np.asarray(naive.point) - targets, axis=-1) > 1e-2)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-9), (np.float32, 2e-3)])
def test_traced_hit_gradients(box_scene, dtype, tol):
    dmap = jax.tree_util.tree_map(
        lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, box_scene[1]
    )

    def hit_points(o, d):
        p = dm.trace_distance_map(dmap, o, d).point
        return p, p

    # one ray onto the plane (z = 0), one onto the box top (z = BOX_TOP), one miss
    o = np.array([[0.02, -0.01, 0.98], [-0.01, 0.03, 1.01], [0.0, 0.0, 1.0]], dtype)
    d = np.array([[0.35, -0.3, -1.0], [0.05, 0.08, -1.0], [0.1, 0.0, 1.0]], dtype)
    z = np.array([0.0, BOX_TOP])
    # jitted: run eagerly, op by op, 3.3 s (float64) and 2.9 s (float32)
    (jac_o, jac_d), p = jax.jit(jax.jacfwd(hit_points, argnums=(0, 1), has_aux=True))(
        jnp.asarray(o), jnp.asarray(d)
    )
    assert p.dtype == dtype and jac_o.dtype == dtype
    assert np.all(np.isfinite(jac_o)) and np.all(np.isfinite(jac_d))
    np.testing.assert_allclose(p[:2, 2], z, atol=tol)
    jac_o = np.asarray(jac_o)[[0, 1, 2], :, [0, 1, 2]]  # per-ray blocks, (3, 3, 3)
    jac_d = np.asarray(jac_d)[[0, 1, 2], :, [0, 1, 2]]
    np.testing.assert_array_equal(p[2], o[2])  # the miss stays at its origin
    np.testing.assert_array_equal(jac_o[2], np.eye(3))
    np.testing.assert_array_equal(jac_d[2], 0.0)
    for k in range(2):
        # hit of a horizontal plane z: p = o - d (o_z - z) / d_z
        proj = np.eye(3) - np.outer(d[k], [0.0, 0.0, 1.0]) / d[k, 2]
        np.testing.assert_allclose(jac_o[k], proj, atol=tol)
        np.testing.assert_allclose(jac_d[k], -(o[k, 2] - z[k]) / d[k, 2] * proj, atol=tol)


# --------------------------------------------------------------------------------------
# light cube map and camera pass
# --------------------------------------------------------------------------------------


def test_light_cube_map_round_trip():
    """A constant caustic on a receiver patch that crosses the -z / +x seam comes back
    as itself, with no gap or double count at the seam, and 0 outside the patch."""
    r = 48
    x0, x1, y0, y1 = -0.35, 1.6, -0.31, 0.29  # seam at x = 1 (c_z = 1)
    tris = _grid_triangles(x0, x1, y0, y1, 0.0, 30, 10)
    lcm = dm.light_cube_map(CENTER, tris, np.full(tris.shape[:2], 2.0), np.ones(len(tris), bool), r)
    assert int(lcm.dropped) == 0
    cov = np.asarray(lcm.coverage)
    assert cov.max() < 1 + 1e-9  # no texel drawn twice
    assert np.all(cov[[0, 5]].max(axis=(1, 2)) > 0.5)  # both faces of the seam drawn
    # stored distances are those of the plane along the texel directions
    w = np.asarray(dm.texel_directions(r))
    covered = cov > 0.5
    expected = CENTER[2] / -w[..., 2][covered]
    np.testing.assert_allclose(np.asarray(lcm.distance)[covered], expected, rtol=1e-12)
    # interior points: one texel footprint (at most ~0.06 m here) away from the border
    rng = np.random.default_rng(3)
    m = 0.07
    inside = np.c_[rng.uniform(x0 + m, x1 - m, 300), rng.uniform(y0 + m, y1 - m, 300)]
    inside = np.c_[inside, np.zeros(300)]
    near_seam = np.c_[np.linspace(0.9, 1.1, 41), np.zeros(41), np.zeros(41)]
    outside = np.c_[rng.uniform(-1.0, -0.45, 100), rng.uniform(-1, 1, 100), np.zeros(100)]
    pts = np.concatenate([inside, near_seam, outside])
    for lookup in ("nearest", "bilinear"):
        e = dm.project_light_cube_map(lcm, CENTER, pts, lookup=lookup, tolerance=1e-6)
        np.testing.assert_allclose(e[:-100], 2.0, rtol=1e-12)
        np.testing.assert_array_equal(e[-100:], 0.0)


def test_light_cube_map_does_not_leak_behind_an_occluder():
    """Caustic on the top of a box: receiver points hidden behind it (from the centre)
    get nothing with the shadow test, the caustic's value without it."""
    c = np.array([0.05, -0.03, 1.0])
    tris = _grid_triangles(-BOX_HALF, BOX_HALF, -BOX_HALF, BOX_HALF, BOX_TOP, 8, 8)
    lcm = dm.light_cube_map(c, tris, np.full(tris.shape[:2], 2.0), np.ones(len(tris), bool), 48)
    rng = np.random.default_rng(4)
    top = np.c_[rng.uniform(-0.17, 0.17, (100, 2)), np.full(100, BOX_TOP)]
    behind = c + (top - c) * (c[2] / (c[2] - BOX_TOP))  # same directions, on z = 0
    np.testing.assert_allclose(behind[:, 2], 0.0, atol=1e-12)
    # the direction test alone cannot tell them apart ...
    np.testing.assert_allclose(
        dm.project_light_cube_map(lcm, c, behind, shadow_test=False), 2.0, rtol=1e-12
    )
    # ... the distance test does
    np.testing.assert_array_equal(dm.project_light_cube_map(lcm, c, behind), 0.0)
    np.testing.assert_allclose(dm.project_light_cube_map(lcm, c, top), 2.0, rtol=1e-12)
    # invalid triangles (NaN) draw nothing
    bad = tris.copy()
    bad[0] = np.nan
    valid = np.ones(len(tris), bool)
    valid[0] = False
    lcm2 = dm.light_cube_map(c, bad, np.full(tris.shape[:2], 2.0), valid, 48)
    assert np.all(np.isfinite(lcm2.irradiance))
