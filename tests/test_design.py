"""`design_lens`: validation, a small design judged by the reference tracer, brightness
invariance, masks."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

import jaxcaustics.inverse.design as design_module
from jaxcaustics import DirectionalLight, PointLight
from jaxcaustics.inverse import (
    image_refine,
    lens_model,
    lens_setup,
    numerics,
    poisson_levels,
    transport_start,
)
from jaxcaustics.inverse.design import design_lens
from jaxcaustics.reference import trace_lens

SPEC = dict(width=0.1, height=0.1, thickness=0.02, screen_distance=0.5)
SMALL = dict(levels=(16,), max_steps=15, start="poisson")  # the irradiance solve


def blob(n=16):
    """A smooth target: two Gaussian spots on a dim background."""
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    spots = np.exp(-((xx - 0.35) ** 2 + (yy - 0.4) ** 2) / 0.02)
    spots += 0.7 * np.exp(-((xx - 0.7) ** 2 + (yy - 0.65) ** 2) / 0.015)
    return 0.3 + spots


def rel_l2(image, target):
    a = image / image.mean()
    b = target / target.mean()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def blob_design():
    return design_lens(blob(), **SPEC, **SMALL)


# ----------------------------------------------------------------- bad specifications


@pytest.fixture
def no_optimisation(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("the optimisation started before the specification was checked")

    monkeypatch.setattr(design_module, "_solve", forbidden)


@pytest.mark.parametrize(
    ("change", "name"),
    [
        (dict(thickness=-0.01), "thickness"),
        (dict(thickness=0.0), "thickness"),
        (dict(screen_distance=0.0), "screen_distance"),
        (dict(screen_distance=-1.0), "screen_distance"),
        (dict(width=0.0), "width"),
        (dict(height=float("nan")), "height"),
        (dict(ior=1.0), "ior"),
        (dict(regularization=-1.0), "regularization"),
        (dict(levels=()), "levels"),
        (dict(mask=np.ones((8, 8), bool)), "mask"),
        (dict(mask=np.zeros((16, 16), bool)), "mask"),
        # a weak lens this strong needs a relief deeper than the blank
        (dict(thickness=1e-5), "thickness"),
        (dict(ior="1.5"), "ior"),
        (dict(thickness="0.5"), "thickness"),
        (dict(levels=(8.7, 16)), "levels"),
        (dict(rtol=-1e-4), "rtol"),
        (dict(rtol=float("nan")), "rtol"),
        (dict(boundary_weight=float("nan")), "boundary_weight"),
        (dict(boundary_weight=-1.0), "boundary_weight"),
        (dict(predict_photons=-3), "predict_photons"),
        (dict(predict_photons=64.5), "predict_photons"),
        (dict(initial=np.full((8, 8), np.nan)), "initial"),
        (dict(initial=np.zeros(8)), "initial"),
        (dict(initial=np.zeros((8, 8), complex)), "initial"),
    ],
)
def test_bad_specifications_raise_before_optimisation(no_optimisation, change, name):
    spec = {**SPEC, **SMALL, **change}
    with pytest.raises(ValueError, match=f"`{name}`"):
        design_lens(blob(), **spec)


@pytest.mark.parametrize(
    "target",
    [np.full((16, 16), np.nan), np.zeros((16, 16)), -blob(), np.ones(16)],
    ids=["nan", "zeros", "negative", "1-d"],
)
def test_bad_targets_raise_before_optimisation(no_optimisation, target):
    with pytest.raises(ValueError, match="`target`"):
        design_lens(target, **SPEC, **SMALL)


def test_a_target_dark_everywhere_inside_its_mask_is_refused(no_optimisation):
    mask = np.zeros((16, 16), bool)
    mask[4:8, 4:8] = True
    target = np.where(mask, 0.0, blob())
    with pytest.raises(ValueError, match="zero everywhere inside `mask`"):
        design_lens(target, **SPEC, mask=mask)


# ----------------------------------------------------------------- designs


def test_small_design_matches_the_target_by_the_reference(blob_design):
    d = blob_design
    assert d.heights.shape == (16, 16)
    assert np.isclose(d.heights.max(), 0.0)
    assert SPEC["thickness"] + d.heights.min() > 0
    # the loss went down by orders of magnitude from the weak-lens start
    assert d.loss_history[-1] < 0.05 * d.loss_history[0]  # measured: 4.0 -> 0.05
    ref = trace_lens(d.scene, 512)
    flat = rel_l2(np.ones_like(ref), blob())
    error = rel_l2(ref, blob())
    # measured: 0.045 (the flat lens: 0.42); the forward model agrees with the reference
    assert error < 0.06, (error, flat)
    assert rel_l2(d.predicted, ref) < 0.03


def test_design_is_invariant_to_the_target_brightness(blob_design):
    brighter = design_lens(3.0 * blob(), **SPEC, **SMALL)
    np.testing.assert_allclose(brighter.heights, blob_design.heights, rtol=0, atol=1e-9)


def circle_design(start="poisson"):
    """A uniform disc (radius 0.4 of the side) as a masked target, 16 x 16, rendered by
    the reference: by the Poisson start (`SMALL`) or the default transport start."""
    n = 16
    x = (np.arange(n) + 0.5) / n - 0.5
    xx, yy = np.meshgrid(x, x)
    mask = xx**2 + yy**2 < 0.4**2
    knobs = SMALL if start == "poisson" else {}
    d = design_lens(np.ones((n, n)), mask=mask, **SPEC, **knobs)
    return mask, trace_lens(d.scene, 512)


@pytest.fixture(scope="module")
def circle():
    return circle_design()


def test_masked_target_moves_light_into_the_mask(circle):
    mask, ref = circle
    outside = ref[~mask].sum() / ref.sum()
    # the flat lens puts 1 - pi 0.4^2 = 50% of its light outside; measured: 14%
    assert outside < 0.2, outside


def test_masked_target_keeps_the_outside_dark_and_the_inside_even():
    """The default (transport) start on the hard disc: measured 2026-12-04, 0.0000 of the
    light outside and an inside standard deviation of 0.012 of the mean (0.025 at
    32 x 32)."""
    mask, ref = circle_design("transport")
    assert ref[~mask].sum() / ref.sum() < 0.01
    assert np.std(ref[mask] / ref[mask].mean()) < 0.05


@pytest.mark.xfail(
    reason=(
        "the Poisson start's irradiance solve does not converge for a hard disc mask: "
        "measured 10% of the light outside and an inside std of 0.88 here; 6% and 0.36 "
        "with the default schedule at 32 x 32 (the default transport start: see above)"
    ),
    strict=False,
)
def test_poisson_start_keeps_a_masked_outside_dark_and_the_inside_even(circle):
    mask, ref = circle
    # the floor (2% of the mean) is all that the design should leave outside: about 1%
    assert ref[~mask].sum() / ref.sum() < 0.03
    assert np.std(ref[mask] / ref[mask].mean()) < 0.15


# ----------------------------------------------------------------- schedule and folding


def test_default_levels_go_up_to_twice_the_target():
    assert poisson_levels.default_levels((128, 128)) == (32, 64, 128, 256)
    assert poisson_levels.default_levels((96, 128)) == (32, 64, 128, 256)
    assert poisson_levels.default_levels((16, 16)) == (32,)


def test_level_targets_keep_the_mean_and_split_pixels_exactly():
    rng = np.random.default_rng(0)
    goal = rng.uniform(0.1, 2.0, (12, 16))
    coarse = lens_model.level_target(goal, (6, 8))
    assert coarse.shape == (6, 8)
    np.testing.assert_allclose(coarse.mean(), goal.mean(), rtol=1e-12)
    np.testing.assert_allclose(coarse[0, 0], goal[:2, :2].mean(), rtol=1e-12)
    fine = lens_model.level_target(goal, (24, 32))
    assert fine.shape == (24, 32)
    np.testing.assert_array_equal(fine[::2, ::2], goal)
    np.testing.assert_array_equal(fine[1::2, 1::2], goal)
    assert lens_model.level_target(goal, (12, 16)) is goal


def test_fresnel_zones_keep_the_slopes_and_bound_the_relief():
    x = np.linspace(-1, 1, 64)
    xx, yy = np.meshgrid(x, x)
    h = -0.05 * (xx**2 + yy**2)  # relief 0.1
    folded = design_module.fresnel_zones(h, 0.03)
    assert folded.max() == 0.0 and folded.min() >= -0.03
    # away from the folds (steps of 0.03 between neighbours) the slopes are unchanged
    step = np.abs(np.diff(folded, axis=1) - np.diff(h, axis=1))
    unfolded = step < 1e-12
    assert unfolded.mean() > 0.85
    np.testing.assert_allclose(step[~unfolded], 0.03, atol=1e-12)
    with pytest.raises(ValueError, match="`depth`"):
        design_module.fresnel_zones(h, 0.0)


def test_max_relief_folds_the_design_into_the_blank(blob_design):
    d = design_lens(blob(), max_relief=2e-4, **SPEC, **SMALL)
    assert d.relief <= 2e-4 + 1e-12
    assert blob_design.relief > 2e-4  # the bound is active (measured: 5.7e-4)


def test_lbfgs_design_improves_on_the_flat_lens():
    d = design_lens(blob(), solver="lbfgs", **{**SPEC, **SMALL, "max_steps": 60})
    assert d.loss_history[-1] < 0.2 * d.loss_history[0]
    assert rel_l2(d.predicted, blob()) < 0.5 * rel_l2(np.ones((16, 16)), blob())


# Known failure (found 2026-12-02, failing since the edge bevel of the transport start,
# before the extrapolated rim: 0.137 and 0.083 at commit 0c9efe2): the bevel throws the
# edge cells' light off the screen, and a target lit to its edges (this blob's 0.3 floor)
# loses its border pixels (-0.24 to -0.35 of the unit mean on the outermost row). Now
# 0.154 (point) and 0.088 (tilted); the flat lens: 0.42. Fitting the heights through the
# bevel (tried) fitted the vertices to 0.002 pixels but gave 0.185.
@pytest.mark.slow
@pytest.mark.xfail(reason="the bevel darkens a lit target's border (see above)", strict=True)
@pytest.mark.parametrize(
    "light",
    [
        PointLight(np.array([0.0, 0.0, 0.82]), 1.0),  # 0.3 m above the lens top
        DirectionalLight(np.array([0.2, 0.0, -1.0])),  # 11 degrees from vertical
    ],
    ids=["point", "tilted"],
)
def test_point_and_tilted_light_designs_match_the_target_by_the_reference(light):
    d = design_lens(blob(), light=light, **SPEC)
    error = rel_l2(trace_lens(d.scene, 512), blob())
    assert error < 0.05, error


@pytest.mark.slow
def test_camera_lens_meets_the_goal_from_its_exported_files(tmp_path):
    """The acceptance case: scikit-image's camera at 128 x 128 in the setting of Mitsuba
    3's caustics tutorial (lens 2 wide, index 1.5, screen 7 past the lens). The exported
    height map (EXR, millimetres; its odd rows and columns are the design's own samples)
    is read back and rendered by the NumPy reference."""
    import trimesh
    from skimage import data

    from jaxcaustics import HeightField, LensScene, export_lens, relative_l2
    from jaxcaustics.io import read_exr

    target = numerics.area_average(data.camera().astype(float), (128, 128))
    d = design_lens(target, width=2.0, height=2.0, thickness=0.5, screen_distance=7.0, ior=1.5)
    paths = export_lens(d.scene, tmp_path, formats=("stl",))
    solid = trimesh.load(paths["stl"])
    assert solid.is_watertight
    np.testing.assert_allclose(solid.extents[:2], [2000.0, 2000.0], rtol=1e-9)  # mm
    z_mm = read_exr(paths["height_exr"]).astype(float)
    heights = z_mm[1::2, 1::2] / 1000.0 - 0.5  # metres above the blank's rest plane
    np.testing.assert_allclose(heights, d.heights, atol=1e-6)  # float32 millimetres
    boundary = json.loads(paths["height_json"].read_text())["boundary"]
    assert boundary == "extrapolate"
    exported = LensScene(
        HeightField(heights, d.scene.surface.extent, boundary),
        d.scene.light,
        d.scene.receiver,
        0.5,
        7.0,
        ior=1.5,
    )
    error = relative_l2(trace_lens(exported, 3072), target)
    # measured 0.0475 (the reference's own noise at 3072^2 photons: 0.012 against 4096^2)
    assert error < 0.05, error


# on request (slow), for the default run's 10-minute budget: the Poisson start's
# non-square levels
@pytest.mark.slow
def test_non_square_design_matches_the_target_by_the_reference():
    rows, cols = 12, 20
    y = (np.arange(rows) + 0.5) / rows
    x = (np.arange(cols) + 0.5) / cols
    xx, yy = np.meshgrid(x, y)
    target = 0.3 + np.exp(-((xx - 0.3) ** 2 + (yy - 0.5) ** 2) / 0.03)
    spec = {**SPEC, "width": 0.15, "height": 0.09}
    d = design_lens(target, **spec, **SMALL)
    assert d.heights.shape == (10, 16)  # 16 samples along the longer side
    assert d.predicted.shape == (rows, cols)
    error = rel_l2(trace_lens(d.scene, (24 * rows, 24 * cols)), target)
    flat = rel_l2(np.ones_like(target), target)
    # measured 0.081 (the flat lens: 0.45): the heights (10 x 16) are coarser than the
    # pixels (12 x 20), so the design cannot follow the target fully
    assert error < 0.25 * flat, (error, flat)


# ----------------------------------------------------------------- the transport start


def silhouette(n=32):
    """A bright disc and bar on exact black (no floor): 27% of the screen lit."""
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    target = ((xx - 0.5) ** 2 + (yy - 0.45) ** 2 < 0.25**2).astype(float)
    target[(abs(xx - 0.5) < 0.06) & (yy > 0.6) & (yy < 0.9)] = 1.0
    return target


@pytest.fixture(scope="module")
def silhouette_design():
    return design_lens(silhouette(), **SPEC)


def test_transport_design_of_a_black_background_by_the_reference(silhouette_design):
    d = silhouette_design
    target = silhouette()
    assert d.levels[0]["stage"] == "transport" and d.levels[1]["stage"] == "landing fit"
    assert not d.levels[0]["smooth"]  # a black background: the grid's own transforms
    assert d.heights.shape == (128, 128)  # four heights per pixel side
    # one level: 128^2 cells are under the multiscale transport's coarsest grid
    assert [level[0] for level in d.levels[0]["levels"]] == [(128, 128)]
    assert np.all(np.isfinite(d.heights)) and np.isclose(d.heights.max(), 0.0)
    ref = trace_lens(d.scene, 1024)
    error = rel_l2(ref, target)
    dark = ref[target == 0].sum() / ref.sum()
    # measured 0.026 and 0.55% of the light on black (the flat lens: 1.5 and 73%; with
    # the clamped rim of earlier versions 0.073 and 3.8%: at 32 x 32 pixels the
    # outermost ring of heights is a larger share of the light than at 128 x 128, the
    # benchmark: 0.033 and 0.57%); the design's own prediction agrees with the reference
    assert error < 0.05, (error, dark)
    assert dark < 0.015, (dark, error, d.predicted_error)
    assert d.levels[2]["stage"] == "image refinement" and d.levels[2]["kept"]
    assert abs(d.predicted_error - error) < 0.01  # measured 0.027 against 0.026
    assert d.converged


def test_landing_fit_gradients_are_finite_in_float32(silhouette_design):
    import jax
    import jax.numpy as jnp

    previous = jax.config.jax_enable_x64
    try:
        jax.config.update("jax_enable_x64", False)
        problem, start, finish = design_module.lens_problem(**SPEC)
        setup = lens_setup.prepare(problem, silhouette(), start, finish)
        shape = setup.shapes[-1]
        problem = lens_model.level_model(setup, shape)
        goal_x, goal_y, _ = transport_start._transport_goal(setup, shape, problem, 100)
        pixel = jnp.asarray([0.1 / 32, 0.1 / 32], jnp.float32)
        sampling = lens_model.vertex_sampling(shape, setup.aperture, problem.grid, setup.boundary)
        fit = transport_start._LandingFit(problem, goal_x, goal_y, jnp.ones(shape), pixel, sampling)

        def loss(h):
            rx, ry = fit.residual(h)
            return 0.5 * jnp.sum(rx**2 + ry**2)

        h = jnp.asarray(silhouette_design.heights, jnp.float32)
        value, grad = jax.jit(jax.value_and_grad(loss))(h)
    finally:
        jax.config.update("jax_enable_x64", previous)
    assert grad.dtype == jnp.float32
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))


def test_a_design_that_misses_the_target_warns():
    """Twelve 1-pixel dots with an 8 x 8 heights grid: the surface cannot focus them."""
    target = np.zeros((16, 16))
    target[2::4, 1::5] = 1.0
    with pytest.warns(UserWarning, match="misses the target") as caught:
        d = design_lens(target, **SPEC, levels=(8,), refine_steps=0)
    assert d.predicted_error > 0.15
    assert any("misses the target" in str(w.message) for w in caught)
    assert d.warnings and "misses the target" in d.warnings[0]


def test_landing_goals_are_read_smoothly_between_their_samples():
    """The landing fit reads its goal map at drifting points (oblique rays' rest-plane
    crossings) with the Catmull-Rom interpolant: exact at the samples, and its slope is
    continuous across the cell lines, where a bilinear read's slope jumps (and a fitted
    surface gets a moire; measured, 20-degree light: 1 - SSIM 0.184 -> 0.170)."""
    import jax.numpy as jnp

    from jaxcaustics.inverse.lens_model import _bilinear
    from jaxcaustics.inverse.transport_start import _bicubic

    x = np.arange(12) + 0.5
    image = jnp.asarray(np.sin(0.4 * x)[None, :] * np.cos(0.3 * x)[:, None])
    rows, cols = np.meshgrid(x, x, indexing="ij")
    exact = _bicubic(image, jnp.asarray(cols), jnp.asarray(rows))
    np.testing.assert_allclose(exact, image, atol=1e-12)
    # the slope along a row just left and right of the cell line at u = 6.5
    eps = 1e-4
    u = jnp.asarray([6.5 - 2 * eps, 6.5 - eps, 6.5 + eps, 6.5 + 2 * eps])
    v = jnp.full(4, 3.25)
    for read, continuous in ((_bicubic, True), (_bilinear, False)):
        f = np.asarray(read(image, u, v))
        left, right = (f[1] - f[0]) / eps, (f[3] - f[2]) / eps
        # measured: the slopes differ by 8e-5 of the slope (bicubic: the difference
        # quotients' own error) against 28% (bilinear)
        assert (abs(right - left) < 1e-3 * abs(left)) == continuous, (read.__name__, left, right)


def test_edges_under_leaning_light_get_a_bevel_and_the_band_it_takes_no_transport():
    """Light leaning outwards at an edge that lies below the top's rest plane would meet
    the surface beyond the aperture (a ring `-h_edge * tan(lean)` wide): the edge rises
    to the rest plane over that width plus a cell, and the transport leaves out the
    band whose rays reach the bevel. Vertical light needs none."""

    from jaxcaustics.inverse.transport_start import _edge_bevel

    cell = 2.0 / 64
    h = np.full((64, 64), -0.1)
    h[32, 32] = 0.0
    setup = _bevel_setup(0.5, 0.0)
    weight, keep, k = _edge_bevel(setup, h)
    assert k == 0 and not weight.any() and np.all(keep == 1.0)

    setup.light = DirectionalLight.from_angles(20.0)  # leans towards +x
    weight, keep, k = _edge_bevel(setup, h)
    lean = abs(np.asarray(setup.light.direction)[0] / np.asarray(setup.light.direction)[2])
    assert k == int(np.ceil(0.1 * lean / cell)) + 1 == 3
    np.testing.assert_allclose(weight[:, -1], 1.0)  # the edge up to the rest plane
    assert not weight[:, : 64 - k].any() and not weight[:, 0].any()  # the other edges stay
    # the band: the bevel's k cells and the ring inwards of its inner end (1.16 cells)
    band = k + 0.1 * lean / cell
    np.testing.assert_allclose(keep[5, ::-1][:6], np.clip(np.arange(6) + 1.0 - band, 0, 1))
    assert np.all(keep[:, :-6] == 1.0)

    setup.light = PointLight(np.array([0.0, 0.0, 7.5 + 10.5]), 1.0)  # leans out everywhere
    weight, keep, k = _edge_bevel(setup, h)
    assert k > 0 and all(np.all(w == 1.0) for w in (weight[0], weight[-1], weight[:, 0]))
    assert keep[32, 32] == 1.0 and keep[0, 32] == 0.0 and keep[32, 0] == 0.0


def test_the_map_smoothing_keeps_ramps_and_removes_a_one_cell_staircase():
    """The transport map read between its samples (leaning light) is smoothed by
    [1, 2, 1] / 4: a ramp (a shift, a uniform stretch) stays as it is inside, the
    discrete Legendre transforms' one-cell alternation goes (measured, 20-degree
    light before refinement: 1 - SSIM 0.150 -> 0.129, the moire arcs gone)."""
    from jaxcaustics.inverse.numerics import binomial_smooth as _binomial_smooth

    rows, cols = np.mgrid[0:9, 0:11].astype(float)
    ramp = 0.3 * rows - 0.7 * cols + 2.0
    smooth = _binomial_smooth(ramp)
    assert smooth.shape == ramp.shape
    np.testing.assert_allclose(smooth[1:-1, 1:-1], ramp[1:-1, 1:-1], atol=1e-12)
    staircase = ramp + 0.1 * (-1.0) ** (rows + cols)
    smooth = _binomial_smooth(staircase)
    np.testing.assert_allclose(smooth[1:-1, 1:-1], ramp[1:-1, 1:-1], atol=1e-12)
    np.testing.assert_allclose(_binomial_smooth(np.full((4, 5), 3.0)), 3.0)


def test_the_image_refinement_moves_only_modes_its_photons_resolve():
    """Heights modes finer than the refinement's photon grid are seen aliased (as
    coarser ones) by its image: the refinement keeps them as they are (measured,
    20-degree light: 1 - SSIM 0.167 -> 0.157, the texture they grew gone)."""
    import jax
    import jax.numpy as jnp

    from jaxcaustics.inverse.image_refine import _ImageRefine, _resolved_modes

    resolved = _resolved_modes((8, 12), 5)  # 6 photons (5 cells) a side resolve 5 modes
    assert resolved.shape == (8, 12) and resolved[4, 4] and not resolved[5, 0]
    assert resolved.sum() == 25
    refine = _ImageRefine(None, None, None, jnp.ones((8, 12)), jnp.asarray(resolved), 6, 4, 0.3)
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(8, 12)))

    @jax.jit  # eager, the DCTs' per-op compilations take seconds
    def spectrum_of_gradient(u):
        grad = jax.grad(lambda u: jnp.sum(weights * refine.heights(u)))(u)
        return jax.scipy.fft.dctn(grad, type=2, norm="ortho")

    spectrum = np.asarray(spectrum_of_gradient(jnp.zeros((8, 12))))
    # zero up to the DCTs' rounding (1e-16) where not resolved; the weights' own elsewhere
    assert np.abs(spectrum[~resolved]).max() < 1e-12 < np.abs(spectrum[resolved]).min()
    u = jnp.asarray(np.random.default_rng(1).normal(size=(8, 12)))
    round_trip = jax.jit(lambda u: refine.heights(refine.variable(u)))
    np.testing.assert_allclose(round_trip(u), u, atol=1e-12)


def test_a_ring_wider_than_the_bevel_can_take_warns():
    """A relief so deep under leaning light that the ring of rays meeting the surface
    beyond the aperture is wider than a quarter of it: the bevel stops there and says so."""

    from jaxcaustics.inverse.transport_start import _edge_bevel

    h = np.full((16, 16), -2.0)
    h[8, 8] = 0.0
    setup = _bevel_setup(2.5, 20.0)  # ring 0.73 m: 5.8 cells of 0.125 m
    with pytest.warns(UserWarning, match="more than the bevel's 4"):
        weight, keep, k = _edge_bevel(setup, h)
    # the band: the 4 bevel cells and the 5.8-cell ring inwards of them
    assert k == 4 and np.all(weight[:, -1] == 1.0) and np.all(weight[:, :-4] == 0.0)
    assert np.all(keep[:, -9:] == 0.0) and np.all(keep[:, :-10] == 1.0)


# 42 s, slow for the default run's budget: the bevel's own test stays in it; the
# leaning-light design end to end, judged by the reference, runs with -m slow
@pytest.mark.slow
def test_point_light_design_bevels_its_edges_and_matches_by_the_reference():
    """The leaning-light path end to end: a short first pass, the bevel, the second
    transport and fit, judged by the reference (measured: relative L2 0.073, 1.2% of
    the flux on black, a 2-cell bevel, 74 transport iterations over both passes; 0.048
    with the clamped rim of earlier versions, while at 128 x 128 the benchmark's
    point-light row went from 0.052 to 0.051)."""
    from jaxcaustics import PointLight

    target = silhouette()
    light = PointLight(np.array([0.0, 0.0, 0.52 + 1.5 * 0.5]), 1.0)  # 1.5 screen distances above
    d = design_lens(target, **SPEC, light=light)
    transport, fit = d.levels[0], d.levels[1]
    assert transport["steps"] > 30 and fit["bevel_cells"] > 0
    # the light the bevel throws off the screen (measured 11.8%) is said, not dropped
    assert any("not in the prediction" in note for note in d.warnings), d.warnings
    ref = trace_lens(d.scene, 1024)
    error = rel_l2(ref, target)
    dark = ref[target == 0].sum() / ref.sum()
    assert error < 0.08 and dark < 0.03, (error, dark)


def test_the_refinement_loss_gradient_through_its_custom_jvp_is_the_reverse_mode_one():
    """`_image_loss` hands L-BFGS its reverse-mode gradient where the solver linearises
    it (faster inside its accept/reject `lax.cond`): the gradient and the linearisation
    must be those of the loss itself (float64, against central differences)."""
    import jax
    import jax.numpy as jnp

    from jaxcaustics import HeightField, LensScene, PlaneReceiver
    from jaxcaustics.inverse.image_refine import _image_loss, _ImageRefine

    rng = np.random.default_rng(3)
    heights = 0.02 * rng.normal(size=(12, 12))
    scene = LensScene(
        HeightField(heights, (-1.0, 1.0, -1.0, 1.0), "clamp"),
        DirectionalLight.from_angles(10.0),
        PlaneReceiver(np.array([-1.2, 1.2, -1.2, 1.2]), (8, 8)),
        0.5,
        3.0,
        ior=1.5,
    )
    goal = np.zeros((8, 8))
    goal[2:6, 1:7] = 1.0
    goal /= goal.mean()
    refine = _ImageRefine(
        scene,
        jnp.asarray(goal),
        jnp.asarray(goal < 0.05),
        jnp.ones((12, 12)),
        jnp.ones((12, 12), bool),
        13,
        4,
        0.3,
    )
    u = jnp.asarray(heights)
    v = jnp.asarray(rng.normal(size=(12, 12)))
    # what L-BFGS takes: the loss's linearisation (through the custom JVP), jitted; the
    # loss at the shifted points comes from the same compiled function (its primal)
    jvp = jax.jit(lambda u, v: jax.jvp(lambda u: _image_loss(u, refine), (u,), (v,)))
    loss, slope = jvp(u, v)
    step = 1e-6
    central = (jvp(u + step * v, v)[0] - jvp(u - step * v, v)[0]) / (2 * step)
    assert np.isfinite(float(loss)) and float(loss) > 0
    assert abs(float(central)) > 1e-3
    assert float(slope) == pytest.approx(float(central), rel=1e-5)


def test_the_landing_fit_step_does_not_overshoot_at_the_extrapolated_rim():
    """The fit's step ``M^-1 J^T W r`` against the exact Gauss-Newton step: the largest
    gain of ``M^-1 J^T W J`` (`M` the DCT symbol, `W` the edge weighting) must stay below
    2, or the fixed-point iteration grows that mode. The lens's "extrapolate" rim makes
    the edge vertices see checkerboards the symbol does not (unweighted: 7.6, which
    diverged at 512^2); weighted, 1.69, as the clamped surface's 1.65 (measured)."""
    import scipy.fft

    n = 16
    symbol = lens_model.fit_symbol((n, n), 1.0, 1.0, 1.0, 1.0)
    dct = scipy.fft.dct(np.eye(n), type=2, norm="ortho", axis=0)
    dct = np.kron(dct, dct)
    inverse = dct.T @ np.diag(1.0 / symbol.ravel()) @ dct
    vertices = np.linspace(0.0, n, n + 1)

    def largest_gain(boundary, edge):
        value, slope = lens_model.catmull_rom_matrix(n, 0.0, n, vertices, boundary)
        w = np.ones(n + 1)
        w[[0, -1]] = edge
        weight = np.kron(np.diag(w), np.diag(w))
        jx, jy = np.kron(value, slope), np.kron(slope, value)
        normal = jx.T @ weight @ jx + jy.T @ weight @ jy
        return np.linalg.eigvals(inverse @ normal).real.max()

    edge = transport_start._EDGE_WEIGHT
    assert largest_gain(lens_model.LENS_BOUNDARY, edge) < 1.8
    assert largest_gain(lens_model.LENS_BOUNDARY, 1.0) > 4.0  # why the weighting is there
    assert largest_gain("clamp", 1.0) < 1.8
    # and the weighting in the fit is this one
    r = transport_start._edge_weighted(np.ones((n + 1, n + 1)))
    np.testing.assert_allclose(np.asarray(r)[0, 1:-1], edge)
    np.testing.assert_allclose(np.asarray(r)[0, 0], edge**2)
    np.testing.assert_allclose(np.asarray(r)[1:-1, 1:-1], 1.0)


