"""Caustic spot lights (Liu, Dong, Bao & Peng 2008): the data type and its light planes.

A caustic spot light (CSL) is a light plane with an intensity image from which one ray
leaves every point ``p``; the ray from ``p`` at distance ``r = |p - c|`` from the plane's
origin ``c`` crosses the optical axis (``c`` along the unit normal ``a``) at distance
``f(r) = alpha / (1 + beta r)`` from ``c``. `SpotLights` holds a *set* of them as arrays
with a leading axis of length ``K`` (a fixed number of slots, so that sets for many light
directions stack and vectorise; unused slots have ``active = False`` and a black image).

Light-plane coordinates: ``u = (p - c) . frame_u``, ``v = (p - c) . (a x frame_u)``; the
image covers ``[-w, w]^2`` in ``(u, v)`` (``w = half_width``), rows along ``v``, columns
along ``u``, pixel ``(i, j)`` centred at ``u = -w + (j + 0.5) 2w / N``,
``v = -w + (i + 0.5) 2w / N``. The image holds *intensity*: power per unit light-plane
area (the library's irradiance units, so a ray bundle that left a horizontal area ``A``
of flat light carries ``A``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..._checks import (
    check_array,
    check_bool,
    check_fits,
    check_int,
    check_memory_limit,
    check_number,
)
from ...scene.ellipsoid import Ellipsoid
from ...scene.scene import (
    PlaneReceiver,
    as_float_array,
    check_finite,
    check_sequence_of,
    is_concrete,
)
from .exit_rays import ellipsoid_hit


class SpotLights(eqx.Module):
    """A set of ``K`` caustic spot lights (Liu et al. 2008), as arrays.

    **Arguments** (leading axis ``K`` on every field):

    - `origin`: ``(K, 3)`` light-plane origins ``c``, metres.
    - `axis`: ``(K, 3)`` unit optical axes ``a`` (the light plane's normal; rays go
      towards ``+a``). Normalised on construction.
    - `frame_u`: ``(K, 3)`` unit in-plane direction of the image's columns
      (perpendicular to `axis`; made so on construction).
    - `alpha`: ``(K,)`` focus distance of the central ray, metres, ``> 0`` (``inf``:
      collimated).
    - `beta`: ``(K,)`` focus law slope, 1/metres, ``>= 0`` (0: a plain spot light).
    - `half_width`: ``(K,)`` the image covers ``[-w, w]^2`` of the light plane, metres.
    - `image`: ``(K, N, N)`` intensity (power per unit light-plane area), ``>= 0``.
    - `active`: ``(K,)`` bool, which slots hold a light (default: all).

    ``lights[k]`` is the one-light set of slot ``k``; ``len(lights)`` is ``K``.
    """

    origin: Float[Array, "K 3"]
    axis: Float[Array, "K 3"]
    frame_u: Float[Array, "K 3"]
    alpha: Float[Array, " K"]
    beta: Float[Array, " K"]
    half_width: Float[Array, " K"]
    image: Float[Array, "K N N"]
    active: Bool[Array, " K"]

    def __init__(self, origin, axis, frame_u, alpha, beta, half_width, image, active=None):
        origin = as_float_array(origin, "origin")
        if origin.ndim != 2 or origin.shape[-1] != 3:
            raise ValueError(f"`origin` must have shape (K, 3), got {origin.shape}")
        k = origin.shape[0]
        axis = as_float_array(axis, "axis")
        frame_u = as_float_array(frame_u, "frame_u")
        for name, arr in (("axis", axis), ("frame_u", frame_u)):
            if arr.shape != (k, 3):
                raise ValueError(f"`{name}` must have shape ({k}, 3), got {arr.shape}")
        alpha = as_float_array(alpha, "alpha")
        beta = as_float_array(beta, "beta")
        half_width = as_float_array(half_width, "half_width")
        for name, arr in (("alpha", alpha), ("beta", beta), ("half_width", half_width)):
            if arr.shape != (k,):
                raise ValueError(f"`{name}` must have shape ({k},), got {arr.shape}")
        image = as_float_array(image, "image")
        if (
            image.ndim != 3
            or image.shape[0] != k
            or image.shape[1] != image.shape[2]
            or image.shape[1] < 1
        ):
            raise ValueError(f"`image` must have shape ({k}, N, N), N >= 1, got {image.shape}")
        if active is None:
            active = jnp.ones((k,), bool)
        if not isinstance(active, jax.Array):
            active = np.asarray(active)
        if active.shape != (k,) or active.dtype != np.bool_:
            raise ValueError(
                f"`active` must be booleans of shape ({k},), got {active.dtype} {active.shape}"
            )
        active = jnp.asarray(active)
        for name, arr in (("origin", origin), ("axis", axis), ("frame_u", frame_u)):
            check_finite(arr, name)
        for name, arr in (("beta", beta), ("half_width", half_width), ("image", image)):
            check_finite(arr, name)
        if is_concrete(alpha):
            a = np.asarray(alpha)
            if np.any(np.isnan(a)) or np.any(a <= 0):
                raise ValueError(f"`alpha` must be positive (inf: collimated), got {a.tolist()}")
        if is_concrete(beta) and np.any(np.asarray(beta) < 0):
            raise ValueError(f"`beta` must be >= 0, got {np.asarray(beta).tolist()}")
        if is_concrete(half_width) and np.any(np.asarray(half_width) <= 0):
            raise ValueError("`half_width` must be positive")
        if is_concrete(image) and np.any(np.asarray(image) < 0):
            raise ValueError("`image` must be >= 0 (an intensity)")
        if is_concrete(axis) and np.any(np.linalg.norm(np.asarray(axis), axis=-1) == 0):
            raise ValueError("`axis` must be non-zero")
        axis = axis / jnp.linalg.norm(axis, axis=-1, keepdims=True)
        frame_u = frame_u - jnp.sum(frame_u * axis, -1, keepdims=True) * axis
        if is_concrete(frame_u) and np.any(np.linalg.norm(np.asarray(frame_u), axis=-1) < 1e-9):
            raise ValueError("`frame_u` must not be parallel to `axis`")
        self.origin = origin
        self.axis = axis
        self.frame_u = frame_u / jnp.linalg.norm(frame_u, axis=-1, keepdims=True)
        self.alpha = alpha
        self.beta = beta
        self.half_width = half_width
        self.image = image
        self.active = active

    def __len__(self) -> int:
        return self.origin.shape[0]

    def __getitem__(self, k) -> SpotLights:
        index = jnp.atleast_1d(jnp.asarray(k)) if isinstance(k, int) else k
        return jax.tree.map(lambda a: a[index], self)

    @property
    def frame_v(self) -> Float[Array, "K 3"]:
        """Unit in-plane direction of the image's rows: ``axis x frame_u``."""
        return jnp.cross(self.axis, self.frame_u)

    @property
    def resolution(self) -> int:
        """``N``, the image's side in pixels."""
        return self.image.shape[-1]

    def power(self) -> Float[Array, " K"]:
        """Power each light emits: the image integrated over its light plane."""
        n = self.resolution
        return jnp.sum(self.image, axis=(-2, -1)) * (2 * self.half_width / n) ** 2


