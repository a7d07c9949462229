"""Bad arguments of the renderers and their knobs (issue 20): refused at the entry, with
a `ValueError` naming the argument, before anything is compiled.

`render`, `two_pass` / `auto_window`, `caustic_triangles` and its helpers
(`trace_photons`, `triangles_image`, `triangle_window`, `splat_photons`,
`CubeMapOptions`), `caustics_mapping`, `adaptive_caustic_map`, `spot_lights`,
`render_batch`, `photon_bytes` and the accuracy-table functions. Memory and work are
estimated before compiling (`memory_limit`, at most 2^31 photons in 2^20 batches): an
absurd request is refused at once with its estimate and the knob to change. The cases
compile nothing (checked with JAX's compile events); the property test renders a few
tiny valid settings.
"""

import math

import jax
import numpy as np
import pytest
import trimesh
from hypothesis import event, given, settings
from hypothesis import strategies as st

import jaxcaustics as jc
from jaxcaustics.scene.checks import check_scene_values
from jaxcaustics.trace.photons import Photons


def _water(n=4):
    x = (np.arange(n) + 0.5) / n
    heights = 0.01 * np.sin(2 * np.pi * x)[None, :] * np.cos(2 * np.pi * x)[:, None]
    return jc.WaterScene(
        jc.HeightField(heights, np.array([0.0, 1.0, 0.0, 1.0]), "periodic"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver(np.array([0.0, 1.0, 0.0, 1.0]), (n, n)),
        np.asarray(0.5),
    )


def _lens(n=8):
    x = (np.arange(8) + 0.5) / 8 * 0.1 - 0.05
    xx, yy = np.meshgrid(x, x)
    return jc.LensScene(
        jc.HeightField(-(xx**2 + 1.3 * yy**2) / 0.25, np.array([0.0, 0.1, 0.0, 0.1]), "clamp"),
        jc.DirectionalLight.from_angles(5.0),
        jc.PlaneReceiver(np.array([-0.01, 0.11, -0.01, 0.11]), (n, n)),
        np.asarray(0.03),
        np.asarray(0.2),
    )


def _ball():
    ball = trimesh.creation.icosphere(subdivisions=0, radius=0.5)
    ball.apply_translation([0.0, 0.0, 1.0])
    return jc.MeshScene(
        jc.Mesh(np.asarray(ball.vertices, float), ball.faces),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(np.array([-2.0, 2.0, -2.0, 2.0]), (8, 8)),
        ior=1.5,
    )


def _ellipsoid():
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (8, 8)),
        ior=1.5,
    )


WATER, LENS, BALL, ELLIPSOID = _water(), _lens(), _ball(), _ellipsoid()
for _scene in (WATER, LENS, BALL, ELLIPSOID):
    check_scene_values(_scene)  # its own first-call NumPy/JAX work, outside the count
# a photon hit location image built from NumPy arrays (tracing one would compile)
PHOTONS = Photons(
    np.zeros((1, 3, 3, 3)),
    np.zeros((1, 3, 3, 3)),
    np.ones((1, 3, 3)),
    np.ones((1, 3, 3), bool),
    1.0,
)
IMAGE = np.ones((4, 4))

_COMPILES = [0]


def _count(event, duration, **kwargs):
    if "backend_compile" in event:
        _COMPILES[0] += 1


jax.monitoring.register_event_duration_secs_listener(_count)


def _refused_uncompiled(call, name):
    before = _COMPILES[0]
    with pytest.raises(ValueError, match=f"`{name}`"):
        call()
    assert _COMPILES[0] == before, "compiled before refusing"


