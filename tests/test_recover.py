"""Recovering a water surface from its caustic (`recover_surface`).

The case: a sum of three long sine waves (periodic over the 1 m square, amplitudes 4, 3
and 2 mm), 0.5 m of water, light 20 degrees from vertical. Its caustic ranges over
about 0.94..1.07 (not folded; rays move less than half a pixel). Every solve uses the
same two-pass window (N = 3, M = 2) and grid sizes where it can, so that the compiled
solvers are shared between tests (compilation dominates the runtime of this file).
"""

import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics.inverse import compare_solvers, recover
from jaxcaustics.inverse.recover import SOLVERS, recover_surface

EXT = (0.0, 1.0, 0.0, 1.0)
DEPTH = 0.5
TERMS = ((1, 0, 0.004, 0.0), (0, 1, 0.003, 1.0), (1, 1, 0.002, 2.0))
WINDOW = dict(samples_x=3, channels_y=2)


def light():
    return jc.DirectionalLight.from_angles(20.0, 30.0)


def true_heights(shape=(16, 16)):
    return np.asarray(jc.sine_sum(shape, EXT, terms=TERMS))


def caustic(heights, image_shape=(32, 32)):
    scene = jc.WaterScene(
        jc.HeightField(heights, EXT), light(), jc.PlaneReceiver(EXT, image_shape), DEPTH
    )
    return np.asarray(jc.render(scene, jc.TwoPass.paper()))  # the paper's window, S = 1


def solve(target, **kwargs):
    kwargs = {
        "extent": EXT,
        "rest_depth": DEPTH,
        "light": light(),
        "heights_shape": (16, 16),
        "start": "ripple",  # these tests are of the image-space solvers from flat water
        **WINDOW,
        **kwargs,
    }
    return recover_surface(target, **kwargs)


def height_error(found, truth):
    truth = truth - truth.mean()
    return float(np.linalg.norm(found - truth) / np.linalg.norm(truth))


@pytest.fixture(scope="module")
def case():
    heights = true_heights()
    return heights, caustic(heights)


@pytest.fixture(scope="module")
def lm_result(case, tmp_path_factory):
    """Levenberg-Marquardt from the caustic stored in an EXR file at 3x its scale."""
    path = tmp_path_factory.mktemp("recover") / "target.exr"
    jc.io.write_exr(path, 3.0 * case[1])
    return solve(path)


# on request: the default path is now the transport start (tests/test_water_start.py);
# this one (49 s of compilation) is the two-pass solver's from flat water
@pytest.mark.slow
def test_levenberg_marquardt_recovers_the_surface_from_its_caustic(case, lm_result):
    """16 x 16 heights from a 32 x 32 caustic (read from an EXR file), from flat water.

    Measured: height error 7.4e-4 (relative L2, means removed), caustic error 7.2e-4
    (relative to the target's contrast), in 43 steps. Tolerances: 5e-3 and 5e-3. The
    remaining error is mostly the bias of the smoothness prior (weight 1e-3).
    """
    heights, target = case
    r = lm_result
    assert r.success and r.solver == "levenberg_marquardt" and r.messages == ("",)
    assert r.heights.shape == (16, 16) and r.image.shape == (32, 32)
    # a file's scale is arbitrary: the target is scaled to mean 1 (flat water's)
    assert abs(float(r.target.mean()) - 1.0) < 1e-6
    assert np.abs(r.target - target).max() < 1e-5  # float32 in the file
    assert abs(float(r.heights.mean())) < 1e-12
    assert height_error(r.heights, heights) < 5e-3
    assert r.image_error < 5e-3
    assert r.levels[0].loss < 1e-3 * r.levels[0].initial_loss
    assert float(r.missed_flux_fraction[0]) < 1e-9
    assert r.levels[0].window == (3, 2) and 1 <= r.steps[0] <= 100
    # the result's scene renders the result's image
    image = np.asarray(jc.render(r.scene, samples_x=3, channels_y=2, supersample=1))
    np.testing.assert_allclose(image, r.image, atol=1e-12)


@pytest.fixture(scope="module")
def small_case():
    heights = true_heights((8, 8))
    return heights, caustic(heights, (16, 16))


SMALL = dict(heights_shape=(8, 8), hit_iterations=1, max_steps=3)


@pytest.mark.slow  # about 20 s of compilation for the four solvers; LM runs by default above
@pytest.mark.parametrize("solver", SOLVERS)
def test_each_solver_runs_and_reduces_the_loss(small_case, solver):
    """8 x 8 heights, 16 x 16 pixels, 3 steps. Measured loss ratios after 3 steps:
    LM 0.77, GN 0.015, BFGS 0.22, Adam 0.50."""
    r = solve(small_case[1], solver=solver, throw=False, **SMALL)
    level = r.levels[-1]
    assert r.solver == solver and len(r.results) == 1 and level.steps == 3
    assert not r.success and "maximum number of solver steps" in r.messages[0]
    assert np.isfinite(level.loss) and level.loss < 0.9 * level.initial_loss, (
        level.loss,
        level.initial_loss,
    )


def test_max_steps_reached_raises_with_throw(small_case):
    # Optax's Adam through optimistix.OptaxMinimiser: Optimistix's error when it throws
    with pytest.raises(RuntimeError, match="max_steps"):
        solve(small_case[1], solver="adam", throw=True, **SMALL)


