"""`transport_map` (the back-and-forth method): a closed-form map, mass, black regions,
bright points, float32 gradients, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.inverse.transport import legendre, level_shapes, pushforward, transport_map

N = 48
X = (np.arange(N) + 0.5) / N
XX, YY = np.meshgrid(X, X)
CORNERS = np.arange(N + 1) / N


def gaussian(cx, cy, s=0.08, x=XX, y=YY):
    return np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))


def quad_areas(plan):
    x, y = plan.map_x, plan.map_y
    return 0.5 * (
        (x[1:, 1:] - x[:-1, :-1]) * (y[1:, :-1] - y[:-1, 1:])
        - (x[1:, :-1] - x[:-1, 1:]) * (y[1:, 1:] - y[:-1, :-1])
    )


def landed(plan, source, k=6):
    """The source's mass carried by the map (each cell split into k x k points, linear in
    its corners) binned into the grid's cells: an independent check of the map."""
    t = (np.arange(k) + 0.5) / k
    a, b = np.meshgrid(t, t)

    def inside(m):
        m00, m01 = m[:-1, :-1, None, None], m[:-1, 1:, None, None]
        m10, m11 = m[1:, :-1, None, None], m[1:, 1:, None, None]
        return (1 - b) * ((1 - a) * m00 + a * m01) + b * ((1 - a) * m10 + a * m11)

    px, py = inside(plan.map_x) * N, inside(plan.map_y) * N
    w = np.broadcast_to((source / source.sum() / k**2)[..., None, None], px.shape)
    image, _, _ = np.histogram2d(
        py.ravel(), px.ravel(), bins=[N, N], range=[[0, N], [0, N]], weights=w.ravel()
    )
    return image


def test_gaussian_to_shifted_gaussian_is_the_shift():
    """Equal Gaussians: the optimal map is the translation between their centres."""
    mu, nu = gaussian(0.4, 0.45), gaussian(0.6, 0.5)
    # the misfit is still creeping down after 100 iterations (0.028 relative L1: the
    # pixel-level floor of the Gaussians' tails); the map is already exact to 0.2 px
    plan = transport_map(mu, nu, iterations=100, tol=1e-4, warn=False)
    cx, cy = np.meshgrid(CORNERS, CORNERS)
    err = np.hypot(plan.map_x - cx - 0.2, plan.map_y - cy - 0.05) * N  # pixels
    weight = gaussian(0.4, 0.45, x=cx, y=cy)
    # measured 0.04 px at the most (0.01 px mass-weighted) where the density is > 10%
    assert err[weight > 0.1].max() < 0.2, err[weight > 0.1].max()


def test_uniform_to_uniform_is_the_identity():
    plan = transport_map(np.ones((8, 12)), np.ones((8, 12)), iterations=5)
    cx, cy = np.meshgrid(np.arange(13) / 12, np.arange(9) / 12)
    np.testing.assert_allclose(plan.map_x, cx, atol=1e-6)
    np.testing.assert_allclose(plan.map_y, cy, atol=1e-6)


def silhouette():
    nu = ((XX - 0.5) ** 2 / 0.09 + (YY - 0.5) ** 2 / 0.04 < 1).astype(float)
    nu[(abs(XX - 0.5) < 0.05) & (abs(YY - 0.75) < 0.2)] = 1.0  # a bar: not convex
    return nu


@pytest.fixture(scope="module")
def silhouette_plan():
    return transport_map(np.ones((N, N)), silhouette(), iterations=100)


def test_mass_is_conserved_and_the_map_does_not_fold(silhouette_plan):
    """The source pushed forward by the solved potentials (the method's own gathered
    push-forward, before any normalisation) carries the source's mass; the map keeps
    every cell's orientation but at its jumps."""
    h = 1.0 / N
    phi = legendre(jnp.asarray(silhouette_plan.potential), h)
    rho = np.asarray(pushforward(phi, jnp.ones((N, N), phi.dtype), h))
    # measured 0.962 of the unit mass: the cells across the map's jumps are sampled at
    # 3 x 3 points, mostly in the black gap, so some of their mass is not seen (the
    # iteration renormalises each push-forward; the independent binning below keeps
    # all of it)
    assert abs(rho.sum() * h * h - 1.0) < 0.06, rho.sum() * h * h
    areas = quad_areas(silhouette_plan)
    # cells that fold (negative area) are a few at the map's jumps, where the corners
    # average the gradients of both sides: measured 6.3% of the cells (along the jumps
    # of this 48 x 48 grid), 1.2% of the area
    assert (areas < 0).mean() < 0.1, (areas < 0).mean()
    assert -areas[areas < 0].sum() < 0.02, areas[areas < 0].sum()


