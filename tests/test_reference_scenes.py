"""The NumPy reference tracers of the lens and mesh scenes (`jaxcaustics.reference`).

Checked against closed forms: flat slabs (uniform images, Fresnel products, the lateral
displacement of oblique and point light, a point light's ``I cos^3 / h^2``), focal
lengths (a plano-convex lens, a ball lens), total internal reflection thresholds and
retro-reflection, mirrors, exact shadows of occluders, flux conservation; and, photon by
photon, Möller–Trumbore and the hierarchy against brute-force alternatives.
"""

import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics import reference as ref
from jaxcaustics.reference import _lens as lens_ref
from jaxcaustics.reference import _mesh as mesh_ref
from jaxcaustics.reference._surface import _Surface, intersect_surface

DOWN = np.array([0.0, 0.0, -1.0])


# --------------------------------------------------------------------------- helpers


def _fresnel(cos_i, n1, n2):
    """Unpolarised transmittance from n1 into n2 at incidence cos_i (textbook form)."""
    sin_t = n1 / n2 * math.sqrt(max(0.0, 1.0 - cos_i * cos_i))
    cos_t = math.sqrt(1.0 - sin_t * sin_t)
    rs = ((n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)) ** 2
    rp = ((n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)) ** 2
    return 1.0 - 0.5 * (rs + rp)


def _solid_angle(x1, x2, y1, y2, h):
    """Solid angle of the rectangle [x1, x2] x [y1, y2] seen from height h above its
    plane, straight above the origin."""

    def f(x, y):
        return math.atan(x * y / (h * math.sqrt(x * x + y * y + h * h)))

    return f(x2, y2) - f(x1, y2) - f(x2, y1) + f(x1, y1)


def _light(direction=None, position=None, intensity=1.0):
    if position is not None:
        return jc.PointLight(np.asarray(position, np.float64), intensity)
    return jc.DirectionalLight(np.asarray(DOWN if direction is None else direction, np.float64))


def _oblique(zenith_deg, azimuth_deg=0.0):
    z, a = math.radians(zenith_deg), math.radians(azimuth_deg)
    return np.array([math.sin(z) * math.cos(a), math.sin(z) * math.sin(a), -math.cos(z)])


def _lens_scene(
    heights=None,
    extent=(-0.5, 0.5, -0.5, 0.5),
    receiver=(-0.6, 0.6, -0.6, 0.6),
    shape=(12, 12),
    *,
    thickness=0.05,
    screen_distance=0.5,
    light=None,
    rotation=0.0,
    **kwargs,
):
    h = np.zeros((8, 8)) if heights is None else np.asarray(heights, np.float64)
    return jc.LensScene(
        jc.HeightField(h, np.asarray(extent, np.float64), "clamp", rotation),
        light if light is not None else _light(),
        jc.PlaneReceiver(np.asarray(receiver, np.float64), shape),
        np.asarray(thickness, np.float64),
        np.asarray(screen_distance, np.float64),
        **kwargs,
    )


def _bumps(n, extent=(-0.5, 0.5, -0.5, 0.5), amplitude=0.004):
    x = np.linspace(extent[0], extent[1], n)
    y = np.linspace(extent[2], extent[3], n)
    xx, yy = np.meshgrid(x, y)
    return amplitude * (np.sin(9.0 * xx + 1.0) * np.cos(7.0 * yy) + 0.5 * np.sin(13.0 * yy))


def _mesh(tm):
    return jc.Mesh(np.asarray(tm.vertices, np.float64), np.asarray(tm.faces))


def _sphere(radius=0.2, centre=(0.0, 0.0, 0.5), subdivisions=3):
    tm = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    tm.apply_translation(centre)
    return tm


def _box(extents, centre):
    tm = trimesh.creation.box(extents=extents)
    tm.apply_translation(centre)
    return tm


def _mesh_scene(
    generator,
    light=None,
    receiver=(-0.5, 0.5, -0.5, 0.5),
    shape=(10, 10),
    **kwargs,
):
    return jc.MeshScene(
        _mesh(generator),
        light if light is not None else _light(),
        jc.PlaneReceiver(np.asarray(receiver, np.float64), shape),
        **kwargs,
    )


def _check_partition(stats):
    fates = ("missed", "blocked", "dropped", "upward", "landed")
    assert stats["emitted"] == sum(stats[k] for k in fates), stats
    assert stats["hit_generator"] <= stats["emitted"] - stats["missed"], stats
    assert stats["on_receiver"] <= stats["landed"], stats


# --------------------------------------------------------------------------- lens