def test_the_fit_reads_the_lens_surface_it_designs():
    """The fit's separable bicubic weights at the photon vertices are the designed lens's
    surface (`HeightField` with `LENS_BOUNDARY`), rim included."""
    import jax.numpy as jnp

    from jaxcaustics import HeightField
    from jaxcaustics.internal import height_and_gradient

    rng = np.random.default_rng(0)
    h = rng.normal(size=(6, 8))
    aperture = (-1.0, 1.0, -0.7, 0.7)
    wy, dwy, wx, dwx = (
        np.asarray(a)
        for a in lens_model.vertex_sampling(h.shape, aperture, (9, 13), lens_model.LENS_BOUNDARY)
    )
    px, py = np.meshgrid(np.linspace(-1.0, 1.0, 13), np.linspace(-0.7, 0.7, 9))
    field = HeightField(h, aperture, lens_model.LENS_BOUNDARY)
    got = height_and_gradient(field, jnp.asarray(px), jnp.asarray(py))
    v, gx, gy = (np.asarray(a) for a in got)
    np.testing.assert_allclose(wy @ h @ wx.T, v, atol=1e-12)
    np.testing.assert_allclose(wy @ h @ dwx.T, gx, atol=1e-11)
    np.testing.assert_allclose(dwy @ h @ wx.T, gy, atol=1e-11)


