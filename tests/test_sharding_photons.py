"""Photon batches split across devices: sharded and single-device renders agree.

The check runs in a subprocess with four simulated CPU devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=4``: the flag must be set before JAX
starts, and the test session's JAX has started already).
"""

import json

import pytest
from _subprocess import run_python

SCRIPT = r"""
import json
import os
import sys

os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
import trimesh

import jaxcaustics as jc
from jaxcaustics.methods.caustic_map.method import caustics_mapping
from jaxcaustics.methods.triangles.method import caustic_triangles

assert len(jax.devices()) == 4
x = (np.arange(12) + 0.5) / 12 * 0.1 - 0.05
xx, yy = np.meshgrid(x, x)
lens = jc.LensScene(
    jc.HeightField(-(xx**2 + 1.3 * yy**2) / 0.25, np.array([0.0, 0.1, 0.0, 0.1]), "clamp"),
    jc.DirectionalLight.from_angles(5.0),
    jc.PlaneReceiver(np.array([-0.01, 0.11, -0.01, 0.11]), (24, 24)),
    np.asarray(0.03),
    np.asarray(0.2),
)
ball = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
ball.apply_translation([0.0, 0.0, 1.0])
mesh_scene = jc.MeshScene(
    jc.Mesh(np.asarray(ball.vertices, float), ball.faces),
    jc.DirectionalLight.from_angles(10.0),
    jc.PlaneReceiver(np.array([-2.0, 2.0, -2.0, 2.0]), (16, 16)),
    ior=1.5,
    interfaces=4,
)
out = {}
checks = sys.argv[1:]
for reconstruction in [c.split("_")[1] for c in checks if c.startswith("triangles_")]:
    # a small memory limit: several bands per device and several rasteriser batches
    # per band (scans inside the sharded loop)
    # (Gouraud's smallest band, 4 rows with its halo rows, is estimated at 43 KB: more
    # than half of 2^16, which the memory check refuses)
    limit = 2**16 if reconstruction == "exact" else 2**17
    small = dict(photons=21, reconstruction=reconstruction, window=6, memory_limit=limit)
    one = caustic_triangles(lens, **small)
    four = caustic_triangles(lens, **small, devices=4)
    out[f"triangles_{reconstruction}"] = [
        float(np.abs(np.asarray(one.image) - np.asarray(four.image)).max()),
        float(np.abs(np.asarray(one.image)).max()),
        four.stats["bands"],
        four.stats["devices"],
    ]
if "caustics_mapping" in checks:
    one = caustics_mapping(mesh_scene, photons=24, map_resolution=32)
    four = caustics_mapping(mesh_scene, photons=24, map_resolution=32, devices=4)
    out["caustics_mapping"] = [
        float(np.abs(np.asarray(one.image) - np.asarray(four.image)).max()),
        float(np.abs(np.asarray(one.image)).max()),
        four.stats["batches"],
        four.stats["devices"],
    ]

weights = jnp.asarray(np.random.default_rng(0).random((24, 24)))


def loss(heights, devices):
    scene = jc.LensScene(
        jc.HeightField(heights, lens.surface.extent, "clamp"),
        lens.light,
        lens.receiver,
        lens.thickness,
        lens.screen_distance,
    )
    image = caustic_triangles(scene, photons=21, window=6, devices=devices).image
    return jnp.sum(weights * image)


if "gradient" in checks:
    g1 = jax.grad(loss)(lens.surface.heights, None)
    g4 = jax.grad(loss)(lens.surface.heights, 4)
    out["gradient"] = [float(jnp.abs(g1 - g4).max()), float(jnp.abs(g1).max())]
print(json.dumps(out))
"""


def run_script(tmp_path, *checks):
    stdout = run_python(tmp_path, SCRIPT, *checks)
    return json.loads(stdout.strip().splitlines()[-1])


def check_triangles(entry):
    # the same photons and triangles, summed in another order: float64 rounding
    diff, scale, bands, devices = entry
    assert devices == 4 and bands >= 4, entry  # at least one band per device
    assert scale > 1.0 and diff <= 1e-12 * scale, entry


# on request (slow), for the default run's budget (a subprocess with four host devices);
# the spot-light table's sharded map runs by default
@pytest.mark.slow
def test_sharded_photon_batches_agree_with_one_device(tmp_path):
    """Caustic triangles (lens scene, exact) and caustics mapping (mesh scene) on four
    simulated devices give the single-device images."""
    out = run_script(tmp_path, "triangles_exact", "caustics_mapping")
    check_triangles(out["triangles_exact"])
    diff, scale, batches, devices = out["caustics_mapping"]
    assert devices == 4 and batches >= 4, out["caustics_mapping"]
    assert scale > 0.1 and diff <= 1e-12 * scale, out["caustics_mapping"]


@pytest.mark.slow
def test_sharded_gradients_and_gouraud_bands_agree_with_one_device(tmp_path):
    """The gradient of a weighted sum of the triangles' image with respect to the lens
    heights (through `shard_map` and `psum`), and Gouraud bands (halo rows and a census
    pass), sharded and not. (About 30 s of CPU: not in the default run.)"""
    out = run_script(tmp_path, "triangles_gouraud", "gradient")
    check_triangles(out["triangles_gouraud"])
    diff, scale = out["gradient"]
    # float64 rounding of sums in another order (measured: 2e-16 relative)
    assert scale > 0.0 and diff <= 1e-10 * scale, out["gradient"]
