"""The plain-NumPy reference tracer (`jaxcaustics.reference`): the tests' ground truth.

Checked against closed forms only (flat water, Fresnel's equations, energy conservation,
the weak-lens limit), against itself (two independent estimators, symmetries), and
for exact first hits and input validation.
"""

import ast
import math
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics import reference as ref
from jaxcaustics.reference._surface import _Surface, intersect_surface

EXT = (0.0, 1.0, 0.0, 1.0)
REFERENCE_DIR = pathlib.Path(ref.__file__).parent


def _scene(
    heights,
    extent=EXT,
    *,
    zenith=0.0,
    azimuth=0.0,
    depth=1.0,
    boundary="periodic",
    receiver_extent=None,
    shape=None,
    rotation=0.0,
    **kwargs,
):
    """A `WaterScene` built from float64 NumPy arrays."""
    heights = np.asarray(heights, dtype=np.float64)
    light = jc.DirectionalLight.from_angles(zenith, azimuth)
    return jc.WaterScene(
        jc.HeightField(heights, np.asarray(extent, np.float64), boundary, rotation),
        jc.DirectionalLight(np.asarray(light.direction, np.float64)),
        jc.PlaneReceiver(np.asarray(receiver_extent or extent, np.float64), shape or heights.shape),
        np.asarray(depth, np.float64),
        **kwargs,
    )


def _grid(n, extent=EXT):
    x = extent[0] + (np.arange(n) + 0.5) * (extent[1] - extent[0]) / n
    y = extent[2] + (np.arange(n) + 0.5) * (extent[3] - extent[2]) / n
    return np.meshgrid(x, y)


def _waves(n, amplitude, modes=((1, 2, 1.0, 0.0), (3, -1, 0.5, 1.0), (2, 1, 0.4, 2.0))):
    """Periodic sum of sines over EXT: ``amplitude * sum a sin(2 pi (kx x + ky y) + phase)``."""
    x, y = _grid(n)
    return amplitude * sum(a * np.sin(2 * np.pi * (kx * x + ky * y) + p) for kx, ky, a, p in modes)


def _bump(n, height=0.04, centre=(0.4, 0.55), sigma=0.08):
    x, y = _grid(n)
    return height * np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * sigma**2))