def sample_light_plane(lights: SpotLights, u, v):
    """Bilinear lookup of each light's intensity at light-plane coordinates ``(u, v)``.

    `u`, `v`: ``(..., K)`` metres. **Returns** ``(..., K)``: the intensity, 0 outside the
    image (the lookup fades to 0 over the outer half pixel, so the value is continuous).
    """
    n = lights.resolution
    w = lights.half_width
    x = (u + w) * (n / (2 * w)) - 0.5  # column coordinate
    y = (v + w) * (n / (2 * w)) - 0.5
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx = x - x0
    fy = y - y0
    x0 = x0.astype(jnp.int32)
    y0 = y0.astype(jnp.int32)
    k = jnp.broadcast_to(jnp.arange(len(lights)), x0.shape)

    def tap(i, j):
        inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        value = lights.image[k, jnp.clip(i, 0, n - 1), jnp.clip(j, 0, n - 1)]
        return jnp.where(inside, value, 0.0)

    return (1 - fy) * ((1 - fx) * tap(y0, x0) + fx * tap(y0, x0 + 1)) + fy * (
        (1 - fx) * tap(y0 + 1, x0) + fx * tap(y0 + 1, x0 + 1)
    )


# --------------------------------------------------------------------------- evaluation


class SpotLightRays(eqx.Module):
    """The caustic spot light rays that reach a set of points (up to three per light).

    Shapes: ``P`` points, ``K`` lights, 3 candidate rays per light (Liu et al.'s radii
    ``r1, r2`` of case (i) and ``r3`` of case (ii)).

    - `irradiance`: ``(P, K, 3)`` flux density each ray brings to a surface facing it
      (perpendicular to the ray), in the lights' intensity units; 0 where not `valid`.
    - `direction`: ``(P, K, 3, 3)`` unit direction of travel of each ray.
    - `source`: ``(P, K, 3, 3)`` the point ``p`` of the light plane each ray leaves from.
    - `valid`: ``(P, K, 3)`` the ray exists, starts inside the light's image and the light
      is active.
    """

    irradiance: Float[Array, "P K 3"]
    direction: Float[Array, "P K 3 3"]
    source: Float[Array, "P K 3 3"]
    valid: Bool[Array, "P K 3"]


