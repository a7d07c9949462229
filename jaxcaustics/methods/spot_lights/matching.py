"""Matching the caustic spot lights of neighbouring light directions and assembling the
CSL triples of every face (Liu et al. 2008, Sect. 4.2-4.3; host code, NumPy):
`build_spot_light_table`, with the conventions of `table.py`.

Matching (Sect. 4.2). A pair's distance is the mean of its distance after tracking forwards
(``[e, 0]``) and after tracking backwards (``[e, 1]``), so the matching does not depend on
the edge's orientation; greedy by increasing distance, pairs beyond `match_threshold`
(default `DEFAULT_MATCH_FRACTION` of the object's size) skipped. An unmatched light of either
end gets a black partner at the other end, at its own axis tracked there, with its
``alpha``, ``beta`` and half width.

Triples. Let ``P_ij(L)`` be the partner of light ``L`` of vertex ``i`` on the edge ``(i, j)``:
the light of ``j`` it was matched with, or the black CSL created for it at ``j`` (at ``L``'s
axis tracked to ``j``). Every light ``L`` of a face's vertex ``i`` *owns* the triple whose
corner ``i`` is ``L`` and whose other corners are ``P_ij(L)`` and ``P_ik(L)``; only the owner
is painted (its image is added). Identical triples merge, their paints add; where the three
pairwise matches agree (``L0 - L1 - L2`` all matched with each other) the three owners give
one triple with every corner painted: the paper's triple, rule (1). Where they do not (a
light that appears or vanishes, or inconsistent matches), the owners give separate triples
whose unpainted corners are the paper's CSLs "labelled so that their image is not added";
such a triple's corners are matched with the owner but not necessarily with each other
(the deviation from rule (1) that makes the others exact):

- rule (3), exactness at the vertices: at barycentric ``(1, 0, 0)`` only corner 0 counts and
  each light of vertex 0 is painted in exactly one triple of the face (its own);
- rule (2), continuity across edges: on the edge ``(i, j)`` a face gives, for every pair
  ``(L, P)`` of that edge's matching, the CSLs at the geometry blended from ``L`` and ``P``
  with the images ``w_i I_L`` and ``w_j I_P`` (one CSL with both, if merged); the third
  corners weigh 0 and the triples owned by the third vertex's lights are black. This depends
  only on the edge's matching, which both faces share, so the light field (the sum of the
  images at each geometry) is the same from both sides.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .directions import direction_edges
from .frames import _canonicalise
from .light_table import _LIGHT_FIELDS, SpotLightTable
from .lights import SpotLights

DEFAULT_MATCH_FRACTION = 0.25
"""Default `match_threshold`, as a fraction of the object's size."""


def axis_distance(point0, axis0, point1, axis1, centre, size) -> np.ndarray:
    """Axis distance of Sect. 4.2: ``sqrt(|b0 - b1|^2 + size^2 |a0 - a1|^2)``.

    `point*`: ``(..., 3)`` any points of the axes (m); `axis*`: ``(..., 3)`` unit directions;
    ``b`` is the point of each axis nearest to `centre` ``(3,)``; `size`: the object's size
    (m, the paper's bounding sphere size ``sqrt(B)``). Broadcasts; returns metres.
    """

    def nearest(p, a):
        return p + np.sum((centre - p) * a, axis=-1, keepdims=True) * a

    b0, b1 = nearest(point0, axis0), nearest(point1, axis1)
    return np.sqrt(np.sum((b0 - b1) ** 2, -1) + size**2 * np.sum((axis0 - axis1) ** 2, -1))