def _blur(image, sigma, periodic):
    """Separable Gaussian blur (sigma in pixels), wrapping or repeating the edges."""
    r = math.ceil(4 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    out = image
    for axis in (0, 1):
        pad = [(r, r) if a == axis else (0, 0) for a in range(image.ndim)]
        p = np.pad(out, pad, mode="wrap" if periodic else "edge")
        n = image.shape[axis]
        out = sum(k[i] * np.take(p, np.arange(i, i + n), axis=axis) for i in range(2 * r + 1))
    return out


def _fresnel_flat(zenith_deg, n):
    """Unpolarised transmittance into index n at incidence `zenith_deg` (textbook form)."""
    ci = math.cos(math.radians(zenith_deg))
    st = math.sin(math.radians(zenith_deg)) / n
    ct = math.sqrt(1.0 - st * st)
    rs = ((ci - n * ct) / (ci + n * ct)) ** 2
    rp = ((n * ci - ct) / (n * ci + ct)) ** 2
    return 1.0 - 0.5 * (rs + rp)


# --------------------------------------------------------------------------- the package


def test_reference_imports_no_jax_and_no_private_library_modules():
    for path in REFERENCE_DIR.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [("." * node.level) + (node.module or "")]
            else:
                continue
            for name in names:
                assert name.split(".")[0] not in ("jax", "jaxlib", "equinox", "jaxcaustics"), (
                    path.name,
                    name,
                )
                assert not name.startswith(".."), (path.name, name)


def test_reference_runs_with_jax_unimportable_on_a_duck_typed_scene():
    """Loaded on its own (jax blocked) it traces a plain namespace: duck typing, no JAX."""
    code = textwrap.dedent(f"""
        import importlib.util, sys, types
        import numpy as np
        sys.modules["jax"] = None  # any `import jax` now raises ImportError
        spec = importlib.util.spec_from_file_location(
            "standalone_reference", {str(REFERENCE_DIR / "__init__.py")!r},
            submodule_search_locations=[{str(REFERENCE_DIR)!r}])
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        spec.loader.exec_module(mod)
        ns = types.SimpleNamespace
        scene = ns(surface=ns(heights=[[0.0] * 4] * 4, extent=[0, 1, 0, 1], boundary="clamp"),
                   light=ns(direction=[0.3, 0.1, -2.0]), receiver=ns(extent=[0, 1, 0, 1],
                   shape=(4, 4)), rest_depth=0.5, ior=(1.33, 1.5), iors=(1.33, 1.5),
                   fresnel=False)
        image = mod.trace_water(scene)
        assert image.shape == (4, 4, 2) and np.abs(image - 1).max() < 1e-12, image
        assert "jaxcaustics" not in sys.modules
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


# --------------------------------------------------------------------------- surface


@pytest.mark.parametrize("boundary", ["periodic", "clamp", "extrapolate"])
def test_surface_height_interpolates_samples_with_the_analytic_gradient(boundary, rng):
    h = rng.normal(size=(12, 9))
    ext = (-1.0, 2.0, 0.5, 2.5)
    x = ext[0] + (np.arange(9) + 0.5) * 3.0 / 9
    y = ext[2] + (np.arange(12) + 0.5) * 2.0 / 12
    value, _, _ = ref.surface_height(h, ext, boundary, *np.meshgrid(x, y))
    np.testing.assert_allclose(value, h, atol=1e-14)  # Catmull-Rom passes through samples
    px, py = rng.uniform(-1.5, 2.5, 200), rng.uniform(0.0, 3.0, 200)
    _, hx, hy = ref.surface_height(h, ext, boundary, px, py)
    e = 1e-6
    fx = (
        ref.surface_height(h, ext, boundary, px + e, py)[0]
        - ref.surface_height(h, ext, boundary, px - e, py)[0]
    ) / (2 * e)
    fy = (
        ref.surface_height(h, ext, boundary, px, py + e)[0]
        - ref.surface_height(h, ext, boundary, px, py - e)[0]
    ) / (2 * e)
    np.testing.assert_allclose(hx, fx, atol=1e-6)
    np.testing.assert_allclose(hy, fy, atol=1e-6)
    if boundary == "periodic":
        shifted = ref.surface_height(h, ext, boundary, px + 3.0 * 2, py - 2.0)
        np.testing.assert_allclose(
            shifted[0], ref.surface_height(h, ext, boundary, px, py)[0], atol=1e-12
        )
    else:  # beyond u = -2 (x < x_min - 1.5 dx) the surface is level (clamp: from u = -1,
        # where all taps are column 0; extrapolate: the odd reflection stops there)
        far = ref.surface_height(h, ext, boundary, np.full(5, -7.0), np.linspace(0.5, 2.5, 5))
        np.testing.assert_allclose(far[1], 0.0, atol=1e-12)
        np.testing.assert_allclose(
            far[0], ref.surface_height(h, ext, boundary, -1.6, np.linspace(0.5, 2.5, 5))[0]
        )


def test_extrapolate_continues_a_plane_past_the_samples(rng):
    """``boundary="extrapolate"`` (odd reflection about the edge sample) reproduces a
    plane exactly out to 1.5 samples beyond the extent (u in [-2, n + 1]), in the reference
    and in JAX; under "clamp" the slope at the extent's edge is -1/8 of the plane's (the
    collar that sends a designed lens's rim light back)."""
    import jax.numpy as jnp

    rows, cols = 6, 7
    ext = (0.0, 7.0, 0.0, 6.0)  # unit samples
    y, x = np.mgrid[0:rows, 0:cols] + 0.5
    plane = 0.3 * x - 0.2 * y + 1.0
    px, py = rng.uniform(-1.5, 8.5, 300), rng.uniform(-1.5, 7.5, 300)
    expected = (0.3 * px - 0.2 * py + 1.0, 0.3, -0.2)
    field = jc.HeightField(plane, ext, "extrapolate")
    got = jc.internal.height_and_gradient(field, jnp.asarray(px), jnp.asarray(py))
    exact = ref.surface_height(plane, ext, "extrapolate", px, py)
    for a, b, c in zip(exact, got, expected, strict=True):
        np.testing.assert_allclose(a, c, atol=1e-12)
        np.testing.assert_allclose(np.asarray(b), c, atol=1e-12)
    _, slope, _ = ref.surface_height(plane, ext, "clamp", np.array([0.0]), np.array([3.0]))
    np.testing.assert_allclose(slope, -0.3 / 8, atol=1e-12)


@pytest.mark.parametrize("zenith", [0.0, 55.0, 80.0])
@pytest.mark.parametrize("boundary", ["periodic", "clamp", "extrapolate"])
def test_intersection_is_the_first_root_to_machine_precision(zenith, boundary, rng):
    """Steep, rough surface: the hit is a root of f(t) = z(t) - rest - H, and a dense scan
    of the ray before it stays above the surface (no earlier crossing was skipped)."""
    n = 24
    h = 0.08 * _waves(n, 1.0) + 0.02 * rng.normal(size=(n, n))
    surf = _Surface.build(h, EXT, boundary)
    z = math.radians(zenith)
    d = np.array([math.sin(z) * 0.8, math.sin(z) * 0.6, -math.cos(z)])
    cx, cy = rng.uniform(-0.2, 1.2, 300), rng.uniform(-0.2, 1.2, 300)
    t, hx, hy = intersect_surface(surf, 1.0, d, cx, cy)
    hit, ghx, ghy = ref.surface_height(h, EXT, boundary, cx + t * d[0], cy + t * d[1])
    # Newton stops within a few ulps of the bracket's span, which scales with the bound
    # range (twice as wide under extrapolate, whose padding reflects the rough edge)
    atol = 2e-14 * (surf.h_hi - surf.h_lo)
    np.testing.assert_allclose(t * d[2], hit, rtol=0, atol=atol)
    np.testing.assert_allclose(np.stack([hx, hy]), np.stack([ghx, ghy]), rtol=1e-12, atol=1e-12)
    t_top = surf.h_hi / d[2]
    s = np.linspace(0.0, 1.0, 2001)[:-2]
    tt = t_top + (t[:, None] - t_top) * s  # strictly before the hit
    above = (
        tt * d[2]
        - ref.surface_height(h, EXT, boundary, cx[:, None] + tt * d[0], cy[:, None] + tt * d[1])[0]
    )
    assert above.min() > 0.0


@pytest.mark.parametrize("rotation", [0.3, 1.1])
@pytest.mark.parametrize("boundary", ["periodic", "clamp", "extrapolate"])
def test_rotated_surface_height_matches_the_jax_side(rotation, boundary, rng):
    """Values and world-axis gradients of a rotated field, NumPy reference against JAX
    (float64), at random points inside and well outside the extent (and the Newton
    steps' kernel, `_height_and_slope`). Measured: at most 2e-14 (H) and 5e-13 (slopes
    of up to ~30) apart."""
    import jax.numpy as jnp

    from jaxcaustics.scene.surface import PaddedField, _height_and_slope

    h = rng.normal(size=(12, 9))
    ext = (-1.0, 2.0, 0.5, 2.5)
    px, py = rng.uniform(-3.0, 4.0, 400), rng.uniform(-2.0, 5.0, 400)
    expected = ref.surface_height(h, ext, boundary, px, py, rotation=rotation)
    field = jc.HeightField(h, ext, boundary, rotation=rotation)
    got = jc.internal.height_and_gradient(field, jnp.asarray(px), jnp.asarray(py))
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_allclose(np.asarray(a), b, rtol=0, atol=1e-10)
    # the Newton steps' own kernel: the height and the slope along a horizontal vector
    ax, ay = 0.6, -1.7
    h_newton, slope = _height_and_slope(
        PaddedField.of(field), jnp.asarray(px), jnp.asarray(py), ax, ay
    )
    np.testing.assert_allclose(np.asarray(h_newton), expected[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(
        np.asarray(slope), ax * expected[1] + ay * expected[2], rtol=0, atol=1e-9
    )
    # the gradient is along the world axes: central differences of the reference
    e = 1e-6
    fx = ref.surface_height(h, ext, boundary, px + e, py, rotation=rotation)[0]
    fx = (fx - ref.surface_height(h, ext, boundary, px - e, py, rotation=rotation)[0]) / (2 * e)
    np.testing.assert_allclose(expected[1], fx, atol=1e-6)


@pytest.mark.parametrize("boundary", ["periodic", "clamp", "extrapolate"])
def test_quarter_turn_is_a_rotated_sample_grid(boundary, rng):
    """rotation = +pi/2 (counter-clockwise seen from above, +x towards +y) is the field
    whose samples are ``np.rot90(h, k=-1)``: with row 0 at y_min (y up), k=-1 turns the
    array counter-clockwise in the world (it looks clockwise printed with row 0 on top)."""
    import jax.numpy as jnp

    h = rng.normal(size=(8, 8))
    ext = (0.0, 2.0, 1.0, 3.0)  # square extent, square pixels
    px, py = rng.uniform(-1.0, 3.0, 300), rng.uniform(0.0, 4.0, 300)
    turned = ref.surface_height(np.rot90(h, k=-1), ext, boundary, px, py)
    rotated = ref.surface_height(h, ext, boundary, px, py, rotation=np.pi / 2)
    for a, b in zip(rotated, turned, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11)
    x, y = jnp.asarray(px), jnp.asarray(py)
    jax_turned = jc.internal.height_and_gradient(
        jc.HeightField(np.rot90(h, k=-1), ext, boundary), x, y
    )
    jax_rotated = jc.internal.height_and_gradient(jc.HeightField(h, ext, boundary, np.pi / 2), x, y)
    for a, b in zip(jax_rotated, jax_turned, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-11)
    # and it is not the other quarter turn
    other = ref.surface_height(np.rot90(h, k=1), ext, boundary, px, py)
    assert np.abs(other[0] - rotated[0]).max() > 0.1


@pytest.mark.parametrize("boundary", ["periodic", "clamp", "extrapolate"])
def test_intersection_with_a_rotated_surface_is_the_first_root(boundary, rng):
    """As above, on a rotated field: the per-cell bounds hold along the field's own axes,
    so the march takes the light's direction in that frame."""
    n = 24
    h = 0.08 * _waves(n, 1.0) + 0.02 * rng.normal(size=(n, n))
    ext, rotation = (0.0, 1.0, 0.0, 0.8), 0.7
    surf = _Surface.build(h, ext, boundary, rotation)
    z = math.radians(55.0)
    d = np.array([math.sin(z) * 0.8, math.sin(z) * 0.6, -math.cos(z)])
    cx, cy = rng.uniform(-0.2, 1.2, 300), rng.uniform(-0.2, 1.2, 300)
    t, hx, hy = intersect_surface(surf, 1.0, d, cx, cy)
    hit, ghx, ghy = ref.surface_height(h, ext, boundary, cx + t * d[0], cy + t * d[1], rotation)
    atol = 2e-14 * (surf.h_hi - surf.h_lo)  # as above
    np.testing.assert_allclose(t * d[2], hit, rtol=0, atol=atol)
    np.testing.assert_allclose(np.stack([hx, hy]), np.stack([ghx, ghy]), rtol=1e-12, atol=1e-12)
    t_top = surf.h_hi / d[2]
    tt = t_top + (t[:, None] - t_top) * np.linspace(0.0, 1.0, 2001)[:-2]
    px, py = cx[:, None] + tt * d[0], cy[:, None] + tt * d[1]
    above = tt * d[2] - ref.surface_height(h, ext, boundary, px, py, rotation)[0]
    assert above.min() > 0.0


def test_rotated_periodic_field_does_not_wrap():
    """A rotated periodic field tiles the plane along its own axes, not the receiver's:
    the estimators pad the emission window and drop photons landing off the receiver
    instead of wrapping them. Flat water stays exactly 1, and the two estimators agree
    as well as unrotated (measured relative L1 after a 1-pixel blur, 16 photons per
    pixel axis: 0.17 %, unrotated 0.15 %; we require < 0.5 %)."""
    from jaxcaustics.reference import _water

    waves = _waves(32, 0.006)
    unrotated = _scene(waves, zenith=30.0, azimuth=25.0)
    scene = _scene(waves, zenith=30.0, azimuth=25.0, rotation=0.4)
    assert _water._whole_periods(_water._read_scene(unrotated))
    assert not _water._whole_periods(_water._read_scene(scene))
    flat = _scene(np.full((8, 8), 0.02), zenith=40.0, azimuth=10.0, rotation=0.4)
    for estimator in (ref.trace_water, ref.area_ratio_water):
        np.testing.assert_allclose(estimator(flat), 1.0, rtol=0, atol=1e-12)
    area = _blur(ref.area_ratio_water(scene, vertices_per_axis=4), 1.0, False)
    photons = _blur(ref.trace_water(scene, photons_per_axis=16), 1.0, False)
    assert area.max() > 1.5
    assert np.abs(photons - area).sum() / np.abs(area).sum() < 0.005


# --------------------------------------------------------------------------- 1. flat water


@pytest.mark.parametrize("estimator", [ref.trace_water, ref.area_ratio_water])
@pytest.mark.parametrize("boundary", ["periodic", "clamp"])
@pytest.mark.parametrize("zenith", [0.0, 30.0, 60.0])
@pytest.mark.parametrize("level", [0.0, 0.05])
def test_flat_water_gives_exactly_one(estimator, boundary, zenith, level):
    """Flat (also raised by a constant: the pattern only shifts) water: exactly 1.0."""
    scene = _scene(
        np.full((16, 20), level),
        (0.0, 1.0, 0.0, 0.8),
        zenith=zenith,
        azimuth=35.0,
        boundary=boundary,
        depth=0.7,
        shape=(12, 18),
    )
    image = estimator(scene)
    assert image.shape == (12, 18) and image.dtype == np.float64
    np.testing.assert_allclose(image, 1.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("estimator", [ref.trace_water, ref.area_ratio_water])
@pytest.mark.parametrize("zenith", [0.0, 30.0, 60.0])
def test_flat_water_with_fresnel_gives_the_transmittance(estimator, zenith):
    iors = (1.33, 1.5, 2.4)
    scene = _scene(
        np.zeros((8, 8)), zenith=zenith, azimuth=10.0, boundary="clamp", ior=iors, fresnel=True
    )
    image = estimator(scene)
    assert image.shape == (8, 8, 3)
    for c, n in enumerate(iors):
        np.testing.assert_allclose(image[..., c], _fresnel_flat(zenith, n), rtol=0, atol=1e-12)


def test_jitter_keeps_flat_exact_and_is_reproducible():
    flat = _scene(np.zeros((8, 8)), zenith=40.0, boundary="clamp")
    np.testing.assert_allclose(ref.trace_water(flat, jitter=True, seed=3), 1.0, atol=1e-12)
    wavy = _scene(_waves(16, 0.01), zenith=40.0)
    a = ref.trace_water(wavy, jitter=True, seed=3)
    np.testing.assert_array_equal(a, ref.trace_water(wavy, jitter=True, seed=3))
    assert np.abs(a - ref.trace_water(wavy, jitter=True, seed=4)).max() > 0
    assert np.abs(a - ref.trace_water(wavy)).max() > 0


# --------------------------------------------------------------------------- 2. energy


@pytest.mark.parametrize("estimator", [ref.trace_water, ref.area_ratio_water])
@pytest.mark.parametrize("zenith", [0.0, 40.0])
def test_periodic_surfaces_conserve_energy(estimator, zenith):
    """Strong caustics (peaks ~25x), oblique light, three dispersion channels: every photon
    wraps onto the receiver, so each channel's mean is 1 to rounding (measured: exactly)."""
    scene = _scene(_waves(32, 0.02), zenith=zenith, azimuth=30.0, ior=(1.2, 1.333, 1.6))
    image = estimator(scene)
    assert image.shape == (32, 32, 3)
    assert image.max() > 5.0 and image.min() < 0.5
    np.testing.assert_allclose(image.mean(axis=(0, 1)), 1.0, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- 3. agreement


@pytest.mark.parametrize(
    "heights, boundary, zenith",
    [
        (_waves(48, 0.008), "periodic", 0.0),
        (_waves(48, 0.008), "periodic", 35.0),
        (_bump(48), "clamp", 0.0),
        (_bump(48), "clamp", 35.0),
    ],
    ids=["sines-0", "sines-35", "bump-0", "bump-35"],
)
def test_photon_tracing_and_area_ratio_agree(heights, boundary, zenith):
    """Relative L1 difference after a 1-pixel Gaussian blur.

    Measured (48x48, caustic peaks 3.6x, 10.6x, 31x, 15x) for the photon tracer with p
    photons per pixel axis against the area-ratio estimator with 4 vertices per pixel
    axis: p = 4: 0.30-1.06 %, p = 8: 0.12-0.35 %, p = 16: 0.04-0.13 %; the area-ratio
    estimator itself moves by 0.10-0.27 % between 2 and 4 vertices per axis. The
    difference falls as ~1/p^1.5 (photon binning noise, which the blur averages) towards
    the area-ratio estimator's own discretisation, so there is no bias between the two: we
    require < 1 % at p = 8 (~3x the largest measured) and p = 16 at least twice as close
    as p = 4 (measured 7.7-8.4x).
    """
    periodic = boundary == "periodic"
    scene = _scene(heights, zenith=zenith, azimuth=25.0, boundary=boundary)
    area = _blur(ref.area_ratio_water(scene, vertices_per_axis=4), 1.0, periodic)

    def diff(p):
        photons = _blur(ref.trace_water(scene, photons_per_axis=p), 1.0, periodic)
        return np.abs(photons - area).sum() / np.abs(area).sum()

    assert diff(8) < 0.01
    assert diff(16) < 0.5 * diff(4)


# --------------------------------------------------------------------------- 4. weak lens


_LENS_MODES = ((1, 0, 1.0, 0.0), (1, 1, 0.6, 1.0), (0, 2, 0.4, 2.0))
_LENS_N = 24
_LENS_SIGMA = 1.5


def _lens_error(amplitude, photons_per_axis):
    """RMS of (E - 1 - prediction) / RMS of the prediction, both blurred alike."""
    n, depth, ior = _LENS_N, 1.0, 1.333
    c = 1.0 - 1.0 / ior
    x, y = _grid(n)
    scene = _scene(_waves(n, amplitude, _LENS_MODES), depth=depth, ior=ior)
    image = ref.trace_water(scene, photons_per_axis=photons_per_axis)
    # Prediction, per mode: Lap H = -(2 pi)^2 (kx^2 + ky^2) H; a pixel averages sin(2 pi k x)
    # by sinc(k dx) along each axis.
    h = 1.0 / n
    lap = sum(
        -((2 * np.pi) ** 2)
        * (kx * kx + ky * ky)
        * a
        * np.sinc(kx * h)
        * np.sinc(ky * h)
        * np.sin(2 * np.pi * (kx * x + ky * y) + p)
        for kx, ky, a, p in _LENS_MODES
    )
    predicted = -c * depth * amplitude * lap
    f = np.fft.fftfreq(n)
    gauss = np.exp(-2 * np.pi**2 * _LENS_SIGMA**2 * (f[:, None] ** 2 + f[None, :] ** 2))

    def blur(img):
        return np.real(np.fft.ifft2(np.fft.fft2(img) * gauss))

    predicted = blur(predicted)
    return np.linalg.norm(blur(image - 1.0) - predicted) / np.linalg.norm(predicted)


def test_weak_lens_limit():
    """Small waves at normal incidence: E ~= 1 - (1 - 1/n) * depth * Laplacian(H).

    Derivation: with d = (0, 0, -1) and the normal (-grad H, 1) / |.|, to first order in
    grad H the refracted direction is T = (1 - 1/n) grad H + (0, 0, -1) (vector Snell with
    eta = 1/n, cos_i ~= cos_t ~= 1: T = eta d + (eta - 1) n). The photon from C lands at
    G(C) ~= C + depth (1 - 1/n) grad H(C): a gradient map whose Jacobian determinant is
    det(I + depth (1 - 1/n) Hess H) ~= 1 + depth (1 - 1/n) Lap H, and the irradiance is its
    inverse, 1 - depth (1 - 1/n) Lap H. The relative error of (E - 1) is then O(E - 1)
    (second order in the amplitude) plus the Catmull-Rom interpolant's curvature error
    (~1.6 % on this 24x24 grid).

    Image and prediction are both blurred (sigma 1.5 px, an exact Fourier multiplier for the
    predicted sines): photons on a regular grid change a pixel only when they cross its
    edge, a quantisation error of order 1 / (p (E - 1)) per pixel that is high-frequency.

    Measured errors (amplitude / photons per axis):
        8e-3 / 32: 0.104, 4e-3 / 32: 0.053 (E - 1 up to 0.23, 0.12: error ~ E - 1, halving)
        2e-3 / 8, 16, 32, 64: 0.36, 0.108, 0.041, 0.032 (falls ~ 1/p^1.5, then saturates
        at the second-order + interpolation floor)
    """
    strong, weak = _lens_error(8e-3, 32), _lens_error(4e-3, 32)
    assert strong < 0.15 and weak < 0.08
    assert 1.6 < strong / weak < 2.4  # second order: halving the amplitude halves the error
    by_photons = [_lens_error(2e-3, p) for p in (8, 16, 32, 64)]
    assert by_photons[0] > 2.0 * by_photons[1] > 4.0 * by_photons[2]  # falls with photons
    assert 0.5 * by_photons[2] < by_photons[3] < 0.05  # ... until the floor: small


# --------------------------------------------------------------------------- 5. periodicity


@pytest.mark.parametrize("zenith", [0.0, 35.0])
def test_periodic_translations(zenith):
    n = 32
    heights = _waves(n, 0.015)
    base = ref.trace_water(_scene(heights, zenith=zenith, azimuth=20.0))
    assert base.max() > 3.0
    # The same surface described over an extent shifted by whole periods.
    moved = (1.0, 2.0, -2.0, -1.0)
    same = ref.trace_water(_scene(heights, moved, zenith=zenith, azimuth=20.0, receiver_extent=EXT))
    np.testing.assert_allclose(same, base, rtol=0, atol=1e-12)
    # The surface translated by (kx, ky) pixels: the image rolls by as much.
    kx, ky = 5, -3
    rolled = ref.trace_water(
        _scene(np.roll(heights, (ky, kx), axis=(0, 1)), zenith=zenith, azimuth=20.0)
    )
    np.testing.assert_allclose(rolled, np.roll(base, (ky, kx), axis=(0, 1)), rtol=0, atol=1e-12)
    # A receiver of two periods tiles the image; a pixel-aligned sub-receiver (padded
    # emission, no wrapping) crops it.
    two = ref.trace_water(
        _scene(
            heights,
            zenith=zenith,
            azimuth=20.0,
            receiver_extent=(0.5, 2.5, 0.0, 1.0),
            shape=(n, 2 * n),
        )
    )
    np.testing.assert_allclose(two, np.roll(np.tile(base, (1, 2)), -n // 2, axis=1), atol=1e-12)
    sub = ref.trace_water(
        _scene(
            heights,
            zenith=zenith,
            azimuth=20.0,
            receiver_extent=(0.25, 0.75, 0.125, 0.625),
            shape=(16, 16),
        )
    )
    np.testing.assert_allclose(sub, base[4:20, 8:24], atol=1e-12)


def test_automatic_margin_catches_all_light_for_clamp():
    """Oblique light moves the bump's caustic 0.4 m downstream, over the receiver's edge:
    photons from outside the emission window land on the receiver."""
    scene = _scene(_bump(32), zenith=40.0, azimuth=30.0, boundary="clamp")
    auto = ref.trace_water(scene)
    np.testing.assert_allclose(auto, ref.trace_water(scene, margin=2.0), atol=1e-12)
    # Light from beyond the receiver-sized emission window focused onto the receiver: the
    # same photons without padding cannot gain energy.
    assert auto.mean() > ref.trace_water(scene, margin=0.0).mean() + 0.005


# --------------------------------------------------------------------------- 6. TIR, inputs


@pytest.mark.parametrize("estimator", [ref.trace_water, ref.area_ratio_water])
@pytest.mark.parametrize("fresnel", [False, True])
def test_total_internal_reflection_loses_light(estimator, fresnel):
    """ior 0.7 (critical angle 44 deg), light at 30 deg, slopes up to 0.69: some TIR.

    Measured means: photons 0.815 (0.757 with Fresnel), area ratio 0.775 (0.728): the
    area-ratio estimator drops whole triangles with a TIR vertex, so it loses more at a
    coarse grid (0.775, 0.794, 0.805, 0.810 at 2, 4, 8, 16 vertices per axis).
    """
    scene = _scene(_waves(32, 0.03), zenith=30.0, azimuth=15.0, ior=0.7, fresnel=fresnel)
    image = estimator(scene)
    assert np.all(np.isfinite(image)) and image.min() >= 0.0
    assert 0.3 < image.mean() < 0.98
    flat = estimator(_scene(np.zeros((8, 8)), zenith=30.0, ior=0.7, fresnel=fresnel))
    np.testing.assert_allclose(flat, _fresnel_flat(30.0, 0.7) if fresnel else 1.0, atol=1e-12)


def test_total_internal_reflection_of_flat_water_gives_zero():
    scene = _scene(np.zeros((8, 8)), zenith=60.0, ior=0.7, boundary="clamp")
    np.testing.assert_array_equal(ref.trace_water(scene), 0.0)
    np.testing.assert_array_equal(ref.area_ratio_water(scene), 0.0)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda s: ref.trace_water(s, photons_per_axis=0), "photons_per_axis"),
        (lambda s: ref.trace_water(s, photons_per_axis=2.5), "photons_per_axis"),
        (lambda s: ref.trace_water(s, photons_per_axis=True), "photons_per_axis"),
        (lambda s: ref.trace_water(s, margin=-1.0), "margin"),
        (lambda s: ref.trace_water(s, margin=float("nan")), "margin"),
        (lambda s: ref.trace_water(s, margin="wide"), "margin"),
        (lambda s: ref.area_ratio_water(s, vertices_per_axis=0), "vertices_per_axis"),
        (lambda s: ref.area_ratio_water(s, samples_per_triangle=0), "samples_per_triangle"),
        (lambda s: ref.area_ratio_water(s, samples_per_triangle=8), "samples_per_triangle"),
        (lambda s: ref.trace_photons(s, [0.0, 1.0], [0.0]), "xs"),
        (lambda s: ref.trace_water(object()), "scene"),
        (lambda s: ref.surface_height(np.zeros(4), EXT, "periodic", 0.0, 0.0), "heights"),
        (lambda s: ref.surface_height(np.zeros((4, 4)), (0, 1, 0), "periodic", 0, 0), "extent"),
        (lambda s: ref.surface_height(np.zeros((4, 4)), (1, 0, 0, 1), "periodic", 0, 0), "extent"),
        (lambda s: ref.surface_height(np.zeros((4, 4)), EXT, "mirror", 0.0, 0.0), "boundary"),
        (lambda s: ref.surface_height(np.zeros((4, 4)), EXT, "clamp", 0, 0, np.nan), "rotation"),
        (lambda s: ref.surface_height(np.zeros((4, 4)), EXT, "clamp", 0, 0, [0, 1]), "rotation"),
        (lambda s: ref.surface_height(np.zeros((4, 4)), EXT, "clamp", 0, 0, "a"), "rotation"),
    ],
)
def test_bad_arguments_raise(call, match):
    with pytest.raises(ValueError, match=match):
        call(_scene(np.zeros((4, 4))))


def test_duck_typed_scene_is_validated():
    class Light:
        direction = np.array([0.0, 0.0, 1.0])  # travelling up

    scene = _scene(np.zeros((4, 4)))
    bad = type(
        "Scene",
        (),
        {
            k: getattr(scene, k)
            for k in ("surface", "receiver", "rest_depth", "ior", "iors", "fresnel")
        },
    )()
    bad.light = Light()
    with pytest.raises(ValueError, match="direction"):
        ref.trace_water(bad)


def test_trace_photons_reports_channels():
    scene = _scene(_waves(16, 0.01), zenith=60.0, ior=(1.3, 0.5))
    xs, ys = np.array([0.1, 0.5, 0.9]), np.array([0.2, 0.4, 0.6])
    gx, gy, tr, valid = ref.trace_photons(scene, xs, ys)
    assert gx.shape == gy.shape == tr.shape == valid.shape == (2, 3)
    assert valid[0].all() and not valid[1].any()  # ior 0.5: critical angle 30 deg, all TIR
    np.testing.assert_array_equal(tr[0], 1.0)
    np.testing.assert_array_equal(tr[1], 0.0)


def test_automatic_margin_warns_when_light_comes_from_too_far():
    """A ramp (slope 0.45) 1.5-3.5 m before a 1 m receiver, under 20 m of water, bends light
    ~2.2 m forward onto the receiver: past the automatic margin's cap (twice the receiver's
    side), so it warns; an explicit margin collects that light."""
    ext = (-4.0, 5.0, 0.0, 1.0)
    x = ext[0] + (np.arange(72) + 0.5) * 9.0 / 72
    ramp = np.tile(0.45 * np.clip(x + 3.5, 0.0, 2.0), (4, 1))
    scene = _scene(ramp, ext, depth=20.0, boundary="clamp", receiver_extent=EXT, shape=(8, 8))
    with pytest.warns(RuntimeWarning, match="margin"):
        capped = ref.trace_water(scene)
    wide = ref.trace_water(scene, margin=6.0)
    assert wide.mean() > capped.mean() + 0.1
    np.testing.assert_allclose(wide, ref.trace_water(scene, margin=8.0), atol=1e-12)