# (call, the argument named, case label)
CASES = [
    # render
    (lambda: jc.render(WATER, ["twopass"]), "method"),
    (lambda: jc.render(WATER, 3), "method"),
    (lambda: jc.render(WATER, return_stats="yes"), "return_stats"),
    (lambda: jc.render(WATER, return_stats=None), "return_stats"),
    (lambda: jc.render(WATER, tolerance="0.1"), "tolerance"),
    (lambda: jc.render(WATER, tolerance=True), "tolerance"),
    (lambda: jc.render(WATER, tolerance=0.5, margin="2"), "margin"),
    (lambda: jc.render(WATER, tolerance=0.5, margin=True), "margin"),
    (lambda: jc.render(WATER, margin=float("nan")), "margin"),
    (lambda: jc.render(WATER, margin=3.0), "margin"),  # without `tolerance`: unused
    (lambda: jc.render(WATER, photons=5), "photons"),  # not a two-pass knob
    (lambda: jc.render(LENS, samples_x=3), "samples_x"),  # not a triangles knob
    (lambda: jc.render(ELLIPSOID, window=3), "window"),  # nor a spot-light (fit) knob
    # two-pass and auto_window
    (lambda: jc.render(WATER, samples_x=True), "samples_x"),
    (lambda: jc.render(WATER, samples_x="auto", channels_y=3), "channels_y"),
    (lambda: jc.render(WATER, channels_y=10**9), "channels_y"),
    (lambda: jc.render(WATER, hit_iterations=True), "hit_iterations"),
    (lambda: jc.render(WATER, hit_iterations=10**7), "hit_iterations"),
    (lambda: jc.render(WATER, supersample=True), "supersample"),
    (lambda: jc.render(WATER, supersample=10**4), "memory_limit"),
    (lambda: jc.render(WATER, memory_limit=5), "memory_limit"),
    (lambda: jc.render(WATER, memory_limit=2.0**30), "memory_limit"),
    (lambda: jc.internal.auto_window(WATER, "3"), "hit_iterations"),
    (lambda: jc.internal.auto_window(WATER, 3, 0), "supersample"),
    (lambda: jc.internal.auto_window(LENS), "scene"),
    (lambda: jc.internal.auto_window(WATER, 3, 10**4), "memory_limit"),
    # caustic triangles
    (lambda: jc.render(LENS, photons=(2.5, 3)), "photons"),
    (lambda: jc.render(LENS, photons=(np.float64(3.0), 3)), "photons"),
    (lambda: jc.render(LENS, photons=100000), "photons"),  # 10^10 photons: over 2^31
    (lambda: jc.render(LENS, photons=(2, 10**9)), "photons"),  # one band over the limit
    (lambda: jc.render(LENS, photons=(2**22, 2), memory_limit=8192), "memory_limit"),  # batches
    (lambda: jc.render(LENS, photons=5, window=10**5), "window"),
    (lambda: jc.render(LENS, photons=5, hit_iterations=10**9), "hit_iterations"),
    (lambda: jc.render(LENS, photons=5, supersample=3), "supersample"),  # "exact": unused
    (lambda: jc.render(LENS, photons=5, batch_size=64), "batch_size"),  # mesh only
    (lambda: jc.render(LENS, photons=5, cube_map=jc.internal.CubeMapOptions()), "cube_map"),
    (lambda: jc.render(BALL, photons=5, hit_iterations=4), "hit_iterations"),  # lens only
    (lambda: jc.render(BALL, photons=5, batch_size=10**12), "batch_size"),
    (
        lambda: jc.render(BALL, photons=5, visibility="distance_map", cube_map="x"),
        "cube_map",
    ),
    (
        lambda: jc.render(BALL, photons=5, visibility="distance_map", reconstruction="gouraud"),
        "reconstruction",
    ),
    (
        lambda: jc.render(LENS, photons=5, reconstruction="gouraud", supersample=10**4),
        "supersample",
    ),
    (lambda: jc.render(LENS, photons=5, memory_limit=1), "memory_limit"),
    (lambda: jc.internal.CubeMapOptions(resolution="64"), "resolution"),
    (lambda: jc.internal.CubeMapOptions(shadow_test="yes"), "shadow_test"),
    (lambda: jc.internal.trace_photons(LENS, (2.5, 3)), "grid"),
    (lambda: jc.internal.trace_photons(LENS, 10**5), "grid"),
    (lambda: jc.internal.trace_photons(LENS, 5, True), "hit_iterations"),
    (lambda: jc.internal.trace_photons(BALL, 5, 4), "hit_iterations"),
    (lambda: jc.internal.trace_photons(WATER, 5), "scene"),
    (lambda: jc.internal.triangles_image(PHOTONS, LENS.receiver, window=10**5), "window"),
    (lambda: jc.internal.triangles_image(None, LENS.receiver), "photons"),
    (lambda: jc.internal.triangle_window(PHOTONS, LENS.receiver, "0.5"), "flux_fraction"),
    (lambda: jc.internal.triangle_window(PHOTONS, None), "receiver"),
    (lambda: jc.internal.splat_photons(PHOTONS, LENS.receiver, 1e-300), "sigma"),
    (lambda: jc.internal.splat_photons(PHOTONS, LENS.receiver, True), "sigma"),
    (lambda: jc.internal.splat_photons(PHOTONS, LENS.receiver, 1e6), "sigma"),
    (lambda: jc.internal.splat_photons(PHOTONS, LENS.receiver, 1.0, 0), "window"),
    # caustic maps
    (lambda: jc.internal.caustics_mapping(BALL, photons=16, sigma=True), "sigma"),
    (lambda: jc.internal.caustics_mapping(BALL, photons=16, sigma=1e-300), "sigma"),
    (lambda: jc.internal.caustics_mapping(BALL, photons=16, sigma=1e6), "sigma"),
    (lambda: jc.internal.caustics_mapping(BALL, photons=16, iterations=10**5), "iterations"),
    (
        lambda: jc.internal.caustics_mapping(BALL, photons=16, intersection=["exact"]),
        "intersection",
    ),
    (
        lambda: jc.internal.caustics_mapping(BALL, photons=16, map_resolution=10**6),
        "map_resolution",
    ),
    (
        lambda: jc.internal.caustics_mapping(BALL, photons=16, gbuffer_resolution=10**6),
        "gbuffer_resolution",
    ),
    (lambda: jc.internal.caustics_mapping(BALL, photons=16, memory_limit=1), "memory_limit"),
    (lambda: jc.internal.caustics_mapping(BALL, photons=100000), "photons"),
    (
        lambda: jc.internal.caustics_mapping(
            BALL, photons=46000, gbuffer_resolution=16, map_resolution=16, memory_limit=200000
        ),
        "memory_limit",
    ),
    (
        lambda: jc.internal.adaptive_caustic_map(BALL, photons=16, base=8, capacity=10**12),
        "capacity",
    ),
    (lambda: jc.internal.adaptive_caustic_map(BALL, photons=8 * 2**20, base=8), "photons"),
    (
        lambda: jc.internal.adaptive_caustic_map(BALL, photons=16, base=8, memory_limit=1),
        "memory_limit",
    ),
    (lambda: jc.internal.adaptive_caustic_map(BALL, photons=16, base=8, metric=None), "metric"),
    (lambda: jc.internal.photon_bytes("1", 5, np.float64), "channels"),
    (lambda: jc.internal.photon_bytes(1, 2.5, np.float64), "window"),
    (lambda: jc.internal.photon_bytes(1, 5, "float99"), "dtype"),
    # spot lights
    (lambda: jc.internal.spot_lights(ELLIPSOID, max_gain="big"), "max_gain"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, max_gain=True), "max_gain"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, max_gain=math.inf), "max_gain"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, intensity_correction="no"), "intensity_correction"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, lights=3), "lights"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, rays_per_axis=2.0), "rays_per_axis"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, samples=10**4), "memory_limit"),
    (lambda: jc.internal.spot_lights(ELLIPSOID, bogus=3), "bogus"),
    # render_batch and the accuracy tables
    (lambda: jc.render_batch([WATER, WATER], ["twopass"]), "method"),
    (lambda: jc.render_batch([WATER, WATER], "twopass", photons=3), "photons"),
    (lambda: jc.internal.choose_method(WATER, 0.5, method=3), "method"),
    (lambda: jc.internal.choose_method(WATER, 0.5, table="x"), "table"),
    (lambda: jc.internal.choose_method(WATER, "0.5"), "tolerance"),
    (lambda: jc.internal.method_support("nope", WATER), "method"),
    (lambda: jc.internal.method_support("twopass", None), "scene"),
    (lambda: jc.image_error(IMAGE * np.nan, IMAGE), "image"),
    (lambda: jc.image_error(IMAGE + 1j, IMAGE), "image"),
    (lambda: jc.image_error(IMAGE, IMAGE, True), "blur"),
    (lambda: jc.reference_image(WATER, bogus=3), "bogus"),
]


