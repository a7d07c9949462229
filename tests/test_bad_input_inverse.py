"""Bad input to the inverse problems, I/O, export, the NumPy reference and the command
line (issue 20): every case is refused with a `ValueError` (or, for a missing file, a
`FileNotFoundError`) naming the argument, or by the CLI with one line naming the flag
and exit code 2, before anything is compiled, traced or written.

Cases already tested elsewhere are not repeated here: `design_lens` with an all-NaN
`initial`, `predict_photons=-3`, `boundary_weight=nan`, a negative or NaN `rtol`
(test_design.py::test_bad_specifications_raise_before_optimisation), a target dark inside
its mask (::test_a_target_dark_everywhere_inside_its_mask_is_refused), ``levels=(4096,)``
(::test_a_heights_grid_too_large_for_the_machine_is_refused_before_any_work);
`recover_surface` with a clamped receiver the light cannot reach
(test_recover.py::test_bad_inputs_raise_before_any_optimisation); `verify_lens` with a
NaN target and ``sun_samples=0`` (test_verify.py); ``design --size 0``
(test_cli.py::test_bad_arguments_exit_with_usage); a TARGET naming a non-picture of
`skimage.data` (test_cli.py::test_a_design_target_that_is_not_a_picture_is_one_line).
"""

import functools
import re
import types
import warnings

import jax
import numpy as np
import pytest

import jaxcaustics as jc
import jaxcaustics.inverse.design as design_module
import jaxcaustics.inverse.sequence as sequence_module
import jaxcaustics.inverse.variants as variants_module
from jaxcaustics import reference
from jaxcaustics.cli.flags import with_flags
from jaxcaustics.cli.main import main
from jaxcaustics.inverse import lens_setup

# every backend compilation while a case runs (none may happen: errors come first)
_COMPILED: list[str] = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: _COMPILED.append(event) if "backend_compile" in event else None
)

NAN, INF = float("nan"), float("inf")
UNWRITABLE = "/proc/jaxcaustics-no-such-folder/out"  # not even root can create it


def refused(call, name, kind=ValueError):
    """`call()` raises `kind` naming `name` in backticks, compiling nothing."""
    _COMPILED.clear()
    with pytest.raises(kind, match=re.escape(f"`{name}")):
        call()
    assert not _COMPILED, f"compiled before refusing: {_COMPILED}"


@pytest.fixture
def forbid(monkeypatch):
    """Anything that would start an optimisation or a trace fails the test instead."""

    def started(*args, **kwargs):
        raise AssertionError("the work started before the arguments were checked")

    monkeypatch.setattr(design_module, "_solve", started)
    import jaxcaustics.devices as sharding

    monkeypatch.setattr(sharding, "map_sharded", started)
    recover = sequence_module.recover_surface
    monkeypatch.setattr(sequence_module, "recover_surface", functools.wraps(recover)(started))
    monkeypatch.setattr(lens_setup, "_physical_memory", lambda: 16 << 30)  # 16 GiB


def blob(n=16):
    x = (np.arange(n) + 0.5) / n
    xx, yy = np.meshgrid(x, x)
    return 0.3 + np.exp(-((xx - 0.35) ** 2 + (yy - 0.4) ** 2) / 0.02)


# ------------------------------------------------------------------ design_lens

SPEC = dict(width=0.1, height=0.1, thickness=0.02, screen_distance=0.5, levels=(16,))