def _safe_sqrt(x):
    """``sqrt(max(x, 0))`` with a finite derivative everywhere (0 where ``x <= 0``)."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def _safe_div(num, den, ok):
    """``num / den`` where `ok`, else ``inf``, with finite derivatives everywhere."""
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), jnp.inf)


def _radii(kappa, beta, z, rho):
    """Light-plane radii of the rays through a point at distance `z` along the axis and
    `rho` from it (Liu et al. Eqs. 2-3), written with ``kappa = 1 / alpha`` and in the
    forms free of cancellation, so that ``beta = 0``, ``alpha = inf`` and ``rho = 0`` need
    no special case. **Returns** ``(r (..., 3), exists (..., 3))``; ``r = inf`` where a
    root does not exist.

    With ``g = 1 - kappa z`` and ``A = kappa beta z``: case (i) (the point lies before the
    ray's focus) solves ``A r^2 - g r + rho = 0``, two roots when ``g > 0`` and
    ``g^2 > 4 A rho``: ``r1 = 2 rho / (g + sqrt(d1))``, ``r2 = (g + sqrt(d1)) / (2 A)``;
    case (ii) (past the focus) solves ``A r^2 - g r - rho = 0``, one positive root
    ``r3 = (g + sqrt(d2)) / (2 A)`` if ``g > 0``, else ``2 rho / (sqrt(d2) - g)``.
    """
    g = 1.0 - kappa * z
    a = kappa * beta * z
    d1 = g * g - 4.0 * a * rho
    s1 = _safe_sqrt(d1)
    case_i = (g > 0) & (d1 >= 0)
    r1 = _safe_div(2.0 * rho, g + s1, case_i & (g + s1 > 0))
    r2 = _safe_div(g + s1, 2.0 * a, case_i & (a > 0))
    s2 = _safe_sqrt(g * g + 4.0 * a * rho)
    r3 = jnp.where(
        g > 0,
        _safe_div(g + s2, 2.0 * a, a > 0),
        _safe_div(2.0 * rho, s2 - g, s2 - g > 0),
    )
    r = jnp.stack([r1, r2, r3], axis=-1)
    exists = jnp.isfinite(r) & (z > 0)[..., None]
    return jnp.where(exists, r, 0.0), exists


def _area_ratio(kappa, beta, z, r):
    """Liu et al.'s intensity correction ``sigma = |h h' / r|`` (Eq. 4) with
    ``h(r) = r (f(r) - z) / f(r)``, computed as ``|(h / r) h'|`` so it is finite at
    ``r = 0`` (its limit there, ``(1 - z / alpha)^2``, is the central ray's)."""
    g = (1.0 - kappa * z)[..., None]
    kbz = (kappa * beta * z)[..., None]
    return jnp.abs((g - kbz * r) * (g - 2.0 * kbz * r))


def evaluate_spot_lights(
    lights: SpotLights,
    points: Float[Array, "P 3"],
    *,
    max_gain: float = 1e4,
    axis_epsilon: float = 1e-9,
    intensity_correction: bool = True,
    memory_limit: int | None = None,
) -> SpotLightRays:
    """Evaluate caustic spot lights at points (Liu et al. 2008, Sections 2.2 and 2.3).

    For each point ``x`` and light: ``z``, ``rho`` = distance of ``x`` along and from the
    optical axis; the up to three light-plane radii of the rays through ``x`` (`_radii`);
    each ray's source ``p = c + r u`` (``u`` the unit direction of ``x`` away from the
    axis; ``p = c - r u`` for ``r3``, a ray that crossed the axis before ``x``) and
    direction (towards the axis point ``c + f(r) a``); the bilinear lookup of the image
    at ``p`` (0 outside it: the ray is dropped); the intensity correction
    ``sigma`` (`_area_ratio`). A ray's flux density perpendicular to itself is
    ``I(p) / (sigma (e . a))``: ``I / sigma`` crosses the plane through ``x`` parallel to
    the light plane, whose area projects onto the ray's cross section by ``e . a``.

    **Focus and axis** (where the paper perturbs points by an epsilon): the ring of rays
    focused exactly at an axis point and the fold where two roots merge are true caustics
    of the ray model, with ``sigma -> 0``. ``sigma`` is replaced by
    ``sqrt(sigma^2 + max_gain^-2)``, so a ray's flux density is at most `max_gain` times
    its light-plane intensity over ``e . a`` (and within 1 part in ``2 (max_gain
    sigma)^2`` of the exact value wherever ``sigma >> 1 / max_gain``). ``rho`` is
    replaced by ``sqrt(rho^2 + axis_epsilon^2)`` (metres) so that values and derivatives
    are smooth across the axis; on the axis itself the (ill-defined) side direction is
    the light's `frame_u`. ``beta = 0`` (a plain spot light) and ``alpha = inf``
    (collimated) are exact special cases of the formulas, not limits.

    **Arguments:**

    - `lights`: a `SpotLights` set of ``K`` lights.
    - `points`: ``(P, 3)`` points in metres.
    - `max_gain`: bound on the intensity correction ``1 / sigma`` (> 0).
    - `axis_epsilon`: smoothing radius around the axis, metres (> 0).
    - `intensity_correction`: apply Eq. 4 (default); ``False`` gives the uncorrected
      rendering of the paper's Fig. 6 (``sigma = 1``).
    - `memory_limit`: bytes the evaluation may take (default 1 GiB; `point_bytes` per
      point and light): more points times lights raise a `ValueError` first.

    **Returns:** `SpotLightRays` with ``(P, K, 3)`` fields.
    """
    options = _check_options(lights, max_gain, axis_epsilon, intensity_correction)
    points = check_array(points, "points", (None, 3))
    pairs = points.shape[0] * len(lights)
    check_fits(
        pairs * point_bytes(points.dtype),
        check_memory_limit(memory_limit),
        f"evaluating {len(lights)} lights at {points.shape[0]} points",
        "lower the number of `points`",
    )
    return _evaluate(lights, points, *options)


def _evaluate(lights, points, max_gain, axis_epsilon, intensity_correction) -> SpotLightRays:
    """`evaluate_spot_lights` once its arguments are checked."""
    dtype = jnp.result_type(points.dtype, lights.origin.dtype)
    d = points[:, None, :] - lights.origin[None]  # (P, K, 3)
    z = jnp.sum(d * lights.axis, axis=-1)
    side = d - z[..., None] * lights.axis
    rho2 = jnp.sum(side * side, axis=-1)
    rho = jnp.sqrt(rho2 + jnp.asarray(axis_epsilon, dtype) ** 2)
    off_axis = rho2 > (axis_epsilon * 1e-3) ** 2
    unit_side = jnp.where(
        off_axis[..., None],
        side / jnp.sqrt(jnp.where(off_axis, rho2, 1.0))[..., None],
        lights.frame_u,
    )
    kappa = 1.0 / lights.alpha
    r, exists = _radii(kappa, lights.beta, z, rho)  # (P, K, 3)
    # before its focus (case (i)) a ray comes from the point's side of the axis; past it
    # (case (ii), r3) it has crossed the axis and comes from the opposite side
    side_of_source = jnp.array([1.0, 1.0, -1.0], dtype)[:, None] * unit_side[:, :, None, :]
    source = lights.origin[None, :, None, :] + r[..., None] * side_of_source
    # direction towards c + f(r) a, scaled by 1 / f(r): a - r kappa (1 + beta r) u
    slope = r * kappa[:, None] * (1.0 + lights.beta[:, None] * r)
    direction = lights.axis[None, :, None, :] - slope[..., None] * side_of_source
    cos_axis = 1.0 / jnp.sqrt(1.0 + slope * slope)
    direction = direction * cos_axis[..., None]
    u = jnp.sum((source - lights.origin[:, None, :]) * lights.frame_u[:, None, :], -1)
    v = jnp.sum((source - lights.origin[:, None, :]) * lights.frame_v[:, None, :], -1)
    intensity = jnp.stack(
        [sample_light_plane(lights, u[..., j], v[..., j]) for j in range(3)], axis=-1
    )
    w = lights.half_width[:, None]
    inside = (jnp.abs(u) <= w) & (jnp.abs(v) <= w)
    valid = exists & inside & lights.active[:, None]
    if intensity_correction:
        sigma = _area_ratio(kappa, lights.beta, z, r)
        sigma = jnp.sqrt(sigma * sigma + (1.0 / max_gain) ** 2)
    else:
        sigma = jnp.ones_like(r)
    irradiance = jnp.where(valid, intensity / (sigma * cos_axis), 0.0)
    return SpotLightRays(irradiance, direction, source, valid)


# --------------------------------------------------------------------------- shading


POINT_FLOATS = 48
"""Numbers one point takes while it is shaded by one light (the rays' fields and XLA's
temporaries: 42 measured in float64, rounded up): memory is ``POINT_FLOATS`` times the
dtype's size per point (`shade_points`, `render_spot_lights`) or per point and light
(`evaluate_spot_lights`)."""


def point_bytes(dtype=jnp.float64) -> int:
    """Memory of one point (per light for `evaluate_spot_lights`), bytes."""
    return POINT_FLOATS * jnp.dtype(dtype).itemsize


def _check_options(lights, max_gain, axis_epsilon, intensity_correction) -> tuple:
    """`lights` checked to be a `SpotLights`; ``(max_gain, axis_epsilon,
    intensity_correction)`` checked and as Python scalars."""
    if not isinstance(lights, SpotLights):
        raise ValueError(f"`lights` must be a SpotLights, got {type(lights).__name__}")
    return (
        check_number(max_gain, "max_gain", low=0.0, low_open=True),
        check_number(axis_epsilon, "axis_epsilon", low=0.0, low_open=True, unit="metres"),
        check_bool(intensity_correction, "intensity_correction"),
    )


def _shading_number(value, name: str, high: float):
    """`value` unchanged (an array stays a differentiable leaf), once checked to be a
    number in ``[0, high]`` (unless traced)."""
    if not isinstance(value, jax.core.Tracer):
        check_number(value, name, low=0.0, high=high)
    return value


class Lambertian(eqx.Module):
    """A matte receiver: radiance ``albedo / pi x irradiance`` in every direction
    (`albedo` in ``[0, 1]``)."""

    albedo: float = 1.0

    def __init__(self, albedo=1.0):
        self.albedo = _shading_number(albedo, "albedo", 1.0)


class Glossy(eqx.Module):
    """A glossy receiver (normalised Blinn-Phong) seen from the point `eye`.

    Radiance towards `eye`: ``albedo / pi E + specular (m + 8) / (8 pi) sum_k E_k
    (n . h_k)^m``, ``E_k`` the irradiance ray ``k`` brings, ``h_k`` the half vector
    between the directions to the light ray's source and to the eye, ``m`` the
    `shininess`. Only the caustic rays' directions are needed: the reason Liu et al.
    keep them. `eye`: ``(3,)`` metres; `albedo`, `specular` in ``[0, 1]``; `shininess`
    in ``[0, 1e6]``.
    """

    eye: Float[Array, 3]
    albedo: float = 0.5
    specular: float = 0.5
    shininess: float = 40.0

    def __init__(self, eye, albedo=0.5, specular=0.5, shininess=40.0):
        eye = as_float_array(eye, "eye")
        if eye.shape != (3,):
            raise ValueError(f"`eye` must have shape (3,), got {eye.shape}")
        check_finite(eye, "eye")
        self.eye = eye
        self.albedo = _shading_number(albedo, "albedo", 1.0)
        self.specular = _shading_number(specular, "specular", 1.0)
        self.shininess = _shading_number(shininess, "shininess", 1e6)


def _segment_blocked(start, end, occluder) -> Bool[Array, "..."]:
    """Whether the segments ``start -> end`` (``(..., 3)``) cross an `Ellipsoid` occluder
    (or start inside it)."""
    shape = jnp.broadcast_shapes(start.shape, end.shape)
    start = jnp.broadcast_to(start, shape).reshape(-1, 3)
    step = jnp.broadcast_to(end, shape).reshape(-1, 3) - start
    inside = jnp.zeros(start.shape[:1], bool)
    t, hit, _ = ellipsoid_hit(occluder, start, step, inside)
    return (hit & (t < 1.0)).reshape(shape[:-1])


def shade_points(
    lights: SpotLights,
    points: Float[Array, "P 3"],
    normals: Float[Array, "P 3"],
    *,
    shading: Lambertian | Glossy | None = None,
    occluders=(),
    max_gain: float = 1e4,
    axis_epsilon: float = 1e-9,
    intensity_correction: bool = True,
    memory_limit: int | None = None,
) -> Float[Array, " P"]:
    """Light arriving at surface points from a set of caustic spot lights.

    Each light's rays are found with `evaluate_spot_lights`; a ray blocked by an
    occluder between its source on the light plane and the point (Liu et al.'s Fig. 10:
    an analytic test per occluder ellipsoid or sphere) brings nothing; a ray reaching the
    back of the surface (``e . n >= 0``) neither. Lights are added one at a time (a scan),
    so memory grows with ``P``, not ``P x K``.

    **Arguments:**

    - `lights`: ``K`` caustic spot lights.
    - `points`, `normals`: ``(P, 3)`` positions (metres) and unit normals.
    - `shading`: ``None`` (default): the irradiance ``E = sum_k E_k max(0, -e_k . n)``;
      `Lambertian` or `Glossy`: the radiance they send (towards `Glossy.eye`).
    - `occluders`: opaque `Ellipsoid` objects (spheres: `Ellipsoid.sphere`).
    - `max_gain`, `axis_epsilon`, `intensity_correction`: see `evaluate_spot_lights`.
    - `memory_limit`: bytes the shading may take (default 1 GiB; `point_bytes` per
      point): more points raise a `ValueError` first.

    **Returns:** ``(P,)``.
    """
    arguments = _shading_arguments(
        lights, shading, occluders, max_gain, axis_epsilon, intensity_correction
    )
    points = check_array(points, "points", (None, 3))
    normals = check_array(normals, "normals", (None, 3))
    if normals.shape != points.shape:
        raise ValueError(
            f"`normals` must have the shape of `points` {points.shape}, got {normals.shape}"
        )
    if is_concrete(normals) and np.any(np.sum(np.asarray(normals) ** 2, axis=-1) == 0):
        raise ValueError("`normals` must be non-zero (unit normals)")
    check_fits(
        points.shape[0] * point_bytes(jnp.result_type(points.dtype, lights.origin.dtype)),
        check_memory_limit(memory_limit),
        f"shading {points.shape[0]} points",
        "lower the number of `points`",
    )
    return _shade_points(lights, points, normals, *arguments)


def _shading_arguments(lights, shading, occluders, max_gain, axis_epsilon, intensity_correction):
    """The arguments `shade_points` and `render_spot_lights` share, checked: ``(shading,
    occluders (a tuple), options)``."""
    options = _check_options(lights, max_gain, axis_epsilon, intensity_correction)
    if shading is not None and not isinstance(shading, (Lambertian, Glossy)):
        raise ValueError(f"`shading` must be None, Lambertian or Glossy, got {shading!r}")
    return shading, check_sequence_of(occluders, "occluders", Ellipsoid), options


@eqx.filter_jit
def _shade_points(lights, points, normals, shading, occluders, options):
    """`shade_points`, compiled once per shape and set of options: a scan over the
    lights whose inactive slots skip the work (`lax.cond`)."""
    max_gain, axis_epsilon, intensity_correction = options
    dtype = jnp.result_type(points.dtype, lights.origin.dtype)
    zeros = jnp.zeros(points.shape[:1], dtype)

    def contribution(light):
        light = jax.tree.map(lambda a: a[None], light)
        rays = _evaluate(light, points, max_gain, axis_epsilon, intensity_correction)
        e = rays.direction[:, 0]  # (P, 3 rays, 3)
        cos = jnp.maximum(-jnp.sum(e * normals[:, None, :], axis=-1), 0.0)
        arriving = rays.irradiance[:, 0] * cos  # (P, 3)
        for occ in occluders:
            blocked = _segment_blocked(rays.source[:, 0], points[:, None, :], occ)
            arriving = jnp.where(blocked, 0.0, arriving)
        if isinstance(shading, Glossy):
            to_eye = shading.eye - points
            to_eye = to_eye / jnp.linalg.norm(to_eye, axis=-1, keepdims=True)
            half = to_eye[:, None, :] - e
            half = half / jnp.linalg.norm(half, axis=-1, keepdims=True)
            n_h = jnp.maximum(jnp.sum(half * normals[:, None, :], axis=-1), 0.0)
            lobe = shading.specular * (shading.shininess + 8) / (8 * jnp.pi)
            value = shading.albedo / jnp.pi * arriving + lobe * arriving * n_h**shading.shininess
        elif isinstance(shading, Lambertian):
            value = shading.albedo / jnp.pi * arriving
        else:
            value = arriving
        return jnp.sum(value, axis=-1).astype(dtype)

    def one_light(total, light):
        added = jax.lax.cond(light.active, contribution, lambda _: zeros, light)
        return total + added, None

    total, _ = jax.lax.scan(one_light, zeros, lights)
    return total


def receiver_points(receiver, samples: int = 1) -> Float[Array, "S R C 3"]:
    """Sample points of a `PlaneReceiver`'s pixels: ``samples x samples`` per pixel on a
    regular sub-grid (``samples = 1``: the pixel centres). **Returns**
    ``(samples^2, rows, cols, 3)`` on ``z = 0``."""
    samples = check_int(samples, "samples", 1)
    x0, x1, y0, y1 = receiver.extent
    rows, cols = receiver.shape
    dtype = receiver.extent.dtype
    sub = (jnp.arange(samples, dtype=dtype) + 0.5) / samples
    xs = x0 + (jnp.arange(cols, dtype=dtype)[None, :] + sub[:, None]) * (x1 - x0) / cols
    ys = y0 + (jnp.arange(rows, dtype=dtype)[None, :] + sub[:, None]) * (y1 - y0) / rows
    x = jnp.broadcast_to(xs[None, :, None, :], (samples, samples, rows, cols))
    y = jnp.broadcast_to(ys[:, None, :, None], (samples, samples, rows, cols))
    pts = jnp.stack([x, y, jnp.zeros_like(x)], axis=-1)
    return pts.reshape(samples * samples, rows, cols, 3)


def render_spot_lights(
    lights: SpotLights,
    receiver,
    *,
    samples: int = 2,
    shading: Lambertian | Glossy | None = None,
    occluders=(),
    max_gain: float = 1e4,
    axis_epsilon: float = 1e-9,
    intensity_correction: bool = True,
    memory_limit: int | None = None,
) -> Float[Array, "rows cols"]:
    """Render a set of caustic spot lights on a `PlaneReceiver` (the plane ``z = 0``,
    normal ``+z``), averaging ``samples x samples`` points per pixel (a caustic is
    sharper than a pixel; the reference bins photons over whole pixels).

    See `shade_points` for `shading`, `occluders`, `max_gain`, `axis_epsilon` and
    `intensity_correction`. `memory_limit`: bytes the rendering may take (default 1 GiB;
    `point_bytes` per sample point, ``rows x cols x samples^2`` of them): a larger
    receiver raises a `ValueError` first.
    **Returns** ``(rows, cols)``: irradiance in the lights' intensity units (or radiance
    with a `shading` model).
    """
    arguments = _shading_arguments(
        lights, shading, occluders, max_gain, axis_epsilon, intensity_correction
    )
    if not isinstance(receiver, PlaneReceiver):
        raise ValueError(f"`receiver` must be a PlaneReceiver, got {type(receiver).__name__}")
    samples = check_int(samples, "samples", 1)
    rows, cols = receiver.shape
    dtype = jnp.result_type(receiver.extent.dtype, lights.origin.dtype)
    check_fits(
        rows * cols * samples**2 * point_bytes(dtype),
        check_memory_limit(memory_limit),
        f"rendering {rows} x {cols} pixels at {samples} x {samples} `samples`",
        "lower `samples` or the receiver's `shape`",
    )
    pts = receiver_points(receiver, samples)
    flat = pts.reshape(-1, 3)
    normals = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], flat.dtype), flat.shape)
    values = _shade_points(lights, flat, normals, *arguments)
    return values.reshape(samples**2, rows, cols).mean(axis=0)