@pytest.mark.parametrize("call, name", CASES, ids=[f"{k}-{n}" for k, (_, n) in enumerate(CASES)])
def test_bad_argument_is_refused_by_name_before_compiling(call, name):
    _refused_uncompiled(call, name)


def test_spot_light_ray_limit_names_the_largest_grid_that_fits():
    fits = 45  # isqrt(2^20 // 512)
    with pytest.raises(ValueError, match=rf"`rays_per_axis` 256 .*`memory_limit`.* {fits}\b"):
        jc.internal.spot_lights(ELLIPSOID, rays_per_axis=256, memory_limit=1 << 20)


# --- one property over `render`'s knobs ------------------------------------------------

# bad values of every kind; the few that happen to be valid (0 Newton steps, M = 0, a
# huge memory limit, a huge triangle batch clamped to the grid's) compile at most three
# new tiny programs
BAD = st.one_of(
    st.text(max_size=3),
    st.none(),
    st.booleans(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**12), 0),
    st.integers(10**6, 10**15),
    st.lists(st.integers(-3, 1), max_size=3),
    st.tuples(st.floats(allow_nan=True), st.integers(-3, 10**9)),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=1),
)
# `tolerance`: a positive one is valid and would render the table's (larger) setting
BAD_TOLERANCE = st.one_of(
    st.text(max_size=3),
    st.booleans(),
    st.floats(max_value=0.0),
    st.sampled_from([math.nan, math.inf]),
    st.integers(-(10**6), 0),
)
RENDERS = {
    "twopass": (
        WATER,
        {},
        ("samples_x", "channels_y", "hit_iterations", "supersample", "memory_limit"),
    ),
    "triangles": (
        LENS,
        {"photons": 5},
        (
            "photons",
            "reconstruction",
            "window",
            "supersample",
            "hit_iterations",
            "memory_limit",
            "batch_size",
            "triangle_batch",
            "visibility",
            "cube_map",
        ),
    ),
}
CALLS = (
    [(method, knob) for method, (_, _, knobs) in RENDERS.items() for knob in knobs + ("margin",)]
    + [(method, "tolerance") for method in RENDERS]
    + [(method, "return_stats") for method in RENDERS]
)


@settings(max_examples=150, deadline=None)
@given(call=st.sampled_from(CALLS), data=st.data())
def test_render_refuses_a_bad_knob_by_name_or_renders_a_finite_image(call, data):
    method, knob = call
    scene, base, _ = RENDERS[method]
    value = data.draw(BAD_TOLERANCE if knob == "tolerance" else BAD, label=knob)
    kwargs = dict(base, **{knob: value}) if knob != "tolerance" else {knob: value}
    try:
        out = jc.render(scene, method, **kwargs)
    except (ValueError, TypeError) as err:
        assert f"`{knob}`" in str(err), (knob, value, str(err))
        event("refused")
        return
    event(f"rendered: {method}")
    image = out[0] if isinstance(out, tuple) else out
    assert np.all(np.isfinite(np.asarray(image))), (knob, value)
