"""Bad arguments to the caustic spot light functions and the image-space / geometry tools
are refused with a `ValueError` naming the argument, before anything is compiled (issue
20). The work that would follow is replaced by a function that fails the test, so a
check that comes too late shows as that failure. The last tests check that the kernels
(`refract`, `reflect`, `fresnel_transmittance`, `height_and_gradient`) still run under
`jax.jit`, where their values are not checked."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxcaustics as jc
from jaxcaustics.methods.caustic_map import gbuffer as _gbuffer
from jaxcaustics.methods.caustic_map.light_view import LightView
from jaxcaustics.methods.spot_lights import bundles as _spot_light_bundles
from jaxcaustics.methods.spot_lights import fit as _spot_light_fit
from jaxcaustics.methods.spot_lights import light_table as _spot_light_light_table
from jaxcaustics.methods.spot_lights import lights as _spot_lights
from jaxcaustics.methods.spot_lights import table as _spot_light_table
from jaxcaustics.scene.ellipsoid import Ellipsoid, EllipsoidScene

NAN = float("nan")
INF = float("inf")
UP = np.array([[0.0, 0.0, 1.0]])


def forbidden(*args, **kwargs):
    raise AssertionError("the work started before the arguments were checked")


@pytest.fixture(scope="module")
def light():
    return jc.internal.SpotLights(
        [[0.0, 0.0, 2.0]], [[0.0, 0.0, -1.0]], [[1.0, 0.0, 0.0]], [1.0], [0.5], [0.3],
        np.ones((1, 4, 4)),
    )  # fmt: skip


@pytest.fixture(scope="module")
def ball():
    return EllipsoidScene(
        Ellipsoid.sphere([0.0, 0.0, 2.0], 1.0),
        jc.DirectionalLight([0.0, 0.0, -1.0]),
        jc.PlaneReceiver((-3.0, 3.0, -3.0, 3.0), (4, 4)),
    )


@pytest.fixture(scope="module")
def glass():
    ico = trimesh.creation.icosphere(0, 0.3)
    return jc.MeshScene(
        jc.Mesh(ico.vertices + [0.0, 0.0, 1.0], ico.faces),
        jc.DirectionalLight([0.0, 0.0, -1.0]),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (4, 4)),
    )


@pytest.fixture(scope="module")
def view():
    e = np.eye(3)
    return LightView(e[2], -e[2], e[0], e[1], np.array([-1.0, 1.0, -1.0, 1.0]), 1.0, 1.0, False)


@pytest.fixture
def no_work(monkeypatch):
    """The compiled work of every function here, replaced by `forbidden`."""
    for module, name in [
        (_spot_lights, "_shade_points"),
        (_spot_lights, "_evaluate"),
        (_spot_lights, "receiver_points"),
        (_spot_light_fit, "_fit_jit"),
        (_spot_light_bundles, "_refine_axis"),
        (_spot_light_table, "map_sharded"),
        (_spot_light_light_table, "_interpolate"),
        (_gbuffer, "_raster_faces"),
        (_gbuffer, "_sample"),
    ]:
        monkeypatch.setattr(module, name, forbidden)


# ------------------------------------------------------------------------- SpotLights


SPOT = dict(
    origin=[[0.0, 0.0, 2.0]],
    axis=[[0.0, 0.0, -1.0]],
    frame_u=[[1.0, 0.0, 0.0]],
    alpha=[1.0],
    beta=[0.5],
    half_width=[0.3],
    image=np.ones((1, 4, 4)),
)


@pytest.mark.parametrize(
    "name, value",
    [
        ("origin", "3"),
        ("origin", [[NAN, 0.0, 0.0]]),
        ("axis", [[0.0, 0.0, 0.0]]),
        ("frame_u", [[0.0, 0.0, 1.0]]),
        ("alpha", [0.0]),
        ("beta", [-0.1]),
        ("half_width", [INF]),
        ("image", np.ones((1, 0, 0))),
        ("image", -np.ones((1, 4, 4))),
        ("active", "yes"),
        ("active", [1]),
    ],
)
def test_spot_lights_constructor(name, value):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.SpotLights(**{**SPOT, name: value})


# ------------------------------------------------------------------ evaluate / shade / render

GOOD = dict(max_gain=1e4, axis_epsilon=1e-9, intensity_correction=True)
BAD_OPTIONS = [
    ("max_gain", "3"),
    ("max_gain", INF),
    ("max_gain", True),
    ("max_gain", 0.0),
    ("axis_epsilon", -1.0),
    ("axis_epsilon", INF),
    ("intensity_correction", "no"),
    ("intensity_correction", None),
    ("memory_limit", 0),
    ("memory_limit", 2.5),
]


@pytest.mark.parametrize("name, value", BAD_OPTIONS)
def test_evaluate_options(light, no_work, name, value):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.evaluate_spot_lights(light, np.zeros((2, 3)), **{name: value})


@pytest.mark.parametrize(
    "lights, points, name",
    [
        ("x", np.zeros((2, 3)), "lights"),
        (None, np.zeros((2, 3)), "lights"),
        ("light", "abc", "points"),
        ("light", None, "points"),
        ("light", np.zeros((2, 2)), "points"),
        ("light", np.full((2, 3), NAN), "points"),
        ("light", np.zeros((1000, 3)), r"points`.*`memory_limit"),  # over 1000 bytes
    ],
)
def test_evaluate_arrays(light, no_work, lights, points, name):
    lights = light if lights == "light" else lights
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.evaluate_spot_lights(lights, points, memory_limit=1000)


@pytest.mark.parametrize("name, value", BAD_OPTIONS)
def test_shade_options(light, no_work, name, value):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.shade_points(light, np.zeros((1, 3)), UP, **{name: value})


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(lights="x"), "lights"),
        (dict(points=np.full((1, 3), NAN)), "points"),
        (dict(points="abc"), "points"),
        (dict(normals=np.zeros((1, 3))), "normals"),
        (dict(normals=np.full((1, 3), NAN)), "normals"),
        (dict(normals=np.zeros((2, 3))), "normals"),
        (dict(normals=None), "normals"),
        (dict(shading="lambert"), "shading"),
        (dict(occluders="ball"), "occluders"),
        (dict(occluders=[1]), r"occluders\[0\]"),
        (dict(occluders=None), "occluders"),
    ],
)
def test_shade_arguments(light, no_work, kwargs, name):
    args = {"lights": light, "points": np.zeros((1, 3)), "normals": UP, **kwargs}
    lights, points, normals = args.pop("lights"), args.pop("points"), args.pop("normals")
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.shade_points(lights, points, normals, **args)


def test_shade_refuses_more_points_than_the_limit(light, no_work):
    points = np.zeros((1000, 3))
    with pytest.raises(ValueError, match=r"`points`.*`memory_limit`"):
        jc.internal.shade_points(light, points, points + 1.0, memory_limit=1000)


@pytest.mark.parametrize("name, value", BAD_OPTIONS + [("samples", 0), ("samples", 2.0),
                                                      ("samples", "2"), ("samples", True),
                                                      ("samples", 10**6), ("shading", "x"),
                                                      ("occluders", [1])])  # fmt: skip
def test_render_arguments(light, no_work, name, value):
    receiver = jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (4, 4))
    with pytest.raises(ValueError, match=f"`{name}"):
        jc.internal.render_spot_lights(light, receiver, **{name: value})


@pytest.mark.parametrize("lights, receiver, name", [("x", "receiver", "lights"),
                                                    ("light", "x", "receiver"),
                                                    ("light", None, "receiver")])  # fmt: skip
def test_render_objects(light, no_work, lights, receiver, name):
    lights = light if lights == "light" else lights
    if receiver == "receiver":
        receiver = jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (4, 4))
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.render_spot_lights(lights, receiver)


def test_render_refuses_a_receiver_over_the_limit(light, no_work):
    receiver = jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (8000, 8000))
    with pytest.raises(ValueError, match=r"`samples` or the receiver's `shape`.*`memory_limit`"):
        jc.internal.render_spot_lights(light, receiver, samples=4)


# ------------------------------------------------------------------------------ the fit

RNG = np.random.default_rng(0)
RAYS = (RNG.normal(size=(16, 3)), np.tile([0.0, 0.0, -1.0], (16, 1)), np.ones(16))


@pytest.mark.parametrize(
    "name, value",
    [
        ("max_lights", 10**9),
        ("resolution", 10**6),
        ("cells", 10**5),
        ("cells", True),
        ("axis_iterations", 2**40),
        ("splat_window", 10**5),
        ("energy_fraction", "0.5"),
        ("energy_fraction", True),
        ("angle_threshold_deg", True),
        ("distance_threshold", True),
        ("dismiss_threshold", INF),
        ("splat_radius", "1"),
        ("memory_limit", 0),
    ],
)
def test_fit_knobs(no_work, name, value):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.fit_spot_lights(RAYS, **{name: value})


@pytest.mark.parametrize(
    "rays, name",
    [
        ((np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)), "origin"),
        ((RAYS[0], np.zeros((16, 3)), RAYS[2]), "direction"),
        ((np.zeros((10**8, 3), np.float32),) * 2 + (np.zeros(10**8, np.float32),), "rays"),
    ],
)
def test_fit_rays(no_work, rays, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.fit_spot_lights(rays)


REFINE = dict(
    origin=RAYS[0],
    direction=RAYS[1],
    energy=RAYS[2],
    axis_point=np.zeros(3),
    axis_direction=np.array([0.0, 0.0, -1.0]),
    distance_threshold=0.1,
    angle_threshold_deg=30.0,
    iterations=3,
)


@pytest.mark.parametrize(
    "name, value",
    [
        ("origin", "o"),
        ("origin", RAYS[0][:, :2]),
        ("origin", RAYS[0] * NAN),
        ("direction", RAYS[1][:-1]),
        ("energy", np.ones(17)),
        ("energy", -RAYS[2]),
        ("axis_point", np.zeros(2)),
        ("axis_point", np.full(3, NAN)),
        ("axis_direction", np.zeros(3)),
        ("distance_threshold", -1.0),
        ("distance_threshold", "a"),
        ("angle_threshold_deg", 200.0),
        ("angle_threshold_deg", NAN),
        ("iterations", 2.5),
        ("iterations", -1),
        ("iterations", "3"),
        ("iterations", True),
    ],
)
def test_refine_axis(no_work, name, value):
    kwargs = {**REFINE, name: value}
    args = [kwargs.pop(n) for n in ("origin", "direction", "energy", "axis_point")]
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.refine_axis(*args, kwargs.pop("axis_direction"), **kwargs)


# ----------------------------------------------------------------------- the moving light

SMALL = dict(subdivisions=0, rays_per_axis=4, tracking_steps=1, max_lights=1, progress=False)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(subdivisions=7), "subdivisions"),
        (dict(rays_per_axis=4.0), "rays_per_axis"),
        (dict(rays_per_axis=10**5), "rays_per_axis"),
        (dict(tracking_steps=10**9), "tracking_steps"),
        (dict(tracking_rays_per_axis=10**5), "tracking_rays_per_axis"),
        (dict(match_threshold=-1.0), "match_threshold"),
        (dict(match_threshold=NAN), "match_threshold"),
        (dict(match_threshold="a"), "match_threshold"),
        (dict(refine_knobs=[1]), "refine_knobs"),
        (dict(refine_knobs={"foo": 1}), "refine_knobs"),
        (dict(refine_knobs={"iterations": -1}), "iterations"),
        (dict(refine_knobs={"angle_threshold_deg": "a"}), "angle_threshold_deg"),
        (dict(devices=1.0), "devices"),
        (dict(chunk=0), "chunk"),
        (dict(progress="no"), "progress"),
        (dict(per_device="x"), "per_device"),
        (dict(foo=1), "fit_knobs"),
        (dict(resolution=10**6), "resolution"),
        (dict(cells=2.5), "cells"),
        (dict(energy_fraction=2.0), "energy_fraction"),
        (dict(subdivisions=6, max_lights=16, resolution=64), "subdivisions"),
        (dict(memory_limit=-1), "memory_limit"),
    ],
)
def test_precompute(ball, no_work, kwargs, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.precompute_spot_lights(ball, **{**SMALL, **kwargs})


@pytest.mark.parametrize("value", ["2", 2.0, -1, 7, True, None])
def test_icosphere_directions(value):
    with pytest.raises(ValueError, match="`subdivisions`"):
        jc.internal.icosphere_directions(value)


def test_interpolate_and_table_files(no_work, tmp_path):
    table = object.__new__(jc.SpotLightTable)  # the checks come before its fields are read
    with pytest.raises(ValueError, match="`table`"):
        jc.internal.interpolate_spot_lights("x", [0.0, 0.0, -1.0])
    for direction in ("down", [NAN, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 1.0]):
        with pytest.raises(ValueError, match="`direction`"):
            jc.internal.interpolate_spot_lights(table, direction)
    for path in (None, 3):
        with pytest.raises(ValueError, match="`path`"):
            jc.SpotLightTable.load(path)
        with pytest.raises(ValueError, match="`path`"):
            jc.SpotLightTable.save(table, path)
    with pytest.raises(ValueError, match="`path`"):
        jc.SpotLightTable.load(tmp_path / "missing.npz")


# ----------------------------------------------------------------------- exit rays


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(rays_per_axis=1), "rays_per_axis"),
        (dict(rays_per_axis=4.0), "rays_per_axis"),
        (dict(rays_per_axis=10**6), "rays_per_axis"),
        (dict(direction=[NAN, 0.0, -1.0]), "direction"),
        (dict(direction=[0.0, 0.0, 0.0]), "direction"),
        (dict(direction="down"), "direction"),
        (dict(channel=1), "channel"),
        (dict(memory_limit=1.5), "memory_limit"),
    ],
)
def test_trace_exit_rays(ball, monkeypatch, kwargs, name):
    from jaxcaustics.methods.spot_lights import exit_rays as _ellipsoid

    monkeypatch.setattr(_ellipsoid, "_ellipsoid_exit_rays", forbidden)
    kwargs = {"rays_per_axis": 4, **kwargs}
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.trace_exit_rays(ball, kwargs.pop("rays_per_axis"), **kwargs)


# ------------------------------------------------------------------- image-space tools


def test_light_view(ball):
    for scene in ("x", None, ball):
        with pytest.raises(ValueError, match="`scene`"):
            jc.internal.light_view(scene)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(scene="x"), "scene"),
        (dict(view="x"), "view"),
        (dict(resolution=0), "resolution"),
        (dict(resolution=8.0), "resolution"),
        (dict(resolution="8"), "resolution"),
        (dict(resolution=10**6), "resolution"),
        (dict(window=0), "window"),
        (dict(window=2.5), "window"),
        (dict(window=9), "window"),
        (dict(memory_limit=100), "resolution"),
    ],
)
def test_geometry_buffers(glass, view, no_work, kwargs, name):
    args = {"scene": glass, "view": view, "resolution": 8, "window": 4, **kwargs}
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.geometry_buffers(**args)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(view="x"), "view"),
        (dict(positions=np.zeros((8, 8))), "positions"),
        (dict(positions="p"), "positions"),
        (dict(origin=np.zeros((4, 2))), "origin"),
        (dict(origin=np.full((4, 3), NAN)), "origin"),
        (dict(direction=np.zeros((5, 3))), "direction"),
        (dict(iterations=-1), "iterations"),
        (dict(iterations=2.5), "iterations"),
        (dict(iterations=10**7), "iterations"),
        (dict(iterations=True), "iterations"),
    ],
)
def test_ray_geo(view, no_work, kwargs, name):
    args = dict(
        view=view,
        positions=np.zeros((8, 8, 3)),
        origin=np.zeros((4, 3)),
        direction=np.tile([0.0, 0.0, -1.0], (4, 1)),
        iterations=2,
    )
    args.update(kwargs)
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.ray_geo(**args)


# ------------------------------------------------------------------------------ kernels

D, N = np.array([[0.0, 0.0, -1.0]]), np.array([[0.0, 0.0, 1.0]])


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: jc.internal.refract("abc", N, 1.5), "direction"),
        (lambda: jc.internal.refract(np.zeros((1, 2)), N, 1.5), "direction"),
        (lambda: jc.internal.refract(D * NAN, N, 1.5), "direction"),
        (lambda: jc.internal.refract(np.zeros((2, 3)), np.zeros((3, 3)), 1.5), "normal"),
        (lambda: jc.internal.refract(D, N, "1.5"), "eta"),
        (lambda: jc.internal.refract(D, N, -1.0), "eta"),
        (lambda: jc.internal.refract(D, N, 0.0), "eta"),
        (lambda: jc.internal.refract(D, N, NAN), "eta"),
        (lambda: jc.internal.refract(D, N, True), "eta"),
        (lambda: jc.internal.refract(D, N, np.array([1.0, -1.0])), "eta"),
        (lambda: jc.internal.reflect("abc", N), "direction"),
        (lambda: jc.internal.reflect(D, None), "normal"),
        (lambda: jc.internal.fresnel_transmittance("a", 1.5), "cos_i"),
        (lambda: jc.internal.fresnel_transmittance(np.array([2.0]), 1.5), "cos_i"),
        (lambda: jc.internal.fresnel_transmittance(np.array([0.5]), -1.0), "eta"),
        (lambda: jc.internal.height_and_gradient("x", np.zeros(2), np.zeros(2)), "surface"),
    ],
)
def test_optics(call, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        call()


@pytest.fixture(scope="module")
def field():
    return jc.HeightField(np.zeros((4, 4)), (0.0, 1.0, 0.0, 1.0))


@pytest.mark.parametrize(
    "x, y, kwargs, name",
    [
        ("a", np.zeros(2), {}, "x"),
        (np.zeros(2), np.zeros(3), {}, "y"),
        (np.full(2, NAN), np.zeros(2), {}, "x"),
        (np.zeros(2), np.zeros(2), dict(curvature="yes"), "curvature"),
        (np.zeros(2), np.zeros(2), dict(curvature=None), "curvature"),
    ],
)
def test_height_and_gradient(field, x, y, kwargs, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        jc.internal.height_and_gradient(field, x, y, **kwargs)


# ----------------------------------------------------------------------------- sharding


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: jc.devices.device_mesh(1.0), "devices"),
        (lambda: jc.devices.device_mesh([jax.devices()[0]] * 2), "devices"),
        (lambda: jc.devices.map_sharded(1, None, np.zeros(4)), "fn"),
        (lambda: jc.devices.map_sharded(lambda s, x: x, None, np.zeros(4), chunk=2.0), "chunk"),
        (
            lambda: jc.devices.map_sharded(lambda s, x: x, None, np.zeros(4), progress="no"),
            "progress",
        ),
        (lambda: jc.devices.map_sharded(lambda s, x: x, None, np.zeros(4), desc=3), "desc"),
    ],
)
def test_sharding(call, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        call()


# ------------------------------------------------------------- the kernels still trace


def test_kernels_run_under_jit(field):
    d, n = jnp.asarray(D), jnp.asarray(N)
    t, tir = jax.jit(jc.internal.refract)(d, n, 1 / 1.5)
    assert np.allclose(t, D) and not bool(tir[0])
    assert np.allclose(jax.jit(jc.internal.reflect)(d, n), -D)
    value = jax.jit(jc.internal.fresnel_transmittance)(jnp.array([1.0]), jnp.asarray(1 / 1.5))
    assert float(value[0]) == pytest.approx(0.96)
    grad = jax.grad(lambda e: jc.internal.refract(d, n, e)[0][0, 2])(0.5)
    assert np.isfinite(float(grad))
    h, hx, hy = eqx.filter_jit(jc.internal.height_and_gradient)(
        field, jnp.array([0.3]), jnp.array([0.4])
    )
    assert float(h[0]) == 0.0 and float(hx[0]) == 0.0