def test_flat_slab_under_normal_light_gives_one_and_fresnel_gives_both_transmittances():
    scene = _lens_scene(ior=(1.5, 1.7))
    image, stats = ref.trace_lens(scene, 100, return_stats=True)
    assert image.shape == (12, 12, 2)
    np.testing.assert_allclose(image[1:-1, 1:-1], 1.0, rtol=1e-12)
    assert np.all(image[0] == 0) and np.all(image[-1] == 0) and np.all(image[:, 0] == 0)
    assert stats["emitted"] == stats["landed"] == stats["on_receiver"] == (10000, 10000)
    assert stats["lost_tir"] == (0, 0)

    fresnel = ref.trace_lens(_lens_scene(ior=(1.5, 1.7), fresnel=True), 100)
    for k, n in enumerate((1.5, 1.7)):
        t0 = 4.0 * n / (n + 1.0) ** 2  # normal incidence, either way through a face
        np.testing.assert_allclose(fresnel[1:-1, 1:-1, k], t0 * t0, rtol=1e-12)
    assert ref.trace_lens(_lens_scene(ior=1.5), 20).shape == (12, 12)


def test_oblique_light_through_a_flat_slab_shifts_by_the_analytic_displacement():
    zenith, azimuth, n, thickness, screen_distance = 35.0, 30.0, 1.6, 0.08, 0.4
    d = _oblique(zenith, azimuth)
    scene = _lens_scene(
        light=_light(d), thickness=thickness, screen_distance=screen_distance, ior=n, fresnel=True,
        receiver=(-1.0, 1.0, -1.0, 1.0), shape=(20, 20),
    )  # fmt: skip
    rng = np.random.default_rng(1)
    xs, ys = rng.uniform(-0.5, 0.5, 300), rng.uniform(-0.5, 0.5, 300)
    landing, weight, alive = ref.trace_lens_photons(scene, xs, ys)
    sin_t = math.sin(math.radians(zenith)) / n
    shift = thickness * sin_t / math.sqrt(1 - sin_t**2) + screen_distance * math.tan(
        math.radians(zenith)
    )
    a = math.radians(azimuth)
    assert alive.all()
    np.testing.assert_allclose(landing[0, :, 0], xs + shift * math.cos(a), atol=1e-12)
    np.testing.assert_allclose(landing[0, :, 1], ys + shift * math.sin(a), atol=1e-12)
    cos_i = math.cos(math.radians(zenith))
    expected = _fresnel(cos_i, 1.0, n) * _fresnel(math.sqrt(1 - sin_t**2), n, 1.0)
    np.testing.assert_allclose(weight, expected, rtol=1e-12)
    # Stokes: a slab's two faces transmit alike.
    np.testing.assert_allclose(expected, _fresnel(cos_i, 1.0, n) ** 2, rtol=1e-12)
    # all the flux lands: the aperture's area times the transmittances
    image = ref.trace_lens(scene, 64)
    np.testing.assert_allclose(image.sum() * 0.1**2, expected, rtol=1e-12)
    # outside the aperture nothing belongs to the lens
    _, w_out, alive_out = ref.trace_lens_photons(scene, [0.5, -0.6, 0.0], [0.0, 0.0, 0.5])
    assert not alive_out.any() and not w_out.any()


def test_point_light_through_a_flat_slab_lands_at_the_analytic_radius():
    n, thickness, screen_distance, height, intensity = 1.5, 0.05, 0.5, 1.3, 2.0
    light = _light(position=(0.1, -0.05, height), intensity=intensity)
    scene = _lens_scene(
        light=light, thickness=thickness, screen_distance=screen_distance, ior=n, fresnel=True
    )
    rng = np.random.default_rng(2)
    xs, ys = rng.uniform(-0.5, 0.5, 300), rng.uniform(-0.5, 0.5, 300)
    landing, weight, alive = ref.trace_lens_photons(scene, xs, ys)
    assert alive.all()
    rx, ry = xs - 0.1, ys + 0.05
    rho = np.hypot(rx, ry)
    h = height - thickness - screen_distance  # light above the rest plane
    sin_i = rho / np.hypot(rho, h)
    cos_i = h / np.hypot(rho, h)
    sin_t = sin_i / n
    radius = rho + thickness * sin_t / np.sqrt(1 - sin_t**2) + screen_distance * sin_i / cos_i
    np.testing.assert_allclose(landing[0, :, 0], 0.1 + radius * rx / rho, atol=1e-12)
    np.testing.assert_allclose(landing[0, :, 1], -0.05 + radius * ry / rho, atol=1e-12)
    cos_t = np.sqrt(1 - sin_t**2)
    t = [_fresnel(ci, 1.0, n) * _fresnel(ct, n, 1.0) for ci, ct in zip(cos_i, cos_t, strict=True)]
    np.testing.assert_allclose(weight[0], intensity * cos_i / (rho**2 + h**2) * np.array(t))