@pytest.mark.slow
def test_coarse_to_fine_passes_each_level_on(case):
    seen = []
    r = solve(case[1], coarse_to_fine=(2, 1), callback=seen.append)
    assert [lv.shape for lv in r.levels] == [(8, 8), (16, 16)]
    assert [lv.level for lv in seen] == [0, 1]
    # the fine level starts from the coarse solution, already close
    assert r.levels[1].initial_loss < 0.1 * r.levels[0].initial_loss
    assert height_error(r.heights, case[0]) < 5e-3


GOOD = dict(extent=EXT, rest_depth=DEPTH)


@pytest.mark.parametrize(
    "target, kwargs, name",
    [
        (np.full((8, 8), np.nan), {}, "target"),
        (np.zeros((8, 8)), {}, "target"),
        (-np.ones((8, 8)), {}, "target"),
        (np.ones(8), {}, "target"),
        (np.ones((8, 8, 3)), {}, "target"),
        (np.ones((8, 8)), {"rest_depth": 0.0}, "rest_depth"),
        (np.ones((8, 8)), {"rest_depth": -1.0}, "rest_depth"),
        (np.ones((8, 8)), {"extent": (1.0, 0.0, 0.0, 1.0)}, "extent"),
        (np.ones((8, 8)), {"receiver_extent": (0.0, 1.0)}, "receiver_extent"),
        (np.ones((8, 8)), {"heights_shape": (1, 8)}, "heights_shape"),
        (np.ones((8, 8)), {"heights_shape": (8, 8, 8)}, "heights_shape"),
        (np.ones((8, 8)), {"solver": "newton"}, "solver"),
        (np.ones((8, 8)), {"smoothness": -1.0}, "smoothness"),
        (np.ones((8, 8)), {"coarse_to_fine": (1, 2)}, "coarse_to_fine"),
        (np.ones((8, 8)), {"coarse_to_fine": (4, 2)}, "coarse_to_fine"),
        (np.ones((8, 8)), {"max_steps": 0}, "max_steps"),
        (np.ones((8, 8)), {"ior": 1.0}, "ior"),
        (np.ones((8, 8)), {"light": "sun"}, "light"),
        (np.ones((8, 8)), {"samples_x": 4}, "samples_x"),
        (np.ones((8, 8)), {"initial": np.full((4, 4), np.inf)}, "initial"),
        (np.ones((8, 8)), {"boundary": "mirror"}, "boundary"),
        (np.ones((8, 8)), {"start": "flat"}, "start"),
        (np.ones((8, 8)), {"blur": -1.0}, "blur"),
        (np.ones((8, 8)), {"blur": 3.0}, "blur"),
        (
            np.ones((8, 8)),
            {"boundary": "clamp", "receiver_extent": (3.0, 4.0, 0.0, 1.0)},
            "receiver_extent",
        ),
        (
            np.ones((8, 8)),
            {"start": "transport", "receiver_extent": (0.0, 2.0, 0.0, 1.0)},
            "start='transport'",
        ),
    ],
)
def test_bad_inputs_raise_before_any_optimisation(target, kwargs, name, monkeypatch):
    def fail(*args, **kw):
        raise AssertionError("optimisation started before the inputs were checked")

    monkeypatch.setattr(recover, "_make_solver", fail)
    monkeypatch.setattr(recover, "auto_window", fail)
    monkeypatch.setattr(recover, "_loss", fail)
    monkeypatch.setattr(recover, "transport_start", fail)
    kw = {**GOOD, "light": light(), **kwargs}
    with pytest.raises(ValueError, match=f"`{name}`"):
        recover_surface(target, **kw)


def test_a_light_from_below_is_refused_where_it_is_made():
    with pytest.raises(ValueError, match="`direction`.*point down"):
        recover_surface(np.ones((8, 8)), **GOOD, light=jc.DirectionalLight((0.0, 0.1, 1.0)))


def test_missing_target_file_raises():
    with pytest.raises(FileNotFoundError):
        recover_surface("/nonexistent/target.png", **GOOD, light=light())


@pytest.mark.slow
def test_solver_comparison_table():
    """Each solver from the same start; prints the table (run with -s to see it)."""
    rows = compare_solvers.compare_solvers(
        true_heights(),
        extent=EXT,
        rest_depth=DEPTH,
        light=light(),
        image_shape=(32, 32),
        max_steps=200,
        throw=False,
        **WINDOW,
    )
    print("\n" + compare_solvers.format_comparison(rows))
    lm = next(r for r in rows if r["solver"] == "levenberg_marquardt")
    assert lm["height_error"] < 5e-3


def test_an_optimistix_solver_object_is_accepted_and_named(small_case):
    """`solver` may be an Optimistix solver object (here Levenberg-Marquardt with its
    default dense linear solve); the result names its class and reports the loss as
    Optimistix does, ``0.5 * sum(residual^2)``."""
    import optimistix as optx

    r = solve(small_case[1], solver=optx.LevenbergMarquardt(1e-6, 1e-9), throw=False, **SMALL)
    level = r.levels[-1]
    assert r.solver == "LevenbergMarquardt" and level.steps == 3
    assert np.isfinite(level.loss) and level.loss < level.initial_loss


def test_a_solver_that_is_neither_a_name_nor_a_solver_is_refused():
    with pytest.raises(ValueError, match="`solver` must be one of"):
        solve(np.ones((16, 16)), solver="newton")
    with pytest.raises(ValueError, match="`solver` must be one of"):
        solve(np.ones((16, 16)), solver=object())