def test_the_rim_of_a_design_steers_its_light_like_its_neighbours(silhouette_design):
    """The outermost ring of cells (a half sample wide) of a transport design: under its
    "extrapolate" rim its light goes where the design sends it; read with a clamped rim
    (the same heights) it falls on the black border of the screen."""
    from jaxcaustics import HeightField, LensScene
    from jaxcaustics.reference import emit_lens_photons, trace_lens_photons

    d = silhouette_design
    assert d.scene.surface.boundary == "extrapolate"
    target = silhouette()
    rows, cols = target.shape
    x0, x1, y0, y1 = np.asarray(d.scene.surface.extent, float)
    half = 0.5 * (x1 - x0) / d.heights.shape[1]
    xs, ys, _ = emit_lens_photons(d.scene, 512)
    rim = np.minimum.reduce([xs - x0, x1 - xs, ys - y0, y1 - ys]) < half
    sx0, sx1, sy0, sy1 = np.asarray(d.scene.receiver.extent, float)

    def on_black(scene):
        xy, weight, alive = trace_lens_photons(scene, xs[rim], ys[rim])
        j = np.clip(((xy[0, :, 0] - sx0) / (sx1 - sx0) * cols).astype(int), 0, cols - 1)
        i = np.clip(((xy[0, :, 1] - sy0) / (sy1 - sy0) * rows).astype(int), 0, rows - 1)
        w = weight[0] * alive[0]
        return float(w[target[i, j] == 0].sum() / w.sum())

    sc = d.scene
    field = HeightField(d.heights, sc.surface.extent, "clamp")
    clamped = LensScene(field, sc.light, sc.receiver, sc.thickness, sc.screen_distance, ior=sc.ior)
    # measured 5.5% and 100%
    assert on_black(d.scene) < 0.2 and on_black(clamped) > 0.6, (
        on_black(d.scene),
        on_black(clamped),
    )