def test_point_light_gives_the_solid_angle_of_each_pixel_through_an_index_one_lens():
    """n = 1 (any surface): straight rays from the lamp, so a pixel gets I times its solid
    angle; the emission grid is chosen to map onto whole sub-cells of the pixels."""
    height, intensity = 1.0, 3.0
    top = 0.5  # the rest plane: magnification height / (height - top) = 2
    scene = _lens_scene(
        _bumps(16), light=_light(position=(0.0, 0.0, height), intensity=intensity),
        thickness=0.05, screen_distance=top - 0.05, ior=1.0, receiver=(-1.0, 1.0, -1.0, 1.0),
        shape=(10, 10),
    )  # fmt: skip
    image = ref.trace_lens(scene, 80)  # 8 x 8 photons per pixel
    px = np.linspace(-1.0, 1.0, 11)
    expected = np.array(
        [
            [_solid_angle(px[j], px[j + 1], px[i], px[i + 1], height) for j in range(10)]
            for i in range(10)
        ]
    ) * (intensity / 0.2**2)
    np.testing.assert_allclose(image, expected, rtol=2e-4)
    # I cos^3 / h^2 at a pixel's centre, to the pixel's curvature
    cos3 = intensity * height / math.hypot(-0.5, 0.5, height) ** 3
    assert image[7, 2] == pytest.approx(cos3, rel=2e-2)


def test_point_light_flux_is_conserved_through_a_wavy_lens():
    height, intensity = 1.2, 1.5
    scene = _lens_scene(
        _bumps(24, amplitude=0.01), light=_light(position=(0.05, 0.0, height), intensity=intensity),
        thickness=0.05, screen_distance=0.45, ior=1.5, receiver=(-2.0, 2.0, -2.0, 2.0),
        shape=(8, 8),
    )  # fmt: skip
    image, stats = ref.trace_lens(scene, 120, return_stats=True)
    assert stats["on_receiver"] == stats["emitted"]
    h = height - 0.5
    omega = _solid_angle(-0.55, 0.45, -0.5, 0.5, h)
    np.testing.assert_allclose(image.sum() * 0.5**2, intensity * omega, rtol=1e-4)


def test_a_far_point_light_matches_a_directional_one():
    scene_d = _lens_scene(_bumps(16, amplitude=0.01), light=_light(_oblique(20.0, 40.0)))
    far = 1e5
    p = -far * _oblique(20.0, 40.0) + np.array([0.0, 0.0, 0.55])
    scene_p = _lens_scene(_bumps(16, amplitude=0.01), light=_light(position=p, intensity=far**2))
    rng = np.random.default_rng(3)
    xs, ys = rng.uniform(-0.5, 0.5, 400), rng.uniform(-0.5, 0.5, 400)
    land_d, w_d, _ = ref.trace_lens_photons(scene_d, xs, ys)
    land_p, w_p, _ = ref.trace_lens_photons(scene_p, xs, ys)
    np.testing.assert_allclose(land_p, land_d, atol=1e-5)
    np.testing.assert_allclose(w_p, w_d * math.cos(math.radians(20.0)), rtol=1e-4)


def test_per_ray_intersection_agrees_with_the_water_intersection():
    rng = np.random.default_rng(4)
    surf = _Surface.build(rng.normal(size=(10, 12)) * 0.05, (0.0, 1.2, 0.0, 1.0), "clamp", 0.3)
    d = _oblique(55.0, 200.0)
    cx, cy = rng.uniform(-0.2, 1.4, 500), rng.uniform(-0.2, 1.2, 500)
    t_ref, hx_ref, hy_ref = intersect_surface(surf, 0.7, d, cx, cy)
    w = np.repeat(d[:, None], cx.size, axis=1)
    t, hx, hy = lens_ref._intersect_rays(surf, w[0], w[1], w[2], cx, cy)
    np.testing.assert_allclose(t, t_ref, atol=1e-12)
    np.testing.assert_allclose(hx, hx_ref, atol=1e-9)
    np.testing.assert_allclose(hy, hy_ref, atol=1e-9)


def test_plano_convex_lens_focuses_at_its_back_focal_distance():
    """Heights -(x^2 + y^2) / (2 R) (a paraxial sphere, reproduced exactly by the bicubic
    away from the edges): f = R / (n - 1) behind the curved face, f - t / n behind the
    flat one."""
    radius, n, thickness = 0.25, 1.5, 0.05
    f = radius / (n - 1.0)
    bfd = f - thickness / n
    x = -0.1 + (np.arange(40) + 0.5) * 0.2 / 40
    heights = -(x[None, :] ** 2 + x[:, None] ** 2) / (2.0 * radius)
    ext = (-0.1, 0.1, -0.1, 0.1)
    phi = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    rho = 0.002
    xs, ys = rho * np.cos(phi), rho * np.sin(phi)
    radial = []
    for screen_distance in (0.4, 0.6):
        scene = _lens_scene(
            heights, ext, thickness=thickness, screen_distance=screen_distance, ior=n
        )
        landing, _, alive = ref.trace_lens_photons(scene, xs, ys)
        assert alive.all()
        radial.append(landing[0, :, 0] * np.cos(phi) + landing[0, :, 1] * np.sin(phi))
    crossing = 0.4 - radial[0] * 0.2 / (radial[1] - radial[0])  # where the ray meets the axis
    np.testing.assert_allclose(crossing, bfd, rtol=1e-4)
    # ... and the flux concentrates there, not at half the distance
    shape, rec = (21, 21), (-0.105, 0.105, -0.105, 0.105)
    focused = ref.trace_lens(
        _lens_scene(heights, ext, rec, shape, thickness=thickness, screen_distance=bfd, ior=n), 100
    )
    defocused = ref.trace_lens(
        _lens_scene(heights, ext, rec, shape, thickness=thickness, screen_distance=bfd / 2, ior=n),
        100,
    )
    area = 0.01**2
    assert focused.sum() * area == pytest.approx(0.2**2, rel=1e-12)
    assert focused[9:12, 9:12].sum() * area > 0.9 * 0.2**2
    assert defocused[9:12, 9:12].sum() * area < 0.2 * 0.2**2


