"""Analytic glass ellipsoids: scene validation, exit rays (Liu et al.'s caustic object
rays) against closed forms and against the NumPy reference, the mesh path, vmap and
gradients; and the reference ellipsoid tracer itself (photon counts, occluders)."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.methods.spot_lights.exit_rays import _square_grid, trace_exit_rays
from jaxcaustics.scene.ellipsoid import Ellipsoid, EllipsoidScene

VERTICAL = jc.DirectionalLight([0.0, 0.0, -1.0])
OBLIQUE = jc.DirectionalLight.from_angles(30.0, 20.0)
SCREEN = jc.PlaneReceiver((-3.0, 3.0, -3.0, 3.0), (16, 16))


def _rotation(seed=1):
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _scene(generator=None, light=OBLIQUE, receiver=SCREEN, **kw):
    if generator is None:
        generator = Ellipsoid.sphere([0.0, 0.0, 2.0], 1.0)
    return EllipsoidScene(generator, light, receiver, **kw)


def _tilted(center=(0.1, -0.2, 2.0)):
    """A rotated ellipsoid, semi-axes 1, 0.7, 0.5 m."""
    return Ellipsoid(center, [1.0, 0.7, 0.5], _rotation())


def _np(rays):
    return np.asarray(rays.origin), np.asarray(rays.direction), np.asarray(rays.energy)


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Ellipsoid([0.0, 0.0], [1.0, 1.0, 1.0]), "center"),
        (lambda: Ellipsoid([0.0, 0.0, 2.0], [1.0, -1.0, 1.0]), "radii"),
        (lambda: Ellipsoid([0.0, 0.0, 2.0], [1.0, np.nan, 1.0]), "radii"),
        (lambda: Ellipsoid([0.0, 0.0, 2.0], [1.0, 1.0, 1.0], np.eye(3) * 1.01), "rotation"),
        (lambda: Ellipsoid([0.0, 0.0, 2.0], [1.0, 1.0, 1.0], np.eye(2)), "rotation"),
        (lambda: Ellipsoid.sphere([0.0, 0.0, 2.0], 0.0), "radius"),
        (lambda: _scene(Ellipsoid.sphere([0.0, 0.0, 0.5], 1.0)), "generator"),
        (lambda: _scene(occluders=[Ellipsoid.sphere([0.0, 3.0, 0.2], 0.3)]), r"occluders\[0\]"),
        (lambda: _scene(occluders=["ball"]), r"occluders\[0\]"),
        (lambda: _scene(light=jc.PointLight([0.0, 0.0, 5.0])), "light"),
        (lambda: _scene(receiver=(0, 1, 0, 1)), "receiver"),
        (lambda: _scene(interfaces=0), "interfaces"),
        (lambda: _scene(ior=()), "ior"),
        (lambda: EllipsoidScene("ball", OBLIQUE, SCREEN), "generator"),
        (lambda: trace_exit_rays(_scene(), 1), "rays_per_axis"),
        (lambda: trace_exit_rays(_scene(), 8.0), "rays_per_axis"),
        (lambda: trace_exit_rays(_scene(), 8, channel=1), "channel"),
        (lambda: trace_exit_rays(_scene(), 8, direction=[0.0, 1.0]), "direction"),
        (lambda: trace_exit_rays("scene", 8), "scene"),
    ],
)
def test_bad_input_names_the_argument(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_floor_check_uses_the_true_z_extent_of_a_rotated_ellipsoid():
    # a needle (semi-axes 1, 0.1, 0.1) tilted 30 degrees from horizontal about y
    a = np.radians(30.0)
    rot = np.array([[np.cos(a), 0.0, -np.sin(a)], [0.0, 1.0, 0.0], [np.sin(a), 0.0, np.cos(a)]])
    low = np.hypot(np.sin(a) * 1.0, np.cos(a) * 0.1)  # 0.5074, far below the 1 m radius
    ok = Ellipsoid([0.0, 0.0, low + 1e-6], [1.0, 0.1, 0.1], rot)
    assert float(ok.half_extents[2]) == pytest.approx(low, rel=1e-12)
    _scene(ok)
    with pytest.raises(ValueError, match="generator"):
        _scene(Ellipsoid([0.0, 0.0, low - 1e-3], [1.0, 0.1, 0.1], rot))


def test_effects_and_iors_follow_the_scene():
    scene = _scene(ior=(1.5, 1.6), fresnel=True, interfaces=4)
    assert scene.iors == (1.5, 1.6)
    fx = scene.effects
    assert (fx.refraction, fx.reflection, fx.fresnel) == (True, False, True)
    assert (fx.total_internal_reflection, fx.dispersion_channels) == (True, 2)
    assert (fx.occlusion, fx.interfaces) == (False, 4)
    occluded = _scene(occluders=[Ellipsoid.sphere([2.0, 0.0, 1.0], 0.5)])
    assert occluded.iors == (1.5,) and occluded.effects.occlusion


@pytest.mark.parametrize("proper", [True, False])
def test_to_mesh_is_closed_outward_and_on_the_surface(proper):
    rot = _rotation() * (1.0 if proper else np.array([1.0, 1.0, -1.0]))
    ell = Ellipsoid([0.3, 0.2, 2.0], [1.0, 0.7, 0.5], rot)
    mesh = ell.to_mesh(2)
    assert mesh.is_watertight() and mesh.faces.shape == (320, 3)
    v = np.asarray(mesh.vertices)
    unit = ((v - [0.3, 0.2, 2.0]) @ rot) / [1.0, 0.7, 0.5]
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, atol=1e-12)
    # positive volume: outward faces; inscribed (icosphere(2) holds 96.6% of the ball)
    volume = mesh.to_trimesh().volume
    assert 0.96 < volume / (4.0 / 3.0 * np.pi * 0.35) < 0.97
    # the analytic bounding box holds the vertices and is touched by them (within 2%)
    half = np.asarray(ell.half_extents)
    span = 0.5 * (v.max(axis=0) - v.min(axis=0))
    assert np.all(span <= half + 1e-12) and np.all(span > 0.98 * half)


# --------------------------------------------------------------------------- closed forms

# Rays per grid side in most tests: odd, so that a cell centre sits on the axis (ray
# `MID`), and shared so that the tests reuse each other's compiled tracers.
N = 65
MID = (N // 2) * N + N // 2


@pytest.mark.parametrize("fresnel", [False, True])
def test_the_central_ray_of_a_sphere_goes_straight_through(fresnel):
    scene = _scene(fresnel=fresnel)
    rays = trace_exit_rays(scene, N)
    o, d, e = _np(rays)
    axis = np.asarray(OBLIQUE.unit_direction)
    np.testing.assert_allclose(o[MID], [0.0, 0.0, 2.0] + axis, atol=1e-12)  # far pole
    np.testing.assert_allclose(d[MID], axis, atol=1e-12)
    t = 1.0 - (0.5 / 2.5) ** 2  # normal-incidence transmittance, per face
    assert e[MID] == pytest.approx(float(rays.spacing) ** 2 * (t * t if fresnel else 1.0))
    assert float(rays.spacing) == pytest.approx(2.0 / N)
    np.testing.assert_allclose(np.asarray(rays.centre), [0.0, 0.0, 2.0])
    assert float(rays.size) == pytest.approx(2.0)


def test_ball_lens_rays_cross_the_axis_where_geometry_says():
    """A ray at height h through a ball (radius R, index n) is deviated by
    ``delta = 2 (asin(h / R) - asin(h / (n R)))`` and leaves along a line at distance h
    from the centre (the path is symmetric), so it crosses the axis at
    ``s(h) = h / sin(delta)`` past the centre; ``s -> f = n R / (2 (n - 1))`` (the ball
    lens's focal length from its centre) as ``h -> 0``. Exact rays: 1e-9 relative.
    Paraxial limit: a fit of s against h^2 (degree 3, h < 0.4 R) extrapolated to h = 0;
    its truncation error is of order (0.4)^8 times the O(1) coefficients, below 1e-4 of
    f."""
    n_glass, radius = 1.5, 1.0
    centre = np.array([0.0, 0.0, 2.0])
    o, d, e = _np(trace_exit_rays(_scene(), N, direction=VERTICAL.unit_direction))
    axis = np.array([0.0, 0.0, -1.0])
    # where the exit ray's line meets the axis line c + s a (closest points of two lines)
    rel = o - centre
    h = np.linalg.norm(np.cross(rel, d), axis=1)  # distance from the centre to the line
    ok = (e > 0) & (h > 1e-9)
    o, d, rel, h = o[ok], d[ok], rel[ok], np.minimum(h[ok], radius)
    da, rd, ra = d @ axis, np.sum(rel * d, axis=1), rel @ axis
    t = (da * ra - rd) / (1.0 - da * da)
    meet = o + t[:, None] * d
    s = (meet - centre) @ axis
    gap = np.linalg.norm(meet - centre - s[:, None] * axis, axis=1)
    np.testing.assert_allclose(gap, 0.0, atol=1e-9)  # they do meet (meridional rays)
    delta = 2.0 * (np.arcsin(h / radius) - np.arcsin(h / (n_glass * radius)))
    np.testing.assert_allclose(s, h / np.sin(delta), rtol=1e-9)
    focal = n_glass * radius / (2.0 * (n_glass - 1.0))
    near = h < 0.4 * radius
    assert near.sum() > 100
    coef = np.polynomial.polynomial.polyfit(h[near] ** 2, s[near], 3)
    assert coef[0] == pytest.approx(focal, rel=1e-4)
    assert s[near].max() < focal  # spherical aberration: marginal rays focus short


def test_without_fresnel_a_sphere_passes_every_ray_it_meets():
    """No total internal reflection in a sphere: every ray that meets it leaves after 2
    events carrying exactly its cell's area; the rays that meet it are the cell centres
    within R of the axis (counted here from the grid's formula)."""
    rays = trace_exit_rays(_scene(), N)
    e = np.asarray(rays.energy)
    spacing = 2.0 / N
    u = -1.0 + (np.arange(N) + 0.5) * spacing
    inside = (u[:, None] ** 2 + u[None, :] ** 2 < 1.0).sum()
    assert np.count_nonzero(e) == inside
    np.testing.assert_allclose(e[e > 0], spacing**2, rtol=1e-12)
    assert e.sum() == pytest.approx(np.pi, rel=0.01)  # the disc's area, midpoint rule
    with_fresnel = np.asarray(trace_exit_rays(_scene(fresnel=True), N).energy)
    assert np.array_equal(with_fresnel > 0, e > 0)
    assert np.all(with_fresnel[e > 0] < spacing**2)
    # every photon loses at least twice the normal-incidence reflectance 4%
    assert with_fresnel.sum() < (1.0 - 0.04) ** 2 * e.sum()


# --------------------------------------------------------------------------- vs reference

DIAMOND = dict(ior=2.4, fresnel=True, interfaces=6)


def test_exit_rays_match_the_reference_ray_by_ray():
    """A rotated ellipsoid of index 2.4 (diamond: many total internal reflections),
    oblique light, Fresnel on, up to 6 events: the JAX exit rays from its grid against
    `reference.trace_ellipsoid_rays` from the same start points (an independent
    formulation: world-frame quadric vs unit-sphere frame). Both are exact, so they agree
    to rounding (1e-9); a ray within rounding of a total internal reflection threshold or
    of the silhouette could flip fate, so up to 2 rays may disagree."""
    scene = _scene(_tilted(), **DIAMOND)
    rays = trace_exit_rays(scene, N)
    o, d, e = _np(rays)
    axis = scene.light.unit_direction
    plane, _ = _square_grid(scene.generator.center, scene.generator.bounding_radius, axis, N)
    starts = np.asarray(plane - 3.0 * axis)
    along = np.broadcast_to(np.asarray(axis), starts.shape)
    ro, rd, rt, status = (x[0] for x in reference.trace_ellipsoid_rays(scene, starts, along))
    exited = status == "exited"
    assert np.count_nonzero(exited != (e > 0)) <= 2
    both = exited & (e > 0)
    assert both.sum() > 1500 and np.count_nonzero(status == "dropped") > 50
    np.testing.assert_allclose(o[both], ro[both], atol=1e-9)
    np.testing.assert_allclose(d[both], rd[both], atol=1e-9)
    np.testing.assert_allclose(e[both], rt[both] * float(rays.spacing) ** 2, rtol=1e-9)
    _, stats = reference.trace_ellipsoid(scene, N, return_stats=True)
    assert stats["tir_events"] > 1000  # the comparison covers total internal reflection


def _land(rays, light_direction, receiver):
    """Bin exit rays landed on z = 0 into the receiver's pixels: irradiance relative to
    the light's on a horizontal plane (energy / |d_z| per pixel area)."""
    o, d, e = _np(rays)
    ok = (e > 0) & (d[:, 2] < 0)
    t = -o[ok, 2] / d[ok, 2]
    x, y = o[ok, 0] + t * d[ok, 0], o[ok, 1] + t * d[ok, 1]
    x0, x1, y0, y1 = np.asarray(receiver.extent)
    rows, cols = receiver.shape
    weights = e[ok] / abs(float(light_direction[2]))
    flux, _, _ = np.histogram2d(
        y, x, bins=(rows, cols), range=[[y0, y1], [x0, x1]], weights=weights
    )
    return flux / ((x1 - x0) / cols * (y1 - y0) / rows)


def test_landed_exit_rays_reproduce_the_reference_image():
    """A sphere under vertical light: the JAX grid (cell centres over the bounding
    square, R = 1) and the reference's (over the projection's bounding rectangle, padded
    by 1e-9 R) hold the same points, so the binned images agree to rounding (landing
    points differ by ~1e-9 m, the reference's cell areas by 2e-9 relative; the receiver's
    pixel edges are placed off any symmetry of the landing pattern). Two dispersion
    channels, Fresnel on."""
    receiver = jc.PlaneReceiver((-1.37, 1.29, -1.31, 1.43), (24, 24))
    scene = _scene(light=VERTICAL, receiver=receiver, ior=(1.5, 1.6), fresnel=True)
    ref = reference.trace_ellipsoid(scene, N)
    assert ref.shape == (24, 24, 2)
    for k in range(2):
        image = _land(trace_exit_rays(scene, N, channel=k), VERTICAL.unit_direction, receiver)
        assert image.sum() > 100.0
        np.testing.assert_allclose(image, ref[..., k], rtol=1e-8, atol=1e-8 * ref.max())


def test_a_rotated_ellipsoid_equals_its_axis_aligned_twin():
    """Axes (1, 0.7, 0.5) along world (y, z, x) is the axis-aligned ellipsoid with radii
    (0.5, 1, 0.7); a general rotation with its columns permuted and flipped (radii
    permuted alike) is the same ellipsoid too. Same grids, same rays (to rounding)."""
    perm = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns y, z, x
    rotated = _scene(Ellipsoid([0.1, 0.0, 2.0], [1.0, 0.7, 0.5], perm), **DIAMOND)
    aligned = _scene(Ellipsoid([0.1, 0.0, 2.0], [0.5, 1.0, 0.7]), **DIAMOND)
    a, b = _np(trace_exit_rays(rotated, N)), _np(trace_exit_rays(aligned, N))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-11)
    assert np.count_nonzero(a[2]) > 1500
    img_a, img_b = reference.trace_ellipsoid(rotated, 128), reference.trace_ellipsoid(aligned, 128)
    assert img_a.sum() > 0
    np.testing.assert_allclose(img_a, img_b, rtol=1e-9, atol=1e-9 * img_b.max())
    rot = _rotation()
    general = Ellipsoid([0.1, 0.0, 2.0], [1.0, 0.7, 0.5], rot)
    twin = Ellipsoid([0.1, 0.0, 2.0], [0.7, 0.5, 1.0], rot[:, [1, 2, 0]] * [1.0, -1.0, 1.0])
    c = _np(trace_exit_rays(_scene(general, **DIAMOND), N))
    d = _np(trace_exit_rays(_scene(twin, **DIAMOND), N))
    for x, y in zip(c, d, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-11)


@pytest.mark.slow  # compiling the mesh tracer takes ~4 s on a loaded 2-core machine
def test_mesh_path_approximates_the_analytic_ellipsoid():
    """`to_mesh(3)` (1280 faces, smooth normals) in a MeshScene against the analytic
    ellipsoid, for two light directions at once (`jax.vmap`). The grids differ (32^2
    rays over the mesh's bounding sphere rounded outwards, 65^2 over the ellipsoid's),
    so they are compared through the total power and the landed images on 12 x 12
    pixels, blurred by one pixel. The inscribed mesh lies up to 0.4% of a radius inside
    the surface and its interpolated normals are off by ~1e-3 rad; measured: power
    within 0.9% (mostly the coarse grid's quadrature of the silhouette), image
    difference 2-3% (its binning noise); tolerances 2% and 6%."""
    ell = _tilted()
    receiver = jc.PlaneReceiver((-2.5, 2.5, -2.5, 2.5), (12, 12))
    analytic = _scene(ell, receiver=receiver, fresnel=True)
    mesh = jc.MeshScene(ell.to_mesh(3), OBLIQUE, receiver, fresnel=True)
    other = jc.DirectionalLight([0.2, -0.5, -1.0]).unit_direction
    dirs = jnp.stack([OBLIQUE.unit_direction, other])
    batched = jax.vmap(lambda d: trace_exit_rays(mesh, 32, direction=d))(dirs)
    for k in range(2):
        a = trace_exit_rays(analytic, N, direction=dirs[k])
        m = jax.tree.map(lambda x, k=k: x[k], batched)
        assert float(m.energy.sum()) == pytest.approx(float(a.energy.sum()), rel=0.02)
        np.testing.assert_allclose(np.asarray(m.centre), np.asarray(a.centre), atol=0.01)
        assert float(m.size) == pytest.approx(float(a.size), rel=0.01)
        ia = gaussian_filter(_land(a, dirs[k], receiver), 1.0, mode="constant")
        im = gaussian_filter(_land(m, dirs[k], receiver), 1.0, mode="constant")
        assert np.abs(ia - im).sum() / ia.sum() < 0.06


# --------------------------------------------------------------------------- jax


def test_vmap_over_directions_equals_separate_calls():
    scene = _scene(_tilted(), **DIAMOND)
    dirs = jnp.array([[0.3, -0.2, -0.93], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    dirs = dirs / jnp.linalg.norm(dirs, axis=1, keepdims=True)
    batched = jax.vmap(lambda d: trace_exit_rays(scene, N, direction=d))(dirs)
    for k in range(3):
        one = trace_exit_rays(scene, N, direction=dirs[k])
        assert float(one.energy.sum()) > 0.3  # upward and sideways light meets it too
        for x, y in zip(jax.tree.leaves(batched), jax.tree.leaves(one), strict=True):
            np.testing.assert_allclose(np.asarray(x[k]), np.asarray(y), atol=1e-12)


@pytest.mark.slow  # compiling the mesh tracer takes ~4 s on a loaded 2-core machine
def test_vmap_over_directions_equals_separate_calls_for_a_mesh_scene():
    mesh = jc.MeshScene(_tilted().to_mesh(1), OBLIQUE, SCREEN)
    dirs = jnp.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    batched = jax.vmap(lambda d: trace_exit_rays(mesh, 8, direction=d).energy)(dirs)
    for k in range(2):
        one = trace_exit_rays(mesh, 8, direction=dirs[k]).energy
        np.testing.assert_allclose(np.asarray(batched[k]), np.asarray(one), atol=1e-12)
        assert float(one.sum()) > 0.3


@pytest.mark.slow  # 5-7 s of compilation; keeps the default run under 10 minutes
def test_gradient_matches_central_differences():
    """d/d(center, radii) of a smooth functional of the exit rays against central
    differences (step 1e-6, float64: truncation ~1e-12, rounding ~1e-10 relative). The
    grid follows the centre and the largest radius; no ray crosses the silhouette within
    a step (checked). Rays in the grid's corners miss the ellipsoid: their gradients must
    stay finite (no NaN). Fresnel is off here to keep the compilation short (its factor
    is plain `trace.optics.fresnel_transmittance`)."""
    rot = jnp.asarray(_rotation())

    def functional(params):
        ell = Ellipsoid(params[:3], params[3:], rot)
        rays = trace_exit_rays(_scene(ell), N)
        weight = rays.energy
        return jnp.sum(weight * (rays.direction[:, 2] + 0.3 * rays.origin[:, 0])), rays.valid

    x0 = jnp.array([0.1, -0.2, 2.0, 1.0, 0.7, 0.5])
    grad = jax.grad(lambda p: functional(p)[0])(x0)
    assert np.all(np.isfinite(np.asarray(grad)))
    step = 1e-6
    fd = []
    valid0 = np.asarray(functional(x0)[1])
    assert not valid0.all()
    for i in range(6):
        up, down = functional(x0.at[i].add(step)), functional(x0.at[i].add(-step))
        assert np.array_equal(np.asarray(up[1]), valid0)
        assert np.array_equal(np.asarray(down[1]), valid0)
        fd.append((float(up[0]) - float(down[0])) / (2 * step))
    np.testing.assert_allclose(np.asarray(grad), fd, rtol=1e-5, atol=1e-7)
    assert np.abs(fd).max() > 0.01


# --------------------------------------------------------------------------- reference


def test_reference_counts_add_up_and_the_sphere_catches_its_cross_section():
    scene = _scene(
        _tilted(), ior=2.4, interfaces=4, occluders=[Ellipsoid.sphere([1.0, 0.0, 0.6], 0.4)]
    )
    _, s = reference.trace_ellipsoid(scene, 96, return_stats=True)
    assert s["emitted"] == 96 * 96
    assert s["emitted"] == s["missed"] + s["blocked"] + s["dropped"] + s["upward"] + s["landed"]
    assert 0 < s["on_receiver"] <= s["landed"]
    assert s["blocked"] > 0 and s["dropped"] > 0 and s["tir_photons"] > 0
    assert s["tir_events"] >= s["tir_photons"]
    assert s["hit_generator"] == s["emitted"] - s["missed"]  # no occluder above it
    # a sphere under oblique light, no Fresnel: every photon that meets it lands or goes
    # up; those that meet it cover its cross-section pi R^2 (to the grid's resolution)
    big = jc.PlaneReceiver((-30.0, 30.0, -30.0, 30.0), (4, 4))
    image, s = reference.trace_ellipsoid(_scene(receiver=big), 128, return_stats=True)
    cell = (2.0 / 128) ** 2
    assert s["hit_generator"] * cell == pytest.approx(np.pi, rel=0.01)
    assert s["hit_generator"] == s["landed"] + s["upward"]
    flux = image.sum() * (60.0 / 4) ** 2  # all photons carry the same flux
    expected = s["on_receiver"] * cell / abs(float(OBLIQUE.unit_direction[2]))
    assert flux == pytest.approx(expected, rel=1e-8)  # cells are padded by 1e-9 per side


def test_reference_occluders_block_photons():
    receiver = jc.PlaneReceiver((-2.0, 2.0, -2.0, 2.0), (16, 16))
    base = dict(light=VERTICAL, receiver=receiver)
    clear, s0 = reference.trace_ellipsoid(_scene(**base), 64, return_stats=True)
    # a larger opaque ball right above the glass one shades it completely
    above = Ellipsoid.sphere([0.0, 0.0, 4.5], 1.2)
    shaded, s1 = reference.trace_ellipsoid(_scene(**base, occluders=[above]), 64, return_stats=True)
    assert s1["landed"] == 0 and not shaded.any()
    assert s1["blocked"] == s0["hit_generator"] and s1["hit_generator"] == 0
    # a small ball under the focus (f = 1.5 m from the centre: z = 0.5) blocks part of it
    below = Ellipsoid.sphere([0.0, 0.0, 0.3], 0.2)
    part, s2 = reference.trace_ellipsoid(_scene(**base, occluders=[below]), 64, return_stats=True)
    assert 0 < s2["blocked"] < s2["hit_generator"]
    assert s2["landed"] + s2["blocked"] == s0["landed"]
    assert part.sum() < clear.sum()


def test_reference_reads_a_duck_typed_scene():
    """Plain namespaces work (no rotation: the identity); point lights are refused."""
    ns = SimpleNamespace
    receiver = ns(extent=[-2.0, 2.0, -2.0, 2.0], shape=(8, 8))
    plain = ns(
        generator=ns(center=[0.1, 0.0, 2.0], radii=[1.0, 0.7, 0.5]),
        light=ns(direction=[0.2, 0.1, -1.0]),
        receiver=receiver,
        ior=1.5,
        fresnel=True,
        interfaces=3,
    )
    scene = EllipsoidScene(
        Ellipsoid([0.1, 0.0, 2.0], [1.0, 0.7, 0.5]),
        jc.DirectionalLight([0.2, 0.1, -1.0]),
        jc.PlaneReceiver((-2.0, 2.0, -2.0, 2.0), (8, 8)),
        fresnel=True,
        interfaces=3,
    )
    image = reference.trace_ellipsoid(plain, 48)
    assert image.sum() > 0
    np.testing.assert_array_equal(image, reference.trace_ellipsoid(scene, 48))
    plain.light = ns(position=[0.0, 0.0, 5.0])
    with pytest.raises(ValueError, match="light"):
        reference.trace_ellipsoid(plain, 8)
