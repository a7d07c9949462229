"""Ray/triangle intersection kernels (JAX), shared by photon tracing and distance maps.

Visibility (*which* triangle a ray meets first) is a discrete choice and carries no
derivative: `nearest_hits` returns indices under `stop_gradient`. The hit itself is then
recomputed from that triangle's vertices by `hit_on_triangle` (Möller–Trumbore), which is
differentiable with respect to the ray and the vertices.

The search (`nearest_hits`, in batches of `batch_size` rays) is exact either way:

- up to `BRUTE_FORCE_FACES` triangles, brute force: every ray against every triangle
  (memory ``batch_size * F`` numbers per step); for so few it is the fastest;
- above, a bounding volume hierarchy (`Hierarchy`, built by `build_hierarchy`): a
  balanced binary tree split at the median along the longest side of the centroids'
  box, as `jaxcaustics.reference` builds its own, with at most `LEAF_FACES` triangles a
  leaf. Each ray walks it front to back without a stack (a heap-numbered tree: the
  next node follows from two numbers, see `_search_tree`), in a `while_loop`, so memory is
  ``batch_size`` rays plus the tree, whatever ``F``.

The tree is built in JAX (sorts along the tree's levels, ``O(F log^2 F)``), not on the
host: a render under `jit`, `grad` or `vmap` sees the vertices as tracers, and the tree
must follow them (a design step moves the vertices); `trace_mesh_rays` builds it once and
passes it to every search of the trace. See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Iterator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

BRUTE_FORCE_FACES = 512
"""Meshes of at most this many triangles are searched by brute force (no tree).
Measured on 2 CPU cores, float32, rays 6 degrees off vertical over an icosphere's box
(the tree's building included): among 320 triangles both took 4.3-5.3 ms for 9409 rays
and 28-33 ms for 66,049; among 1280, brute force 16 and 113 ms, the tree 8.5 and 40 ms.
On the 320-face blob of the accuracy report, the first search of 9409 photons took
2.5 ms by brute force and 7.3 ms in the tree; its whole trace (three searches) 7.2 ms by
brute force and 25-54 ms in the tree (64 to 256 lanes; 1.1 against 3.7-6.6 ms at 1089
photons)."""


@contextlib.contextmanager
def brute_force_limit(faces: int) -> Iterator[None]:
    """Inside the block, search meshes of at most `faces` triangles by brute force
    (`BRUTE_FORCE_FACES` is set to `faces`, and restored on leaving): to time or check the
    brute-force search against the tree on one mesh. The search is chosen while a
    function is traced: one compiled before the block keeps the search it was compiled
    with."""
    global BRUTE_FORCE_FACES
    saved = BRUTE_FORCE_FACES
    BRUTE_FORCE_FACES = int(faces)
    try:
        yield
    finally:
        BRUTE_FORCE_FACES = saved


MIN_LANES = 256
RAYS_PER_LANE = 64
"""A tree search walks ``max(MIN_LANES, rays // RAYS_PER_LANE)`` rays at a time (at most
its `batch_size`). Too few lanes, and the loop's steps cost more than the walks; too
many, and lanes idle at the end waiting for the longest walk. Measured on 2 CPU cores,
9409 rays among 320 triangles: 1.6 ms with 256 lanes, 3.6 ms with 1024, 9.1 ms with
4096; 66,049 rays among 20,480: 44, 33 and 47 ms."""


LEAF_FACES = 4
"""Most triangles in one leaf of a `Hierarchy`."""

HIERARCHY_RAY_FLOATS = 64
"""Numbers one ray of a tree search holds (the ray, its best hit, a leaf's triangles:
counted from the code, not measured), for the memory estimates."""

HIERARCHY_FACE_FLOATS = 48
"""Numbers the tree takes per triangle (the sorted triangles, the node boxes, the sorts'
temporaries: counted from the code, not measured), for the memory estimates."""

BRUTE_FORCE_FLOATS = 16
"""Numbers one ray takes per triangle in a brute-force search."""


def _cross(a: Array, b: Array) -> Array:
    return jnp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def _moller_trumbore_parts(o, d, v0, e1, e2) -> tuple[Array, Array, Array, Array]:
    """`moller_trumbore` on coordinates: each argument a tuple ``(x, y, z)`` of arrays
    that broadcast (a triangle as its corner `v0` and edges ``e1 = v1 - v0``,
    ``e2 = v2 - v0``). Elementwise arithmetic only, which XLA fuses into one loop (the
    same written with stacked vectors and sums ran 5x slower in the tree search)."""
    px = d[1] * e2[2] - d[2] * e2[1]
    py = d[2] * e2[0] - d[0] * e2[2]
    pz = d[0] * e2[1] - d[1] * e2[0]
    det = e1[0] * px + e1[1] * py + e1[2] * pz
    parallel = jnp.abs(det) < jnp.finfo(det.dtype).tiny
    inv = jnp.where(parallel, 0.0, 1.0 / jnp.where(parallel, 1.0, det))
    sx, sy, sz = o[0] - v0[0], o[1] - v0[1], o[2] - v0[2]
    b1 = (sx * px + sy * py + sz * pz) * inv
    qx = sy * e1[2] - sz * e1[1]
    qy = sz * e1[0] - sx * e1[2]
    qz = sx * e1[1] - sy * e1[0]
    b2 = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv
    return t, b1, b2, det


def _parts(a: Array) -> tuple[Array, Array, Array]:
    return a[..., 0], a[..., 1], a[..., 2]


def moller_trumbore(origin, direction, v0, v1, v2):
    """Ray ``origin + t direction`` against triangles ``(v0, v1, v2)`` (broadcasting).

    **Returns:** ``(t, b1, b2, det)``: the ray parameter, the barycentric weights of
    ``v1`` and ``v2`` (``b0 = 1 - b1 - b2``) and the determinant (0 for a ray parallel to
    the triangle's plane, where the other outputs are 0 instead of infinite).
    """
    return _moller_trumbore_parts(
        _parts(origin), _parts(direction), _parts(v0), _parts(v1 - v0), _parts(v2 - v0)
    )


def _is_hit(t, b1, b2, det, t_min):
    """Whether a `moller_trumbore` result is a hit past `t_min`. Edges count as inside
    (``b >= 0``), so a ray through a shared edge or vertex of a closed mesh is not lost
    between its triangles."""
    return (det != 0) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > t_min)


def ray_triangle_distances(
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    triangles: Float[Array, "F 3 3"],
    t_min: float | Array = 0.0,
) -> Float[Array, "P F"]:
    """Ray parameter of every ray/triangle hit with ``t > t_min``; ``inf`` for misses
    (edges count as inside)."""
    o = origins[:, None, :]
    d = directions[:, None, :]
    t, b1, b2, det = moller_trumbore(
        o, d, triangles[None, :, 0], triangles[None, :, 1], triangles[None, :, 2]
    )
    return jnp.where(_is_hit(t, b1, b2, det, t_min), t, jnp.inf)


def search_bytes(rays: int, faces: int, dtype=jnp.float64) -> int:
    """Memory of one `nearest_hits` batch of `rays` rays among `faces` triangles, bytes
    (for the renderers' estimates)."""
    size = jnp.dtype(dtype).itemsize
    if faces <= BRUTE_FORCE_FACES:
        return size * rays * faces * BRUTE_FORCE_FLOATS
    return size * (rays * HIERARCHY_RAY_FLOATS + faces * HIERARCHY_FACE_FLOATS)


class Hierarchy(eqx.Module):
    """A bounding volume hierarchy over triangles, numbered as a heap.

    Node ``k`` (from 1) has children ``2k`` and ``2k + 1``; the ``2^depth`` leaves are
    nodes ``2^depth ... 2^(depth+1) - 1``. Build with `build_hierarchy`.

    - `leaves`: ``(2^depth, LEAF_FACES)`` triangle indices of each leaf; ``F`` (one past
      the last) pads a leaf of fewer triangles.
    - `leaf_triangles`: ``(2^depth, 9, LEAF_FACES)`` each leaf's triangles as rows of
      coordinates (``v0`` x, y, z, ``v1 - v0`` x, y, z, ``v2 - v0`` x, y, z), zero
      (degenerate: no ray hits it) in a padding slot; one row read per visit.
    - `boxes`: ``(2^(depth+1), 6)`` each node's box, lower then upper corner (row 0
      unused).
    - `axes`: ``(2^(depth+1),)`` the axis (0, 1, 2) along which each inner node was
      split: its first child holds the lower coordinates.
    """

    leaves: Int[Array, "L K"]
    leaf_triangles: Float[Array, "L 9 K"]
    boxes: Float[Array, "N 6"]
    axes: Int[Array, " N"]


def _levels(faces: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The tree's shape, which depends on the number of triangles alone: per level,
    each node's first position in the sorted triangles and its count."""
    depth = max(0, math.ceil(math.log2(faces / LEAF_FACES))) if faces > LEAF_FACES else 0
    starts = np.zeros(1, np.int64)
    levels = []
    for _ in range(depth + 1):
        sizes = np.diff(np.append(starts, faces))
        levels.append((starts, sizes))
        starts = np.stack([starts, starts + sizes // 2], axis=1).ravel()
    return levels


def build_hierarchy(triangles: Float[Array, "F 3 3"]) -> Hierarchy:
    """A `Hierarchy` over `triangles` (no derivatives; works under `jit` and `vmap`).

    Every node is split at the median, along the longest side of its triangles'
    centroids' box, into two halves (its children). The boxes are widened by a few
    rounding units so that a ray grazing a triangle's edge still enters its leaf.
    """
    tri = jax.lax.stop_gradient(triangles)
    faces = tri.shape[0]
    centroid = tri.mean(axis=1)
    levels = _levels(faces)
    order = jnp.arange(faces, dtype=jnp.int32)
    position = np.arange(faces)
    axes = [jnp.zeros(1, jnp.int32)]  # (row 0 unused)
    for starts, sizes in levels[:-1]:
        node = np.repeat(np.arange(starts.size), sizes)
        c = centroid[order]
        span = jax.ops.segment_max(c, node, starts.size, indices_are_sorted=True)
        span = span - jax.ops.segment_min(c, node, starts.size, indices_are_sorted=True)
        axes.append(jnp.argmax(span, axis=1).astype(jnp.int32))
        key = c[position, axes[-1][node]]
        order = order[jnp.lexsort((key, jnp.asarray(node)))]
    axes.append(jnp.zeros(levels[-1][0].size, jnp.int32))  # leaves: not split
    starts, sizes = levels[-1]
    slots = np.arange(LEAF_FACES)
    filled = slots[None, :] < sizes[:, None]
    leaves = jnp.where(filled, order[np.where(filled, starts[:, None] + slots, 0)], faces)

    fill = filled[:, :, None, None]
    corners = jnp.where(fill, tri[jnp.where(filled, leaves, 0)], 0.0)  # (L, K, 3, 3)
    lower = [jnp.min(jnp.where(fill, corners, jnp.inf), axis=(1, 2))]
    upper = [jnp.max(jnp.where(fill, corners, -jnp.inf), axis=(1, 2))]
    while lower[0].shape[0] > 1:  # parents from their two children, up to the root
        lower.insert(0, jnp.minimum(lower[0][0::2], lower[0][1::2]))
        upper.insert(0, jnp.maximum(upper[0][0::2], upper[0][1::2]))
    scale = jnp.max(jnp.abs(tri))
    pad = 64 * jnp.finfo(tri.dtype).eps * scale + jnp.finfo(tri.dtype).tiny
    unused = jnp.zeros((1, 3), tri.dtype)
    v0 = corners[:, :, 0]
    rows = jnp.concatenate([v0, corners[:, :, 1] - v0, corners[:, :, 2] - v0], axis=-1)
    return Hierarchy(
        leaves=leaves,
        leaf_triangles=jnp.swapaxes(rows, 1, 2),
        boxes=jnp.concatenate(
            [jnp.concatenate([unused] + lower) - pad, jnp.concatenate([unused] + upper) + pad],
            axis=1,
        ),
        axes=jnp.concatenate(axes),
    )


def _visit(tree: Hierarchy, t_min, lane):
    """One step of one ray's walk through `tree` (see `_search_tree`): the node's box,
    a leaf's triangles, and the next node. **Returns** the lane's new ``(node, seen,
    best_t, best)``."""
    o, d, inverse, skip, node, seen, best_t, best = lane
    first_leaf = tree.leaves.shape[0]
    box = tree.boxes[node]
    t0 = (box[:3] - o) * inverse
    t1 = (box[3:] - o) * inverse
    near = jnp.max(jnp.minimum(t0, t1))
    far = jnp.min(jnp.maximum(t0, t1))
    enter = (near <= far) & (far >= t_min) & (near <= best_t)
    leaf = node >= first_leaf
    slot = jnp.clip(node - first_leaf, 0, first_leaf - 1)
    index = tree.leaves[slot]
    rows = tree.leaf_triangles[slot]
    hit = _moller_trumbore_parts(
        _parts(o), _parts(d), tuple(rows[0:3]), tuple(rows[3:6]), tuple(rows[6:9])
    )
    visible = _is_hit(*hit, t_min) & (index != skip) & enter & leaf
    t = jnp.where(visible, hit[0], jnp.inf)
    t_leaf = jnp.min(t)
    k = jnp.min(jnp.where(t == t_leaf, index, jnp.iinfo(jnp.int32).max))
    # ties go to the lower index, as in the brute-force search
    better = (t_leaf < best_t) | ((t_leaf == best_t) & (k < best))
    best_t = jnp.where(better, t_leaf, best_t)
    best = jnp.where(better, k, best)
    # down: the child on the ray's side first; or on, past this subtree
    down = enter & ~leaf
    back = d[tree.axes[node]] < 0
    done = jax.lax.population_count(seen ^ (seen + 1)) - 1  # trailing second visits
    up = seen >> done
    node = jnp.where(down, 2 * node + back, jnp.where(up == 0, 0, (node >> done) ^ 1))
    seen = jnp.where(down, 2 * seen, up + 1)
    return node, seen, best_t, best


def _search_tree(origins, directions, exclude, tree: Hierarchy, t_min, lanes: int):
    """Nearest hits of rays in `tree`: ``(t, index)`` as `nearest_hits`.

    Each ray walks the tree front to back, without a stack: at an inner node it enters
    first the child on its own side of the split (the upper one where it runs towards
    lower coordinates), and skips every box beyond the nearest hit found so far.
    Besides the node's heap number the walk keeps its number in the ray's own order
    (`seen`: a 0 bit for the child entered first, 1 for the second, at every level);
    after a subtree, the next node is found by stripping the trailing second visits off
    that number and stepping to the sibling of the node reached (0: the walk is over).

    `lanes` rays walk together, one node a step; a lane whose ray is done takes the next
    ray at once, so that no lane idles while a long walk ends (rays took 1 to 150 steps,
    31 on average, on a 20,480-face ball: batches that wait for their slowest ray spent
    three times the steps).
    """
    rays = origins.shape[0]
    lanes = min(lanes, max(MIN_LANES, rays // RAYS_PER_LANE), rays)
    tiny = jnp.finfo(directions.dtype).tiny
    safe = jnp.where(jnp.abs(directions) < tiny, jnp.where(directions < 0, -tiny, tiny), directions)
    inverses = 1.0 / safe

    def load(ray):
        k = jnp.minimum(ray, rays - 1)  # an idle lane (``ray == rays``) reads the last ray
        return origins[k], directions[k], inverses[k], exclude[k]

    start = jnp.arange(lanes, dtype=jnp.int32)
    ones = jnp.ones(lanes, jnp.int32)
    inf = jnp.full(lanes, jnp.inf, origins.dtype)
    walk = (ones, ones, inf, jnp.zeros(lanes, jnp.int32))
    out = (jnp.full(rays, jnp.inf, origins.dtype), jnp.zeros(rays, jnp.int32))
    init = (start, jnp.int32(lanes), walk, out)

    def step(state):
        ray, next_ray, walk, (out_t, out_index) = state
        walk = jax.vmap(functools.partial(_visit, tree, t_min))((*load(ray), *walk))
        node, seen, best_t, best = walk
        finished = (node == 0) & (ray < rays)
        target = jnp.where(finished, ray, rays)  # writes of the other lanes are dropped
        out_t = out_t.at[target].set(best_t, mode="drop")
        out_index = out_index.at[target].set(best, mode="drop")
        fresh = next_ray + jnp.cumsum(finished, dtype=jnp.int32) - 1
        ray = jnp.where(finished, jnp.minimum(fresh, rays), ray)
        next_ray = next_ray + jnp.sum(finished, dtype=jnp.int32)
        restart = (ones, ones, inf, jnp.zeros(lanes, jnp.int32))
        walk = tuple(jnp.where(finished, r, w) for r, w in zip(restart, walk, strict=True))
        return ray, next_ray, walk, (out_t, out_index)

    _, _, _, (t, index) = jax.lax.while_loop(lambda s: jnp.any(s[0] < rays), step, init)
    return t, jnp.where(jnp.isfinite(t), index, 0)


def nearest_hits(
    origins: Float[Array, "P 3"],
    directions: Float[Array, "P 3"],
    triangles: Float[Array, "F 3 3"],
    t_min: float | Array = 0.0,
    batch_size: int = 4096,
    exclude: Int[Array, " P"] | None = None,
    tree: Hierarchy | None = None,
) -> tuple[Float[Array, " P"], Int[Array, " P"]]:
    """Nearest hit of each ray among `triangles` (no derivatives).

    `exclude` (optional, one index per ray, -1 for none) is a triangle each ray must not
    hit: the one it just left, which a straight ray cannot meet again. `tree`: the
    triangles' `Hierarchy` when the caller has built it already; otherwise one is built
    here for more than `BRUTE_FORCE_FACES` triangles.

    **Returns:** ``(t, index)``: the ray parameter (``inf`` when the ray misses every
    triangle) and the triangle's index (0 for a miss; check ``isfinite(t)``).
    """
    sg = jax.lax.stop_gradient
    origins, directions, triangles = sg(origins), sg(directions), sg(triangles)

    if exclude is None:
        exclude = jnp.full(origins.shape[:1], -1, jnp.int32)
    if tree is None:
        tree = search_tree(triangles)
    if tree is not None:
        return _search_tree(origins, directions, exclude, sg(tree), t_min, batch_size)
    index = jnp.arange(triangles.shape[0], dtype=jnp.int32)

    def one(ray):
        o, d, skip = ray
        t = ray_triangle_distances(o[None], d[None], triangles, t_min)[0]
        t = jnp.where(index == skip, jnp.inf, t)
        # the lowest index at the nearest t, by two plain minima: XLA fuses them with
        # the distances, where argmin and t[k] ran apart (2.5 against 5 to 9 ms, 9409
        # rays among 320 triangles)
        best = jnp.min(t)
        return best, jnp.min(jnp.where(t == best, index, triangles.shape[0]))

    t, index = jax.lax.map(one, (origins, directions, exclude), batch_size=batch_size)
    return t, jnp.where(jnp.isfinite(t), index, 0)


def search_tree(triangles: Float[Array, "F 3 3"]) -> Hierarchy | None:
    """The `Hierarchy` `nearest_hits` would build for `triangles`, or ``None`` where it
    searches by brute force: build it once for many searches among the same triangles."""
    if triangles.shape[0] > BRUTE_FORCE_FACES:
        return build_hierarchy(triangles)
    return None


def hit_on_triangle(
    origin: Float[Array, "... 3"],
    direction: Float[Array, "... 3"],
    triangle: Float[Array, "... 3 3"],
) -> tuple[Float[Array, "..."], Float[Array, "... 3"]]:
    """Differentiable hit of rays with given triangles (whose index was chosen already).

    **Returns:** ``(t, barycentric)`` with ``barycentric = (b0, b1, b2)`` along the last
    axis.
    """
    t, b1, b2, _ = moller_trumbore(
        origin, direction, triangle[..., 0, :], triangle[..., 1, :], triangle[..., 2, :]
    )
    return t, jnp.stack([1.0 - b1 - b2, b1, b2], axis=-1)


def face_normals(vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"]) -> Float[Array, "F 3"]:
    """Unnormalised face normals ``(v1 - v0) x (v2 - v0)`` (length = twice the area)."""
    tri = vertices[faces]
    return _cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def vertex_normals(vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"]) -> Float[Array, "V 3"]:
    """Unit vertex normals: the normalised sum of the area-weighted normals of the faces
    around each vertex."""
    fn = face_normals(vertices, faces)
    acc = jnp.zeros_like(vertices).at[faces.reshape(-1)].add(jnp.repeat(fn, 3, axis=0))
    norm = jnp.linalg.norm(acc, axis=-1, keepdims=True)
    return acc / jnp.where(norm > 0, norm, 1.0)
