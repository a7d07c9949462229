"""`design(problem, target)`: the problem as data, its strategies, and `design_lens` as its
keyword form (the same designs); bad problems refused by name before anything runs."""

import warnings

import numpy as np
import optimistix as optx
import pytest

import jaxcaustics as jc
import jaxcaustics.inverse.design as design_module
from jaxcaustics.inverse import driver

SPEC = dict(width=0.1, height=0.1, thickness=0.02, screen_distance=0.5)
PROBLEM = jc.DesignProblem(jc.Lens(thickness=0.02), jc.Rectangle(0.1, 0.1), jc.Screen(0.5))


def blob(n=16):
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    return 0.3 + np.exp(-((xx - 0.35) ** 2 + (yy - 0.4) ** 2) / 0.02)


def letters(n=24):
    """A bright bar and a dot on black (dark on more than 10% of the screen: the image
    refinement runs)."""
    t = np.zeros((n, n))
    t[6:9, 4:20] = 1.0
    t[14:19, 10:15] = 1.0
    return t


def same(a, b):
    np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_array_equal(a.predicted, b.predicted)
    assert a.loss_history == b.loss_history
    assert [r["stage"] for r in a.levels] == [r["stage"] for r in b.levels]


# ----------------------------------------------------------------- the same designs


# the transport start and two refinement steps on the bar-and-dot target: compiled once
# per worker and shared by the tests below (the resumed design reuses the programs)
TRANSPORT = dict(start=jc.TransportStart(max_steps=6), finish=jc.ImageRefinement(2))


@pytest.fixture(scope="module")
def transport_design():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jc.design(PROBLEM, letters(), **TRANSPORT)


def test_design_lens_is_design_with_its_keywords_under_the_transport_start(transport_design):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        old = jc.design_lens(letters(), **SPEC, refine_steps=2, max_steps=6)
    same(old, transport_design)
    assert [r["stage"] for r in old.levels] == ["transport", "landing fit", "image refinement"]
    assert transport_design.problem == PROBLEM


