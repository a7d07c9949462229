"""Fitting caustic spot lights to rays (Liu, Dong, Bao & Peng 2008, Section 3.1).

Synthetic rays come from known CSLs: points ``p`` on a disc of the light plane, each ray
aimed at ``c + f(r) a`` and its origin moved along the ray by a random amount (so the
plane offset is not trivially 0). The disc's points come in pairs ``p``, ``2c - p`` with
equal energies, as a regular emission grid would give, so the bundle's mean direction and
least-squares axis are the CSL's axis exactly.

The default run shares one compiled configuration (``FIT``) between the fitting tests.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.methods.spot_lights.fit import (
    FitInfo,
    as_ray_set,
    fit_focus_law,
    fit_spot_lights,
    focus_law_error,
    lines_through_cell,
    rasterise_lines,
    refine_axis,
    splat_intensity,
)
from jaxcaustics.methods.spot_lights.lights import SpotLights

FIT = dict(max_lights=3, resolution=32, cells=16, axis_iterations=30, fit_steps=60)
RAYS_PER_LIGHT = 300  # half of each light's rays: the other half mirrors them


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def csl_rays(alpha, beta, c, a, *, radius=0.5, n=RAYS_PER_LIGHT, seed=0, energy=1.0):
    """Rays ``(origin, direction, energy)`` of the CSL ``(alpha, beta)`` with plane origin
    ``c`` and axis ``a``: ``2 n`` points on a disc of `radius`, point-symmetric about ``c``."""
    rng = np.random.default_rng(seed)
    a = _unit(np.asarray(a, float))
    c = np.asarray(c, float)
    e1 = _unit(np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0]))
    e2 = np.cross(a, e1)
    rr = radius * np.sqrt(rng.uniform(0, 1, n))
    th = rng.uniform(0, 2 * np.pi, n)
    uv = np.stack([rr * np.cos(th), rr * np.sin(th)], -1)
    uv = np.concatenate([uv, -uv])
    p = c + uv[:, :1] * e1 + uv[:, 1:] * e2
    f = alpha / (1 + beta * np.linalg.norm(uv, axis=-1))
    d = _unit(c + f[:, None] * a - p)
    q = p + rng.uniform(-0.3, 0.5, 2 * n)[:, None] * d
    w = energy * rng.uniform(0.5, 1.5, n)
    return q, d, np.concatenate([w, w])


def exit_rays(q, d, w, *, centre, size=1.0, spacing=0.02):
    """An object shaped like the ray tracer's ``ExitRays``."""
    return SimpleNamespace(
        origin=q, direction=d, energy=w, spacing=spacing, centre=np.asarray(centre), size=size
    )


AXIS = _unit(np.array([0.2, -0.1, -1.0]))
CENTRE = np.array([0.1, 0.2, 0.3])


@pytest.mark.parametrize(
    "alpha, beta",
    [
        # on request (7 s, the default run's budget): the three others stay
        pytest.param(1.5, 0.8, marks=pytest.mark.slow),
        (2.5, 3.0),
        (2.0, 0.0),
        (60.0, 0.5),
    ],
    ids=["focused", "strong-slope", "spot-light", "nearly-collimated"],
)
def test_fit_recovers_known_csl(alpha, beta):
    """Acceptance: alpha, beta and the plane (ell) to 1e-6 (relative; the plane origin
    ``c = b + ell a`` to 1e-6 size). With beta = 0 (a plain spot light) all rays meet in
    one point and every plane along the axis fits exactly: only the focus ``c + alpha a``
    is determined, and beta is 0 to 1e-8 / size."""
    q, d, w = csl_rays(alpha, beta, CENTRE, AXIS)
    lights, info = fit_spot_lights(exit_rays(q, d, w, centre=CENTRE), **FIT)
    assert isinstance(lights, SpotLights) and isinstance(info, FitInfo)
    np.testing.assert_array_equal(lights.active, [True, False, False])
    np.testing.assert_allclose(lights.axis[0], AXIS, atol=1e-9)
    focus = lights.origin[0] + lights.alpha[0] * lights.axis[0]
    np.testing.assert_allclose(focus, CENTRE + alpha * AXIS, rtol=1e-6, atol=1e-6)
    if beta == 0:
        assert 0 <= float(lights.beta[0]) < 1e-8
    else:
        np.testing.assert_allclose(lights.alpha[0], alpha, rtol=1e-6)
        np.testing.assert_allclose(lights.beta[0], beta, rtol=1e-6)
        np.testing.assert_allclose(lights.origin[0], CENTRE, atol=1e-6)
    assert int(info.rays[0]) == len(w)  # exact data: nothing dismissed
    np.testing.assert_allclose(info.fraction, 1.0, rtol=1e-12)
    assert float(info.rms[0]) < 1e-6


