"""Caustic spot lights: evaluation against brute force, hard cases, shading, rendering."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.methods.spot_lights.lights import (
    Glossy,
    Lambertian,
    SpotLights,
    evaluate_spot_lights,
    render_spot_lights,
    sample_light_plane,
    shade_points,
)


def make_light(alpha=1.0, beta=0.5, half_width=0.3, n=48, dtype=np.float64, axis=(0, 0, -1)):
    """One CSL at height 2 m pointing down (by default), a smooth non-uniform image."""
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    frame_u = np.cross(axis, [0.3, 1.0, 0.2])
    x = (np.arange(n) + 0.5) / n * 2 - 1
    image = 1.0 + 0.5 * np.cos(2.0 * x)[None, :] * (1.0 + 0.3 * x[:, None])
    return SpotLights(
        np.array([[0.1, -0.2, 2.0]], dtype),
        axis[None].astype(dtype),
        frame_u[None].astype(dtype),
        np.array([alpha], dtype),
        np.array([beta], dtype),
        np.array([half_width], dtype),
        image[None].astype(dtype),
    )


def local_frame(light):
    c = np.asarray(light.origin[0])
    return c, np.asarray(light.axis[0]), np.asarray(light.frame_u[0]), np.asarray(light.frame_v[0])


def brute_force(light, x, dense=401):
    """Flux density on the plane through `x` perpendicular to the axis, by mapping a dense
    triangulated grid of the light plane along the CSL rays onto that plane and adding
    ``I(p) area_p / area_q`` of every mapped triangle that contains `x` (every sheet of
    rays through `x`). Independent of the root formulas and of Eq. 4: the map follows the
    CSL definition (a ray from p meets the axis at distance f(r)) directly."""
    c, a, eu, ev = local_frame(light)
    alpha, beta = float(light.alpha[0]), float(light.beta[0])
    w = float(light.half_width[0])
    d = x - c
    z = d @ a
    target = np.array([d @ eu, d @ ev])
    g = (np.arange(dense) + 0.5) / dense * 2 * w - w
    pu, pv = np.meshgrid(g, g)
    r = np.hypot(pu, pv)
    scale = 1.0 - z * (1.0 + beta * r) / alpha  # q = p (1 - z / f(r))
    qu, qv = pu * scale, pv * scale
    intensity = np.asarray(
        sample_light_plane(
            light, jnp.asarray(pu.ravel()[:, None]), jnp.asarray(pv.ravel()[:, None])
        )
    ).reshape(pu.shape)
    total = 0.0
    # two triangles per grid cell
    for (i0, j0), (i1, j1), (i2, j2) in (
        ((0, 0), (0, 1), (1, 1)),
        ((0, 0), (1, 1), (1, 0)),
    ):
        sl = lambda arr, i, j: arr[i : dense - 1 + i, j : dense - 1 + j]  # noqa: E731
        A = np.stack([sl(qu, i0, j0), sl(qv, i0, j0)], -1)
        B = np.stack([sl(qu, i1, j1), sl(qv, i1, j1)], -1)
        C = np.stack([sl(qu, i2, j2), sl(qv, i2, j2)], -1)
        e1, e2, t = B - A, C - A, target - A
        det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            b1 = (t[..., 0] * e2[..., 1] - t[..., 1] * e2[..., 0]) / det
            b2 = (e1[..., 0] * t[..., 1] - e1[..., 1] * t[..., 0]) / det
        inside = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (det != 0)
        area_p = 0.5 * (2 * w / dense) ** 2
        i_mean = (sl(intensity, i0, j0) + sl(intensity, i1, j1) + sl(intensity, i2, j2)) / 3
        total += np.sum(np.where(inside, i_mean * area_p / np.abs(0.5 * det), 0.0))
    return total


def cross_section_density(light, x):
    """Flux density through the plane through `x` parallel to the light plane, with the
    focus bound `max_gain` out of the way (1e9: a relative effect below 1e-12 here)."""
    rays = evaluate_spot_lights(light, jnp.asarray(x)[None], max_gain=1e9)
    cos_axis = np.sum(np.asarray(rays.direction[0, 0]) * np.asarray(light.axis[0]), axis=-1)
    return float(np.sum(np.asarray(rays.irradiance[0, 0]) * cos_axis)), rays


@pytest.mark.parametrize(
    "beta,z,rho_range,rays",
    [
        # before every focus: one ray (r1); the slow ones keep the default run short
        pytest.param(0.5, 0.4, (0.02, 0.15), 1, marks=pytest.mark.slow),
        (2.0, 0.7, (0.002, 0.012), 3),  # among the foci, inside the fold: r1, r2, r3
        pytest.param(2.0, 0.7, (0.02, 0.05), 1, marks=pytest.mark.slow),  # outside the fold
        (0.5, 1.6, (0.02, 0.15), 1),  # past every focus: r3
    ],
)
def test_evaluation_matches_brute_force(beta, z, rho_range, rays):
    """Flux density through the plane perpendicular to the axis at random points, against
    `brute_force`. Tolerance 2%: the brute force linearises the ray map over triangles of
    0.75 mm and averages the intensity over each; near the ring of rays focused next to
    the axis and at the outer rays past the foci its own error (measured against a grid
    twice as fine) reaches 1.2%. Points near the fold (inverse-square-root singularity)
    and on the axis are not drawn."""
    light = make_light(beta=beta)
    c, a, eu, ev = local_frame(light)
    rng = np.random.default_rng(int(z * 10 + beta))
    counts = []
    for _ in range(5):
        rho = rng.uniform(*rho_range)
        phi = rng.uniform(0, 2 * np.pi)
        x = c + z * a + rho * (np.cos(phi) * eu + np.sin(phi) * ev)
        got, found = cross_section_density(light, x)
        want = brute_force(light, x, dense=801)
        assert got == pytest.approx(want, rel=0.02), (rho, phi, got, want)
        counts.append(int(np.sum(np.asarray(found.valid))))
    # the case's rays were found (a point may also lie where no ray of the image reaches)
    assert max(counts) == rays and counts.count(rays) >= 3, counts


def test_rays_pass_through_the_point():
    """Every valid ray leaves its light-plane source and goes through the query point."""
    light = make_light()
    rng = np.random.default_rng(1)
    c, a, eu, ev = local_frame(light)
    pts = (
        c + rng.uniform(0.2, 2.0, (200, 1)) * a + rng.normal(0, 0.1, (200, 2)) @ np.stack([eu, ev])
    )
    rays = evaluate_spot_lights(light, jnp.asarray(pts))
    valid = np.asarray(rays.valid[:, 0])
    assert valid.sum() > 100
    to_x = pts[:, None, :] - np.asarray(rays.source[:, 0])
    to_x /= np.linalg.norm(to_x, axis=-1, keepdims=True)
    cos = np.sum(to_x * np.asarray(rays.direction[:, 0]), axis=-1)
    np.testing.assert_allclose(cos[valid], 1.0, atol=1e-9)
    # sources lie on the light plane
    np.testing.assert_allclose((np.asarray(rays.source[:, 0]) - c) @ a, 0.0, atol=1e-12)


def test_plain_spot_light_and_collimated_limits():
    """beta = 0: every ray meets the axis at alpha, like a point source focus; alpha =
    inf: rays parallel to the axis, irradiance = intensity (no focusing)."""
    collimated = make_light(alpha=np.inf, beta=0.0)
    c, a, eu, ev = local_frame(collimated)
    x = c + 1.3 * a + 0.05 * eu - 0.1 * ev
    rays = evaluate_spot_lights(collimated, jnp.asarray(x)[None], max_gain=1e9)
    assert int(np.sum(np.asarray(rays.valid))) == 1
    want = float(sample_light_plane(collimated, jnp.array([[0.05]]), jnp.array([[-0.1]]))[0, 0])
    got = np.asarray(rays.irradiance)[np.asarray(rays.valid)]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    spot = make_light(alpha=1.0, beta=0.0)
    x = c + 0.5 * a + 0.05 * eu  # halfway to the focus: the beam is half as wide
    got, _ = cross_section_density(spot, x)
    want = 4.0 * float(sample_light_plane(spot, jnp.array([[0.1]]), jnp.array([[0.0]]))[0, 0])
    assert got == pytest.approx(want, rel=1e-9)
    # and very large alpha agrees with the collimated limit
    big = make_light(alpha=1e12, beta=0.0)
    np.testing.assert_allclose(
        cross_section_density(big, x)[0], cross_section_density(collimated, x)[0], rtol=1e-6
    )


def hard_points(light):
    c, a, eu, _ = local_frame(light)
    alpha = float(light.alpha[0])
    # on the axis before, among and past the foci, and at the central focus itself (for a
    # nearly collimated light: near and far points)
    zs = [0.3, 0.7 * alpha, alpha, 1.2 * alpha] if alpha < 100 else [0.3, 1.0, 50.0, 80.0]
    pts = [c + z * a for z in zs]  # on the axis, including the central focus
    pts += [c + z * a + 1e-7 * eu for z in zs]  # next to it
    return np.array(pts)


@eqx.filter_jit
def _value_and_gradients(light, pts):
    normals = jnp.broadcast_to(-light.axis[0], pts.shape)

    def loss(light, pts):
        return jnp.sum(shade_points(light, pts, normals))

    return loss(light, pts), eqx.filter_grad(loss)(light, pts), jax.grad(loss, 1)(light, pts)


# float64 on request (slow), for the default run's budget: the hard case runs in float32
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=pytest.mark.slow)])
def test_values_and_gradients_finite_on_axis_and_at_focus(dtype):
    """On the axis (before, among, past the foci and at the central focus), 1e-7 m off
    it, for a plain spot light (beta = 0), nearly and exactly collimated lights and a
    strongly aberrated one, in float64 and float32."""
    for alpha, beta in [(1.0, 0.5), (1.0, 0.0), (1e30, 0.0), (np.inf, 0.3), (2.0, 5.0)]:
        light = make_light(alpha=alpha, beta=beta, dtype=dtype)
        pts = jnp.asarray(hard_points(light), dtype)
        value, g_light, g_pts = _value_and_gradients(light, pts)
        assert np.isfinite(float(value)) and float(value) > 0, (alpha, beta)
        for leaf in jax.tree.leaves(g_light) + [g_pts]:
            if jnp.issubdtype(leaf.dtype, jnp.floating):
                assert np.all(np.isfinite(np.asarray(leaf))), (alpha, beta)


def test_focus_brightness_bounded_by_max_gain():
    """At the central focus the correction is capped: flux density <= max_gain x I / cos."""
    light = make_light(alpha=1.0, beta=0.0)
    c, a, _, _ = local_frame(light)
    for gain in (10.0, 1e3):
        rays = evaluate_spot_lights(light, jnp.asarray(c + 0.999999 * a)[None], max_gain=gain)
        top = float(jnp.max(light.image)) * gain
        assert float(jnp.max(rays.irradiance)) <= top * 1.0001
    assert float(jnp.max(rays.irradiance)) > 100 * float(jnp.min(light.image))


def test_gradient_matches_finite_differences():
    light = make_light()
    c, a, eu, ev = local_frame(light)
    pts = jnp.asarray([c + 0.5 * a + 0.07 * eu, c + 1.4 * a - 0.1 * ev, c + 0.9 * a + 0.1 * eu])
    normals = jnp.broadcast_to(jnp.array([0.1, 0.0, 1.0]) / np.hypot(0.1, 1), pts.shape)

    @jax.jit
    def loss(alpha, beta, origin):
        lt = SpotLights(
            origin, light.axis, light.frame_u, alpha, beta, light.half_width, light.image
        )
        return jnp.sum(shade_points(lt, pts, normals) * jnp.array([1.0, 2.0, 3.0]))

    args = (light.alpha, light.beta, light.origin)
    grads = jax.grad(loss, argnums=(0, 1, 2))(*args)
    for k in range(3):
        flat = np.asarray(args[k]).ravel()
        for i in range(flat.size):
            h = 1e-6
            up, down = flat.copy(), flat.copy()
            up[i] += h
            down[i] -= h
            a_up = list(args)
            a_dn = list(args)
            a_up[k] = jnp.asarray(up.reshape(np.shape(args[k])))
            a_dn[k] = jnp.asarray(down.reshape(np.shape(args[k])))
            fd = (float(loss(*a_up)) - float(loss(*a_dn))) / (2 * h)
            assert float(np.asarray(grads[k]).ravel()[i]) == pytest.approx(fd, rel=1e-5, abs=1e-8)


def test_inactive_lights_and_outside_image_give_nothing():
    light = make_light()
    c, a, eu, _ = local_frame(light)
    off = SpotLights(
        light.origin,
        light.axis,
        light.frame_u,
        light.alpha,
        light.beta,
        light.half_width,
        light.image,
        active=jnp.array([False]),
    )
    pts = jnp.asarray([c + 0.5 * a + 0.1 * eu, c - 0.5 * a, c + 0.5 * a + 5.0 * eu])
    assert float(jnp.sum(evaluate_spot_lights(off, pts).irradiance)) == 0.0
    rays = evaluate_spot_lights(light, pts)
    assert bool(jnp.any(rays.valid[0]))
    assert not bool(jnp.any(rays.valid[1]))  # behind the light plane
    assert not bool(jnp.any(rays.valid[2]))  # no ray of the image reaches it


def test_render_conserves_power_of_a_collimated_light():
    """A collimated light straight down puts its whole power on a receiver covering it."""
    import jaxcaustics as jc

    light = make_light(alpha=np.inf, beta=0.0, axis=(0, 0, -1))
    receiver = jc.PlaneReceiver((-0.5, 0.7, -0.8, 0.4), (60, 60))
    image = render_spot_lights(light, receiver, samples=3)
    pixel = 1.2 * 1.2 / 3600
    assert float(jnp.sum(image)) * pixel == pytest.approx(float(light.power()[0]), rel=0.01)


def test_sphere_occluder_casts_a_shadow_and_shading_models():
    import jaxcaustics as jc
    from jaxcaustics.scene.ellipsoid import Ellipsoid

    light = make_light(alpha=np.inf, beta=0.0, axis=(0, 0, -1))
    receiver = jc.PlaneReceiver((-0.3, 0.5, -0.6, 0.2), (40, 40))
    free = render_spot_lights(light, receiver, samples=1)
    ball = Ellipsoid.sphere([0.1, -0.2, 1.0], 0.1)
    shadow = render_spot_lights(light, receiver, samples=1, occluders=[ball])
    centre = (20, 20)  # pixel under the ball's centre (0.1, -0.2)
    assert float(free[centre]) > 0.5 and float(shadow[centre]) == 0.0
    # the shadow of the ball (radius 0.1 m) under the collimated light: a disc of its
    # radius, where the intensity is close to its value at the centre (10%: the disc is
    # 10 pixels across and the image varies by a few per cent over it)
    lost = float(jnp.sum(free - shadow)) * (0.8 / 40) ** 2
    centre_intensity = float(sample_light_plane(light, jnp.zeros((1, 1)), jnp.zeros((1, 1)))[0, 0])
    assert lost == pytest.approx(np.pi * 0.1**2 * centre_intensity, rel=0.1)
    lam = render_spot_lights(light, receiver, samples=1, shading=Lambertian(0.8))
    np.testing.assert_allclose(lam, 0.8 / np.pi * free, rtol=1e-12)
    # glossy: under a uniform collimated light the lobe peaks below the eye
    uniform = SpotLights(
        light.origin,
        light.axis,
        light.frame_u,
        light.alpha,
        light.beta,
        light.half_width,
        jnp.ones_like(light.image),
    )
    eye = jnp.array([0.1, -0.2, 3.0])
    glossy = render_spot_lights(uniform, receiver, samples=1, shading=Glossy(eye, 0.0, 1.0, 200.0))
    peak = np.unravel_index(int(jnp.argmax(glossy)), glossy.shape)
    assert peak == pytest.approx(centre, abs=1)
    assert float(glossy[centre]) == pytest.approx(208 / (8 * np.pi), rel=1e-3)


def test_bad_inputs_name_the_argument():
    light = make_light()
    with pytest.raises(ValueError, match="points"):
        evaluate_spot_lights(light, jnp.zeros((3, 2)))
    with pytest.raises(ValueError, match="max_gain"):
        evaluate_spot_lights(light, jnp.zeros((3, 3)), max_gain=0.0)
    with pytest.raises(ValueError, match="alpha"):
        SpotLights(
            light.origin,
            light.axis,
            light.frame_u,
            -light.alpha,
            light.beta,
            light.half_width,
            light.image,
        )
    with pytest.raises(ValueError, match="beta"):
        SpotLights(
            light.origin,
            light.axis,
            light.frame_u,
            light.alpha,
            -light.beta,
            light.half_width,
            light.image,
        )
    with pytest.raises(ValueError, match="image"):
        SpotLights(
            light.origin,
            light.axis,
            light.frame_u,
            light.alpha,
            light.beta,
            light.half_width,
            light.image[:, :3],
        )
    with pytest.raises(ValueError, match="frame_u"):
        SpotLights(
            light.origin,
            light.axis,
            light.axis,
            light.alpha,
            light.beta,
            light.half_width,
            light.image,
        )