def greedy_match(distance: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Greedy matching by increasing distance (Sect. 4.2).

    `distance`: ``(K0, K1)``, ``inf`` (or NaN) for pairs that must not match. Pairs are
    taken in order of increasing distance; a pair beyond `threshold` or with a light
    already matched is skipped. **Returns** ``(partner0 (K0,), partner1 (K1,))``: the
    matched index on the other side, ``-1`` where unmatched.
    """
    k0, k1 = distance.shape
    partner0 = np.full(k0, -1, np.int64)
    partner1 = np.full(k1, -1, np.int64)
    for flat in np.argsort(distance, axis=None, kind="stable"):
        i, j = divmod(int(flat), k1)
        if not distance[i, j] <= threshold:
            break  # sorted: every later pair is farther (NaN sorts last)
        if partner0[i] < 0 and partner1[j] < 0:
            partner0[i], partner1[j] = j, i
    return partner0, partner1


def _match_edges(lights, edges, moved_origin, moved_axis, centre, size, threshold):
    """Pairwise matching on every edge. The distance of a pair is the mean of the distance
    after tracking ``a``'s light to ``b`` and that after tracking ``b``'s light to ``a``
    (symmetric in the edge's orientation). **Returns** ``(partners (E, 2, K), match
    (E, 2K, 2))``: ``partners[e, 0, i]`` the slot of ``b`` matched with slot ``i`` of
    ``a`` (-1: black partner, -2: inactive slot), ``partners[e, 1]`` the reverse."""
    k = lights["active"].shape[1]
    partners = np.full((len(edges), 2, k), -2, np.int64)
    match = np.full((len(edges), 2 * k, 2), -2, np.int32)
    for e, (a, b) in enumerate(edges):
        act_a, act_b = lights["active"][a], lights["active"][b]
        forward = axis_distance(
            moved_origin[e, 0][:, None],
            moved_axis[e, 0][:, None],
            lights["origin"][b][None],
            lights["axis"][b][None],
            centre,
            size,
        )
        backward = axis_distance(
            lights["origin"][a][:, None],
            lights["axis"][a][:, None],
            moved_origin[e, 1][None],
            moved_axis[e, 1][None],
            centre,
            size,
        )
        distance = 0.5 * (forward + backward)
        distance[~act_a, :] = np.inf
        distance[:, ~act_b] = np.inf
        p0, p1 = greedy_match(distance, threshold)
        partners[e, 0] = np.where(act_a, p0, -2)
        partners[e, 1] = np.where(act_b, p1, -2)
        rows = [(i, p0[i]) for i in np.flatnonzero(act_a)]
        rows += [(-1, j) for j in np.flatnonzero(act_b & (p1 < 0))]
        if rows:
            match[e, : len(rows)] = rows
    return partners, match


def _face_triples(face, edge_of, edges, partners, active) -> dict:
    """Owner triples of one face, merged (see the module docstring). Keys: three corner
    nodes, ``("L", vertex, slot)`` a light or ``("B", edge, side, slot)`` the black CSL at
    ``edges[edge, side]`` that partners slot ``slot`` of the other end; values: paints."""
    triples: dict = {}
    for i in range(3):
        v = int(face[i])
        for s in np.flatnonzero(active[v]):
            corners: list = [None, None, None]
            corners[i] = ("L", v, int(s))
            for j in ((i + 1) % 3, (i + 2) % 3):
                u = int(face[j])
                e = edge_of[(min(v, u), max(v, u))]
                side = 0 if edges[e, 0] == v else 1
                partner = int(partners[e, side, s])
                corners[j] = ("L", u, partner) if partner >= 0 else ("B", e, 1 - side, int(s))
            paint = triples.setdefault(tuple(corners), [0.0, 0.0, 0.0])
            assert paint[i] == 0.0  # each light owns one triple
            paint[i] = 1.0
    return triples


def _node_geometry(node, lights, edges, moved_origin, moved_axis):
    """``(slot, origin, axis, alpha, beta, half_width)`` of a triple corner node."""
    if node[0] == "L":
        _, v, s = node
        origin, axis, slot = lights["origin"][v, s], lights["axis"][v, s], s
    else:
        _, e, side, s = node
        source = 1 - side
        v = edges[e, source]
        origin, axis, slot = moved_origin[e, source, s], moved_axis[e, source, s], -1
    return (
        slot,
        origin,
        axis,
        lights["alpha"][v, s],
        lights["beta"][v, s],
        lights["half_width"][v, s],
    )


def build_spot_light_table(
    directions,
    faces,
    lights: SpotLights,
    moved_origin,
    moved_axis,
    *,
    centre,
    size,
    match_threshold: float | None = None,
) -> SpotLightTable:
    """Match the CSL sets of neighbouring directions and build the triples of every face.

    **Arguments:**

    - `directions`: ``(V, 3)`` unit vectors towards the light; `faces`: ``(F, 3)`` int.
    - `lights`: `SpotLights` with leading axes ``(V, K)``, the set of every direction.
    - `moved_origin`, `moved_axis`: ``(E, 2, K, 3)``, edges as `direction_edges(faces)`:
      ``[e, 0]`` the lights of ``edges[e, 0]`` with their axes tracked to ``edges[e, 1]``
      (an axis point, m, and a unit direction), ``[e, 1]`` the reverse. Non-finite entries
      fall back to the light's own axis.
    - `centre`: ``(3,)`` the object's centre (m); `size`: its size (m).
    - `match_threshold`: the largest axis distance of a matched pair (m); default
      `DEFAULT_MATCH_FRACTION` times `size`.

    **Returns:** a `SpotLightTable` (``T`` = the most triples of any face).
    """
    directions = np.asarray(directions, np.float64)
    if directions.ndim != 2 or directions.shape[1] != 3:
        raise ValueError(f"`directions` must have shape (V, 3), got {directions.shape}")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"`faces` must be an int array of shape (F, 3), got {faces.shape}")
    v_count = directions.shape[0]
    if faces.min() < 0 or faces.max() >= v_count:
        raise ValueError(f"`faces` must index the {v_count} directions")
    if (
        not isinstance(lights, SpotLights)
        or lights.origin.shape[:1] != (v_count,)
        or (lights.origin.ndim != 3)
    ):
        raise ValueError(f"`lights` must be a SpotLights with leading axes ({v_count}, K)")
    k = lights.origin.shape[1]
    edges = direction_edges(faces)
    moved_origin = np.asarray(moved_origin, np.float64)
    moved_axis = np.asarray(moved_axis, np.float64)
    for name, arr in (("moved_origin", moved_origin), ("moved_axis", moved_axis)):
        if arr.shape != (len(edges), 2, k, 3):
            raise ValueError(f"`{name}` must have shape ({len(edges)}, 2, {k}, 3), got {arr.shape}")
    centre = np.asarray(centre, np.float64)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise ValueError(f"`centre` must be a finite (3,) point, got shape {centre.shape}")
    size = float(size)
    if not size > 0 or not np.isfinite(size):
        raise ValueError(f"`size` must be positive and finite, got {size}")
    threshold = DEFAULT_MATCH_FRACTION * size if match_threshold is None else match_threshold
    threshold = float(threshold)
    if not threshold >= 0:
        raise ValueError(f"`match_threshold` must be >= 0, got {match_threshold}")

    lights = _canonicalise(lights)
    host = {name: np.asarray(getattr(lights, name)) for name in _LIGHT_FIELDS}
    # Tracking that failed (non-finite) falls back to the light's own axis.
    ends = edges.T  # (2, E): source vertex of [e, 0] and [e, 1]
    own_origin = np.stack([host["origin"][ends[0]], host["origin"][ends[1]]], axis=1)
    own_axis = np.stack([host["axis"][ends[0]], host["axis"][ends[1]]], axis=1)
    bad = ~(np.all(np.isfinite(moved_origin), -1) & np.all(np.isfinite(moved_axis), -1))
    moved_origin = np.where(bad[..., None], own_origin, moved_origin)
    moved_axis = np.where(bad[..., None], own_axis, moved_axis)
    moved_axis = moved_axis / np.linalg.norm(moved_axis, axis=-1, keepdims=True)

    partners, edge_match = _match_edges(
        host, edges, moved_origin, moved_axis, centre, size, threshold
    )
    edge_of = {(int(a), int(b)): e for e, (a, b) in enumerate(edges)}
    per_face = [_face_triples(f, edge_of, edges, partners, host["active"]) for f in faces]
    t = max([1] + [len(triples) for triples in per_face])

    f_count = len(faces)
    active = np.zeros((f_count, t), bool)
    slot = np.full((f_count, t, 3), -1, np.int32)
    origin = np.zeros((f_count, t, 3, 3))
    axis = np.zeros((f_count, t, 3, 3))
    axis[..., 2] = 1.0
    alpha = np.ones((f_count, t, 3))
    beta = np.zeros((f_count, t, 3))
    half_width = np.ones((f_count, t, 3))
    paint = np.zeros((f_count, t, 3))
    for f, triples in enumerate(per_face):
        for j, (corners, paints) in enumerate(triples.items()):
            active[f, j] = True
            paint[f, j] = paints
            for i, node in enumerate(corners):
                geometry = _node_geometry(node, host, edges, moved_origin, moved_axis)
                (
                    slot[f, j, i],
                    origin[f, j, i],
                    axis[f, j, i],
                    alpha[f, j, i],
                    beta[f, j, i],
                    half_width[f, j, i],
                ) = geometry

    dtype = lights.origin.dtype
    as_float = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return SpotLightTable(
        directions=as_float(directions),
        faces=jnp.asarray(faces, jnp.int32),
        edges=jnp.asarray(edges),
        lights=lights,
        edge_match=jnp.asarray(edge_match),
        triple_active=jnp.asarray(active),
        triple_slot=jnp.asarray(slot),
        corner_origin=as_float(origin),
        corner_axis=as_float(axis),
        corner_alpha=as_float(alpha),
        corner_beta=as_float(beta),
        corner_half_width=as_float(half_width),
        corner_paint=as_float(paint),
        centre=as_float(centre),
        size=as_float(size),
        match_threshold=as_float(threshold),
    )