@pytest.mark.slow
def test_fit_focus_law_on_given_axis():
    """On a given axis (origin ``b``): the plane offset is recovered; beta = 0 gives the
    focus ``ell + alpha``; `focus_law_error` vanishes for the true law."""
    b = CENTRE - 0.25 * AXIS  # the plane is at ell = 0.25
    fit = jax.jit(lambda q, d, w: fit_focus_law(q, d, w, b, AXIS, size=1.0, steps=60))
    alpha, beta, ell, rms = fit(*csl_rays(2.0, 0.0, CENTRE, AXIS))
    np.testing.assert_allclose(ell + alpha, 2.25, rtol=1e-6)
    assert 0 <= float(beta) < 1e-8 and float(rms) < 1e-6
    q, d, w = csl_rays(1.5, 0.8, CENTRE, AXIS)
    alpha, beta, ell, rms = fit(q, d, w)
    np.testing.assert_allclose([alpha, beta, ell], [1.5, 0.8, 0.25], rtol=1e-6)
    error = focus_law_error(q, d, b, AXIS, 1.5, 0.8, 0.25, size=1.0)
    assert error.shape == w.shape and float(jnp.max(error)) < 1e-20
    start = fit_focus_law(q, d, w, b, AXIS, size=1.0, steps=60, initial=(1.0, 0.5, 0.0))
    np.testing.assert_allclose(start[:3], [1.5, 0.8, 0.25], rtol=1e-6)


def two_lights():
    """Two CSLs 90 degrees apart: ``A`` (more energy) towards -z, ``B`` towards +x."""
    a_axis, b_axis = np.array([0.0, 0, -1]), np.array([1.0, 0, 0])
    ca, cb = np.array([-0.5, 0.1, 0.3]), np.array([0.4, 0.0, -0.2])
    half = RAYS_PER_LIGHT // 2  # as many rays in all as one light of the other tests
    qa, da, wa = csl_rays(1.0, 0.5, ca, a_axis, radius=0.3, n=half, seed=1, energy=2.0)
    qb, db, wb = csl_rays(0.8, 1.5, cb, b_axis, radius=0.3, n=half, seed=2)
    rays = tuple(np.concatenate(pair) for pair in ((qa, qb), (da, db), (wa, wb)))
    truth = [(a_axis, ca, 1.0, 0.5, wa.sum()), (b_axis, cb, 0.8, 1.5, wb.sum())]
    return exit_rays(*rays, centre=np.zeros(3)), truth


def test_two_separated_lights():
    rays, truth = two_lights()
    lights, info = fit_spot_lights(rays, energy_fraction=0.95, **FIT)
    np.testing.assert_array_equal(lights.active, [True, True, False])
    for k, (axis, c, alpha, beta, energy) in enumerate(truth):  # A first: more energy
        np.testing.assert_allclose(lights.axis[k], axis, atol=1e-9)
        np.testing.assert_allclose(lights.origin[k], c, atol=1e-6)
        np.testing.assert_allclose([lights.alpha[k], lights.beta[k]], [alpha, beta], rtol=1e-6)
        np.testing.assert_allclose(info.energy[k], energy, rtol=1e-12)
    assert float(info.fraction) >= 0.95
    np.testing.assert_allclose(info.total_energy, sum(t[-1] for t in truth), rtol=1e-12)
    np.testing.assert_allclose(lights.power(), info.energy, rtol=1e-12)  # images integrate
    # the unused slot: black, finite, inactive
    assert float(jnp.max(lights.image[2])) == 0.0 and info.energy[2] == 0.0
    for leaf in jax.tree.leaves(lights):
        assert bool(jnp.all(jnp.isfinite(leaf)))
    assert float(lights.alpha[2]) > 0 and float(lights.half_width[2]) > 0
    # frame_u is perpendicular to the axis; the image holds the bundle around its centre
    np.testing.assert_allclose(jnp.sum(lights.frame_u * lights.axis, -1), 0.0, atol=1e-12)
    assert lights.half_width[0] > 0.3