@pytest.mark.slow  # 19 s (compiling two levels); the transport start's twin runs by default
def test_design_lens_is_design_with_its_keywords_under_the_poisson_levels():
    light = jc.DirectionalLight.from_angles(10.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        old = jc.design_lens(blob(), **SPEC, light=light, start="poisson", levels=(8, 12),
                             max_steps=3)  # fmt: skip
        problem = jc.DesignProblem(PROBLEM.element, PROBLEM.outline, PROBLEM.screen, light)
        new = jc.design(problem, blob(), start=jc.PoissonLevels((8, 12), 3), finish=None)
    same(old, new)
    assert [r["shape"] for r in new.levels] == [(8, 8), (12, 12)]


def test_every_level_report_carries_an_optimistix_result(transport_design):
    for report in transport_design.levels:
        assert isinstance(report["result"], optx.RESULTS), report
    # the refinement is a step budget: stopping at it is no shortfall
    assert transport_design.levels[-1]["budget"]
    assert transport_design.levels[-1]["result"] == optx.RESULTS.max_steps_reached


# ----------------------------------------------------------------- the driver


def test_the_driver_stops_a_stalled_fixed_point_and_keeps_its_best_iterate():
    """A fixed point whose misfit stops falling ends after `patience` steps with the best
    iterate, not the last."""
    import equinox as eqx
    import jax.numpy as jnp

    class Bouncing(eqx.Module):
        def __call__(self, y, args):
            # the misfit of y is |y - 1|; the step overshoots to 1 + (1 - y) * 1.5
            return 1.0 + (1.0 - y) * 1.5, jnp.abs(y - 1.0)

    history = []
    run = driver.iterate(
        Bouncing(), optx.FixedPointIteration(rtol=0.0, atol=1e-9), jnp.asarray(0.5), None,
        max_steps=50, history=history, patience=3,
    )  # fmt: skip
    assert run.stalled and run.steps == 4, (run.steps, history)
    assert float(run.y) == 0.5 and run.misfit == 0.5  # the first iterate was the best
    assert history == [0.5 * m**2 for m in (0.5, 0.75, 1.125, 1.6875)]


def test_the_driver_stops_a_diverging_solver_and_keeps_the_last_finite_iterate():
    """Gradient descent with a step far too long on ``y^4`` overflows in a few steps: the
    run ends as diverged with the iterate before the overflow, and no NaN or infinite loss
    in the history (NaN heights were reported downstream as impossible geometry)."""
    import jax.numpy as jnp

    def loss(y, args):
        return jnp.sum(y**4)

    history, seen = [], []
    run = driver.iterate(
        loss, optx.GradientDescent(learning_rate=10.0, rtol=0.0, atol=0.0),
        jnp.ones(2, jnp.float32), None, max_steps=50, history=history,
        callback=lambda info: seen.append(info["loss"]),
    )  # fmt: skip
    assert run.diverged and run.result == optx.RESULTS.nonlinear_divergence
    assert 1 <= run.steps < 50 and len(history) == run.steps - 1 and seen == history
    assert np.all(np.isfinite(np.asarray(run.y))) and np.all(np.isfinite(history))


def test_a_diverged_design_stage_is_named_as_such_not_as_a_step_limit():
    import types

    from jaxcaustics.inverse import design

    report = {"stage": "irradiance", "shape": (32, 32), "steps": 7, "loss": 1.0,
              "result": optx.RESULTS.nonlinear_divergence}  # fmt: skip
    setup = types.SimpleNamespace(
        warn_error=0.15, shapes=[(32, 32)], target_shape=(16, 16), start=None
    )
    notes = design._design_warnings(setup, [report], 0.1, 0.0)
    assert len(notes) == 1 and "(32, 32) diverged at step 7" in notes[0], notes
    assert "`solver`" in notes[0] and design._stopped(report)


def test_the_driver_reports_max_steps_when_the_budget_ends_the_run():
    import jax.numpy as jnp

    def residual(y, args):
        return y - 3.0

    solver = optx.GaussNewton(rtol=1e-6, atol=1e-6)
    history = []
    run = driver.iterate(residual, solver, jnp.zeros(2), None, max_steps=1, history=history)
    # Optimistix's Gauss-Newton accepts its first step at the second: y is still 0
    assert run.result == optx.RESULTS.max_steps_reached and run.steps == 1
    assert history == [9.0]  # 0.5 |0 - 3|^2 per component
    run = driver.iterate(residual, solver, jnp.zeros(2), None, max_steps=10, history=[])
    assert run.result == optx.RESULTS.successful and run.steps < 10
    np.testing.assert_allclose(np.asarray(run.y), 3.0)


# ----------------------------------------------------------------- bad problems


@pytest.fixture
def no_work(monkeypatch):
    def started(*args, **kwargs):
        raise AssertionError("the design started before the problem was checked")

    monkeypatch.setattr(design_module, "_solve", started)


@pytest.mark.parametrize(
    ("build", "name"),
    [
        (lambda: jc.Lens(thickness=0.0), "thickness"),
        (lambda: jc.Lens(thickness=0.02, ior=0.9), "ior"),
        (lambda: jc.Lens(thickness=0.02, ior=(1.5, 1.6)), "ior"),
        (lambda: jc.Rectangle(0.1, -0.1), "height"),
        (lambda: jc.Rectangle("0.1", 0.1), "width"),
        # a screen behind the element (above its bottom face)
        (lambda: jc.Screen(-0.5), "screen_distance"),
        (lambda: jc.Screen(0.5, extent=(1.0, -1.0, -1.0, 1.0)), "screen_extent"),
        # light from behind: travelling up, or a point light below the element's top
        (lambda: jc.DirectionalLight([0.0, 0.0, 1.0]), "direction"),
        (
            lambda: jc.DesignProblem(
                jc.Lens(0.02), jc.Rectangle(0.1, 0.1), jc.Screen(0.5), jc.PointLight([0, 0, 0.3])
            ),
            "light",
        ),
        (lambda: jc.DesignProblem("lens", jc.Rectangle(0.1, 0.1), jc.Screen(0.5)), "element"),
        (lambda: jc.DesignProblem(jc.Lens(0.02), (0.1, 0.1), jc.Screen(0.5)), "outline"),
        (lambda: jc.DesignProblem(jc.Lens(0.02), jc.Rectangle(0.1, 0.1), 0.5), "screen"),
        (lambda: jc.TransportStart(iterations=0), "iterations"),
        (lambda: jc.TransportStart(grid=2), "grid"),
        (lambda: jc.PoissonLevels(levels=()), "levels"),
        (lambda: jc.PoissonLevels(floor=0.0), "floor"),
        (lambda: jc.PoissonLevels(solver="newton"), "solver"),
        (lambda: jc.ImageRefinement(steps=-1), "steps"),
    ],
)
def test_bad_problems_and_strategies_are_refused_by_name_when_built(build, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        build()


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(problem=SPEC), "problem"),
        (dict(start="transport"), "start"),
        (dict(finish=8), "finish"),
        (dict(mask=np.ones((4, 4), bool)), "mask"),
        (dict(max_relief=0.0), "max_relief"),
        (dict(callback="print"), "callback"),
    ],
)
def test_design_refuses_bad_arguments_before_any_work(no_work, kwargs, name):
    arguments = {"problem": PROBLEM, "target": blob(), **kwargs}
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.design(**arguments)


# ----------------------------------------------------------------- checkpoints


def test_an_interrupted_design_resumes_where_it_stopped_and_ends_the_same(
    transport_design, tmp_path
):
    """Ctrl-C in the refinement (the second round): the checkpoint keeps the transport
    start's heights, and the resumed design runs the refinement alone."""

    def stop_in_the_refinement(info):
        if info["level"] == 1:
            raise KeyboardInterrupt

    path = tmp_path / "design.ckpt"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(KeyboardInterrupt, match="after 1 of 2 rounds"):
            jc.design(PROBLEM, letters(), **TRANSPORT, checkpoint=path,
                      callback=stop_in_the_refinement)  # fmt: skip
        assert path.is_file()
        seen = []
        resumed = jc.design(PROBLEM, letters(), **TRANSPORT, checkpoint=path, resume=True,
                            callback=seen.append)  # fmt: skip
    np.testing.assert_array_equal(resumed.heights, transport_design.heights)
    assert {info["level"] for info in seen} == {1}  # the transport was not run again
    assert [r["stage"] for r in resumed.levels] == ["checkpoint", "image refinement"]
    # a checkpoint of another design is refused, not resumed
    with pytest.raises(ValueError, match="`checkpoint`.*another design"):
        jc.design(PROBLEM, 2.0 + letters(), **TRANSPORT, checkpoint=path, resume=True)


def test_a_checkpoint_is_never_written_over_a_file_that_is_not_one(no_work, tmp_path):
    picture = tmp_path / "target.png"
    picture.write_bytes(b"\x89PNG\r\n\x1a\n not a checkpoint")
    with pytest.raises(ValueError, match="`checkpoint`.*not a jaxcaustics checkpoint"):
        jc.design(PROBLEM, blob(), checkpoint=picture)
    assert picture.read_bytes().startswith(b"\x89PNG")
    with pytest.raises(ValueError, match="`resume=True` needs a `checkpoint`"):
        jc.design(PROBLEM, blob(), resume=True)