@pytest.mark.parametrize(
    ("change", "name"),
    [
        (dict(heights_shape=(16.7, 16)), "heights_shape"),  # was cut to (16, 16)
        (dict(heights_shape="88"), "heights_shape"),  # was (8, 8)
        (dict(heights_shape=(4, 10**9)), "heights_shape"),
        (dict(screen_extent=(-INF, INF, -1.0, 1.0)), "screen_extent"),  # named `extent`
        (dict(screen_extent="abcd"), "screen_extent"),  # a bare NumPy message
        (dict(levels=(4096, 16), start="poisson"), "levels"),  # only the last was sized
        (dict(levels=(16.0,)), "levels"),
        (dict(levels="16"), "levels"),
        (dict(oversample=10**4), "oversample"),  # named only `levels`
        (dict(max_steps=2.0), "max_steps"),
        (dict(floor="0.1"), "floor"),
        (dict(floor=np.nan), "floor"),
        (dict(floor=True, start="poisson"), "floor"),
        (dict(warn_error=True), "warn_error"),
        (dict(warn_error=INF), "warn_error"),
        (dict(throw="no"), "throw"),
        (dict(throw=None), "throw"),
        (dict(callback=3), "callback"),
        (dict(transport_iterations=10**12), "transport_iterations"),
        (dict(refine_steps=2.0), "refine_steps"),
        (dict(predict_photons=10**6), "predict_photons"),  # 10^12 photons after the design
        (dict(ior=np.inf), "ior"),
        (dict(width=[0.1]), "width"),
    ],
)
def test_design_lens_refuses(forbid, change, name):
    refused(lambda: design_module.design_lens(blob(), **{**SPEC, **change}), name)


@pytest.mark.parametrize(
    ("target", "name"),
    [
        (np.ones((16, 16), complex), "target"),  # the imaginary part was dropped
        (np.ones((4097, 4096), np.float32), "target"),  # over 4096^2 pixels
        ("camera", "target"),
    ],
)
def test_design_lens_refuses_targets(forbid, target, name):
    refused(lambda: design_module.design_lens(target, **SPEC), name)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(screen_distances="0.5"), "screen_distances"),  # iterated character by character
        (dict(screen_distances=["0.5"]), "screen_distances[0]"),  # a string was a number
        (dict(screen_distances=[0.5, NAN]), "screen_distances[1]"),
        (dict(screen_distances=[[0.5]]), "screen_distances[0]"),
        (dict(screen_distances=[0.5], per_device="x"), "per_device"),  # only after the set-up
        (dict(screen_distances=[0.5], throw="x"), "throw"),
    ],
)
def test_design_lens_variants_refuses(forbid, kwargs, name):
    spec = dict(width=0.1, height=0.1, thickness=0.02, levels=(16,))
    refused(lambda: variants_module.design_lens_variants(blob(), **spec, **kwargs), name)


@pytest.mark.parametrize(
    ("heights", "depth", "name"),
    [
        (np.full((4, 4), np.nan), 0.001, "heights"),  # gave NaN heights
        (np.zeros((4, 4), complex), 0.001, "heights"),
        (np.zeros((0, 4)), 0.001, "heights"),  # a NumPy reduction error
        ("abc", 0.001, "heights"),
        (np.zeros((4, 4)), "0.1", "depth"),
    ],
)
def test_fresnel_zones_refuses(heights, depth, name):
    refused(lambda: jc.internal.fresnel_zones(heights, depth), name)


# ------------------------------------------------------------------ recover_surface

LIGHT = jc.DirectionalLight.from_angles(20.0, 30.0)
WATER = dict(extent=(0.0, 1.0, 0.0, 1.0), rest_depth=0.5, light=LIGHT)
CAUSTIC = 1.0 + 0.1 * np.sin(np.arange(64.0)).reshape(8, 8)