def test_energy_fraction_stops_early():
    """With a fraction the first light already holds, the second slot stays unused."""
    rays, truth = two_lights()
    share = truth[0][-1] / (truth[0][-1] + truth[1][-1])
    lights, info = fit_spot_lights(rays, energy_fraction=0.9 * share, **FIT)
    np.testing.assert_array_equal(lights.active, [True, False, False])
    np.testing.assert_allclose(info.fraction, share, rtol=1e-12)


@pytest.mark.slow  # 8-10 s of compilation; the default run covers the fit unbatched
def test_vmap_and_jit_equal_single_calls():
    rays, _ = two_lights()
    other = exit_rays(*csl_rays(1.5, 0.8, CENTRE, AXIS), centre=CENTRE)
    singles = [fit_spot_lights(r, **FIT) for r in (rays, other)]
    pair = [as_ray_set(r) for r in (rays, other)]  # a pytree, so it stacks and vmaps
    batch = jax.tree.map(lambda *x: jnp.stack(x), *pair)

    @jax.jit
    def batched(r):
        return jax.vmap(lambda one: fit_spot_lights(one, **FIT))(r)

    out = batched(batch)
    for i, single in enumerate(singles):
        for got, want in zip(jax.tree.leaves(out), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(got[i], want, rtol=1e-8, atol=1e-10)


@pytest.mark.slow  # a third compilation of the whole fit
def test_float32_input_finite():
    q, d, w = (x.astype(np.float32) for x in csl_rays(1.5, 0.8, CENTRE, AXIS))
    rays = exit_rays(q, d, w, centre=CENTRE.astype(np.float32), size=np.float32(1.0))
    rays.spacing = np.float32(0.02)
    lights, info = fit_spot_lights(rays, **FIT)
    assert lights.image.dtype == jnp.float32
    for leaf in jax.tree.leaves((lights, info)):
        assert bool(jnp.all(jnp.isfinite(leaf)))
    assert bool(lights.active[0])
    np.testing.assert_allclose([lights.alpha[0], lights.beta[0]], [1.5, 0.8], rtol=2e-2)


def cells_crossed(o, d, lo, side, cells):
    """Reference for one line: the cells between consecutive crossings of grid planes."""
    h = side / cells
    planes = lo[:, None] + h * np.arange(cells + 1)  # (3, cells + 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((planes - o[:, None]) / d[:, None]).ravel()
    t = np.sort(t[np.isfinite(t)])
    mid = o + 0.5 * (t[:-1] + t[1:])[:, None] * d
    idx = np.floor((mid - lo) / h).astype(int)
    return np.unique(idx[np.all((idx >= 0) & (idx < cells), axis=1)], axis=0)


def test_rasterise_matches_plane_crossings():
    """Exact DDA: each line adds its energy once to every cell it crosses (reference:
    the midpoints between the line's sorted crossings of all grid planes)."""
    rng = np.random.default_rng(3)
    n, cells, lo, side = 40, 8, np.array([-1.0, -1.0, -1.0]), 2.0
    origin = rng.uniform(-0.8, 0.8, (n, 3))
    direction = _unit(rng.normal(size=(n, 3)))
    direction[0] = [0.0, 0.0, 1.0]  # axis-parallel lines
    direction[1] = _unit(np.array([1.0, 1.0, 0.0]))
    energy = rng.uniform(0.5, 2.0, n)
    grid = np.asarray(rasterise_lines(origin, direction, energy, lo, side, cells))
    want = np.zeros((cells,) * 3)
    for o, dvec, e in zip(origin, direction, energy, strict=True):
        want[tuple(cells_crossed(o, dvec, lo, side, cells).T)] += e
    np.testing.assert_allclose(grid, want, rtol=1e-12)
    # the lines through a cell are those the rasteriser counted there
    best = np.array(np.unravel_index(np.argmax(grid), grid.shape))
    through = np.asarray(lines_through_cell(origin, direction, lo, side, cells, best))
    np.testing.assert_allclose(energy[through].sum(), grid.max(), rtol=1e-12)


def test_refine_axis_ignores_other_rays():
    """From a rough start the axis converges to the CSL's; rays aimed elsewhere (far
    from the axis, or at a steep angle) are not members."""
    q, d, w = csl_rays(1.5, 0.8, CENTRE, AXIS)
    rng = np.random.default_rng(4)
    far = (rng.uniform(-1, 1, (50, 3)) + [3.0, 0, 0], _unit(rng.normal(size=(50, 3))))
    steep = (
        CENTRE + rng.uniform(-0.1, 0.1, (50, 3)),
        _unit(np.cross(AXIS, rng.normal(size=(50, 3)))),
    )
    origin = np.concatenate([q, far[0], steep[0]])
    direction = np.concatenate([d, far[1], steep[1]])
    energy = np.concatenate([w, np.ones(100)])
    start = _unit(AXIS + [0.05, 0.0, 0.0])
    point, axis, member = refine_axis(
        origin, direction, energy, CENTRE + [0.03, -0.02, 0.0], start,
        distance_threshold=0.1, angle_threshold_deg=30.0, iterations=30,
    )  # fmt: skip
    np.testing.assert_allclose(axis, AXIS, atol=1e-9)
    off = (point - CENTRE) - ((point - CENTRE) @ AXIS) * AXIS
    np.testing.assert_allclose(off, 0.0, atol=1e-9)
    np.testing.assert_array_equal(member, np.arange(len(energy)) < len(w))


def test_splat_conserves_energy_and_has_ewa_shape():
    """One oblique ray: the image integrates to its energy and its covariance is the
    cylinder's footprint (``(radius/2)^2 (I + g g^T)``) plus the low-pass (1 pixel^2)."""
    c, a, fu = np.zeros(3), np.array([0.0, 0, 1]), np.array([1.0, 0, 0])
    tilt = np.deg2rad(40.0)
    d = np.array([[np.sin(tilt) * np.cos(0.5), np.sin(tilt) * np.sin(0.5), np.cos(tilt)]])
    q = np.array([[0.01, -0.02, 0.0]]) - 0.3 * d
    w, n, radius = 1.0, 48, 0.05
    image = splat_intensity(
        q, d, np.array([2.5]), c, a, fu, w, radius=radius, resolution=n, window=24
    )
    pixel = 2 * w / n
    np.testing.assert_allclose(jnp.sum(image) * pixel**2, 2.5, rtol=1e-12)
    centres = -w + (np.arange(n) + 0.5) * pixel
    uu, vv = np.meshgrid(centres, centres)  # rows along v
    mass = np.asarray(image) / np.sum(image)
    mean = np.array([np.sum(mass * uu), np.sum(mass * vv)])
    np.testing.assert_allclose(mean, [0.01, -0.02], atol=2e-3)
    du, dv = uu - mean[0], vv - mean[1]
    cov = np.array([[np.sum(mass * du * du), np.sum(mass * du * dv)]] * 2)
    cov[1] = [cov[0, 1], np.sum(mass * dv * dv)]
    g = d[0, :2] / d[0, 2]
    want = (radius / 2) ** 2 * (np.eye(2) + np.outer(g, g)) + pixel**2 * np.eye(2)
    np.testing.assert_allclose(cov, want, rtol=0.05)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(max_lights=0), "max_lights"),
        (dict(resolution=4), "resolution"),
        (dict(cells=2.5), "cells"),
        (dict(axis_iterations=0), "axis_iterations"),
        (dict(fit_steps=-1), "fit_steps"),
        (dict(energy_fraction=0.0), "energy_fraction"),
        (dict(energy_fraction=1.5), "energy_fraction"),
        (dict(distance_threshold=0.0), "distance_threshold"),
        (dict(angle_threshold_deg=90.0), "angle_threshold_deg"),
        (dict(dismiss_threshold=-1.0), "dismiss_threshold"),
        (dict(splat_radius=0.0), "splat_radius"),
        (dict(splat_window=True), "splat_window"),
    ],
)
def test_bad_knobs_raise(kwargs, name):
    q, d, w = csl_rays(1.5, 0.8, CENTRE, AXIS, n=4)
    with pytest.raises(ValueError, match=name):
        fit_spot_lights(exit_rays(q, d, w, centre=CENTRE), **kwargs)


