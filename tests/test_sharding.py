"""Sharding: batches of scenes (`render_batch`, `stack_scenes`), lens design variants
(`design_lens_variants`), argument checks.

The sharded runs need several devices: they run in a subprocess with four simulated CPU
devices (``XLA_FLAGS=--xla_force_host_platform_device_count=4``, which must be set before
JAX starts) and compare against single-device runs of the same programs.
"""

import textwrap

import jax
import numpy as np
import pytest
from _subprocess import run_python

import jaxcaustics as jc
from jaxcaustics.devices import (
    _addressable,
    gather_to_host,
    stack_scenes,
    unstack_scenes,
)
from jaxcaustics.inverse.variants import design_lens_variants
from jaxcaustics.methods.batch import render_batch

SCRIPT = textwrap.dedent(
    """
    import os, sys
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    import jax
    jax.config.update("jax_enable_x64", True)
    import equinox as eqx
    import jax.numpy as jnp
    import numpy as np
    import jaxcaustics as jc
    from jaxcaustics.methods.batch import render_batch
    from jaxcaustics.devices import MESH_AXIS, gather_to_host, stack_scenes

    assert len(jax.devices()) == 4, jax.devices()
    rng = np.random.default_rng(0)

    def water(k):
        h = 0.004 * rng.normal(size=(12, 12))
        return jc.WaterScene(
            jc.HeightField(h, [-1.0, 1.0, -1.0, 1.0]),
            jc.DirectionalLight([0.1, 0.0, -1.0]),
            jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], (12, 12)),
            0.8 + 0.1 * k,
        )

    # 5 water surfaces (padded to 8 on 4 devices), two-pass, both per-device modes
    waters = [water(k) for k in range(5)]
    batch = stack_scenes(waters)
    knobs = dict(samples_x=7, channels_y=6)
    single = np.stack([np.asarray(jc.render(s, "twopass", **knobs)) for s in waters])
    assert single.std() > 0.05  # real caustics, not flat light
    for mode in ("map", "vmap"):
        images = render_batch(batch, per_device=mode, **knobs)
        assert images.shape == (5, 12, 12)
        np.testing.assert_allclose(gather_to_host(images), single, rtol=1e-12, atol=1e-12)

    # 4 lenses over a spread of screen_distances, caustic triangles ("auto" window: the largest)
    x = np.linspace(-1.0, 1.0, 10)
    bowl = -0.002 * (x[None] ** 2 + x[:, None] ** 2)

    def lens(k):
        return jc.LensScene(
            jc.HeightField(bowl + 2e-4 * rng.normal(size=(10, 10)), [-0.05, 0.05, -0.05, 0.05],
                           "clamp"),
            jc.DirectionalLight([0.0, 0.0, -1.0]),
            jc.PlaneReceiver([-0.08, 0.08, -0.08, 0.08], (16, 16)),
            0.01,
            0.25 + 0.05 * k,
        )

    lenses = [lens(k) for k in range(4)]
    images = render_batch(lenses, photons=21)  # a list is stacked here
    assert images.sharding.spec == jax.sharding.PartitionSpec(MESH_AXIS)  # split 4 ways
    assert len(images.sharding.device_set) == 4
    window = jc.CausticTriangles(photons=21).sized_for(lenses).window
    single = np.stack(
        [np.asarray(jc.render(s, "triangles", photons=21, window=window)) for s in lenses]
    )
    assert single.max() > 2.0  # focused light
    np.testing.assert_allclose(gather_to_host(images), single, rtol=1e-10, atol=1e-10)

    if "slow" in sys.argv:
        # gradients through a sharded batch (reverse mode through the vectorised hit fails
        # inside JAX: per_device="map")
        heights = jnp.asarray(batch.surface.heights)

        def loss(h, devices):
            scenes = eqx.tree_at(lambda s: s.surface.heights, batch, h)
            images = render_batch(scenes, devices=devices, per_device="map", **knobs)
            return jnp.sum((images - 1.0) ** 2)

        g4 = jax.grad(loss)(heights, None)
        g1 = jax.grad(loss)(heights, 1)
        assert float(jnp.abs(g1).max()) > 1.0
        np.testing.assert_allclose(g4, g1, rtol=1e-10, atol=1e-10)

        # design variants over three screen_distances, against design_lens one by one
        from jaxcaustics.inverse.design import design_lens
        from jaxcaustics.inverse.variants import design_lens_variants

        y, x = np.mgrid[-1:1:12j, -1:1:12j]
        target = np.exp(-((x - 0.2) ** 2 + y**2) / 0.2) + 0.1
        # variants run the Poisson start (they refuse the transport start, design_lens's
        # default): both must be told it, or they solve different problems
        spec = dict(width=0.05, height=0.05, thickness=0.01, levels=(8,), max_steps=4,
                    predict_photons=25, start="poisson")
        screen_distances = [0.2, 0.3, 0.45]
        variants = design_lens_variants(target, screen_distances=screen_distances, **spec)
        for screen_distance, got in zip(screen_distances, variants):
            want = design_lens(target, screen_distance=screen_distance, **spec)
            # the same steps, compiled as one loop instead of step by step
            np.testing.assert_allclose(got.heights, want.heights, rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(got.loss_history, want.loss_history, rtol=1e-8)
            np.testing.assert_allclose(got.predicted, want.predicted, rtol=1e-8, atol=1e-8)
            assert got.levels[0]["steps"] == want.levels[0]["steps"]
            assert bool(got.result == want.result)
            assert float(got.scene.screen_distance) == screen_distance
        # a longer screen_distance needs a shallower relief for the same caustic
        reliefs = [d.relief for d in variants]
        assert reliefs[0] > reliefs[1] > reliefs[2] > 0
    print("OK")
    """
)