def test_a_heights_grid_too_large_for_the_machine_is_refused_before_any_work(monkeypatch):
    """``levels=(4096,)`` once ran on to 9 GB in 10 s; the estimate (1.3 kB a sample,
    measured) is refused above `memory_limit`, by default half the machine's memory (here
    made 16 GiB)."""
    pages = {"SC_PAGE_SIZE": 4096, "SC_PHYS_PAGES": (16 << 30) // 4096}
    monkeypatch.setattr(lens_setup.os, "sysconf", lambda name: pages[name])
    assert lens_setup.default_memory_limit() == 8 << 30
    with pytest.raises(ValueError, match="levels"):
        design_lens(blob(), **SPEC, levels=(4096,), start="poisson")
    # a 4096^2 target: its heights grid is the cost (the prediction is traced in bands)
    with pytest.raises(ValueError, match=r"heights grid \(4096, 4096\).*`heights_shape`"):
        design_lens(np.ones((4096, 4096)), **SPEC)
    eight = lens_setup.default_memory_limit()
    lens_setup._check_design_memory((1024, 1024), 2, 0, eight)  # 6.1 GiB: fine
    with pytest.raises(ValueError, match="GiB.*`memory_limit`"):  # with 4 GiB more: not
        lens_setup._check_design_memory((1024, 1024), 2, image_refine._REFINE_MEMORY, eight)


def test_a_minimiser_object_designs_on_the_half_sum_of_squares():
    """An Optimistix minimiser given as `solver` gets ``0.5 * sum(residual^2)`` (as the
    names "lbfgs", "bfgs" and "adam" do), and lowers it."""
    import optimistix as optx

    with pytest.warns(UserWarning, match="max_steps=5"):  # five steps do not converge
        d = design_lens(blob(), **SPEC, **{**SMALL, "max_steps": 5}, solver=optx.BFGS(1e-6, 1e-9))
    history = d.loss_history
    assert len(history) >= 2 and history[-1] < history[0]


def test_the_default_prediction_has_four_photons_a_pixel_side_up_to_2049():
    """4 photons a pixel side up to 2049 a side, and at least 2 beyond: a 512-pixel
    target's 2049^2 photons were once capped at the 1 GiB of one trace (2047); they are
    now traced in bands when they do not fit (`test_design_memory`). At 1024 pixels 2049
    predict the lettering's design as 4097 do (0.0853 against 0.0859), in a quarter of
    the time, unless the image refinement fitted the heights on 2049."""
    from jaxcaustics.inverse.lens_setup import predict_photons_default

    assert predict_photons_default((128, 128)) == 513
    assert predict_photons_default((4, 512)) == 2049
    assert predict_photons_default((1024, 1024)) == 2049
    assert predict_photons_default((2048, 1024)) == 4097
    # not the photon grid the refinement fitted the heights to (it flatters them)
    assert predict_photons_default((1024, 1024), refined=2049) == 4097
    assert predict_photons_default((1024, 1024), refined=1025) == 2049
    assert predict_photons_default((128, 128), refined=513) == 513  # 4 a side already


def _bevel_setup(thickness: float, zenith_deg: float) -> SimpleNamespace:
    """What `_edge_bevel` reads of a setup: a 2 m square lens, its bottom face 7 m above
    the ground, `thickness` thick, under collimated light `zenith_deg` from vertical."""
    return SimpleNamespace(
        aperture=(-1.0, 1.0, -1.0, 1.0),
        screen_distance=7.0,
        thickness=thickness,
        top=7.0 + thickness,
        is_mirror=False,
        light=DirectionalLight.from_angles(zenith_deg),
    )


def test_a_target_has_dark_regions_past_a_tenth_of_its_pixels_below_5_percent():
    """What picks the image refinement's run and the transport's transforms."""
    from jaxcaustics.inverse.design_setup import has_dark_regions

    target = np.ones((10, 10))
    target[:1] = 0.04 * target.mean()  # a tenth: not yet
    assert not has_dark_regions(target)
    target[1, :1] = 0.0
    assert has_dark_regions(target)
    assert has_dark_regions(silhouette()) and not has_dark_regions(blob())


def test_a_photograph_on_a_coarse_grid_gets_a_few_refinement_steps():
    """Fewer than four heights samples a target pixel side, with at least two of the
    refinement's photons: a photograph is refined too (`PHOTO_STEPS`); with four
    samples, not; a target on black gets `STEPS`, and `COARSE_STEPS` on fewer than
    four samples. The variable's scale grows with the landing gain in pixels (4x the
    pixels: 4x the scale), never below 1."""
    import jaxcaustics as jc
    from jaxcaustics.inverse import image_refine
    from jaxcaustics.inverse.lens_setup import prepare

    problem = jc.DesignProblem(jc.Lens(0.02), jc.Rectangle(0.1, 0.1), jc.Screen(0.5))
    finish = jc.ImageRefinement()

    def setup(target, grid):
        return prepare(problem, target, jc.TransportStart(grid=grid), finish)

    coarse, fine = setup(blob(32), 64), setup(blob(32), 128)
    n = finish.photons_for(coarse)
    assert image_refine._fine_detail(coarse, n) and not image_refine._fine_detail(fine, n)
    assert not image_refine._fine_detail(coarse, 2 * 32)  # one photon a pixel side
    assert finish.budget(coarse) == image_refine.PHOTO_STEPS
    # at 1024 pixels the cap of 1025 photons is one a pixel side: a photograph gets two
    assert finish.photons_for(setup(blob(1024), 1024)) == 2 * 1024 + 1
    # a target on black: `COARSE_STEPS` on fewer than four samples a pixel side
    assert finish.budget(setup(silhouette(), 128)) == image_refine.STEPS
    assert finish.budget(setup(silhouette(), 64)) == image_refine.COARSE_STEPS
    assert image_refine.COARSE_STEPS > image_refine.STEPS
    assert image_refine._variable_scale(coarse) == 1.0  # 32 pixels: below the tuned gain
    wide, wider = setup(blob(256), 512), setup(blob(512), 1024)
    assert image_refine._variable_scale(wide) > 1.0
    assert image_refine._variable_scale(wider) == pytest.approx(
        2 * image_refine._variable_scale(wide)
    )