def test_bad_rays_raise():
    q, d, w = csl_rays(1.5, 0.8, CENTRE, AXIS, n=4)
    with pytest.raises(ValueError, match="lacks"):
        fit_spot_lights(SimpleNamespace(origin=q, direction=d, energy=w))
    with pytest.raises(ValueError, match="energy"):
        fit_spot_lights((q, d, w[:-1]))
    with pytest.raises(ValueError, match="size"):
        fit_spot_lights((q, d, w, 0.02, CENTRE, -1.0))


# ---------------------------------------------------------------------------------------
# Slow: a glass ball's refracted rays (spherical aberration: a CSL fits only approximately)


def ball_rays(per_axis, *, radius=0.5, ior=1.5):
    """Exit rays of a glass ball lit from above (two refractions, unit energy each)."""
    s = (np.arange(per_axis) + 0.5) / per_axis * 2 - 1
    x, y = (v.ravel() * radius for v in np.meshgrid(s, s))
    hit = x * x + y * y < (0.98 * radius) ** 2
    x, y = x[hit], y[hit]
    p1 = np.stack([x, y, np.sqrt(radius**2 - x * x - y * y)], -1)
    light = np.array([0.0, 0.0, -1.0])

    def refract(d, n, eta):
        cos_i = -np.sum(d * n, -1, keepdims=True)
        k = 1 - eta**2 * (1 - cos_i**2)
        return eta * d + (eta * cos_i - np.sqrt(k)) * n

    d1 = refract(np.broadcast_to(light, p1.shape), p1 / radius, 1 / ior)
    p2 = p1 - 2 * np.sum(p1 * d1, -1, keepdims=True) * d1  # the chord's far end
    d2 = refract(d1, -p2 / radius, ior)
    spacing = 2 * radius / per_axis
    return exit_rays(p2, _unit(d2), np.full(len(x), spacing**2), centre=np.zeros(3),
                     size=2 * radius, spacing=spacing)  # fmt: skip