def test_total_internal_reflection_at_the_bottom_loses_exactly_the_predicted_photons():
    """Top z = c x^2 under normal light: a photon enters where the slope is s = 2 c x,
    is bent by alpha - beta from the vertical (tan alpha = |s|, sin beta = sin alpha / n)
    and is lost iff n sin(alpha - beta) > 1 at the bottom face."""
    c, iors = 3.0, (1.5, 2.0)
    x = -0.5 + (np.arange(48) + 0.5) / 48
    heights = np.broadcast_to(c * x[None, :] ** 2, (8, 48))
    scene = _lens_scene(heights, ior=iors, thickness=0.01, receiver=(-9.0, 9.0, -9.0, 9.0))
    xs = np.linspace(-0.45, 0.45, 1001)  # away from the clamped edge samples
    ys = np.zeros_like(xs)
    _, weight, alive = ref.trace_lens_photons(scene, xs, ys)
    for k, n in enumerate(iors):
        alpha = np.arctan(np.abs(2 * c * xs))
        beta = np.arcsin(np.sin(alpha) / n)
        margin = n * np.sin(alpha - beta) - 1.0
        clear = np.abs(margin) > 1e-9
        np.testing.assert_array_equal(alive[k][clear], (margin < 0)[clear])
        assert np.all(weight[k][~alive[k]] == 0)
    assert alive[0].all() and not alive[1].all() and alive[1].any()  # 1.5: slopes < 7
    image, stats = ref.trace_lens(scene, (8, 96), return_stats=True)
    xs_e, ys_e, _ = ref.emit_lens_photons(scene, (8, 96))
    _, _, alive_e = ref.trace_lens_photons(scene, xs_e, ys_e)
    assert stats["lost_tir"] == tuple(int((~a).sum()) for a in alive_e)
    assert stats["lost_tir"][0] == 0 and stats["lost_tir"][1] > 0
    np.testing.assert_allclose(image[..., 0].sum() * 1.5**2, 1.0, rtol=1e-12)
    np.testing.assert_allclose(image[..., 1].sum() * 1.5**2, alive_e[1].mean(), rtol=1e-12)


