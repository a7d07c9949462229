"""The focus law of a caustic spot light fitted to a ray bundle (Liu et al. 2008,
Sect. 3.1.2, Eq. 5; step 4 of the spot-light fit, `fit.py`): the per-ray error
`focus_law_error` and its minimisation `fit_focus_law` over ``alpha``, ``beta`` and the
light plane's offset ``ell``."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .fit_common import _floats, _plane_hits, _safe_norm, _tiny

ALPHA_MAX = 1e8
"""Largest ``alpha`` a fit returns, in units of ``size`` (a collimated bundle's focus)."""

BETA_START = 1e-6
"""Smallest ``beta`` a fit starts from, in units of ``1 / size``: ``beta = s^2`` has a
stationary point at ``s = 0``, so the optimisation starts a little off it."""

ELL_BOUND = 1.0
"""The light plane stays within ``ELL_BOUND x size`` of the bundle axis origin ``b``
(the foot of the bundle's mean ray origin): ``|ell| <= ELL_BOUND size``. Eq. 5 alone
often keeps improving, slowly, as the plane recedes upstream (a glass ball's bundle: 100x
lower cost at 8 sizes than at 0), which would leave a huge, coarse image and light the
space between the plane and the object that the bundle never reached."""

ELL_GRID = 33
"""Plane offsets tried for the initial guess: ``ELL_GRID`` values spanning
``[-ELL_BOUND, ELL_BOUND] size``."""


def _eq5_terms(origin, direction, axis_point, axis, kappa, gamma, ell, width):
    """Per-ray pieces of Eq. 5 for the CSL with ``1 / alpha = kappa``,
    ``beta / alpha = gamma`` and ``c = axis_point + ell axis``: ``d - e`` ``(R, 3)`` and
    ``t1^2 + t2^2`` ``(R,)``. Uses ``e = unit(a - (kappa + gamma r)(p - c))``, which is
    ``unit(c + f(r) a - p)`` divided by ``f(r) > 0``, finite even for collimated lights."""
    c = axis_point + ell * axis
    p, t, _ = _plane_hits(origin, direction, c, axis)
    v = p - c
    r = _safe_norm(v)
    e = axis - (kappa + gamma * r)[:, None] * v
    e = e / jnp.linalg.norm(e, axis=-1, keepdims=True)
    t1 = jnp.abs(t)
    t2 = t1 + width
    return direction - e, t1 * t1 + t2 * t2


def _unpack(x, size):
    """``(kappa, gamma, ell)`` from the optimisation variables
    ``x = (log(alpha / size), sqrt(beta size), arcsin(ell / (ELL_BOUND size)))``: any
    ``x`` gives ``alpha > 0``, ``beta >= 0`` and ``|ell| <= ELL_BOUND size`` (the
    bounded-parameter transform of MINUIT)."""
    log_alpha = jnp.minimum(x[0], math.log(ALPHA_MAX))
    kappa = jnp.exp(-log_alpha) / size
    beta = x[1] ** 2 / size
    return kappa, kappa * beta, ELL_BOUND * size * jnp.sin(x[2])


def _pack(alpha, beta, ell, size):
    """Inverse of `_unpack`, starting off its stationary points: ``beta`` at least
    ``BETA_START / size``, ``|ell|`` at most 0.99 of its bound."""
    beta = jnp.maximum(beta, BETA_START / size)
    ell = jnp.clip(ell / (ELL_BOUND * size), -0.99, 0.99)
    return jnp.stack([jnp.log(alpha / size), jnp.sqrt(beta * size), jnp.arcsin(ell)])


def focus_law_error(origin, direction, axis_point, axis_direction, alpha, beta, ell, *, size):
    """Per-ray Eq. 5 error ``E = (t1^2 + t2^2) |d - e|^2`` ``(R,)``, metres^2.

    - `origin`, `direction`: ``(R, 3)`` bundle rays ``q``, ``d`` (unit directions).
    - `axis_point`, `axis_direction`: ``(3,)`` the axis origin ``b`` and unit axis ``a``.
    - `alpha` (metres), `beta` (1/metres), `ell` (metres): the CSL, ``c = b + ell a``.
    - `size`: the object's size; ``w = 4 size`` in ``t2 = t1 + w``.
    """
    origin, direction, axis_point, axis_direction, alpha, beta, ell, size = _floats(
        origin, direction, axis_point, axis_direction, alpha, beta, ell, size
    )
    diff, t_sq = _eq5_terms(
        origin, direction, axis_point, axis_direction, 1 / alpha, beta / alpha, ell, 4 * size
    )
    return t_sq * jnp.sum(diff * diff, axis=-1)


def _eq5_cost(origin, direction, weight, axis_point, axis, kappa, gamma, ell, width):
    diff, t_sq = _eq5_terms(origin, direction, axis_point, axis, kappa, gamma, ell, width)
    return jnp.sum(weight * t_sq * jnp.sum(diff * diff, axis=-1)), jnp.sum(weight * t_sq)


def _ell_grid(dtype):
    """Plane offsets in units of size, ordered by distance from 0 (0, +s, -s, +2s, ...)."""
    k = np.arange(ELL_GRID)
    signed = np.where(k % 2 == 1, 1, -1) * ((k + 1) // 2)
    return jnp.asarray(signed * (ELL_BOUND / (ELL_GRID // 2)), dtype)


def _initial_focus_law(origin, direction, weight, axis_point, axis, size):
    """Initial ``x`` (see `_unpack`) for the focus-law fit.

    For each plane offset ``ell`` of `_ell_grid`, ``kappa = 1/alpha`` and
    ``gamma = beta/alpha`` solve the linear least-squares problem
    ``min sum w (t1^2 + t2^2) |g + (kappa + gamma r)(p - c)|^2``, where
    ``g = d_perp / (d . a)`` is the ray's transverse slope: exact for rays of a CSL, and
    Eq. 5 to first order in the ray angles. They are clamped into the constraints and
    scored by Eq. 5; the start is the grid offset nearest 0 whose cost is within rounding
    (and 0.1 %) of the least.
    """
    dtype = origin.dtype
    width = 4 * size
    eps = jnp.finfo(dtype).eps

    def at(ell_unit):
        ell = ell_unit * size
        c = axis_point + ell * axis
        p, t, cos = _plane_hits(origin, direction, c, axis)
        v = (p - c) / size
        r = _safe_norm(v)
        g = (direction - cos[:, None] * axis) / jnp.where(cos != 0, cos, 1.0)[:, None]
        t1 = jnp.abs(t)
        wt = weight * (t1 * t1 + (t1 + width) ** 2)
        vv = jnp.sum(v * v, axis=-1)
        gv = jnp.sum(g * v, axis=-1)
        m = jnp.array([[wt @ vv, wt @ (r * vv)], [wt @ (r * vv), wt @ (r * r * vv)]], dtype)
        rhs = -jnp.array([wt @ gv, wt @ (r * gv)], dtype)
        m = m + (1e-12 * jnp.trace(m) + _tiny(dtype)) * jnp.eye(2, dtype=dtype)
        k_unit, g_unit = jnp.linalg.solve(m, rhs)  # kappa size, gamma size^2
        k_unit = jnp.maximum(jnp.where(jnp.isfinite(k_unit), k_unit, 0.0), 1 / ALPHA_MAX)
        g_unit = jnp.maximum(jnp.where(jnp.isfinite(g_unit), g_unit, 0.0), 0.0)
        x = _pack(size / k_unit, g_unit / k_unit / size, ell, size)
        kappa, gamma, ell = _unpack(x, size)
        cost, scale = _eq5_cost(
            origin, direction, weight, axis_point, axis, kappa, gamma, ell, width
        )
        return x, cost, scale

    xs, costs, scales = jax.lax.map(at, _ell_grid(dtype))  # one offset at a time: memory O(R)
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
    best = jnp.min(costs)
    near = costs <= best * (1 + 1e-3) + 100 * eps * scales
    return xs[jnp.argmax(near)]


def _fit_x(origin, direction, weight, axis_point, axis, size, x0, steps, tolerance):
    """Trust-region Gauss-Newton (Optimistix's `Dogleg`, normal equations solved by SVD)
    on Eq. 5 from ``x0``; **returns** ``(x, steps taken)``.

    The solve runs in the default float type where that is wider than the data's
    (float32 rays with x64 enabled): Optimistix 0.1.0 then makes float64 internal scalars
    that clash with float32 residuals."""
    dtype = origin.dtype
    wide = jnp.promote_types(dtype, jnp.result_type(float))
    origin, direction, weight, axis_point, axis, size, x0 = (
        jnp.asarray(v, wide) for v in (origin, direction, weight, axis_point, axis, size, x0)
    )
    width = 4 * size
    root_weight = jnp.sqrt(weight)  # outside the residual: no derivative of sqrt at 0

    def residuals(x, _):
        kappa, gamma, ell = _unpack(x, size)
        diff, t_sq = _eq5_terms(origin, direction, axis_point, axis, kappa, gamma, ell, width)
        return (root_weight * jnp.sqrt(t_sq))[:, None] * diff  # t_sq >= width^2 > 0

    solver = optx.Dogleg(rtol=tolerance, atol=tolerance, linear_solver=lx.Normal(lx.SVD()))
    sol = optx.least_squares(residuals, solver, x0, max_steps=steps, throw=False)
    x = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, x0)
    return x.astype(dtype), jnp.asarray(sol.stats["num_steps"], jnp.int32)


def _default_tolerance(dtype) -> float:
    return max(1e-10, 100 * float(jnp.finfo(dtype).eps))


def _law(x, size):
    """``(alpha, beta, ell)`` in metres, 1/metres, metres from ``x``."""
    kappa, gamma, ell = _unpack(x, size)
    return 1 / kappa, gamma / kappa, ell


def fit_focus_law(
    origin,
    direction,
    energy,
    axis_point,
    axis_direction,
    *,
    size,
    steps: int = 100,
    initial=None,
    tolerance: float | None = None,
):
    """Fit a CSL's ``alpha``, ``beta`` and plane offset ``ell`` to a ray bundle (Eq. 5).

    Minimises ``sum_i w_i (t1^2 + t2^2) |d_i - e_i|^2`` with ``optx.least_squares``
    (residuals ``sqrt(w_i (t1^2 + t2^2)) (d_i - e_i)``, ``throw=False``) over
    ``x = (log(alpha / size), sqrt(beta size), arcsin(ell / (ELL_BOUND size)))``, which
    keeps ``alpha > 0``, ``beta >= 0`` and the plane within ``ELL_BOUND size`` of ``b``
    (``alpha`` is capped at ``ALPHA_MAX size``). The solver is
    `optx.Dogleg` (trust-region Gauss-Newton; the normal equations by SVD, since the
    problem is rank-deficient when ``beta = 0``): Levenberg-Marquardt's damping stalls
    the ``sqrt(beta)`` variable near ``beta = 0``, where Gauss-Newton steps halve it. The
    start is `initial` or a grid search over ``ell`` with a closed-form
    ``(alpha, beta)`` per offset (`_initial_focus_law`). With ``beta = 0`` all rays meet
    in one point and only ``ell + alpha`` (where the focus is) is determined; the search
    then prefers the offset nearest 0.

    - `origin`, `direction`: ``(R, 3)`` bundle rays (metres; unit directions).
    - `energy`: ``(R,)`` weights ``w`` (0: not in the bundle).
    - `axis_point`, `axis_direction`: ``(3,)`` the bundle axis ``b``, unit ``a``.
    - `size`: the object's size (metres): length scale and ``w = 4 size``.
    - `steps`: static, at most this many solver steps.
    - `initial`: optional ``(alpha, beta, ell)`` start.
    - `tolerance`: the solver's ``rtol = atol`` (default ``max(1e-10, 100 eps)``).

    **Returns** ``(alpha, beta, ell, rms)``: the law (metres, 1/metres, metres) and the
    energy-weighted RMS of ``sqrt(E)`` over the bundle, metres.
    """
    origin, direction, energy, axis_point, axis_direction, size = _floats(
        origin, direction, energy, axis_point, axis_direction, size
    )
    tolerance = _default_tolerance(origin.dtype) if tolerance is None else tolerance
    if initial is None:
        x0 = _initial_focus_law(origin, direction, energy, axis_point, axis_direction, size)
    else:
        alpha0, beta0, ell0 = (jnp.asarray(v, origin.dtype) for v in initial)
        x0 = _pack(alpha0, beta0, ell0, size)
    x, _ = _fit_x(origin, direction, energy, axis_point, axis_direction, size, x0, steps, tolerance)
    alpha, beta, ell = _law(x, size)
    error = focus_law_error(
        origin, direction, axis_point, axis_direction, alpha, beta, ell, size=size
    )
    return alpha, beta, ell, _rms(energy, error)


def _rms(weight, error):
    total = jnp.sum(weight)
    return jnp.sqrt((weight @ error) / jnp.where(total > 0, total, 1.0))