@pytest.mark.slow
def test_glass_ball():
    """The bundle angle is 60 degrees: the ball's marginal rays leave it steeply."""
    rays = ball_rays(96)
    lights, info = fit_spot_lights(rays, max_lights=8, resolution=64, angle_threshold_deg=60.0)
    k = int(np.argmax(info.energy))
    # the thresholds' cut through the regular grid need not be symmetric: 1e-3 size
    np.testing.assert_allclose(lights.axis[k], [0, 0, -1], atol=1e-3)
    np.testing.assert_allclose(lights.origin[k][:2], 0.0, atol=1e-3)
    assert float(info.fraction) >= 0.95
    np.testing.assert_allclose(lights.power(), info.energy, rtol=1e-9)
    focus = float(lights.origin[k][2] - lights.alpha[k])  # paraxial focus: z = -0.75
    assert -1.0 < focus < -0.5


@pytest.mark.slow
def test_traced_glass_sphere_exit_rays():
    """The ray tracer's own ``ExitRays`` (duck typed): a glass sphere under a slightly
    slanted sun gives a main light along the light's direction holding most energy."""
    import jaxcaustics as jc
    from jaxcaustics.methods.spot_lights.exit_rays import trace_exit_rays

    scene = jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight.from_angles(10.0, 30.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (16, 16)),
        ior=1.5,
    )
    rays = trace_exit_rays(scene, 96)
    lights, info = fit_spot_lights(rays, max_lights=8, angle_threshold_deg=60.0)
    k = int(np.argmax(info.energy))
    np.testing.assert_allclose(lights.axis[k], scene.light.unit_direction, atol=2e-3)
    assert float(info.energy[k]) > 0.8 * float(info.total_energy)
    assert float(info.fraction) >= 0.95
    np.testing.assert_allclose(lights.power(), info.energy, rtol=1e-9)
