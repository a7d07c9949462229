"""Memory bounds of the photon renderers.

The JAX renderers trace and draw their photons in batches under `memory_limit`; the
bound is checked on XLA's compiled memory analysis (no run): a 16384^2-photon job is a
loop over batches, so its graph (and its compile time) does not grow with the photon
count. Small runs check that the batched images equal the one-batch images. The NumPy
reference tracers chunk their photons under the same kind of limit.
"""

import importlib
import math

import jax
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics import reference as ref
from jaxcaustics.methods.caustic_map.method import _dense_map, _view_and_buffers, caustics_mapping
from jaxcaustics.methods.spot_lights.method import max_rays_per_axis, ray_bytes, spot_lights
from jaxcaustics.methods.triangles.method import band_bytes, caustic_triangles, triangle_bytes

MiB, GiB = 1 << 20, 1 << 30
# what the compiled temporaries may hold besides the photon buffers: the receiver image
# (64 x 64 here), the lens heights or the 256^2 geometry buffers and their mip levels,
# the caustic map: a few MiB; allowed 32 MiB
ALLOWANCE = 32 * MiB


def lens_scene(shape=(64, 64), samples=16):
    """A plano-convex lens (focal length about 0.5 m) over a screen 0.2 m below."""
    x = (np.arange(samples) + 0.5) / samples * 0.1 - 0.05
    xx, yy = np.meshgrid(x, x)
    return jc.LensScene(
        jc.HeightField(-(xx**2 + 1.3 * yy**2) / 0.25, np.array([0.0, 0.1, 0.0, 0.1]), "clamp"),
        jc.DirectionalLight.from_angles(5.0),
        jc.PlaneReceiver(np.array([-0.01, 0.11, -0.01, 0.11]), shape),
        np.asarray(0.03),
        np.asarray(0.2),
    )


def ball_scene(shape=(32, 32), subdivisions=1):
    ball = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.5)
    ball.apply_translation([0.0, 0.0, 1.0])
    return jc.MeshScene(
        jc.Mesh(np.asarray(ball.vertices, float), ball.faces),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(np.array([-2.0, 2.0, -2.0, 2.0]), shape),
        ior=1.5,
        interfaces=4,
    )


def compiled_temporaries(render, scene):
    """XLA's temporaries of ``render(scene)`` under `jax.jit`, compiled, not run, and
    the result's `stats`."""
    stats = {}

    def image(s):
        result = render(s)
        stats.update(result.stats)
        return result.image

    analysis = jax.jit(image).lower(scene).compile().memory_analysis()
    return analysis.temp_size_in_bytes, stats


@pytest.mark.parametrize(
    "case",
    [
        ("lens", "exact", 256 * MiB),
        pytest.param(("lens", "gouraud", 256 * MiB), marks=pytest.mark.slow),
        pytest.param(("lens", "exact", 24 * GiB), marks=pytest.mark.slow),
        pytest.param(("mesh", "exact", 256 * MiB), marks=pytest.mark.slow),
        pytest.param(("mesh", "exact", 24 * GiB), marks=pytest.mark.slow),
    ],
)
def test_triangles_at_16384_squared_photons_stay_under_the_limit(case):
    kind, reconstruction, limit = case
    scene = lens_scene() if kind == "lens" else ball_scene()
    temp, stats = compiled_temporaries(
        lambda s: caustic_triangles(
            s, photons=16384, memory_limit=limit, window=8, reconstruction=reconstruction
        ),
        scene,
    )
    assert stats["bands"] > 1 and stats["peak_buffer_photons"] < 16384**2
    assert stats["peak_buffer_bytes"] <= limit
    # the memory model bounds what XLA allocates, and so does the limit
    assert temp <= stats["peak_buffer_bytes"] + ALLOWANCE, (temp, stats)
    assert temp <= limit + ALLOWANCE


