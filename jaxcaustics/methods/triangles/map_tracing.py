"""Rays traced in a layered distance map (`trace_distance_map`): a linear search along
the ray for the first sample that passes from *undershooting* (``|l - c| < |l' - c|``,
the point is in front of the stored surface seen in its direction) to *overshooting* in
some layer, then a secant search inside that bracket; and its check against exact ray
casting (`exact_hits`, `tracing_error_table`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ...scene.mesh import Mesh
from ...trace.intersect import nearest_hits
from .cube_faces import _float_dtype, _texel_index, direction_face, face_coordinates
from .layered_map import (
    MATERIAL_EMPTY,
    MATERIAL_OCCLUDER,
    MATERIAL_RECEIVER,
    LayeredDistanceMap,
)


class DistanceMapHit(eqx.Module):
    """Result of `trace_distance_map`, per ray.

    - `point`: shape ``(P, 3)``, the hit point (the ray's origin where not found).
    - `distance`: shape ``(P,)``, the ray parameter ``d`` with ``point = o + d R``
      (in units of ``|R|``; ``inf`` where not found).
    - `layer`: shape ``(P,)`` int32, the layer whose surface was hit (-1: none).
    - `material`: shape ``(P,)`` int32, that surface's material (0: none).
    - `normal`: shape ``(P, 3)``, its stored unit normal (zero where not found).
    - `found`: shape ``(P,)`` bool.
    """

    point: Float[Array, "P 3"]
    distance: Float[Array, " P"]
    layer: Int[Array, " P"]
    material: Int[Array, " P"]
    normal: Float[Array, "P 3"]
    found: Bool[Array, " P"]


def _lookup(planes, present, h, resolution: int, lookup: str, layer=None):
    """Evaluate the stored surfaces at the offsets `h` (``(..., 3)``, relative to c).

    **Returns:** ``(gh, g_near, ok, face, row, col)`` where ``gh = g . h`` (per layer,
    ``(..., L)``, or for the given `layer` ``(...)``) is the ratio ``|l - c| / |l' - c|``
    times the homogeneous weight, ``g_near`` the nearest texel's plane vector, ``ok``
    whether the nearest texel is non-empty.
    """
    face = direction_face(jax.lax.stop_gradient(h))
    x, y, _ = face_coordinates(h, face, resolution)  # differentiable (bilinear weights)
    row, col = _texel_index(jax.lax.stop_gradient(x), jax.lax.stop_gradient(y), resolution)
    if layer is None:
        g_near = jnp.moveaxis(planes[:, face, row, col], 0, -2)  # (..., L, 3)
        ok = jnp.moveaxis(present[:, face, row, col], 0, -1)  # (..., L)
        hh = h[..., None, :]
    else:
        g_near = planes[layer, face, row, col]
        ok = present[layer, face, row, col]
        hh = h
    if lookup == "planar":
        return jnp.sum(g_near * hh, axis=-1), g_near, ok, face, row, col
    # bilinear: blend the four nearest texel centres' tangent-plane predictions, within
    # the face (clamp to edge at the seams).
    xs, ys = x - 0.5, y - 0.5
    c0 = jnp.clip(jnp.floor(xs), 0, resolution - 2).astype(jnp.int32)
    r0 = jnp.clip(jnp.floor(ys), 0, resolution - 2).astype(jnp.int32)
    fx = jnp.clip(xs - c0, 0.0, 1.0)
    fy = jnp.clip(ys - r0, 0.0, 1.0)
    gh: Array | float = 0.0
    for dr, dc, wgt in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy))) + (
        (1, 0, (1 - fx) * fy),
        (1, 1, fx * fy),
    ):
        if layer is None:
            gc = jnp.moveaxis(planes[:, face, r0 + dr, c0 + dc], 0, -2)
            gh = gh + wgt[..., None] * jnp.sum(gc * hh, axis=-1)
        else:
            gc = planes[layer, face, r0 + dr, c0 + dc]
            gh = gh + wgt * jnp.sum(gc * hh, axis=-1)
    return gh, g_near, ok, face, row, col


def default_scale(dmap: LayeredDistanceMap) -> Float[Array, ""]:
    """The median finite layer-0 distance of `dmap` (1 if there is none): the distance
    the linear search of `trace_distance_map` reaches half-way."""
    d = dmap.distance[0]
    med = jnp.nanmedian(jnp.where(jnp.isfinite(d), d, jnp.nan))
    return jnp.where(jnp.isfinite(med), med, 1.0)


def trace_distance_map(
    dmap: LayeredDistanceMap,
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    *,
    linear_steps: int = 32,
    secant_iterations: int = 4,
    max_distance: float | None = None,
    scale: float | None = None,
    lookup: Literal["planar", "bilinear"] = "planar",
    tolerance: float = 1e-2,
    attempts: int = 4,
) -> DistanceMapHit:
    """Trace rays in a layered distance map: linear search, then secant search.

    **Search function.** For a point ``l`` on the ray and a layer, let ``l'`` be the
    layer's surface point seen from ``c`` in the direction of ``l``. The point
    *undershoots* where ``|l - c| < |l' - c|`` and *overshoots* where it is larger; the
    hit is the root of ``f = |l - c| / |l' - c| - 1`` (the paper's ``|l|`` vs ``|l'|``
    comparison, as a ratio).

    **Lookup** (`lookup`). Every texel stores a point and a normal, i.e. a tangent plane,
    and ``|l - c| / |l' - c| = g . (l - c)`` for that plane (`LayeredDistanceMap.planes`).

    - ``"planar"`` (default): the texel the direction of ``l`` falls into supplies the
      plane (nearest-texel lookup, each texel a planar facet). Planar surfaces (the
      receiver, box faces) are reproduced exactly, and silhouettes stay sharp (at texel
      edges), so there are no "rubber sheets" across depth discontinuities.
    - ``"bilinear"``: the texture filter of the paper: bilinear interpolation, within a
      face, between the four nearest texel centres of their tangent-plane predictions
      (still exact for planes, smooth for curved surfaces, but blending foreground and
      background at silhouettes).

    Face seams: the lookup never blends across faces; the face is chosen from the
    direction of ``l`` and the bilinear weights are clamped to the face (clamp to edge),
    each corner's plane being evaluated at the exact direction, so a planar surface is
    continuous across seams.

    **Linear search.** Samples ``t_i = i / N``, ``i = 0..N`` (``N = linear_steps``) of a
    homogeneous parameter: ``l(t) = o + R d(t)`` with ``d(t) = s t / (1 - t + t s / M)``
    (``s = scale``, ``M = max_distance``). With ``max_distance=None`` (the default)
    ``M = inf``: ``d = s t / (1 - t)`` maps ``[0, 1]`` to ``[0, inf]`` (the last sample
    is the ray's point at infinity, whose direction is ``R``), so the search covers the
    whole receiver plane, out to its horizon, with steps that grow with the distance
    (the direction of ``l`` seen from ``c`` changes less and less). With a finite ``M``
    and ``scale=None`` the samples are uniform in ``d`` on ``[0, M]``. Otherwise `scale`
    defaults to `default_scale` (the median stored distance), reached half-way. The
    search function is evaluated in the finite form ``G = (1 - t + t s / M) f`` (same
    sign as ``f``, finite at ``t = 1``; for a planar facet it is linear in ``t``, so one
    secant step inside a facet is exact).

    **Bracket.** A candidate is an interval ``[t_i, t_i+1]`` and a layer where the first
    sample undershoots and the second overshoots a non-empty texel, taken in order along
    the ray (nearer intervals first, then lower layers). `secant_iterations` secant
    (false-position) steps shrink it, each costing one lookup in that layer; the estimate
    is the last secant point (with 0 iterations: the overshooting sample of the linear
    search, the paper's linear search alone). The candidate is accepted if one of the
    two final bracket ends' planes is really crossed inside the bracket (within
    `tolerance`, relative): otherwise the sign change came from a jump between surfaces
    (the ray passed an occluder's edge into the region hidden behind it), and the next
    candidate is tried, up to `attempts` of them. A ray that passes below a box's edge
    thus finds the plane behind it in the next layer instead of a false hit on the edge.

    **Arguments:**

    - `dmap`: the `LayeredDistanceMap`.
    - `origins`: shape ``(P, 3)``, ray origins (metres; near the reference point, e.g.
      on the caustic generator).
    - `directions`: shape ``(P, 3)``, ray directions (need not be unit).
    - `linear_steps`, `secant_iterations`: the knobs of the search (static).
    - `max_distance`: farthest ray parameter searched (``None``: infinity; static).
    - `scale`: the ray parameter reached half-way (``None``: see above; static).
    - `lookup`: ``"planar"`` or ``"bilinear"`` (static).
    - `tolerance`: relative mismatch that still counts as crossing a plane.
    - `attempts`: how many candidate brackets to try per ray (static).

    **Returns:** a `DistanceMapHit`. Rays that find nothing have ``found = False`` (no
    NaN). The hit is differentiable with respect to `origins` and `directions`: inside a
    bracket the secant result is a smooth function of them (the choice of texels, layer
    and bracket is discrete and carries no derivative).
    """
    _check_trace_args(lookup, linear_steps, secant_iterations, attempts)
    return _trace(
        dmap,
        origins,
        directions,
        max_distance,
        scale,
        jnp.asarray(tolerance),
        linear_steps=int(linear_steps),
        max_steps=int(linear_steps),
        record=(int(secant_iterations),),
        lookup=lookup,
        attempts=attempts,
    )[0]


def _check_trace_args(lookup, linear_steps, secant_iterations, attempts):
    if lookup not in ("planar", "bilinear"):
        raise ValueError(f"`lookup` must be 'planar' or 'bilinear', got {lookup!r}")
    for name, val, low in (
        ("linear_steps", linear_steps, 1),
        ("secant_iterations", secant_iterations, 0),
        ("attempts", attempts, 1),
    ):
        if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < low:
            raise ValueError(f"`{name}` must be an integer >= {low}, got {val!r}")


@eqx.filter_jit
def _trace(
    dmap,
    origins,
    directions,
    max_distance,
    scale,
    tolerance,
    *,
    linear_steps,
    max_steps,
    record,
    lookup,
    attempts,
):
    dtype = _float_dtype(origins, directions)
    origins = jnp.asarray(origins, dtype)
    directions = jnp.asarray(directions, dtype)
    sg = jax.lax.stop_gradient
    center = sg(dmap.center).astype(dtype)
    planes, present = dmap.planes()
    planes = sg(planes).astype(dtype)
    resolution, n_layers = dmap.resolution, dmap.layers
    if scale is None:
        s = jnp.asarray(max_distance if max_distance is not None else default_scale(dmap))
    else:
        s = jnp.asarray(scale)
    s = sg(s).astype(dtype)
    inv_m = 0.0 if max_distance is None else 1.0 / jnp.asarray(max_distance, dtype)
    rel = origins - center  # (P, 3)

    def weight(t):
        return 1.0 - t + t * s * inv_m

    def offset(t, rel_, dir_):  # homogeneous offset from c: weight * (l - c)
        return weight(t)[..., None] * rel_ + (t * s)[..., None] * dir_

    # --- linear search ---------------------------------------------------------------
    # samples i / linear_steps, padded with copies of t = 1 up to `max_steps` (a padded
    # interval [1, 1] holds no sign change): one compilation serves every step count
    steps = jnp.asarray(linear_steps)
    ts = jnp.minimum(jnp.arange(max_steps + 1, dtype=dtype) / steps.astype(dtype), 1.0)
    n = max_steps
    tt = jnp.broadcast_to(ts, (origins.shape[0], n + 1))
    h = offset(tt, rel[:, None], directions[:, None])  # (P, n+1, 3)
    gh, g_near, ok, *_ = _lookup(planes, present, h, resolution, lookup)
    w = weight(tt)[..., None]  # (P, n+1, 1)
    big = gh - w  # G per layer, (P, n+1, L)
    under = big < 0
    over = ok & (big >= 0)
    cand = under[:, :-1] & over[:, 1:]  # (P, n, L)
    flat = cand.reshape(cand.shape[0], -1)
    n_cand = flat.shape[1]
    key = jnp.where(flat, jnp.arange(n_cand, dtype=jnp.int32), n_cand)
    a_cnt = min(attempts, n_cand)
    chosen = -jax.lax.top_k(-key, a_cnt)[0]  # (P, A) ascending
    usable = chosen < n_cand
    chosen = jnp.where(usable, chosen, 0)
    interval, layer = chosen // n_layers, chosen % n_layers

    rows = jnp.arange(origins.shape[0], dtype=jnp.int32)[:, None]

    def take(arr, idx, lay):  # arr (P, n+1, L, ...) -> (P, A, ...)
        return arr[rows, idx, lay]

    ta = ts[interval]
    tb = ts[interval + 1]
    ga, gb = take(big, interval, layer), take(big, interval + 1, layer)
    pa, pb = take(g_near, interval, layer), take(g_near, interval + 1, layer)
    oka, okb = take(ok, interval, layer), take(ok, interval + 1, layer)

    # --- secant search (scan; the state after every recorded count is finalised) -----
    rel_a = jnp.broadcast_to(rel[:, None], ta.shape + (3,))
    dir_a = jnp.broadcast_to(directions[:, None], ta.shape + (3,))

    def step(state, _):
        ta, tb, ga, gb, pa, pb, oka, okb, _est = state
        denom = gb - ga
        frac = jnp.where(denom > 0, -ga / jnp.where(denom > 0, denom, 1.0), 0.5)
        tn = ta + (tb - ta) * jnp.clip(frac, 0.0, 1.0)
        hn = offset(tn, rel_a, dir_a)
        ghn, gnn, okn, *_ = _lookup(planes, present, hn, resolution, lookup, layer=layer)
        gn = ghn - weight(tn)
        over_n = okn & (gn >= 0)
        new = (
            jnp.where(over_n, ta, tn),
            jnp.where(over_n, tn, tb),
            jnp.where(over_n, ga, gn),
            jnp.where(over_n, gn, gb),
            jnp.where(over_n[..., None], pa, gnn),
            jnp.where(over_n[..., None], gnn, pb),
            jnp.where(over_n, oka, okn),
            jnp.where(over_n, okn, okb),
            tn,
        )
        return new, new

    state0 = (ta, tb, ga, gb, pa, pb, oka, okb, tb)
    n_iter = max(record)
    if n_iter:
        _, states = jax.lax.scan(step, state0, None, length=n_iter)
    results = []
    for k in record:
        state = state0 if k == 0 else jax.tree_util.tree_map(lambda x, k=k: x[k - 1], states)
        results.append(
            _finish(
                dmap,
                planes,
                present,
                origins,
                directions,
                center,
                state,
                usable,
                layer,
                weight,
                offset,
                rel_a,
                dir_a,
                s,
                tolerance,
            )
        )
    return tuple(results)


def _finish(
    dmap,
    planes,
    present,
    origins,
    directions,
    center,
    state,
    usable,
    layer,
    weight,
    offset,
    rel_a,
    dir_a,
    s,
    tolerance,
):
    """Accept a bracket if one of its final ends' planes is crossed inside it; pick the
    first accepted candidate of every ray."""
    sg = jax.lax.stop_gradient
    ta, tb, _, _, pa, pb, oka, okb, est = state
    ha, hb = offset(ta, rel_a, dir_a), offset(tb, rel_a, dir_a)
    wa, wb = weight(ta), weight(tb)
    crossed_a = oka & (jnp.sum(pa * hb, axis=-1) - wb >= -tolerance * wb)
    crossed_b = okb & (jnp.sum(pb * ha, axis=-1) - wa <= tolerance * wa)
    accept = usable & (crossed_a | crossed_b) & (weight(est) > 0)
    first = jnp.argmax(accept, axis=1)
    found = jnp.any(accept, axis=1)

    def pick(arr):
        return jnp.take_along_axis(arr, first[:, None], 1)[:, 0]

    t_hit = pick(est)
    lay = pick(layer)
    w_hit = weight(t_hit)
    w_safe = jnp.where(found & (w_hit > 0), w_hit, 1.0)
    dist = jnp.where(found, s * t_hit / w_safe, jnp.inf)
    point = origins + directions * jnp.where(found, dist, 0.0)[:, None]
    _, _, _, face, row, col = _lookup(
        planes, present, sg(point - center), dmap.resolution, "planar", layer=lay
    )
    material = jnp.where(found, dmap.material[lay, face, row, col], MATERIAL_EMPTY)
    normal = dmap.normal[lay, face, row, col]
    normal = jnp.where(found[:, None], sg(normal).astype(point.dtype), 0.0)
    return DistanceMapHit(
        point=point,
        distance=dist,
        layer=jnp.where(found, lay, -1).astype(jnp.int32),
        material=material.astype(jnp.int32),
        normal=normal,
        found=found,
    )


def exact_hits(
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    occluders: Sequence[Mesh] = (),
    receiver: bool = True,
) -> tuple[Float[Array, " P"], Int[Array, " P"]]:
    """Exact nearest hits of rays with the receiver plane ``z = 0`` and the occluders
    (every triangle, both sides), for checking `trace_distance_map`.

    **Returns:** ``(distance, material)``: the ray parameter (``inf`` for a miss) and the
    material (0 none, 1 receiver, ``2 + k`` occluder ``k``).
    """
    origins = jnp.asarray(origins)
    directions = jnp.asarray(directions)
    dtype = _float_dtype(origins, directions)
    best = jnp.full(origins.shape[:1], jnp.inf, dtype)
    mat = jnp.zeros(origins.shape[:1], jnp.int32)
    if receiver:
        dz = directions[:, 2]
        safe = jnp.where(dz != 0, dz, 1.0)
        t = jnp.where(dz != 0, -origins[:, 2] / safe, jnp.inf)
        t = jnp.where(t > 0, t, jnp.inf)
        mat = jnp.where(t < best, MATERIAL_RECEIVER, mat)
        best = jnp.minimum(best, t)
    for k, occ in enumerate(occluders):
        t, _ = nearest_hits(origins, directions, jnp.asarray(occ.triangles, dtype))
        mat = jnp.where(t < best, MATERIAL_OCCLUDER + k, mat)
        best = jnp.minimum(best, t)
    return best, mat


def tracing_error_table(
    dmap: LayeredDistanceMap,
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    occluders: Sequence[Mesh] = (),
    *,
    receiver: bool = True,
    linear_steps: Sequence[int] = (8, 16, 32, 64),
    secant_iterations: Sequence[int] = (0, 1, 2, 4),
    max_distance: float | None = None,
    scale: float | None = None,
    lookup: Literal["planar", "bilinear"] = "planar",
    tolerance: float = 1e-2,
    attempts: int = 4,
) -> dict[str, np.ndarray]:
    """Accuracy of `trace_distance_map` against exact ray casting, per search setting.

    Hit points are compared with `exact_hits` for every combination of `linear_steps`
    and `secant_iterations` (the other keywords are those of `trace_distance_map`). It
    compiles the search once: every step count runs with ``max(linear_steps)`` samples,
    the extra ones parked at the ray's end, so timings here say nothing of speed.

    **Returns:** a dict of NumPy arrays of shape ``(len(linear_steps),
    len(secant_iterations))``: ``"median"``, ``"p95"`` and ``"max"`` of the distance
    between the traced and the exact hit point (metres), over rays that both find;
    ``"missed"``, the fraction of rays with an exact hit that the search did not find;
    ``"false"``, the fraction of rays found by the search with no exact hit or a
    different material. Also ``"linear_steps"`` and ``"secant_iterations"`` (1-D).
    """
    for n in linear_steps:
        _check_trace_args(lookup, n, 0, attempts)
    for it in secant_iterations:
        _check_trace_args(lookup, 1, it, attempts)
    origins, directions = jnp.asarray(origins), jnp.asarray(directions)
    t_hit, m_hit = exact_hits(origins, directions, occluders, receiver)
    t_exact, m_exact = np.asarray(t_hit), np.asarray(m_hit)
    has = np.isfinite(t_exact)
    p_exact = np.asarray(origins) + np.asarray(directions) * np.where(has, t_exact, 0)[:, None]
    shape = (len(linear_steps), len(secant_iterations))
    out = {k: np.zeros(shape) for k in ("median", "p95", "max", "missed", "false")}
    for i, n in enumerate(linear_steps):
        hits = _trace(
            dmap,
            origins,
            directions,
            max_distance,
            scale,
            jnp.asarray(tolerance),
            linear_steps=jnp.asarray(n),
            max_steps=max(linear_steps),
            record=tuple(secant_iterations),
            lookup=lookup,
            attempts=attempts,
        )
        for j, hit in enumerate(hits):
            found = np.asarray(hit.found)
            both = found & has
            err = np.linalg.norm(np.asarray(hit.point) - p_exact, axis=-1)[both]
            if err.size:
                out["median"][i, j] = np.median(err)
                out["p95"][i, j] = np.percentile(err, 95)
                out["max"][i, j] = err.max()
            else:
                out["median"][i, j] = out["p95"][i, j] = out["max"][i, j] = np.nan
            out["missed"][i, j] = np.mean(~found[has]) if has.any() else 0.0
            wrong = found & (~has | (np.asarray(hit.material) != m_exact))
            out["false"][i, j] = np.mean(wrong[found]) if found.any() else 0.0
    out["linear_steps"] = np.asarray(linear_steps)
    out["secant_iterations"] = np.asarray(secant_iterations)
    return out