@pytest.mark.parametrize(
    ("change", "name"),
    [
        (dict(target=np.ones((8, 8), complex)), "target"),
        (dict(target=np.ones((4097, 4096), np.float32)), "target"),
        (dict(target=0.01 * CAUSTIC), "target"),  # water absorbing 99% of the light
        (dict(heights_shape=(8.0, 8)), "heights_shape"),  # was accepted as (8, 8)
        (dict(heights_shape=(5000, 5000)), "heights_shape"),
        (dict(smoothness="0.1"), "smoothness"),  # strings and bools were numbers
        (dict(smoothness=True), "smoothness"),
        (dict(rtol="1e-6"), "rtol"),
        (dict(blur="1"), "blur"),
        (dict(learning_rate="0.1"), "learning_rate"),
        (dict(coarse_to_fine="1"), "coarse_to_fine"),
        (dict(initial="x"), "initial"),  # a bare NumPy message
        (dict(initial=np.ones((8, 8), complex)), "initial"),
        (dict(throw="no"), "throw"),
        (dict(normalize="yes"), "normalize"),
        (dict(samples_x=100001), "samples_x"),  # compiled for minutes after the start
        (dict(samples_x=3, channels_y=100000), "channels_y"),
    ],
)
def test_recover_surface_refuses(forbid, monkeypatch, change, name):
    import jaxcaustics.inverse.recover as recover

    def started(*args, **kwargs):
        raise AssertionError("the recovery started before the arguments were checked")

    for work in ("transport_start", "_make_solver", "auto_window", "_loss"):
        monkeypatch.setattr(recover, work, started)
    kwargs = {"target": CAUSTIC, **WATER, **change}
    refused(lambda: recover.recover_surface(**kwargs), name)


def test_recover_surface_names_a_missing_target_file():
    refused(
        lambda: jc.recover_surface("/no/such/caustic.png", **WATER), "target", FileNotFoundError
    )


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(warm="no"), "warm"),
        (dict(progress="no"), "progress"),
        (dict(resume="no"), "resume"),
        (dict(resume=True), "resume"),  # no checkpoint: started afresh silently
        (dict(checkpoint=3), "checkpoint"),
        (dict(checkpoint="/tmp"), "checkpoint"),  # a folder: failed after a frame
        (dict(checkpoint=f"{UNWRITABLE}/video.npz"), "checkpoint"),  # failed after a frame
        (dict(foo=1), "~unknown"),  # a TypeError from the first frame
        (dict(heights_shape="ab"), "heights_shape"),  # an int() error
        (dict(samples_x="a"), "samples_x"),  # a TypeError
    ],
)
def test_recover_sequence_refuses(forbid, kwargs, name):
    if name == "~unknown":
        with pytest.raises(ValueError, match="unknown arguments of recover_surface"):
            jc.recover_sequence([CAUSTIC], **WATER, **kwargs)
        return
    refused(lambda: jc.recover_sequence([CAUSTIC], **WATER, **kwargs), name)


def test_recover_sequence_refuses_missing_options_and_files(forbid):
    refused(lambda: jc.recover_sequence([CAUSTIC], rest_depth=0.5, light=LIGHT), "extent")
    refused(
        lambda: jc.recover_sequence(["/no/such/frame.png"], **WATER),
        "frames[0]",
        FileNotFoundError,
    )


# ------------------------------------------------------------------ verify_lens

X = (np.arange(16) + 0.5) / 16 * 2 - 1
LENS = jc.LensScene(
    jc.HeightField(1.5e-3 * np.exp(-(X[None, :] ** 2 + X[:, None] ** 2) / 0.15), (0, 0.1, 0, 0.1)),
    jc.DirectionalLight.from_angles(0.0),
    jc.PlaneReceiver((-0.02, 0.12, -0.02, 0.12), (32, 32)),
    thickness=0.01,
    screen_distance=0.3,
)
SCREEN = np.ones((32, 32))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(target=np.ones((32, 32), complex)), "target"),
        (dict(mask=np.ones((4, 4), bool)), "mask"),  # unchecked: a late IndexError
        (dict(mask=np.full((32, 32), np.nan)), "mask"),
        (dict(mask=np.zeros((32, 32), bool)), "mask"),
        (dict(photons_per_axis=10**7), "photons_per_axis"),  # 10^14 photons
        (dict(sun_samples=10**9), "sun_samples"),
        (dict(samples=(10**5, 10**5)), "samples"),  # ran for minutes
    ],
)
def test_verify_lens_refuses(monkeypatch, kwargs, name):
    def no_trace(*args, **kw):
        raise AssertionError("traced before the arguments were checked")

    monkeypatch.setattr(reference, "trace_mesh", no_trace)
    target = kwargs.pop("target", SCREEN)
    refused(lambda: jc.verify_lens(LENS, target, **kwargs), name)


