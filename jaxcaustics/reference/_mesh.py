"""Photon tracing through triangle meshes (`MeshScene`), plain NumPy, float64.

Photons leave the light (`emit_mesh_photons`), and make at most ``scene.interfaces``
events with the generator: mirror reflection about the shading normal, refraction
(entering or leaving decided by the geometric normal, ``d . n_face < 0`` enters), or
total internal reflection (stays on its side, factor 1); an occluder met before the
next generator hit stops a photon. Photons that never meet the generator are not
rendered; those still inside after the last event, or about to meet the generator
again, are dropped; the rest must go down and reach ``z = 0`` past the occluders. Flat
normals are face normals; smooth ones interpolate area-weighted vertex normals with
the hit's barycentrics. See the package docstring.

Ray/triangle hits are exact Möller–Trumbore tests in float64. A bounding volume
hierarchy (median splits, complete binary tree, boxes padded outwards) only culls the
triangles a ray cannot hit; it never changes which hit is the nearest.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from ._lens import (
    LANDED,
    _cells,
    _check_int,
    _finish_stats,
    _grid_shape,
    _image,
    _Light,
    _read_iors,
    _Receiver,
    _refract_rays,
    _rng,
)
from ._optics import MAX_EMITTED, _check_bool, _real, chunk_photons

# Photons traced per vectorised batch (emission), and rays per BVH traversal batch.
_CHUNK = 1 << 16
_RAYS = 1 << 11
# Faces per leaf of the hierarchy at most.
_LEAF = 2
# Barycentric slack of the inside test: a ray through a shared edge hits (at least) one
# of the two triangles despite rounding (no leaks through the cracks of a closed mesh).
_BARY_TOL = 1e-12
# Hits nearer than this fraction of the scene's size along a ray are ignored (besides the
# triangle the ray leaves, which a straight ray cannot meet again).
_REL_T_MIN = 1e-9

# Photon fates beyond the lens codes (LANDED = 0 is shared).
_ACTIVE = -1
MISSED = 5  # never met the generator
BLOCKED = 6  # stopped by an occluder
DROPPED = 7  # still inside after `interfaces` events, or would meet the generator again
UPWARD = 8  # left the generator going up (or horizontally) without meeting an occluder


# --------------------------------------------------------------------------- triangles


@dataclasses.dataclass(frozen=True, eq=False)
class _Tris:
    """Triangles (structure of arrays) with a bounding volume hierarchy.

    The faces are sorted so that node ``k`` of level ``l`` (``2**l`` nodes) covers a
    contiguous range of them; its children are nodes ``2k`` and ``2k + 1`` of level
    ``l + 1``. Leaves (the last level) list at most `_LEAF` faces, padded with the index
    ``count`` of a degenerate dummy triangle that no ray hits.
    """

    v0: np.ndarray  # (3, F + 1)
    e1: np.ndarray  # (3, F + 1): v1 - v0
    e2: np.ndarray  # (3, F + 1): v2 - v0
    boxes: list[tuple[np.ndarray, np.ndarray]]  # per level: lo (3, K), hi (3, K)
    leaves: np.ndarray  # (K_leaves, _LEAF)
    count: int

    @classmethod
    def build(cls, vertices: np.ndarray, faces: np.ndarray) -> _Tris:
        tri = vertices[faces]  # (F, 3 corners, 3 coordinates)
        f = tri.shape[0]
        scale = float(np.abs(tri).max()) + float(np.ptp(tri.reshape(-1, 3), axis=0).max())
        pad = 1e-9 * scale + 1e-300
        depth = max(0, math.ceil(math.log2(f / _LEAF))) if f > _LEAF else 0
        centroid = tri.mean(axis=1)
        t_lo, t_hi = tri.min(axis=1), tri.max(axis=1)
        order = np.arange(f)
        starts = np.zeros(1, dtype=np.int64)
        boxes = []
        for level in range(depth + 1):
            sizes = np.diff(np.append(starts, f))
            boxes.append(
                (
                    np.minimum.reduceat(t_lo[order], starts, axis=0).T - pad,
                    np.maximum.reduceat(t_hi[order], starts, axis=0).T + pad,
                )
            )
            if level == depth:
                break
            # Split every node at its median along the longest side of its centroids' box.
            c = centroid[order]
            span = np.maximum.reduceat(c, starts, axis=0) - np.minimum.reduceat(c, starts, axis=0)
            node = np.repeat(np.arange(starts.size), sizes)
            key = c[np.arange(f), np.argmax(span, axis=1)[node]]
            order = order[np.lexsort((key, node))]
            starts = np.stack([starts, starts + sizes // 2], axis=1).ravel()
        sizes = np.diff(np.append(starts, f))
        leaves = np.full((starts.size, _LEAF), f, dtype=np.int64)
        for slot in range(_LEAF):
            has = sizes > slot
            leaves[has, slot] = order[starts[has] + slot]
        zero = np.zeros((1, 3))
        return cls(
            v0=np.concatenate([tri[:, 0], zero]).T.copy(),
            e1=np.concatenate([tri[:, 1] - tri[:, 0], zero]).T.copy(),
            e2=np.concatenate([tri[:, 2] - tri[:, 0], zero]).T.copy(),
            boxes=boxes,
            leaves=leaves,
            count=f,
        )

    def hits(
        self, o: np.ndarray, d: np.ndarray, r: np.ndarray, f: np.ndarray, t_min: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Möller–Trumbore for the pairs (ray ``r``, face ``f``): ``t``, barycentrics
        ``(u, v)`` of ``v1`` and ``v2``, and whether it is a hit with ``t > t_min``."""
        ox, oy, oz = o[0, r], o[1, r], o[2, r]
        dx, dy, dz = d[0, r], d[1, r], d[2, r]
        e1x, e1y, e1z = self.e1[0, f], self.e1[1, f], self.e1[2, f]
        e2x, e2y, e2z = self.e2[0, f], self.e2[1, f], self.e2[2, f]
        px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz
        sx, sy, sz = ox - self.v0[0, f], oy - self.v0[1, f], oz - self.v0[2, f]
        qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = (sx * px + sy * py + sz * pz) * inv
            v = (dx * qx + dy * qy + dz * qz) * inv
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            hit = (
                (det != 0.0)
                & (u >= -_BARY_TOL)
                & (v >= -_BARY_TOL)
                & (u + v <= 1.0 + _BARY_TOL)
                & (t > t_min)
                & np.isfinite(t)
            )
        return t, u, v, hit

    def nearest(
        self,
        o: np.ndarray,
        d: np.ndarray,
        t_min: float,
        skip: np.ndarray | None = None,
        brute: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Nearest hit with ``t > t_min`` of rays ``o + t d`` (``o``, ``d``: (3, N)),
        ignoring face ``skip[i]`` for ray ``i`` (-1: none).

        Returns ``t`` (inf: no hit), the face (-1: none) and the barycentrics ``(u, v)``
        of the face's second and third vertices. ``brute`` tests every face (no
        hierarchy).
        """
        n = o.shape[1]
        t_best = np.full(n, np.inf)
        face = np.full(n, -1, dtype=np.int64)
        bu, bv = np.zeros(n), np.zeros(n)
        for lo in range(0, n, _RAYS):
            hi = min(lo + _RAYS, n)
            oc, dc = o[:, lo:hi], d[:, lo:hi]
            m = hi - lo
            if brute:
                r = np.repeat(np.arange(m), self.count)
                f = np.tile(np.arange(self.count), m)
            else:
                r, f = self._candidates(oc, dc, t_min)
            if not r.size:
                continue
            t, u, v, hit = self.hits(oc, dc, r, f, t_min)
            if skip is not None:
                hit &= f != skip[lo:hi][r]
            r, f, t, u, v = r[hit], f[hit], t[hit], u[hit], v[hit]
            best = np.full(m, np.inf)
            np.minimum.at(best, r, t)
            sel = t == best[r]
            rows = lo + r[sel]
            t_best[rows], face[rows], bu[rows], bv[rows] = t[sel], f[sel], u[sel], v[sel]
        return t_best, face, bu, bv

    def _candidates(
        self, o: np.ndarray, d: np.ndarray, t_min: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(ray, face) pairs whose leaf box the ray meets (slab test, level by level)."""
        m = o.shape[1]
        inv = 1.0 / np.where(d == 0.0, 1e-300, d)  # finite: no 0 * inf below
        r = np.arange(m)
        k = np.zeros(m, dtype=np.int64)
        last = len(self.boxes) - 1
        for level, (blo, bhi) in enumerate(self.boxes):
            near = np.full(r.size, -np.inf)
            far = np.full(r.size, np.inf)
            with np.errstate(over="ignore", invalid="ignore"):
                for axis in range(3):
                    oo, ii = o[axis, r], inv[axis, r]
                    t1 = (blo[axis, k] - oo) * ii
                    t2 = (bhi[axis, k] - oo) * ii
                    near = np.maximum(near, np.minimum(t1, t2))
                    far = np.minimum(far, np.maximum(t1, t2))
            keep = (near <= far) & (far > t_min)
            r, k = r[keep], k[keep]
            if level < last:
                r = np.repeat(r, 2)
                k = (2 * k[:, None] + np.arange(2)).ravel()
        return np.repeat(r, _LEAF), self.leaves[k].ravel()