def run_script(tmp_path, *args):
    assert "OK" in run_python(tmp_path, SCRIPT, *args, timeout=1200)


@pytest.mark.slow  # about 11 s; the default run checks sharding in test_sharding_photons
def test_render_batch_sharded_agrees_with_single_device(tmp_path):
    run_script(tmp_path)


@pytest.mark.slow
def test_gradients_and_design_variants_sharded_agree(tmp_path):
    # also: gradients through render_batch, design_lens_variants against design_lens
    run_script(tmp_path, "slow")


# --------------------------------------------------------------------------- in process


def water(heights, ior=1.333, shape=(8, 8)):
    return jc.WaterScene(
        jc.HeightField(heights, [-1.0, 1.0, -1.0, 1.0]),
        jc.DirectionalLight([0.0, 0.0, -1.0]),
        jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], shape),
        1.0,
        ior=ior,
    )


def test_stack_and_unstack_scenes():
    scenes = [water(np.full((8, 8), 0.01 * k)) for k in range(3)]
    batch = stack_scenes(scenes)
    assert batch.surface.heights.shape == (3, 8, 8)
    assert batch.rest_depth.shape == (3,)
    assert batch.receiver.shape == (8, 8) and batch.ior == 1.333
    for k, scene in enumerate(unstack_scenes(batch)):
        np.testing.assert_array_equal(scene.surface.heights, scenes[k].surface.heights)


@pytest.mark.parametrize(
    ("other", "match"),
    [
        (water(np.zeros((8, 8)), ior=1.5), r"scenes\[2\].*ior"),
        (water(np.zeros((6, 8))), r"scenes\[2\].*heights.*shape"),
        (water(np.zeros((8, 8)), shape=(4, 4)), r"scenes\[2\].*receiver\.shape"),
        (
            jc.LensScene(
                jc.HeightField(np.zeros((8, 8)), [-1.0, 1.0, -1.0, 1.0], "clamp"),
                jc.DirectionalLight([0.0, 0.0, -1.0]),
                jc.PlaneReceiver([-1.0, 1.0, -1.0, 1.0], (8, 8)),
            ),
            r"scenes\[2\].*LensScene",
        ),
    ],
)
def test_stack_scenes_names_the_mismatch(other, match):
    with pytest.raises(ValueError, match=match):
        stack_scenes([water(np.zeros((8, 8))), water(np.ones((8, 8)) * 0.01), other])


def test_stack_scenes_rejects_empty():
    with pytest.raises(ValueError, match="scenes"):
        stack_scenes([])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(devices=0), "devices"),
        (dict(devices=-1), "devices"),
        (dict(devices=[]), "devices"),
        (dict(method="nope"), "method"),
        (dict(per_device="pmap"), "per_device"),
    ],
)
def test_render_batch_rejects_bad_arguments(kwargs, match):
    batch = stack_scenes([water(np.zeros((8, 8)))] * 2)
    with pytest.raises(ValueError, match=match):
        render_batch(batch, **kwargs)


def test_render_batch_needs_a_batch():
    with pytest.raises(ValueError, match="batch"):
        render_batch(water(np.zeros((8, 8))))  # not stacked: scalar leaves


def test_one_process_drives_every_device():
    # the single-process path of the multi-host code: every device is this process's,
    # and gathering a device array gives NumPy
    assert jax.process_count() == 1
    assert [d for _, d in _addressable(jax.devices())] == jax.devices()
    out = gather_to_host({"a": jax.numpy.arange(3.0), "b": "label"})
    assert isinstance(out["a"], np.ndarray) and out["b"] == "label"


TARGET = np.outer(np.hanning(8) + 0.2, np.hanning(8) + 0.2)
SPEC = dict(width=0.05, height=0.05, thickness=0.01, levels=(8,), max_steps=2)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(screen_distances=[]), "screen_distances"),
        (dict(screen_distances=[0.2, -1.0]), r"screen_distances\[1\].*screen_distance"),
        (dict(screen_distances=[0.2], screen_distance=0.3), "screen_distance"),
        (dict(screen_distances=[0.2], callback=print), "callback"),
        (dict(screen_distances=[0.2], devices=0), "devices"),
        (dict(screen_distances=[0.2], spline=3), "spline"),
    ],
)
def test_design_variants_reject_bad_arguments(kwargs, match, monkeypatch):
    from jaxcaustics.inverse import variants

    def forbidden(*args, **kwargs):
        raise AssertionError("the optimisation started before the arguments were checked")

    monkeypatch.setattr(variants, "iterate_traced", forbidden)
    with pytest.raises(ValueError, match=match):
        design_lens_variants(TARGET, **{**SPEC, **kwargs})