@pytest.mark.parametrize(
    ("image", "target", "name"),
    [
        (np.full((4, 4), np.nan), np.ones((4, 4)), "image"),  # gave NaN
        (np.ones((4, 4)), np.zeros((4, 4)), "target"),  # divided by zero
        (np.ones((4, 5)), np.ones((4, 4)), "image"),  # a broadcasting error
    ],
)
def test_relative_l2_refuses(image, target, name):
    refused(lambda: jc.relative_l2(image, target), name)


# ------------------------------------------------------------------ transport_map


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(source="abc"), "source"),  # a bare NumPy message
        (dict(source=np.ones((8, 8), complex)), "source"),  # ran on the real part
        (dict(source=np.ones((4097, 4096), np.float32)), "source"),  # a MemoryError
        (dict(iterations=10**12), "iterations"),  # an OverflowError in the jitted loop
        (dict(tol=NAN), "tol"),  # ran with a NaN tolerance
        (dict(tol="0.1"), "tol"),  # a TypeError from jit
        (dict(tol=-1.0), "tol"),
        (dict(stall=NAN), "stall"),
        (dict(stall=2.0), "stall"),
        (dict(warn="no"), "warn"),
    ],
)
def test_transport_map_refuses(kwargs, name):
    source = kwargs.pop("source", np.ones((8, 8)))
    target = np.ones(source.shape if isinstance(source, np.ndarray) else (8, 8))
    refused(lambda: jc.internal.transport_map(source, target, **kwargs), name)


# ------------------------------------------------------------------ export

FIELD = jc.HeightField(np.zeros((3, 3)), (0.0, 0.01, 0.0, 0.01), "clamp")
# heights whose default solid, even at one point per sample (4097^2), is over the 16.7M
# points a grid may have (the default falls back from 2 per sample to 1)
BIG_FIELD = jc.HeightField(np.zeros((4096, 4096), np.float32), (0.0, 0.1, 0.0, 0.1), "clamp")


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: jc.internal.lens_solid(FIELD, "0.004"), "thickness"),  # a string was a number
        (
            lambda: jc.internal.lens_solid(FIELD, 0.004, samples=(10**5, 10**5)),
            "samples",
        ),  # minutes
        (lambda: jc.internal.lens_solid(FIELD, 0.004, samples=(8.0, 8)), "samples"),
        (lambda: jc.internal.lens_solid(BIG_FIELD, 0.004), "samples"),  # its default grid
        (lambda: jc.internal.lens_height_map(FIELD, 0.004, samples="88"), "samples"),
        (lambda: jc.manufacturability(FIELD, thickness=0.004, tool_radius_mm="1"), "tool_radius"),
        (lambda: jc.manufacturability(FIELD, thickness=0.004, samples=(10**5, 10**5)), "samples"),
        (lambda: jc.export_lens(FIELD, "/tmp/never", thickness=0.004, formats=()), "formats"),
        (lambda: jc.export_lens(FIELD, UNWRITABLE, thickness=0.004), "directory"),
    ],
)
def test_export_refuses(call, name):
    refused(call, name)


# ------------------------------------------------------------------ image files


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda p: jc.write_png(p / "x.png", np.ones((4, 4)), exposure="2"), "exposure"),
        (lambda p: jc.write_png(p / "x.png", np.ones((4, 4)), exposure=True), "exposure"),
        (lambda p: jc.write_png(p / "x.png", np.ones((4, 4)), gamma="2.2"), "gamma"),
        (lambda p: jc.write_png(p / "x.png", np.ones((4, 4)), bit_depth=8.0), "bit_depth"),
        (lambda p: jc.io.write_png_linear16(p / "x.png", np.ones((4, 4)), vmax=True), "vmax"),
        (lambda p: jc.write_png(f"{UNWRITABLE}/x.png", np.ones((4, 4))), "path"),
        (lambda p: jc.io.write_exr(f"{UNWRITABLE}/x.exr", np.ones((4, 4))), "path"),
        (lambda p: jc.io.write_exr(p / "a_file" / "x.exr", np.ones((4, 4))), "path"),
        (lambda p: jc.read_image(p / "a.png", as_gray="no"), "as_gray"),
    ],
)
def test_image_files_refuse(tmp_path, call, name):
    jc.write_png(tmp_path / "a.png", np.ones((4, 4)))
    (tmp_path / "a_file").write_text("")
    refused(lambda: call(tmp_path), name)