def test_rotated_aperture_and_jitter():
    rot = math.radians(30.0)
    scene = _lens_scene(rotation=rot, receiver=(-0.8, 0.8, -0.8, 0.8), shape=(16, 16))
    rng = np.random.default_rng(5)
    xs, ys = rng.uniform(-0.75, 0.75, 2000), rng.uniform(-0.75, 0.75, 2000)
    _, _, alive = ref.trace_lens_photons(scene, xs, ys)
    u = math.cos(rot) * xs + math.sin(rot) * ys  # into the field's frame
    v = -math.sin(rot) * xs + math.cos(rot) * ys
    np.testing.assert_array_equal(alive[0], (np.abs(u) < 0.5) & (np.abs(v) < 0.5))
    image = ref.trace_lens(scene, 200, jitter=True, seed=7)
    np.testing.assert_allclose(image.sum() * 0.1**2, 1.0, rtol=1e-12)
    assert image[8, 8] == pytest.approx(1.0, abs=0.1) and image[0, 0] == 0.0
    # the jitter depends on the seed alone
    wavy = _lens_scene(_bumps(16, amplitude=0.01))
    a = ref.trace_lens(wavy, 48, jitter=True, seed=1)
    b = ref.trace_lens(wavy, 48, jitter=True, seed=1)
    c = ref.trace_lens(wavy, 48, jitter=True, seed=2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-3
    np.testing.assert_allclose(a.sum(), c.sum(), rtol=1e-12)


# --------------------------------------------------------------------------- mesh: hits


def _plane_hits(vertices, faces, o, d):
    """Brute force, another way: plane intersection, then barycentrics by signed areas."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)  # (F, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("fk,fk->f", n, a - o) / (n @ d)
    p = o + t[:, None] * d
    nn = np.einsum("fk,fk->f", n, n)
    l0 = np.einsum("fk,fk->f", n, np.cross(c - b, p - b)) / nn
    l1 = np.einsum("fk,fk->f", n, np.cross(a - c, p - c)) / nn
    l2 = 1.0 - l0 - l1
    inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0) & (t > 0)
    edge = np.minimum(np.minimum(np.abs(l0), np.abs(l1)), np.abs(l2))
    return np.where(inside, t, np.inf), edge, np.stack([l0, l1, l2], axis=1)


def test_moller_trumbore_agrees_with_plane_and_barycentric_tests():
    rng = np.random.default_rng(6)
    vertices = rng.uniform(-1, 1, size=(90, 3))
    faces = np.arange(90).reshape(30, 3)
    o = rng.uniform(-2, 2, size=(400, 3))
    d = rng.normal(size=(400, 3))
    t, face, bary = ref.intersect_mesh(vertices, faces, o, d)
    hits = 0
    for i in range(400):
        tp, edge, lam = _plane_hits(vertices, faces, o[i], d[i])
        if np.isfinite(tp).any():
            j = int(np.argmin(tp))
            if edge[j] < 1e-9:
                continue
            hits += 1
            assert face[i] == j
            assert t[i] == pytest.approx(tp[j], rel=1e-10)
            np.testing.assert_allclose(bary[i], lam[j], atol=1e-10)
        else:
            assert face[i] == -1 and t[i] == np.inf
    assert hits > 40


def test_hierarchy_finds_the_same_nearest_hits_as_brute_force():
    tm = _sphere(subdivisions=3)
    tris = mesh_ref._Tris.build(np.asarray(tm.vertices), np.asarray(tm.faces))
    rng = np.random.default_rng(7)
    centre = np.array([[0.0], [0.0], [0.5]])
    o = rng.uniform(-0.3, 0.3, (3, 2000)) + centre
    o[:, 1500:] = rng.uniform(-0.1, 0.1, (3, 500)) + centre  # inside
    d = rng.normal(size=(3, 2000))
    d /= np.linalg.norm(d, axis=0)
    skip = rng.integers(-1, 1280, 2000)
    fast = tris.nearest(o, d, 1e-12, skip)
    slow = tris.nearest(o, d, 1e-12, skip, brute=True)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.isfinite(fast[0][1500:]).all() and (fast[1] >= 0).sum() > 600


def test_whole_paths_are_the_same_without_the_hierarchy(monkeypatch):
    tm = _sphere(subdivisions=2)
    occluder = _mesh(_box((0.3, 0.3, 0.01), (0.1, 0.0, 0.1)))
    scene = _mesh_scene(
        tm, _light(_oblique(25.0, 60.0)), interfaces=4, ior=(1.5, 2.2), occluders=[occluder]
    )
    image, stats = ref.trace_mesh(scene, 40, return_stats=True)
    nearest = mesh_ref._Tris.nearest

    def brute(self, o, d, t_min, skip=None, brute=False):
        return nearest(self, o, d, t_min, skip, brute=True)

    monkeypatch.setattr(mesh_ref._Tris, "nearest", brute)
    image_b, stats_b = ref.trace_mesh(scene, 40, return_stats=True)
    np.testing.assert_array_equal(image, image_b)
    assert stats == stats_b
    assert min(stats["tir_events"]) > 0 and min(stats["blocked"]) > 0


# --------------------------------------------------------------------------- mesh: scenes


def test_index_one_sphere_lands_straight_in_its_shadow_and_normals_do_not_matter():
    tm = _sphere()
    scene = _mesh_scene(tm, ior=1.0)
    o, d, w = ref.emit_mesh_photons(scene, 120)
    landing, weight, alive = ref.trace_mesh_photons(scene, o, d, w)
    t, _, _ = ref.intersect_mesh(tm.vertices, tm.faces, o, d)
    np.testing.assert_array_equal(alive[0], np.isfinite(t))
    np.testing.assert_allclose(landing[0][alive[0]], o[alive[0], :2], atol=1e-12)
    assert np.all(np.hypot(*landing[0][alive[0]].T) <= 0.2 + 1e-12)
    np.testing.assert_array_equal(weight[0][alive[0]], w[alive[0]])
    smooth, stats = ref.trace_mesh(scene, 120, return_stats=True)
    flat = ref.trace_mesh(_mesh_scene(tm, ior=1.0, normals="flat"), 120)
    np.testing.assert_allclose(smooth, flat, atol=1e-12)
    _check_partition(stats)
    assert stats["landed"] == stats["hit_generator"] == int(alive.sum())
    # the flux is the shadow's area (the projected faces facing the light)
    n = np.cross(tm.vertices[tm.faces[:, 1]] - tm.vertices[tm.faces[:, 0]],
                 tm.vertices[tm.faces[:, 2]] - tm.vertices[tm.faces[:, 0]])  # fmt: skip
    shadow = 0.5 * np.clip(n[:, 2], 0, None).sum()
    assert smooth.sum() * 0.1**2 == pytest.approx(shadow, rel=5e-3)


def test_glass_box_under_normal_light_transmits_its_shadow_and_normals_matter():
    box = _box((0.4, 0.4, 0.2), (0.0, 0.0, 0.5))
    image, stats = ref.trace_mesh(_mesh_scene(box, normals="flat"), 40, return_stats=True)
    np.testing.assert_allclose(image[3:7, 3:7], 1.0, rtol=1e-7)
    assert image.sum() == pytest.approx(16.0, rel=1e-7)
    assert stats["landed"] == stats["emitted"] == 1600
    fresnel = ref.trace_mesh(_mesh_scene(box, normals="flat", ior=(1.5, 2.0), fresnel=True), 40)
    for k, n in enumerate((1.5, 2.0)):
        np.testing.assert_allclose(fresnel[3:7, 3:7, k], (4 * n / (n + 1) ** 2) ** 2, rtol=1e-7)
    smooth = ref.trace_mesh(_mesh_scene(box, normals="smooth"), 40)
    assert np.abs(smooth - image).max() > 0.5


def test_ball_lens_focuses_at_its_paraxial_focal_distance():
    """A ray at height rho through a sphere leaves it at distance rho from the centre,
    turned by 2 (i - r) (sin i = rho / R, sin r = sin i / n): it meets the axis at
    rho / sin(2 (i - r)) from the centre, f = n R / (2 (n - 1)) in the paraxial limit. A
    fine icosphere with smooth normals follows the sphere to its faceting."""
    radius, n = 0.2, 1.5
    f = n * radius / (2 * (n - 1))
    phi = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    spheres = [_mesh_scene(_sphere(radius, (0.0, 0.0, zc), 5), ior=n) for zc in (0.4, 0.6)]
    for rho in (0.01, 0.05, 0.1):
        radial = []
        for scene in spheres:
            o = np.stack([rho * np.cos(phi), rho * np.sin(phi), np.full(16, 1.0)], axis=1)
            landing, _, alive = ref.trace_mesh_photons(scene, o, np.tile(DOWN, (16, 1)))
            assert alive.all()
            radial.append(landing[0, :, 0] * np.cos(phi) + landing[0, :, 1] * np.sin(phi))
        crossing = 0.4 - radial[0] * 0.2 / (radial[1] - radial[0])
        i = math.asin(rho / radius)
        exact = rho / math.sin(2 * (i - math.asin(math.sin(i) / n)))
        assert crossing.mean() == pytest.approx(exact, rel=5e-3)
        np.testing.assert_allclose(crossing, exact, rtol=2.5e-2)
        if rho == 0.01:
            assert exact == pytest.approx(f, rel=1e-3)
    # the flux concentrates in the focal plane
    scene = _mesh_scene(
        _sphere(radius, (0.0, 0.0, f), subdivisions=3), ior=n,
        receiver=(-0.21, 0.21, -0.21, 0.21), shape=(21, 21),
    )  # fmt: skip
    image, stats = ref.trace_mesh(scene, 100, return_stats=True)
    _check_partition(stats)
    assert image[10, 10] > 30 * image.mean()


def test_interfaces_one_drops_every_refracted_photon():
    image, stats = ref.trace_mesh(_mesh_scene(_sphere(), interfaces=1), 60, return_stats=True)
    assert stats["landed"] == 0 and not image.any()
    assert stats["dropped"] == stats["hit_generator"] > 0
    _check_partition(stats)


def test_porro_prism_reflects_totally_twice_and_returns_the_light_up():
    a, top = 0.2, 0.6
    points = [(x, y, top) for x in (-a, a) for y in (-0.2, 0.2)]
    points += [(0.0, y, top - a) for y in (-0.2, 0.2)]
    prism = trimesh.convex.convex_hull(np.array(points))
    assert prism.is_watertight and prism.volume > 0
    scene = _mesh_scene(prism, interfaces=4, ior=1.5, normals="flat")
    image, stats = ref.trace_mesh(scene, (20, 30), return_stats=True)
    assert not image.any() and stats["landed"] == 0
    assert stats["upward"] == stats["hit_generator"] == stats["tir_photons"] > 500
    assert stats["tir_events"] == 2 * stats["tir_photons"]
    ms = mesh_ref._read_mesh_scene(scene)
    o, d, w = ref.emit_mesh_photons(scene, (4, 6))
    paths = mesh_ref._trace_mesh(ms, o.T.copy(), d.T.copy(), w)[0]
    assert (paths.events == 4).all()
    np.testing.assert_allclose(paths.direction.T, np.tile([0.0, 0.0, 1.0], (24, 1)), atol=1e-12)
    _, stats3 = ref.trace_mesh(
        _mesh_scene(prism, interfaces=3, normals="flat"), (20, 30), return_stats=True
    )
    assert stats3["dropped"] == stats3["hit_generator"] == stats["hit_generator"]
    # below the critical index nothing reflects totally (sin 45 deg < 1 / 1.3)
    _, stats13 = ref.trace_mesh(
        _mesh_scene(prism, ior=1.3, normals="flat"), (20, 30), return_stats=True
    )
    assert stats13["tir_events"] == 0 and stats13["landed"] > 0


def test_vertical_mirror_reflects_oblique_light_onto_the_analytic_strip():
    """Mirror x = 0, |y| <= 0.3, 0.2 <= z <= 0.6 under light at 45 deg towards +x: the
    light at height z lands at x = -z, with irradiance 1 (|d_z| is unchanged)."""
    v = np.array([[0, -0.3, 0.2], [0, 0.3, 0.2], [0, 0.3, 0.6], [0, -0.3, 0.6]], float)
    mirror = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    scene = _mesh_scene(
        mirror, _light(_oblique(45.0)), receiver=(-0.8, 0.0, -0.4, 0.4), shape=(8, 8),
        material="mirror", ior=(1.3, 1.4),
    )  # fmt: skip
    image, stats = ref.trace_mesh(scene, (60, 40), return_stats=True)
    assert image.shape == (8, 8)
    expected = np.zeros((8, 8))
    expected[1:7, 2:6] = 1.0
    np.testing.assert_allclose(image, expected, atol=1e-7)
    assert stats["landed"] == stats["emitted"] == 2400


def test_horizontal_mirror_under_normal_light_sends_everything_up():
    v = np.array([[-0.2, -0.2, 0.3], [0.2, -0.2, 0.3], [0.2, 0.2, 0.3], [-0.2, 0.2, 0.3]])
    mirror = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    image, stats = ref.trace_mesh(_mesh_scene(mirror, material="mirror"), 30, return_stats=True)
    assert not image.any() and stats["upward"] == stats["hit_generator"] == 900


def test_occluders_block_exactly_their_shadow():
    sphere = _sphere()
    base = _mesh_scene(sphere, ior=1.0)
    o, d, w = ref.emit_mesh_photons(base, 80)
    _, _, alive = ref.trace_mesh_photons(base, o, d, w)
    _, stats0 = ref.trace_mesh(base, 80, return_stats=True)
    below = _mesh(_box((0.6, 1.0, 0.01), (0.3, 0.0, 0.1)))  # x in [0, 0.6] under the sphere
    above = _mesh(_box((1.0, 0.6, 0.01), (0.0, 0.3, 0.9)))  # y in [0, 0.6] over it
    scene = _mesh_scene(sphere, ior=1.0, occluders=[below])
    landing, _, alive_b = ref.trace_mesh_photons(scene, o, d, w)
    assert np.all(landing[0][alive_b[0], 0] < 0)
    np.testing.assert_array_equal(alive_b[0], alive[0] & (o[:, 0] < 0))
    _, stats = ref.trace_mesh(scene, 80, return_stats=True)
    assert stats["blocked"] == int((alive[0] & (o[:, 0] > 0)).sum()) > 0
    _check_partition(stats)
    scene = _mesh_scene(sphere, ior=1.0, occluders=[above])
    _, stats = ref.trace_mesh(scene, 80, return_stats=True)
    assert stats["blocked"] == int((alive[0] & (o[:, 1] > 0)).sum()) > 0
    assert stats["hit_generator"] == stats0["hit_generator"] - stats["blocked"]
    assert stats["missed"] == stats0["missed"]
    _check_partition(stats)


def test_point_light_over_an_index_one_box_gives_each_pixel_its_solid_angle():
    """Box top at z = 0.5 (half side 0.25), lamp at z = 1: its shadow is [-0.5, 0.5]^2,
    and the emission grid maps onto 10 x 10 photons per pixel."""
    intensity = 2.0
    box = _box((0.5, 0.5, 0.1), (0.0, 0.0, 0.45))
    light = _light(position=(0.0, 0.0, 1.0), intensity=intensity)
    image, stats = ref.trace_mesh(_mesh_scene(box, light, ior=1.0), 100, return_stats=True)
    assert stats["on_receiver"] == stats["emitted"]
    px = np.linspace(-0.5, 0.5, 11)
    expected = np.array(
        [
            [_solid_angle(px[j], px[j + 1], px[i], px[i + 1], 1.0) for j in range(10)]
            for i in range(10)
        ]
    ) * (intensity / 0.1**2)
    np.testing.assert_allclose(image, expected, rtol=1e-4)
    # pixel centres: I cos^3 / h^2, to the pixel's curvature
    centres = (px[:-1] + px[1:]) / 2
    xx, yy = np.meshgrid(centres, centres)
    np.testing.assert_allclose(image, intensity / (1 + xx**2 + yy**2) ** 1.5, rtol=1e-2)


def test_point_light_through_a_glass_box_lands_at_the_slab_displacement():
    n, intensity = 1.5, 2.0
    box = _box((0.6, 0.6, 0.1), (0.0, 0.0, 0.45))
    light = _light(position=(0.0, 0.0, 1.0), intensity=intensity)
    scene = _mesh_scene(box, light, ior=n, normals="flat", fresnel=True)
    rng = np.random.default_rng(8)
    q = np.concatenate([rng.uniform(-0.15, 0.15, (200, 2)), np.full((200, 1), 0.5)], axis=1)
    o = np.tile([0.0, 0.0, 1.0], (200, 1))
    landing, weight, alive = ref.trace_mesh_photons(scene, o, q - o)
    assert alive.all()
    rho = np.hypot(q[:, 0], q[:, 1])
    sin_i = rho / np.hypot(rho, 0.5)
    sin_t = sin_i / n
    radius = rho + 0.1 * sin_t / np.sqrt(1 - sin_t**2) + 0.4 * sin_i / np.sqrt(1 - sin_i**2)
    np.testing.assert_allclose(landing[0], q[:, :2] * (radius / rho)[:, None], atol=1e-12)
    cos_i, cos_t = np.sqrt(1 - sin_i**2), np.sqrt(1 - sin_t**2)
    t = [_fresnel(ci, 1.0, n) * _fresnel(ct, n, 1.0) for ci, ct in zip(cos_i, cos_t, strict=True)]
    np.testing.assert_allclose(weight[0], t, rtol=1e-12)


def test_dispersion_channels_trace_each_index():
    sphere = _sphere()
    image, stats = ref.trace_mesh(_mesh_scene(sphere, ior=(1.4, 1.6)), 60, return_stats=True)
    assert image.shape == (10, 10, 2) and len(stats["landed"]) == 2
    for k, n in enumerate((1.4, 1.6)):
        np.testing.assert_array_equal(image[..., k], ref.trace_mesh(_mesh_scene(sphere, ior=n), 60))
    assert np.abs(image[..., 0] - image[..., 1]).max() > 0.1


# --------------------------------------------------------------------------- package


def test_lens_and_mesh_tracers_run_on_duck_typed_scenes_without_jax():
    code = textwrap.dedent(f"""
        import importlib.util, sys, types
        import numpy as np
        sys.modules["jax"] = None  # any `import jax` now raises ImportError
        path = {str(ref.__file__)!r}
        spec = importlib.util.spec_from_file_location(
            "standalone_reference", path, submodule_search_locations=[path.rsplit("/", 1)[0]])
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        spec.loader.exec_module(mod)
        ns = types.SimpleNamespace
        rec = ns(extent=[-0.6, 0.6, -0.6, 0.6], shape=(12, 12))
        lens = ns(surface=ns(heights=[[0.0] * 4] * 4, extent=[-0.5, 0.5, -0.5, 0.5],
                  boundary="clamp"), light=ns(direction=[0.0, 0.0, -2.0]), receiver=rec,
                  thickness=0.05, screen_distance=0.5, ior=1.5, fresnel=False)
        image = mod.trace_lens(lens, 50)
        assert image.shape == (12, 12) and abs(image[1:-1, 1:-1] - 1).max() < 1e-12
        v = [[-0.2, -0.2, 0.3], [0.2, -0.2, 0.3], [0.2, 0.2, 0.3], [-0.2, 0.2, 0.3]]
        mesh = ns(generator=ns(vertices=v, faces=[[0, 1, 2], [0, 2, 3]]), light=ns(
                  position=[0.0, 0.0, 1.0], intensity=1.0), receiver=rec, material="mirror",
                  ior=1.5, fresnel=False, interfaces=2, normals="flat", occluders=())
        image, stats = mod.trace_mesh(mesh, 20, return_stats=True)
        assert not image.any() and stats["upward"] == 400, stats
        assert "jaxcaustics" not in sys.modules
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


@pytest.mark.parametrize("bad", [0, -3, 2.5, (4, 0), (1, 2, 3), "8", True])
def test_bad_photon_counts_are_rejected(bad):
    with pytest.raises(ValueError, match="photons_per_axis"):
        ref.trace_lens(_lens_scene(), bad)
    with pytest.raises(ValueError, match="photons_per_axis"):
        ref.trace_mesh(_mesh_scene(_sphere()), bad)


def test_bad_scenes_are_rejected():
    import types

    ns = types.SimpleNamespace
    scene = _mesh_scene(_sphere())
    fake = ns(**{k: getattr(scene, k) for k in (
        "generator", "light", "receiver", "ior", "fresnel", "interfaces", "normals", "occluders"
    )}, material="glass")  # fmt: skip
    with pytest.raises(ValueError, match="material"):
        ref.trace_mesh(fake, 4)
    with pytest.raises(ValueError, match="MeshScene"):
        ref.trace_mesh(_lens_scene(), 4)
    with pytest.raises(ValueError, match="LensScene"):
        ref.trace_lens(scene, 4)
    inside = _light(position=(0.0, 0.0, 0.6))  # inside the sphere
    with pytest.raises(ValueError, match="`light`"):  # the library refuses it when built
        _mesh_scene(_sphere(), inside)
    beside = ns(**{**vars(fake), "material": scene.material, "light": inside})
    with pytest.raises(ValueError, match="in front of it"):  # and so does the reference
        ref.trace_mesh(beside, 4)
    with pytest.raises(ValueError, match="same size"):
        ref.trace_lens_photons(_lens_scene(), [0.0, 0.1], [0.0])