@pytest.mark.parametrize(
    "intersection, limit",
    [
        ("image_space", 256 * MiB),
        pytest.param("exact", 256 * MiB, marks=pytest.mark.slow),
        pytest.param("image_space", 24 * GiB, marks=pytest.mark.slow),
        pytest.param("exact", 24 * GiB, marks=pytest.mark.slow),
    ],
)
def test_caustics_mapping_at_16384_squared_photons_stays_under_the_limit(intersection, limit):
    """The photon pass, given the geometry buffers: under `jax.jit` the buffers of a
    traced scene are rasterised with every face covering the whole view (faces x 256^2
    texels, some 480 MiB for this ball), a cost outside the photon memory limit."""
    scene = ball_scene()
    buffers = _view_and_buffers(scene, 256)
    window = 2 * math.ceil(3 * 0.5) + 1  # sigma 'auto': max(0.5, 64 / 16384)
    per_photon = jc.internal.photon_bytes(1, window, np.float64)
    batch = limit // per_photon  # as caustics_mapping sizes it
    assert 1 < 16384**2 // batch

    def photon_pass(s, b):
        return _dense_map(s, b, 16384, (64, 64), 0.5, window, batch, intersection, 4, None)

    temp = jax.jit(photon_pass).lower(scene, buffers).compile().memory_analysis()
    temp = temp.temp_size_in_bytes
    # besides the photons: the map, the receiver image and, for the exact intersection,
    # the mesh search of one ray batch (4096 rays x 80 faces): measured up to 66 MiB
    allowance = 96 * MiB
    assert temp <= batch * per_photon + allowance, (temp, batch)
    assert temp <= limit + allowance


@pytest.mark.parametrize(
    "reconstruction", ["exact", pytest.param("gouraud", marks=pytest.mark.slow)]
)
def test_banded_triangles_equal_the_one_band_image(reconstruction):
    scene = lens_scene(shape=(24, 24), samples=12)
    knobs = dict(photons=21, window=6, reconstruction=reconstruction, triangle_batch=256)
    whole = caustic_triangles(scene, **knobs)
    assert whole.stats["bands"] == 1 and whole.photons is not None
    # four photon rows of 21 columns per band (two halo rows more for Gouraud)
    halo = 2 if reconstruction == "gouraud" else 0
    row = band_bytes(21, 1, np.float64)
    banded = caustic_triangles(scene, memory_limit=2 * (4 + halo) * row, **knobs)
    stats = banded.stats
    assert stats["bands"] == math.ceil(20 / 3) and banded.photons is None
    assert stats["peak_buffer_photons"] == (4 + halo) * 21
    band_triangles = 2 * (3 + halo) * 20
    assert stats["batches"] == stats["bands"] * math.ceil(band_triangles / 256)
    scale = float(np.abs(np.asarray(whole.image)).max())
    assert scale > 1.0
    # the same triangles, added in another order: float64 rounding
    np.testing.assert_allclose(banded.image, whole.image, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(
        banded.missed_flux_fraction, whole.missed_flux_fraction, rtol=0, atol=1e-12
    )


@pytest.mark.slow
def test_banded_mesh_triangles_equal_the_one_band_image():
    scene = ball_scene(shape=(16, 16))
    knobs = dict(photons=17, window=8, triangle_batch=512, batch_size=64)
    whole = caustic_triangles(scene, **knobs)
    rays = band_bytes(0, 0, np.float64, faces=80, ray_batch=64)
    banded = caustic_triangles(
        scene, memory_limit=2 * (rays + 5 * band_bytes(17, 1, np.float64)), **knobs
    )
    assert banded.stats["bands"] == 4 and banded.stats["ray_batch"] == 64
    scale = float(np.abs(np.asarray(whole.image)).max())
    assert scale > 0.1
    np.testing.assert_allclose(banded.image, whole.image, rtol=0, atol=1e-12 * scale)


@pytest.mark.slow
def test_auto_window_is_the_same_in_bands():
    """window='auto' in bands comes from a first pass's histogram: the same window, so
    the same image."""
    scene = lens_scene(shape=(24, 24), samples=12)
    whole = caustic_triangles(scene, photons=21, triangle_batch=512)
    banded = caustic_triangles(
        scene, photons=21, triangle_batch=512, memory_limit=2 * 6 * band_bytes(21, 1)
    )
    assert banded.stats["bands"] > 1
    tiers = banded.stats["tiers"]
    assert tiers[0][0] == jc.internal.triangle_window(whole.photons, scene.receiver)
    largest = max(batch * triangle_bytes(window) for window, _, batch in tiers)
    assert banded.stats["peak_buffer_bytes"] - largest == band_bytes(6 * 21, 1)
    scale = float(np.abs(np.asarray(whole.image)).max())
    np.testing.assert_allclose(banded.image, whole.image, rtol=0, atol=1e-12 * scale)


# 16 s, slow for the default run's budget: the batched run under the memory limit stays
# in it; this equality of batched and single images runs with -m slow
@pytest.mark.slow
def test_caustics_mapping_batches_equal_one_batch():
    scene = ball_scene()
    knobs = dict(photons=48, map_resolution=32, gbuffer_resolution=48)
    whole = caustics_mapping(scene, **knobs)
    per_photon = jc.internal.photon_bytes(1, 5, np.float64)  # sigma 2/3 texel: 5 x 5 splats
    batched = caustics_mapping(scene, memory_limit=700 * per_photon, **knobs)
    assert whole.stats["batches"] == 1
    assert batched.stats["batches"] == math.ceil(48 * 48 / 700)
    assert batched.stats["peak_buffer_bytes"] == 700 * per_photon
    assert batched.stats["splatted"] == whole.stats["splatted"] > 0
    scale = float(np.abs(np.asarray(whole.image)).max())
    assert scale > 0.1
    np.testing.assert_allclose(batched.image, whole.image, rtol=0, atol=1e-12 * scale)


def test_spot_lights_refuse_more_rays_than_the_limit_holds():
    scene = jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (16, 16)),
        ior=1.5,
    )
    limit = 1 << 20
    fits = max_rays_per_axis(limit)
    assert fits**2 * ray_bytes() <= limit < (fits + 1) ** 2 * ray_bytes()
    with pytest.raises(ValueError, match=rf"`rays_per_axis` 256 .*`memory_limit`.* {fits}\b"):
        spot_lights(scene, rays_per_axis=256, memory_limit=limit)