# ------------------------------------------------------------------ the NumPy reference

WATER_SCENE = jc.WaterScene(
    jc.HeightField(np.zeros((8, 8)), (0.0, 1.0, 0.0, 1.0)),
    jc.DirectionalLight.from_angles(10.0),
    jc.PlaneReceiver((0.0, 1.0, 0.0, 1.0), (8, 8)),
    0.5,
)
MESH_SCENE = types.SimpleNamespace(  # duck-typed: the reference reads fields only
    generator=types.SimpleNamespace(
        vertices=np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, 2.0]]),
        faces=np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]),
    ),
    light=types.SimpleNamespace(direction=np.array([0.0, 0.0, -1.0])),
    receiver=types.SimpleNamespace(extent=(-1.0, 2.0, -1.0, 2.0), shape=(8, 8)),
    ior=1.5,
    fresnel=False,
    material="refractor",
    normals="flat",
    interfaces=4,
    occluders=(),
)
ORIGINS, DIRECTIONS = np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]])


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: reference.trace_lens(LENS, 10**9), "photons_per_axis"),  # ran for ever
        (lambda: reference.emit_lens_photons(LENS, 10**6), "photons_per_axis"),  # 7 TiB
        (lambda: reference.trace_lens(LENS, 4, jitter="yes"), "jitter"),
        (lambda: reference.trace_lens(LENS, 4, jitter=True, seed="a"), "seed"),  # TypeError
        (lambda: reference.trace_lens(LENS, 4, jitter=True, seed=-1), "seed"),
        (lambda: reference.trace_lens(LENS, 4, return_stats="yes"), "return_stats"),
        (lambda: reference.trace_lens_photons(LENS, [NAN], [0.05]), "xs"),
        (lambda: reference.trace_lens_photons(LENS, ["a"], ["b"]), "xs"),
        (lambda: reference.trace_water(WATER_SCENE, photons_per_axis=10**6), "photons_per_axis"),
        (lambda: reference.trace_water(WATER_SCENE, margin="0.1"), "margin"),
        (lambda: reference.trace_water(WATER_SCENE, margin=True), "margin"),
        (lambda: reference.trace_water(WATER_SCENE, jitter="yes"), "jitter"),
        (
            lambda: reference.area_ratio_water(WATER_SCENE, samples_per_triangle=10**12),
            "samples_per_triangle",
        ),
        (lambda: reference.trace_photons(WATER_SCENE, [NAN], [0.5]), "xs"),
        (lambda: reference.surface_height(np.zeros((4, 4)), (0, 1, 0, 1), "clamp", [NAN], 0), "x"),
        (
            lambda: reference.surface_height(
                np.zeros((4, 4), complex), (0, 1, 0, 1), "clamp", 0, 0
            ),
            "heights",
        ),
        (lambda: reference.surface_height(np.zeros((4, 4)), "abcd", "clamp", 0, 0), "extent"),
        (
            lambda: reference.surface_height(
                np.zeros((4, 4)), (0, 1, 0, 1), "clamp", [0, 0], [0] * 3
            ),
            "x",
        ),
        (
            lambda: reference.intersect_mesh(np.eye(3), [[0, 1, 2]], ORIGINS, [[NAN] * 3]),
            "directions",
        ),
        (
            lambda: reference.intersect_mesh(
                np.eye(3), [[0, 1, 2]], ORIGINS, DIRECTIONS, t_min="0"
            ),
            "t_min",
        ),
        (lambda: reference.chunk_photons(None, 0), "default"),
        (lambda: reference.trace_mesh(MESH_SCENE, 4, return_stats="yes"), "return_stats"),
        (lambda: reference.emit_mesh_photons(MESH_SCENE, 10**5), "photons_per_axis"),
        (lambda: reference.trace_mesh_photons(MESH_SCENE, ORIGINS, DIRECTIONS, NAN), "weights"),
    ],
)
def test_reference_refuses(call, name):
    refused(call, name)


