"""Rounds with checkpoints: resume ends where an uninterrupted run ends."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcaustics.inverse.checkpoint import load_checkpoint, run_rounds, save_checkpoint


def _descent_round(state):
    """A few steps of gradient descent on a small least-squares problem."""
    x = state["x"]
    for _ in range(5):
        x = x - 0.1 * jax.grad(lambda v: jnp.sum((v - jnp.arange(v.size)) ** 2))(x)
    return {"x": x, "steps": state["steps"] + 5, "loss": jnp.sum((x - jnp.arange(x.size)) ** 2)}


def _initial():
    return {"x": jnp.zeros(4), "steps": 0, "loss": jnp.asarray(0.0)}


def test_save_and_load_round_trip(tmp_path):
    state = {"x": jnp.arange(3.0), "steps": 7, "nested": (jnp.ones((2, 2)), 1.5)}
    path = save_checkpoint(tmp_path / "c.npz", state, 3)
    loaded, rounds = load_checkpoint(path, state)
    assert rounds == 3 and loaded["steps"] == 7 and loaded["nested"][1] == 1.5
    np.testing.assert_array_equal(loaded["x"], state["x"])
    assert loaded["x"].dtype == state["x"].dtype


def test_interrupted_run_resumes_to_the_same_result(tmp_path):
    rounds = [_descent_round] * 6
    straight, done, interrupted = run_rounds(rounds, _initial(), progress=False)
    assert done == 6 and not interrupted

    calls = {"n": 0}

    def ctrl_c_in_round_4(state):
        calls["n"] += 1
        if calls["n"] == 1:
            raise KeyboardInterrupt
        return _descent_round(state)

    path = tmp_path / "run.npz"
    broken = rounds[:3] + [ctrl_c_in_round_4] + rounds[4:]
    partial, done, interrupted = run_rounds(broken, _initial(), checkpoint=path)
    assert interrupted and done == 3 and path.is_file()
    resumed, done, interrupted = run_rounds(broken, _initial(), checkpoint=path, resume=True)
    assert done == 6 and not interrupted
    np.testing.assert_array_equal(resumed["x"], straight["x"])
    assert resumed["steps"] == straight["steps"] == 30


def test_bad_checkpoints_name_the_path(tmp_path):
    with pytest.raises(ValueError, match="path"):
        load_checkpoint(tmp_path / "missing.npz", _initial())
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="path"):
        load_checkpoint(garbage, _initial())
    path = save_checkpoint(tmp_path / "other.npz", {"y": jnp.zeros(2)}, 1)
    with pytest.raises(ValueError, match="structure"):
        load_checkpoint(path, _initial())
    path = save_checkpoint(
        tmp_path / "shape.npz", {"x": jnp.zeros(5), "steps": 0, "loss": jnp.asarray(0.0)}, 1
    )
    with pytest.raises(ValueError, match="shape"):
        load_checkpoint(path, _initial())


def test_live_rounds_get_a_reporter():
    seen = []

    def round_(state, report):
        report(f"at {state}")  # no bar (progress=False): a no-op, but callable
        seen.append(state)
        return state + 1

    state, done, interrupted = run_rounds([round_] * 3, 0, progress=False, live=True)
    assert (state, done, interrupted) == (3, 3, False)
    assert seen == [0, 1, 2]


def test_a_fresh_run_over_a_checkpoint_says_it_starts_afresh(tmp_path):
    from jaxcaustics.inverse.checkpoint import check_checkpoint, fingerprint, refuse_another_run

    path = save_checkpoint(tmp_path / "run.ckpt", _initial(), 2)
    with pytest.warns(UserWarning, match=r"run\.ckpt.*starts afresh.*resume"):
        check_checkpoint(path, resume=False)
    check_checkpoint(path, resume=True)  # resuming: nothing to say
    # a digest a part: the part that differs is named
    parts = {"target": np.arange(4.0), "options": {"depth": 0.5, "name": "a"}}
    first = fingerprint(parts)
    assert first.shape == (2, 8)
    again = fingerprint({"target": np.arange(4.0), "options": {"depth": 0.6, "name": "a"}})
    assert np.array_equal(first[0], again[0]) and not np.array_equal(first[1], again[1])
    save_checkpoint(path, {**_initial(), "fingerprint": first}, 1)
    with pytest.raises(ValueError, match="another test: its options differ"):
        refuse_another_run(path, True, {**_initial(), "fingerprint": again}, list(parts), "test")
    refuse_another_run(path, True, {**_initial(), "fingerprint": first}, list(parts), "test")