def test_black_regions_get_almost_no_light(silhouette_plan):
    """Exact zeros over 70% of the target, no floor: the map sends the source into the
    silhouette; what lands outside is the cells across the map's jumps."""
    nu = silhouette()
    image = landed(silhouette_plan, np.ones((N, N)))
    assert np.all(np.isfinite(silhouette_plan.map_x))
    dark = image[nu == 0].sum()
    # measured 5.4% at 48 x 48 (the flat lens: 79%); relative L2 0.20
    assert dark < 0.08, dark
    l2 = np.linalg.norm(image / image.mean() - nu / nu.mean()) / np.linalg.norm(nu / nu.mean())
    assert l2 < 0.3, l2


def test_bright_points_collect_the_light():
    rng = np.random.default_rng(0)
    nu = np.zeros((N, N))
    centres = rng.uniform(0.2, 0.8, (6, 2))
    for cx, cy in centres:
        nu += gaussian(cx, cy, s=1.0 / N)
    nu[nu < 1e-3] = 0.0
    plan = transport_map(np.ones((N, N)), nu, iterations=100)
    image = landed(plan, np.ones((N, N)))
    near = np.zeros((N, N), bool)
    for cx, cy in centres:
        near |= np.hypot(XX - cx, YY - cy) < 2.5 / N
    # measured 86.5% of the light within 2.5 px of the six points (they cover 5% of
    # the screen; the flat lens puts 5% there) in float32; bound 0.8 leaves room for
    # the float64 run's own rounding of the map's jumps
    assert image[near].sum() > 0.8, image[near].sum()


def test_steps_are_finite_and_differentiable_in_float32():
    """A step's pieces (Legendre transform, gathered push-forward) on a target with
    exact zeros: values and gradients finite in float32."""
    h = np.float32(1.0 / N)
    nu = jnp.asarray(silhouette() / silhouette().mean(), jnp.float32)

    def misfit(bump):  # the potential |x|^2 / 2 + 1e-3 bump (`legendre` takes the bump)
        phi = legendre(legendre(1e-3 * bump, h), h)
        rho = pushforward(phi, jnp.ones((N, N), jnp.float32), h)
        return jnp.sum((rho - nu) ** 2)

    bump = jnp.asarray(gaussian(0.5, 0.5), jnp.float32)
    value, grad = jax.jit(jax.value_and_grad(misfit))(bump)
    assert value.dtype == jnp.float32
    assert np.isfinite(float(value))
    assert np.all(np.isfinite(np.asarray(grad)))
    assert np.abs(np.asarray(grad)).max() > 0


def test_float64_and_float32_give_the_same_map():
    """float32 is JAX's default (the test suite runs in float64)."""
    previous = jax.config.jax_enable_x64
    pair = gaussian(0.45, 0.5), gaussian(0.55, 0.5)
    try:
        jax.config.update("jax_enable_x64", True)
        plan64 = transport_map(*pair, iterations=40, warn=False)
        jax.config.update("jax_enable_x64", False)
        plan32 = transport_map(*pair, iterations=40, warn=False)
    finally:
        jax.config.update("jax_enable_x64", previous)
    assert plan32.potential.dtype == np.float32 and plan64.potential.dtype == np.float64
    # measured 1.3e-4 of the domain (0.006 px) at the most
    np.testing.assert_allclose(plan32.map_x, plan64.map_x, atol=2e-3)


@pytest.mark.parametrize(
    ("source", "target", "match"),
    [
        (np.ones((8, 8)), np.zeros((8, 8)), "`target` is all zeros"),
        (np.zeros((8, 8)), np.ones((8, 8)), "`source` is all zeros"),
        (np.ones((8, 8)), np.full((8, 8), np.nan), "`target` contains NaN"),
        (np.ones((8, 8)), -np.ones((8, 8)), "`target` must be non-negative"),
        (np.ones((8, 8)), np.ones((8, 9)), "one shape"),
        (np.ones(8), np.ones(8), "`source` must be a 2-D"),
    ],
)
def test_bad_densities_are_refused(source, target, match):
    with pytest.raises(ValueError, match=match):
        transport_map(source, target)


def test_running_out_of_iterations_warns():
    with pytest.warns(UserWarning, match="still falling"):
        plan = transport_map(np.ones((N, N)), silhouette(), iterations=3)
    assert not plan.converged and plan.iterations == 3