def _mesh_of(mesh, name: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        vertices, faces = mesh.vertices, mesh.faces
    except AttributeError as err:
        raise ValueError(f"`{name}` must have `vertices` and `faces`: {err}") from err
    return _mesh_arrays(vertices, faces, name)


def _mesh_arrays(vertices, faces, name: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise ValueError(f"`{name}.vertices` must be finite, of shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"`{name}.faces` must be integers of shape (F, 3), F >= 1, got {f.shape}")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValueError(f"`{name}.faces` indices must lie in [0, {v.shape[0] - 1}]")
    return v, f.astype(np.int64)


def intersect_mesh(
    vertices, faces, origins, directions, *, t_min: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit of rays with a triangle mesh (exact Möller–Trumbore, float64).

    **Arguments:**

    - `vertices`: array-like of shape ``(V, 3)``.
    - `faces`: array-like of ints, shape ``(F, 3)``.
    - `origins`, `directions`: array-likes of shape ``(N, 3)``: rays ``o + t d`` (``d``
      need not be unit; ``t`` is in its units).
    - `t_min`: only hits with ``t > t_min`` count (a float); default 0.0.

    **Returns:** ``(t, face, barycentrics)``:

    - `t`: `np.ndarray` of shape ``(N,)``, the ray parameter of the nearest hit, ``inf``
      where none.
    - `face`: `np.ndarray` of ints, shape ``(N,)``, the index of the face hit, -1 where
      none.
    - `barycentrics`: `np.ndarray` of shape ``(N, 3)``, ``(b0, b1, b2)`` of the hit point
      in the face's vertices (0 where none). A ray through a shared edge or vertex reports
      one of the faces there.
    """
    v, f = _mesh_arrays(vertices, faces, "mesh")
    o, d = (_real(a, name) for a, name in ((origins, "origins"), (directions, "directions")))
    o, d = o.reshape(-1, 3).T, d.reshape(-1, 3).T
    if o.shape != d.shape:
        raise ValueError("`origins` and `directions` must have the same shape (N, 3)")
    if not (isinstance(t_min, numbers.Real) and not isinstance(t_min, bool) and np.isfinite(t_min)):
        raise ValueError(f"`t_min` must be a finite number, got {t_min!r}")
    t, face, u, w = _Tris.build(v, f).nearest(o, d, float(t_min))
    hit = face >= 0
    bary = np.where(hit[:, None], np.stack([1.0 - u - w, u, w], axis=1), 0.0)
    return t, face, bary


# --------------------------------------------------------------------------- the scene


@dataclasses.dataclass(frozen=True, eq=False)
class _MeshScene:
    """A `MeshScene` read into float64 NumPy values (duck typed, validated)."""

    vertices: np.ndarray  # (V, 3)
    faces: np.ndarray  # (F, 3)
    gen: _Tris
    face_normal: np.ndarray  # (3, F) unit geometric normals
    vertex_normal: np.ndarray  # (3, V) unit, area-weighted
    occ: _Tris | None
    occ_vertices: np.ndarray  # (V_occ, 3), possibly empty
    light: _Light
    receiver: _Receiver
    mirror: bool
    smooth: bool
    iors: tuple[float, ...]
    multichannel: bool
    fresnel: bool
    interfaces: int
    t_min: float


def _read_mesh_scene(scene) -> _MeshScene:
    try:
        generator, light, receiver = scene.generator, scene.light, scene.receiver
        material, ior, fresnel = scene.material, scene.ior, scene.fresnel
        interfaces, normals = scene.interfaces, scene.normals
        occluders = tuple(getattr(scene, "occluders", ()))
    except AttributeError as err:
        raise ValueError(f"`scene` must be a MeshScene-like object: {err}") from err
    if material not in ("refractor", "mirror"):
        raise ValueError(f"`scene.material` must be 'refractor' or 'mirror', got {material!r}")
    if normals not in ("smooth", "flat"):
        raise ValueError(f"`scene.normals` must be 'smooth' or 'flat', got {normals!r}")
    interfaces = _check_int(interfaces, "scene.interfaces")
    v, f = _mesh_of(generator, "scene.generator")
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # (F, 3), |.| = 2 area
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    face_normal = np.where(length > 0.0, cross / np.where(length > 0.0, length, 1.0), 0.0)
    vn = np.zeros_like(v)
    for corner in range(3):
        np.add.at(vn, f[:, corner], cross)
    vn_len = np.linalg.norm(vn, axis=1, keepdims=True)
    vn = np.where(vn_len > 0.0, vn / np.where(vn_len > 0.0, vn_len, 1.0), 0.0)
    occ_v, occ_f = [], []
    offset = 0
    for k, occ in enumerate(occluders):
        ov, of = _mesh_of(occ, f"scene.occluders[{k}]")
        occ_v.append(ov)
        occ_f.append(of + offset)
        offset += ov.shape[0]
    occ_vertices = np.concatenate(occ_v) if occ_v else np.zeros((0, 3))
    everything = np.concatenate([v, occ_vertices])
    size = float(np.abs(everything).max() + np.ptp(everything, axis=0).max())
    mirror = material == "mirror"
    iors, multichannel = ((1.0,), False) if mirror else _read_iors(ior)
    return _MeshScene(
        vertices=v,
        faces=f,
        gen=_Tris.build(v, f),
        face_normal=face_normal.T.copy(),
        vertex_normal=vn.T.copy(),
        occ=_Tris.build(occ_vertices, np.concatenate(occ_f)) if occ_f else None,
        occ_vertices=occ_vertices,
        light=_Light.read(light),
        receiver=_Receiver.read(receiver),
        mirror=mirror,
        smooth=normals == "smooth",
        iors=iors,
        multichannel=multichannel,
        fresnel=bool(fresnel),
        interfaces=interfaces,
        t_min=_REL_T_MIN * size,
    )


# --------------------------------------------------------------------------- tracing


@dataclasses.dataclass
class _Paths:
    """Per-channel results of `_trace_channel` (arrays of shape (N,))."""

    x: np.ndarray  # landing point (0 unless landed)
    y: np.ndarray
    weight: np.ndarray  # flux carried to the screen (0 unless landed)
    status: np.ndarray  # LANDED, MISSED, BLOCKED, DROPPED, UPWARD
    events: np.ndarray  # interface events (refractions, reflections, TIR)
    tir: np.ndarray  # total internal reflections among them
    direction: np.ndarray  # (3, N) direction after the last event


def _trace_channel(
    ms: _MeshScene,
    o: np.ndarray,
    d: np.ndarray,
    w: np.ndarray,
    ior: float,
    first: tuple[np.ndarray, ...] | None = None,
) -> _Paths:
    """Follow photons ``o + t d`` (3, N), flux `w`, through the generator (one index)."""
    n = o.shape[1]
    o, d, w = o.copy(), d.copy(), w.astype(np.float64, copy=True)
    status = np.full(n, _ACTIVE, dtype=np.int8)
    inside = np.zeros(n, dtype=bool)
    skip = np.full(n, -1, dtype=np.int64)
    events = np.zeros(n, dtype=np.int64)
    tir_count = np.zeros(n, dtype=np.int64)
    gx, gy = np.zeros(n), np.zeros(n)
    for k in range(ms.interfaces + 1):
        a = np.flatnonzero(status == _ACTIVE)
        if not a.size:
            break
        oa, da = o[:, a], d[:, a]
        if k == 0 and first is not None:
            tg, fg, bu, bv, to = first
        else:
            tg, fg, bu, bv = ms.gen.nearest(oa, da, ms.t_min, skip[a])
            if ms.occ is not None:
                to = ms.occ.nearest(oa, da, ms.t_min)[0]
            else:
                to = np.full(tg.shape, np.inf)
        gen = np.isfinite(tg)
        occ_first = to < tg
        ins = inside[a]
        st = np.full(a.size, _ACTIVE, dtype=np.int8)
        if k == 0:
            st[~gen] = MISSED
        else:
            st[~gen & ins] = DROPPED  # inside a closed mesh, no way out: only by rounding
            leave = ~gen & ~ins
            down = leave & (da[2] < 0.0)
            st[leave & ~down] = np.where(np.isfinite(to[leave & ~down]), BLOCKED, UPWARD)
            with np.errstate(divide="ignore", invalid="ignore"):
                ts = np.where(down, -oa[2] / da[2], 0.0)
            st[down & (to <= ts)] = BLOCKED
            land = down & ~(to <= ts)
            st[land] = LANDED
            gx[a[land]] = oa[0, land] + ts[land] * da[0, land]
            gy[a[land]] = oa[1, land] + ts[land] * da[1, land]
        if k == ms.interfaces:  # no event left: inside, or meeting the generator again
            st[gen & ins] = DROPPED
            st[gen & ~ins & occ_first] = BLOCKED
            st[gen & ~ins & ~occ_first] = DROPPED
        else:
            st[gen & occ_first] = BLOCKED
        status[a] = st
        ev = gen & (st == _ACTIVE)
        if not ev.any():
            continue
        e = a[ev]
        de = da[:, ev]
        p = oa[:, ev] + tg[ev] * de
        face = fg[ev]
        ng = ms.face_normal[:, face]
        entering = np.sum(de * ng, axis=0) < 0.0
        if ms.smooth:
            b1, b2 = bu[ev], bv[ev]
            corners = ms.faces[face]
            ns = (
                (1.0 - b1 - b2) * ms.vertex_normal[:, corners[:, 0]]
                + b1 * ms.vertex_normal[:, corners[:, 1]]
                + b2 * ms.vertex_normal[:, corners[:, 2]]
            )
            length = np.linalg.norm(ns, axis=0)
            ns = np.where(length > 0.0, ns / np.where(length > 0.0, length, 1.0), ng)
        else:
            ns = ng
        dot = np.sum(de * ns, axis=0)
        if ms.mirror:
            nd = de - 2.0 * dot * ns
            tir = np.zeros(e.size, dtype=bool)
            new_inside = np.zeros(e.size, dtype=bool)
        else:
            ns = np.where(dot > 0.0, -ns, ns)  # oriented against the ray
            eta = np.where(entering, 1.0 / ior, ior)
            refracted, tr, tir = _refract_rays(de, ns, eta, ms.fresnel)
            reflected = de + 2.0 * np.abs(dot) * ns
            nd = np.where(tir, reflected, refracted)
            new_inside = np.where(tir, ~entering, entering)
            w[e] *= np.where(tir, 1.0, tr)
        o[:, e] = p
        d[:, e] = nd / np.linalg.norm(nd, axis=0)
        skip[e] = face
        inside[e] = new_inside
        events[e] += 1
        tir_count[e] += tir
    landed = status == LANDED
    return _Paths(
        x=gx,
        y=gy,
        weight=np.where(landed, w, 0.0),
        status=status,
        events=events,
        tir=tir_count,
        direction=d,
    )


def _trace_mesh(ms: _MeshScene, o: np.ndarray, d: np.ndarray, w: np.ndarray) -> list[_Paths]:
    """All channels; the first hits (independent of the index) are found once."""
    tg, fg, bu, bv = ms.gen.nearest(o, d, ms.t_min)
    to = ms.occ.nearest(o, d, ms.t_min)[0] if ms.occ is not None else np.full(tg.shape, np.inf)
    return [_trace_channel(ms, o, d, w, ior, (tg, fg, bu, bv, to)) for ior in ms.iors]


def _rays(origins, directions, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    o = _real(origins, "origins").reshape(-1, 3)
    d = _real(directions, "directions").reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError(f"`origins` and `directions` must both be (N, 3), got {o.shape} {d.shape}")
    try:
        w = np.broadcast_to(_real(weights, "weights"), o.shape[:1]).copy()
    except ValueError as err:
        raise ValueError(f"`weights` must be one number or one per ray: {err}") from err
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    if not np.all(norm > 0.0) or not np.all(np.isfinite(o)) or not np.all(np.isfinite(d)):
        raise ValueError("`origins` and `directions` must be finite, directions non-zero")
    return o.T.copy(), (d / norm).T.copy(), w


def trace_mesh_photons(
    scene, origins, directions, weights=1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trace given photons through a `MeshScene`, one channel per index of refraction.

    **Arguments:**

    - `scene`: a `MeshScene`, read by duck typing (see the module docstring).
    - `origins`, `directions`: array-likes of shape ``(N, 3)``: rays ``o + t d``,
      ``t > 0`` (directions are normalised here). Start them before anything they should
      meet (from the light).
    - `weights`: array-like of shape ``(N,)`` or a scalar, the flux each photon carries
      (see `emit_mesh_photons`); default 1.0.

    **Returns:** ``(landing_xy, weight, alive)``:

    - `landing_xy`: `np.ndarray` of shape ``(C, N, 2)``, landing points on ``z = 0`` (0
      where not alive); ``C = 1`` for a mirror.
    - `weight`: `np.ndarray` of shape ``(C, N)``, the flux reaching the screen: `weights`
      times the Fresnel transmittance of every refraction if ``scene.fresnel``; 0 where
      not alive.
    - `alive`: `np.ndarray` of bools, shape ``(C, N)``, True for photons that met the
      generator and landed on ``z = 0`` (anywhere).
    """
    ms = _read_mesh_scene(scene)
    o, d, w = _rays(origins, directions, weights)
    paths = _trace_mesh(ms, o, d, w)
    landing = np.stack([np.stack([p.x, p.y], axis=-1) for p in paths])
    return (
        landing,
        np.stack([p.weight for p in paths]),
        np.stack([p.status == LANDED for p in paths]),
    )


# --------------------------------------------------------------------------- emission


@dataclasses.dataclass(frozen=True)
class _Emitter:
    """A grid of cells on a plane through `centre` spanned by unit `u`, `v`, perpendicular
    to the light's direction (directional) or to the axis light -> centre (point)."""

    centre: np.ndarray
    u: np.ndarray
    v: np.ndarray
    axis: np.ndarray  # unit normal of the plane, along the light
    rect: tuple[float, float, float, float]  # (a0, a1, b0, b1) along u and v
    back: float  # directional: origins are `back` before the plane along the light
    light: _Light

    def photons(
        self, rows: int, cols: int, lo: int, hi: int, rng
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a0, a1, b0, b1 = self.rect
        ha, hb = (a1 - a0) / cols, (b1 - b0) / rows
        fa, fb = _cells(rows, cols, lo, hi, rng)
        q = (
            self.centre[:, None]
            + (a0 + fa * ha) * self.u[:, None]
            + (b0 + fb * hb) * self.v[:, None]
        )
        if not self.light.is_point:
            d = np.repeat(self.axis[:, None], q.shape[1], axis=1)
            w = np.full(q.shape[1], ha * hb / abs(float(self.axis[2])))
            return q - self.back * d, d, w
        assert self.light.position is not None
        p = self.light.position[:, None]
        d = q - p
        r2 = np.sum(d * d, axis=0)
        d = d / np.sqrt(r2)
        w = self.light.intensity * np.abs(self.axis @ d) * (ha * hb) / r2
        if self.light.lambertian:
            w = w * np.abs(d[2])
        return np.repeat(p, q.shape[1], axis=1), d, w


def _emitter(ms: _MeshScene) -> _Emitter:
    v = ms.vertices
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.linalg.norm(v - centre, axis=1).max())
    light = ms.light
    if light.is_point:
        assert light.position is not None
        axis = centre - light.position
        dist = float(np.linalg.norm(axis))
        if not dist > 0.0:
            raise ValueError("the point light sits at the centre of the generator")
        axis = axis / dist
    else:
        assert light.direction is not None
        axis = light.direction
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = helper - (helper @ axis) * axis
    u /= np.linalg.norm(u)
    w = np.cross(u, axis)
    rel = v - centre
    if light.is_point:
        assert light.position is not None
        depth = (v - light.position) @ axis  # distance in front of the light along the axis
        if not np.all(depth > 1e-9 * max(radius, dist)):
            raise ValueError(
                "the point light must see the whole generator in front of it (every vertex "
                "beyond the plane through the light perpendicular to the light -> centre axis)"
            )
        proj = light.position + (v - light.position) * (dist / depth)[:, None]
        rel = proj - centre
    a, b = rel @ u, rel @ w
    pad = 1e-9 * max(radius, 1e-300)
    rect = (float(a.min()) - pad, float(a.max()) + pad, float(b.min()) - pad, float(b.max()) + pad)
    everything = np.concatenate([v, ms.occ_vertices])
    back = max(0.0, float(((centre - everything) @ axis).max())) + radius + 1e-3 * max(radius, 1.0)
    return _Emitter(centre, u, w, axis, rect, back, light)


def emit_mesh_photons(
    scene, photons_per_axis=512, *, jitter: bool = False, seed=0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The photons `trace_mesh` emits: origins (N, 3), unit directions (N, 3), flux (N,).

    The generator's vertices are projected onto a plane through the centre of its
    bounding box, perpendicular to the light's direction (directional light: parallel
    projection) or to the axis from a point light to that centre (central projection from
    the light; every vertex must lie in front of the light along that axis). The
    bounding rectangle of the projections (padded by 1e-9 of the generator's size) is
    cut into a ``rows x cols`` grid of equal cells (axis ``u`` across columns, ``v``
    across rows), one photon per cell at its centre or jittered in it. A directional
    photon starts on the light's line through its grid point, before every vertex of the
    generator and occluders, and carries ``A_perp / |d_z|`` (``A_perp`` the cell's area);
    a point-light photon starts at the light, goes through its grid point ``q`` and
    carries ``I |w . axis| A / r^2`` (``r = |q - light|``). Rows are row-major over the
    grid.
    """
    ms = _read_mesh_scene(scene)
    rows, cols = _grid_shape(photons_per_axis, MAX_EMITTED)
    o, d, w = _emitter(ms).photons(rows, cols, 0, rows * cols, _rng(jitter, seed))
    return o.T.copy(), d.T.copy(), w


def trace_mesh(
    scene,
    photons_per_axis=512,
    *,
    jitter: bool = False,
    seed=0,
    return_stats: bool = False,
    memory_limit: int | None = None,
):
    """Irradiance on the screen of a `MeshScene` by forward photon tracing (ground truth).

    Photons from `emit_mesh_photons` are traced exactly (nearest ray/triangle hits,
    refraction, reflection, total internal reflection, Fresnel, occluders, up to
    ``scene.interfaces`` events; see the module docstring) and binned into the receiver's
    pixels. Only photons that met the generator count (no direct light).

    **Arguments:**

    - `scene`: a `MeshScene`, read by duck typing.
    - `photons_per_axis`: the emission grid over the generator's projection, an int or
      ``(rows, cols)``; an integer ``n`` gives ``n x n``; default 512. The accuracy knob
      (midpoint quadrature of the light's flux over each cell).
    - `jitter`: jitter each photon uniformly inside its cell
      (``numpy.random.default_rng(seed)``, draws in row-major cell order); default False.
    - `seed`: int seed for the jitter; default 0.
    - `return_stats`: also return a dict of photon counts (ints, or a tuple of ints per
      channel for a sequence of indices); default False: ``emitted``; ``hit_generator``
      (met the generator before any occluder); ``missed`` (never met the generator);
      ``blocked`` (stopped by an occluder, before or after the generator); ``dropped``
      (too many interfaces: still inside after ``scene.interfaces`` events, or about to
      meet the generator again); ``upward`` (left the generator going up or horizontally:
      never lands); ``landed`` (reached ``z = 0``); ``on_receiver`` (landed on the
      receiver); ``tir_photons`` (photons reflected totally at least once: in a mesh total
      internal reflection loses nothing by itself, such photons end up in one of the
      other fates) and ``tir_events`` (number of total internal reflections).
      ``emitted = missed + blocked + dropped + upward + landed``.
    - `memory_limit`: bytes of photons traced at a time, an int or None (``PHOTON_BYTES``
      = 1024 per photon, an estimate of its arrays and temporaries); default None: 2^16
      (64 MiB) photons at a time. The image does not depend on it (up to the order of
      float64 sums).

    **Returns:** a float64 `np.ndarray` of shape ``(rows, cols)`` (a scalar index, or a
    mirror) or ``(rows, cols, C)``: irradiance relative to the light's irradiance on a
    horizontal plane (directional light) or W/m^2 (point light). With `return_stats`,
    ``(image, stats)``.
    """
    ms = _read_mesh_scene(scene)
    chunk = chunk_photons(memory_limit, _CHUNK)
    rows, cols = _grid_shape(photons_per_axis)
    rng = _rng(jitter, seed)
    return_stats = _check_bool(return_stats, "return_stats")
    emitter = _emitter(ms)
    rec = ms.receiver
    c = len(ms.iors)
    flux = np.zeros((c, rec.shape[0] * rec.shape[1]))
    keys: tuple[str, ...] = ("missed", "blocked", "dropped", "upward", "landed", "on_receiver")
    keys += ("tir_photons", "tir_events")
    counts = {key: np.zeros(c, dtype=np.int64) for key in keys}
    codes = {"missed": MISSED, "blocked": BLOCKED, "dropped": DROPPED, "upward": UPWARD}
    codes["landed"] = LANDED
    hit = np.zeros(c, dtype=np.int64)
    total = rows * cols
    for lo in range(0, total, chunk):
        o, d, w = emitter.photons(rows, cols, lo, min(lo + chunk, total), rng)
        for k, path in enumerate(_trace_mesh(ms, o, d, w)):
            f, m = rec.bin(path.x, path.y, path.weight)
            flux[k] += f
            counts["on_receiver"][k] += m
            for key, code in codes.items():
                counts[key][k] += np.count_nonzero(path.status == code)
            counts["tir_photons"][k] += np.count_nonzero(path.tir > 0)
            counts["tir_events"][k] += int(path.tir.sum())
            hit[k] += np.count_nonzero(path.events > 0)
    image = _image(rec, flux, ms.multichannel)
    if not return_stats:
        return image
    stats = {"emitted": np.full(c, total, dtype=np.int64), "hit_generator": hit, **counts}
    return image, _finish_stats(stats, ms.multichannel)