@pytest.mark.parametrize(
    "render",
    [
        lambda s, **k: caustic_triangles(s, photons=9, **k),
        lambda s, **k: caustics_mapping(ball_scene(), photons=8, **k),
    ],
)
@pytest.mark.parametrize("limit", [0, 1.5, "1GiB"])
def test_bad_memory_limit_names_the_argument(render, limit):
    with pytest.raises(ValueError, match="memory_limit"):
        render(lens_scene(), memory_limit=limit)


# --- the NumPy reference tracers -------------------------------------------------------


def water_scene():
    x = (np.arange(8) + 0.5) / 8
    heights = 0.01 * np.sin(2 * np.pi * x)[None, :] * np.cos(2 * np.pi * x)[:, None]
    return jc.WaterScene(
        jc.HeightField(heights, np.array([0.0, 1.0, 0.0, 1.0]), "periodic"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver(np.array([0.0, 1.0, 0.0, 1.0]), (8, 8)),
        np.asarray(0.5),
    )


def ellipsoid_scene():
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (16, 16)),
        ior=1.5,
    )


# tracer, scene, knobs, the module's function that traces one chunk and which of its
# arguments is a 1-D array over the chunk's photons
REFERENCE_CASES = {
    "water": (ref.trace_water, water_scene, {"photons_per_axis": 3}, "_trace", 1),
    "lens": (ref.trace_lens, lens_scene, {"photons_per_axis": 40}, "_trace_lens", 1),
    "mesh": (ref.trace_mesh, ball_scene, {"photons_per_axis": 40}, "_trace_mesh", 3),
    "ellipsoid": (
        ref.trace_ellipsoid,
        ellipsoid_scene,
        {"photons_per_axis": 40},
        "_trace_channel",
        3,
    ),
}


@pytest.mark.parametrize("name", sorted(REFERENCE_CASES))
def test_reference_chunks_follow_the_limit(name, monkeypatch):
    tracer, make_scene, knobs, function, argument = REFERENCE_CASES[name]
    module = importlib.import_module(f"jaxcaustics.reference._{name}")
    scene = make_scene()
    whole = tracer(scene, **knobs)
    sizes = []
    original = getattr(module, function)

    def spy(*args, **kwargs):
        sizes.append(np.size(args[argument]))
        return original(*args, **kwargs)

    monkeypatch.setattr(module, function, spy)
    limit = 100 * ref.PHOTON_BYTES + 5
    chunked = tracer(scene, memory_limit=limit, **knobs)
    assert len(sizes) > 3 and max(sizes) <= 100, sizes
    if name != "water":  # water chunks whole emission rows (its layout picks the width)
        assert max(sizes) == 100
    np.testing.assert_allclose(chunked, whole, rtol=1e-12, atol=1e-12 * np.abs(whole).max())
    with pytest.raises(ValueError, match="memory_limit"):
        tracer(scene, memory_limit=0, **knobs)