def test_stretched_cells_leave_a_map_along_one_axis_alone():
    """Densities that vary along x only: the optimal map is the 1-D monotone
    rearrangement whatever the metric, so stretching the cells along x (the cost of lens
    design under leaning light) must give the same map in units of the grid's width,
    and the unchanged map along y."""
    mu, nu = gaussian(0.4, 0.5, s=0.2) ** 0 + 0.5 * XX, 1.5 - XX
    plain = transport_map(mu, nu, iterations=60, warn=False)
    stretched = transport_map(mu, nu, iterations=60, warn=False, stretch=0.8)
    # measured: 0.006 px apart (the two solves' own tolerance)
    assert np.abs(stretched.map_x / 0.8 - plain.map_x).max() * N < 0.05
    assert np.abs(stretched.map_y - plain.map_y).max() * N < 0.05
    # the stretched domain, up to the corner map's extrapolated edge (measured 4.5e-5)
    assert stretched.map_x.max() == pytest.approx(0.8, abs=1e-3)
    with pytest.raises(ValueError, match="`stretch`"):
        transport_map(mu, nu, stretch=0.0)


def test_a_non_separable_map_depends_on_the_stretch():
    """A diagonal shift of a Gaussian: the stretch changes the metric, so the map moves
    (the check above is not vacuous)."""
    mu, nu = gaussian(0.35, 0.35), gaussian(0.6, 0.55)
    plain = transport_map(mu, nu, iterations=60, warn=False)
    stretched = transport_map(mu, nu, iterations=60, warn=False, stretch=0.8)
    assert np.abs(stretched.map_x / 0.8 - plain.map_x).max() * N > 0.5


def test_smooth_transforms_leave_no_staircase_where_the_map_compresses():
    """Uniform light onto a target up to 4x brighter: the grid's transforms put every
    maximiser on a cell centre, and the cells' images alternate in area (measured: RMS
    16% of the local mean, up to 86%); the smooth interpolants' map moves continuously
    (RMS 0.6%, at most 3%) and pushes the source forward closer to the target (misfit
    0.015 against 0.118)."""
    from scipy.ndimage import uniform_filter

    mu = np.ones((N, N))
    nu = 0.3 + 1.4 * XX * (0.5 + YY)

    def alternation(plan):
        a = quad_areas(plan)
        return np.abs(a / uniform_filter(a, 3, mode="nearest") - 1)[2:-2, 2:-2]

    grid = transport_map(mu, nu, iterations=100, warn=False)
    smooth = transport_map(mu, nu, iterations=100, warn=False, smooth=True)
    assert np.sqrt(np.mean(alternation(grid) ** 2)) > 0.1  # the staircase is there
    assert np.sqrt(np.mean(alternation(smooth) ** 2)) < 0.02
    assert alternation(smooth).max() < 0.1
    assert smooth.residual[-1] < 0.03 < grid.residual[-1]


def test_level_shapes_halve_down_to_the_coarsest():
    assert level_shapes((1024, 1024), 256) == [(256, 256), (512, 512), (1024, 1024)]
    assert level_shapes((1023, 700), 256) == [(256, 175), (512, 350), (1023, 700)]
    assert level_shapes((300, 300), 256) == [(150, 150), (300, 300)]
    assert level_shapes((256, 256), 256) == [(256, 256)]
    assert level_shapes((1024, 1024), None) == [(1024, 1024)]
    assert level_shapes((4096, 6), 64)[0] == (4096, 6)  # too thin to halve


# the smooth transforms' variant is slow (20 s of the default run's 8 minutes)
@pytest.mark.parametrize("smooth", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_multiscale_transport_reaches_the_single_levels_map(smooth):
    """A 144^2 pair of Gaussians solved from a 36^2 level up (two halvings) against one
    level: the same map, to a fraction of a cell, in fewer iterations on the finest grid
    (the coarse levels' potentials start each finer one)."""
    n = 144
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    mu = gaussian(0.4, 0.45, s=0.15, x=xx, y=yy) + 0.2
    nu = gaussian(0.55, 0.5, s=0.1, x=xx, y=yy) + 0.1 * (xx > 0.7)
    one = transport_map(mu, nu, iterations=100, warn=False, smooth=smooth, coarsest=None)
    multi = transport_map(mu, nu, iterations=100, warn=False, smooth=smooth, coarsest=36)
    assert [level[0] for level in multi.levels] == [(36, 36), (72, 72), (144, 144)]
    assert one.levels == [((n, n), one.iterations, pytest.approx(one.residual[-1]))]
    assert multi.iterations < one.iterations, (multi.iterations, one.iterations)
    assert multi.residual[-1] < 1.2 * one.residual[-1], (multi.residual[-1], one.residual[-1])
    apart = np.hypot(multi.map_x - one.map_x, multi.map_y - one.map_y) * n  # cells
    # measured: median 0.02 cells, 90% within 0.14 (grid) and 0.09 (smooth); the
    # largest (up to 30 cells) at the domain's corners, which map onto the target's
    # empty corners (its Gaussian is 1e-7 there): a map the densities barely fix
    median, ninety = np.percentile(apart, [50, 90])
    assert median < 0.05 and ninety < 0.25, (median, ninety)