# ------------------------------------------------------------------ the command line


def cli(argv):
    """The exit code of ``jaxcaustics ARGV``, argparse's exits included."""
    try:
        return main(argv)
    except SystemExit as exit_:
        return exit_.code


@pytest.fixture
def out(tmp_path):
    import OpenEXR

    (tmp_path / "a_file").write_text("")
    jc.write_png(tmp_path / "black.png", np.zeros((8, 8)))
    jc.write_png(tmp_path / "target.png", np.linspace(0.2, 1.0, 64).reshape(8, 8))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"Y": np.full((8, 8), np.nan, np.float32)}) as f:
        f.write(str(tmp_path / "nan.exr"))  # `write_exr` refuses NaN: another tool's file
    (tmp_path / "frames").mkdir()
    return tmp_path


CLI_CASES = [
    # design
    (["design", "--size", "100000"], "--size"),  # a 7 TiB resize
    (["design", "--ior", "nan"], "--ior"),
    (["design", "--light", "torch"], "--light"),
    (["design", "--light", "led:3mm"], "--light"),  # no distance
    (["design", "--light", "led:-3mm@100mm"], "--light"),
    (["design", "--ior", "0.5"], "--ior"),
    (["design", "--ior", "inf"], "--ior"),
    (["design", "--levels", "100000"], "--levels"),  # a 75 GiB jnp.zeros before the design
    (["design", "--steps", "0"], "--steps"),
    (["design", "--steps", "-3"], "--steps"),
    (["design", "--width", "1e400"], "--width"),  # an infinite length
    (["design", "--tool-radius", "1e400"], "--tool-radius"),
    (["design", "--output", "{out}/a_file"], "--output"),  # exit code 1
    (["design", "--output", UNWRITABLE], "--output"),  # exit code 1
    (["design", "--resume", "--output", "{out}/fresh"], "--resume"),  # started afresh
    (["design", "/etc/hostname"], "TARGET"),  # named `path`
    (["design", "{out}/black.png"], "TARGET"),  # all black: named `target` after a resize
    (["design", "{out}/nan.exr"], "TARGET"),
    # its target.png would be written over the picture it was made from
    (["design", "{out}/target.png", "--output", "{out}"], "--output"),
    (["design", "--outline", "{out}/target.png", "--output", "{out}"], "--output"),
    # recover
    (["recover", "--size", "0,1"], "--size"),  # named `extent`, after tracing the sea
    (["recover", "--size", "nan,1"], "--size"),
    (["recover", "--depth", "0"], "--depth"),
    (["recover", "--depth", "nan"], "--depth"),
    (["recover", "--zenith", "90"], "--zenith"),
    (["recover", "--azimuth", "inf"], "--azimuth"),  # "math domain error"
    (["recover", "--ior", "1"], "--ior"),  # traced the sea first
    (["recover", "--ior", "-1"], "--ior"),
    (["recover", "--blur", "-1"], "--blur"),
    (["recover", "--blur", "nan"], "--blur"),
    (["recover", "--gamma", "0"], "--gamma"),
    (["recover", "--heights", "0"], "--heights"),
    (["recover", "--heights", "100000"], "--heights"),  # the process aborted in XLA
    (["recover", "--heights", "1000"], "--heights"),  # the built-in sea: hours of tracing
    (["recover", "--steps", "0"], "--steps"),
    (["recover", "--output", "{out}/a_file"], "--output"),
    (["recover", "--resume", "--output", "{out}/fresh"], "--resume"),
    (["recover", "/no/such/frame.png"], "TARGET"),  # exit code 1
    (["recover", "/etc/hostname"], "TARGET"),
    (["recover", "{out}/frames"], "TARGET"),  # an empty folder
    (["recover", "{out}/nan.exr"], "TARGET"),
    (["recover", "{out}/target.png", "--output", "{out}"], "--output"),
    # render water
    (["render", "water", "--size", "5000x5000"], "--size"),
    (["render", "water", "--heightfield-size", "100000x100000"], "--heightfield-size"),  # abort
    (["render", "water", "--frames", "1000000000"], "--frames"),
    (["render", "water", "--hit-iterations", "1000000000"], "--hit-iterations"),
    (["render", "water", "--supersample", "100000"], "--supersample"),
    (["render", "water", "--samples-x", "100001", "--channels-y", "2"], "--samples-x"),
    (["render", "water", "--dt", "1e308", "--frames", "3"], "--dt"),  # infinite times
    (["render", "water", "--output", UNWRITABLE], "--output"),
]


@pytest.mark.parametrize(("argv", "flag"), CLI_CASES, ids=[" ".join(a) for a, _ in CLI_CASES])
def test_cli_refuses_in_one_line(out, capsys, monkeypatch, argv, flag):
    def started(*args, **kwargs):
        raise AssertionError("the work started before the flags were checked")

    for name in ("design_lens",):
        monkeypatch.setattr(design_module, name, started)
    monkeypatch.setattr(sequence_module, "recover_sequence", started)
    monkeypatch.setattr(reference, "trace_water", started)
    monkeypatch.setattr(jc, "render", started)
    monkeypatch.setattr(jc.internal, "auto_window", started)
    argv = [a.replace("{out}", str(out)) for a in argv]
    if "--output" not in argv:
        argv += ["--output", str(out / "results")]
    _COMPILED.clear()
    code = cli(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert "Traceback" not in err and flag in lines[-1], err
    assert not _COMPILED, f"compiled before refusing: {_COMPILED}"


LATE_CLI_CASES = [
    # named `surface` and `rest_depth`, which `render water` does not take
    (["render", "water", "--amplitude", "100"], r"`--amplitude` 100 m.*`--depth` 1 m"),
    # named `num_waves` and `wavelength_range`
    (["recover", "--size", "0.001,0.001"], r"`--size` 0.001,0.001 m.*built-in sea"),
]


@pytest.mark.parametrize(("argv", "said"), LATE_CLI_CASES, ids=[a[0] for a, _ in LATE_CLI_CASES])
def test_cli_names_the_flag_behind_a_check_that_needs_the_sea(
    capsys, monkeypatch, tmp_path, argv, said
):
    """Checks that need the sea's heights (drawn first: they compile) name the flags,
    before rendering or tracing."""

    def started(*args, **kwargs):
        raise AssertionError("the work started before the waves were checked")

    monkeypatch.setattr(jc, "render", started)
    monkeypatch.setattr(reference, "trace_water", started)
    code = main([*argv, "--output", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert re.search(said, err.strip().splitlines()[-1]), err


def test_cli_render_water_on_a_tiny_floor_keeps_the_window_on_it(capsys, tmp_path):
    """On a 1 cm floor the automatic window (65 x 64) reached past the 16 x 16 pixels and
    was refused naming `samples_x`; now it is cut to the receiver and the render runs,
    its missed light said once, in the flags' words."""
    argv = ["render", "water", "--extent", "0.01x0.01", "--size", "16x16",
            "--heightfield-size", "16x16", "--quiet", "--output", str(tmp_path)]  # fmt: skip
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "N = 33, M = 32" in err and "samples_x" not in err, err
    assert err.count("of the light lands outside") == 1, err


def test_cli_names_flags_in_library_errors_and_warnings():
    """A library error or warning that reaches the command names its flag (`levels` ->
    `--levels`), once where two arguments share it, and the command's words for the
    library's phrases."""
    flags = {"levels": "--levels", "heights_shape": "--levels", "solver": "--solver"}
    phrases = {"the target's size": "`--size`"}

    def run(args):
        warnings.warn("the `solver` diverged", stacklevel=1)
        raise ValueError("lower `levels` or `heights_shape` (set by the target's size)")

    shown = []
    with warnings.catch_warnings():
        warnings.showwarning = lambda message, *a, **k: shown.append(str(message))
        with pytest.raises(ValueError, match=r"^lower `--levels` \(set by `--size`\)$"):
            with_flags(run, flags, phrases)(None)
    assert shown == ["the `--solver` diverged"]

    def fail(args):
        raise RuntimeError("level 0: the `solver` failed")

    with pytest.raises(RuntimeError, match="the `--solver` failed"):
        with_flags(fail, flags)(None)


@pytest.mark.parametrize("solve", ["design", "recover"])
def test_runaway_conjugate_gradient_steps_are_refused(solve):
    """`cg_steps=10**9` ran (each linear solve would have taken that many steps)."""
    target = np.ones((16, 16))
    with pytest.raises(ValueError, match="`cg_steps`"):
        if solve == "design":
            jc.design_lens(target, width=0.05, height=0.05, thickness=0.01, screen_distance=0.5,
                           cg_steps=10**9)  # fmt: skip
        else:
            light = jc.DirectionalLight([0.0, 0.0, -1.0])
            jc.recover_surface(target, extent=(0, 1, 0, 1), rest_depth=0.5, light=light,
                               cg_steps=10**9)  # fmt: skip


def test_a_target_no_water_that_deep_makes_is_refused_naming_it(monkeypatch):
    """A caustic of one bright pixel on black asks for waves deeper than the water: it
    was recovered for 36 s and then refused as the internal "`surface` reaches the
    ground"; now the transport start's heights are checked, before the fold fit."""
    import jaxcaustics.inverse.recover as recover_module

    def fold_fit(*args, **kwargs):
        raise AssertionError("the fold fit ran before the heights were checked")

    monkeypatch.setattr(recover_module, "refine_folds", fold_fit)
    target = np.zeros((16, 16))
    target[5, 5] = 1.0
    light = jc.DirectionalLight([0.0, 0.0, -1.0])
    with pytest.raises(ValueError, match="`target` cannot be made.*`rest_depth` 0.5 m"):
        jc.recover_surface(target, extent=(0, 1, 0, 1), rest_depth=0.5, light=light,
                           normalize=True)  # fmt: skip


def test_a_runaway_solver_keeps_the_level_start_and_says_so():
    """Gradient descent with a step of 1e9 sends the heights through the ground and then
    to NaN: reported as impossible geometry before; now a warning naming the solver, and
    the level's start heights (finite) in the result."""
    import optimistix as optx

    target = 1.0 + 0.1 * np.random.default_rng(0).standard_normal((16, 16))
    light = jc.DirectionalLight([0.0, 0.0, -1.0])
    solver = optx.GradientDescent(learning_rate=1e9, rtol=0.0, atol=0.0)
    with pytest.warns(UserWarning, match="GradientDescent solver diverged at level 0"):
        result = jc.recover_surface(
            target, extent=(0, 1, 0, 1), rest_depth=0.5, light=light, start="ripple",
            solver=solver, max_steps=5, throw=False,
        )  # fmt: skip
    assert result.levels[0].result == optx.RESULTS.nonlinear_divergence
    # the start's ripple is 0.01 m peak to peak; the runaway's, 2.8e20 m
    assert np.all(np.isfinite(result.heights)) and np.ptp(result.heights) < 0.02
    assert np.isfinite(result.image_error)


def test_a_blank_too_thin_for_the_start_is_refused_before_the_rest(monkeypatch):
    """The transport start's relief through the blank was found after the refinement
    and the prediction (or named the internal `surface` when the refinement built its
    scene); now right after the start, naming `thickness` and what to change."""

    def predicted(*args, **kwargs):
        raise AssertionError("the prediction ran before the relief was checked")

    monkeypatch.setattr(design_module, "predict_caustic", predicted)
    target = np.ones((16, 16))
    target[4:8, 4:8] = 6.0
    with pytest.raises(ValueError, match="`thickness` 0.0001 m is too thin.*`max_relief`"):
        jc.design_lens(target, width=0.05, height=0.05, thickness=1e-4, screen_distance=0.25)
