"""Photon tracing through a glass ellipsoid (`EllipsoidScene`), plain NumPy, float64.

An ellipsoid (centre ``c``, semi-axes ``r``, orthonormal ``R`` whose columns are its
axes) is the quadric ``(x - c)^T Q (x - c) = 1`` with ``Q = R diag(r)^-2 R^T``, handled
here directly in world coordinates: a ray ``o + t d`` meets it where
``alpha t^2 + 2 beta t + gamma = 0`` (``alpha = d^T Q d``, ``beta = d^T Q (o - c)``,
``gamma = (o - c)^T Q (o - c) - 1``), both roots by the cancellation-free pair
``s = -(beta + sign(beta) sqrt(beta^2 - alpha gamma))``, ``t = s / alpha`` and
``t = gamma / s``; the outward normal is ``Q (x - c)`` normalised.

A photon outside the generator meets it at the smaller root (if beyond ``t_min``, 1e-9
of the generator's largest semi-axis); one inside at the larger root. Paths follow the
mesh tracer's rules (`_mesh.py`): at most ``scene.interfaces`` events (refraction from 1
into ``n`` entering, from ``n`` into 1 leaving; total internal reflection reflects,
factor 1, and keeps the side), an occluder (opaque ellipsoids) met before the next event
or before landing stops the photon, photons that never meet the generator are not
rendered, photons still inside after the last event are dropped, the rest land on
``z = 0`` going down. See the package docstring.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._lens import (
    LANDED,
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
from ._mesh import _ACTIVE, BLOCKED, DROPPED, MISSED, UPWARD, _Emitter, _rays
from ._optics import _check_bool, chunk_photons

# Photons traced per vectorised batch: bounds the memory in use.
_CHUNK = 1 << 16
# Roots nearer than this fraction of the generator's largest semi-axis are ignored (the
# surface a photon stands on after an event).
_REL_T_MIN = 1e-9
# A ray that left the generator (`trace_ellipsoid_rays`; never landed).
EXITED = 9


@dataclasses.dataclass(frozen=True, eq=False)
class _Quadric:
    """An ellipsoid as the quadric ``(x - c)^T q (x - c) = 1``, float64."""

    c: np.ndarray  # (3,) centre
    q: np.ndarray  # (3, 3) R diag(r^-2) R^T
    a: np.ndarray  # (3, 3) R diag(r^2) R^T: support function sqrt(e^T a e)
    radius: float  # largest semi-axis

    @classmethod
    def read(cls, ellipsoid, name: str) -> _Quadric:
        try:
            center, radii = ellipsoid.center, ellipsoid.radii
            rotation = getattr(ellipsoid, "rotation", np.eye(3))
        except AttributeError as err:
            raise ValueError(f"`{name}` must have `center` and `radii`: {err}") from err
        c = np.asarray(center, dtype=np.float64)
        r = np.asarray(radii, dtype=np.float64)
        rot = np.asarray(rotation, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"`{name}.center` must be 3 finite numbers, got {c!r}")
        if r.shape != (3,) or not np.all(np.isfinite(r)) or not np.all(r > 0.0):
            raise ValueError(f"`{name}.radii` must be 3 finite positive numbers, got {r!r}")
        if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
            raise ValueError(f"`{name}.rotation` must be a finite (3, 3) matrix")
        if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-6:
            raise ValueError(f"`{name}.rotation` must be orthonormal")
        return cls(c, (rot / r**2) @ rot.T, (rot * r**2) @ rot.T, float(r.max()))

    def support(self, e: np.ndarray) -> float:
        """``max over the ellipsoid of e . (x - c)`` for a unit vector `e`."""
        return float(np.sqrt(e @ self.a @ e))

    @property
    def lowest_z(self) -> float:
        return float(self.c[2]) - self.support(np.array([0.0, 0.0, 1.0]))

    def roots(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Both roots ``t_lo <= t_hi`` of the rays ``o + t d`` (3, N) on the surface
        (``nan`` where the line misses it)."""
        rel = o - self.c[:, None]
        qd = self.q @ d
        alpha = np.sum(d * qd, axis=0)
        beta = np.sum(rel * qd, axis=0)
        gamma = np.sum(rel * (self.q @ rel), axis=0) - 1.0
        disc = beta * beta - alpha * gamma
        real = disc >= 0.0
        s = -(beta + np.copysign(np.sqrt(np.where(real, disc, 0.0)), beta))
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = s / alpha
            t2 = np.where(s != 0.0, gamma / s, t1)
        lo = np.where(real, np.minimum(t1, t2), np.nan)
        hi = np.where(real, np.maximum(t1, t2), np.nan)
        return lo, hi

    def normal(self, x: np.ndarray) -> np.ndarray:
        """Unit outward normals at surface points `x` (3, N)."""
        n = self.q @ (x - self.c[:, None])
        return n / np.linalg.norm(n, axis=0)


@dataclasses.dataclass(frozen=True, eq=False)
class _EllipsoidScene:
    """An `EllipsoidScene` read into float64 NumPy values (duck typed, validated)."""

    gen: _Quadric
    occ: tuple[_Quadric, ...]
    light: _Light
    receiver: _Receiver
    iors: tuple[float, ...]
    multichannel: bool
    fresnel: bool
    interfaces: int
    t_min: float

    def generator_hit(self, o: np.ndarray, d: np.ndarray, inside: np.ndarray) -> np.ndarray:
        """Ray parameter of the next generator hit (inf: none): the smaller root from
        outside, the larger from inside, if beyond ``t_min``."""
        lo, hi = self.gen.roots(o, d)
        t = np.where(inside, hi, lo)
        return np.where(t > self.t_min, t, np.inf)  # nan compares False: no hit

    def occluder_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Ray parameter of the nearest occluder hit (inf: none; ``t_min`` for a ray
        starting inside an occluder)."""
        best = np.full(o.shape[1], np.inf)
        for quad in self.occ:
            lo, hi = quad.roots(o, d)
            t = np.where(lo > self.t_min, lo, np.where(hi > self.t_min, self.t_min, np.inf))
            best = np.minimum(best, t)
        return best


def _read_scene(scene, need_receiver: bool = True) -> _EllipsoidScene:
    try:
        generator, light = scene.generator, scene.light
        ior, fresnel, interfaces = scene.ior, scene.fresnel, scene.interfaces
        occluders = tuple(getattr(scene, "occluders", ()))
        receiver = scene.receiver if need_receiver else None
    except AttributeError as err:
        raise ValueError(f"`scene` must be an EllipsoidScene-like object: {err}") from err
    if hasattr(light, "position"):
        raise ValueError("`scene.light` must be a directional light (ellipsoid scenes)")
    gen = _Quadric.read(generator, "scene.generator")
    occ = tuple(_Quadric.read(o, f"scene.occluders[{k}]") for k, o in enumerate(occluders))
    for name, quad in [("scene.generator", gen)] + [
        (f"scene.occluders[{k}]", o) for k, o in enumerate(occ)
    ]:
        if quad.lowest_z < -1e-9 * quad.radius:
            raise ValueError(f"`{name}` reaches below the screen (z < 0)")
    iors, multichannel = _read_iors(ior)
    return _EllipsoidScene(
        gen=gen,
        occ=occ,
        light=_Light.read(light),
        receiver=_Receiver.read(receiver) if need_receiver else None,  # type: ignore[arg-type]
        iors=iors,
        multichannel=multichannel,
        fresnel=bool(fresnel),
        interfaces=_check_int(interfaces, "scene.interfaces"),
        t_min=_REL_T_MIN * gen.radius,
    )


@dataclasses.dataclass
class _Fates:
    """Per-channel results of `_trace_channel` (arrays of shape (N,), or (3, N))."""

    x: np.ndarray  # landing point (0 unless landed)
    y: np.ndarray
    weight: np.ndarray  # flux carried to the screen, or out of the object (else 0)
    status: np.ndarray  # LANDED, MISSED, BLOCKED, DROPPED, UPWARD, or EXITED
    events: np.ndarray  # interface events (refractions and total internal reflections)
    tir: np.ndarray  # total internal reflections among them
    origin: np.ndarray  # (3, N) point of the last event
    direction: np.ndarray  # (3, N) direction after the last event


def _trace_channel(
    es: _EllipsoidScene, o: np.ndarray, d: np.ndarray, w: np.ndarray, ior: float, land: bool
) -> _Fates:
    """Follow photons ``o + t d`` (3, N), flux `w`, through the generator (one index).

    With `land`, photons that leave the generator go on to ``z = 0`` past the occluders;
    without, they stop where they leave it (status EXITED) and occluders are ignored.
    """
    n = o.shape[1]
    o, d, w = o.copy(), d.copy(), w.astype(np.float64, copy=True)
    status = np.full(n, _ACTIVE, dtype=np.int8)
    inside = np.zeros(n, dtype=bool)
    events = np.zeros(n, dtype=np.int64)
    tir_count = np.zeros(n, dtype=np.int64)
    gx, gy = np.zeros(n), np.zeros(n)
    for k in range(es.interfaces + 1):
        a = np.flatnonzero(status == _ACTIVE)
        if not a.size:
            break
        oa, da, ins = o[:, a], d[:, a], inside[a]
        tg = es.generator_hit(oa, da, ins)
        to = es.occluder_hit(oa, da) if land else np.full(a.size, np.inf)
        gen = np.isfinite(tg)
        occ_first = to < tg
        st = np.full(a.size, _ACTIVE, dtype=np.int8)
        if k == 0:
            st[~gen] = MISSED
        else:
            st[~gen & ins] = DROPPED  # inside with no way out: only by rounding (grazing)
            leave = ~gen & ~ins
            if not land:
                st[leave] = EXITED
            else:
                down = leave & (da[2] < 0.0)
                up = leave & ~down
                st[up] = np.where(np.isfinite(to[up]), BLOCKED, UPWARD)
                with np.errstate(divide="ignore", invalid="ignore"):
                    ts = np.where(down, -oa[2] / da[2], 0.0)
                st[down & (to <= ts)] = BLOCKED
                landed = down & ~(to <= ts)
                st[landed] = LANDED
                gx[a[landed]] = oa[0, landed] + ts[landed] * da[0, landed]
                gy[a[landed]] = oa[1, landed] + ts[landed] * da[1, landed]
        if k == es.interfaces:  # no event left: inside, or (by rounding) meeting it again
            st[gen & ins] = DROPPED
            st[gen & ~ins] = np.where(occ_first[gen & ~ins], BLOCKED, DROPPED)
        else:
            st[gen & occ_first] = BLOCKED
        status[a] = st
        ev = gen & (st == _ACTIVE)
        if not ev.any():
            continue
        e = a[ev]
        de = da[:, ev]
        p = oa[:, ev] + tg[ev] * de
        normal = es.gen.normal(p)
        dot = np.sum(de * normal, axis=0)
        m = np.where(dot > 0.0, -normal, normal)  # oriented against the ray
        entering = ~ins[ev]
        eta = np.where(entering, 1.0 / ior, ior)
        refracted, tr, tir = _refract_rays(de, m, eta, es.fresnel)
        reflected = de + 2.0 * np.abs(dot) * m
        nd = np.where(tir, reflected, refracted)
        o[:, e] = p
        d[:, e] = nd / np.linalg.norm(nd, axis=0)
        w[e] *= np.where(tir, 1.0, tr)
        inside[e] = np.where(tir, ~entering, entering)
        events[e] += 1
        tir_count[e] += tir
    done = LANDED if land else EXITED
    return _Fates(
        x=gx,
        y=gy,
        weight=np.where(status == done, w, 0.0),
        status=status,
        events=events,
        tir=tir_count,
        origin=o,
        direction=d,
    )


def trace_ellipsoid_rays(
    scene, origins, directions
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Trace given rays through an `EllipsoidScene`'s generator to where they leave it.

    Occluders, the receiver and the light are not used: each ray follows its own
    direction from its origin, which must lie outside the generator.

    **Arguments:**

    - `scene`: an `EllipsoidScene`, read by duck typing (``generator``, ``ior``,
      ``fresnel``, ``interfaces``).
    - `origins`, `directions`: array-likes of shape ``(N, 3)``: rays ``o + t d``,
      ``t > 0`` (directions are normalised here).

    **Returns:** ``(exit_origin, exit_direction, transmittance, status)``:

    - `exit_origin`: `np.ndarray` of shape ``(C, N, 3)``, where each ray leaves the
      generator (meaningless unless it exited), ``C = len(scene.iors)``.
    - `exit_direction`: `np.ndarray` of shape ``(C, N, 3)``, the unit direction after
      leaving it.
    - `transmittance`: `np.ndarray` of shape ``(C, N)``, the product of the Fresnel
      transmittances of its refractions (1 without Fresnel; total internal reflections
      count 1); 0 unless it exited.
    - `status`: `np.ndarray` of strings, shape ``(C, N)``, ``"exited"``, ``"missed"``
      (never met the generator) or ``"dropped"`` (still inside after
      ``scene.interfaces`` events).
    """
    es = _read_scene(scene, need_receiver=False)
    o, d, w = _rays(origins, directions, 1.0)
    fates = [_trace_channel(es, o, d, w, ior, land=False) for ior in es.iors]
    status = np.stack([f.status for f in fates])
    names = np.full(status.shape, "dropped", dtype="<U7")
    names[status == EXITED] = "exited"
    names[status == MISSED] = "missed"
    return (
        np.stack([f.origin.T for f in fates]),
        np.stack([f.direction.T for f in fates]),
        np.stack([f.weight for f in fates]),
        names,
    )


def _emitter(es: _EllipsoidScene) -> _Emitter:
    """The emission grid: the bounding rectangle of the generator's parallel projection
    onto the plane through its centre perpendicular to the light (support functions
    along the grid's axes), photons starting before every ellipsoid along the light."""
    assert es.light.direction is not None
    axis = es.light.direction
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = helper - (helper @ axis) * axis
    u /= np.linalg.norm(u)
    v = np.cross(u, axis)
    gen = es.gen
    hu, hv = gen.support(u), gen.support(v)
    pad = 1e-9 * gen.radius
    rect = (-hu - pad, hu + pad, -hv - pad, hv + pad)
    # every point x of every ellipsoid must satisfy (x - centre) . axis > -back
    reach = max(quad.support(-axis) + (gen.c - quad.c) @ axis for quad in (gen, *es.occ))
    back = max(0.0, float(reach)) + 1e-3 * max(gen.radius, 1.0)
    return _Emitter(gen.c, u, v, axis, rect, back, es.light)


def trace_ellipsoid(
    scene,
    photons_per_axis=512,
    *,
    jitter: bool = False,
    seed=0,
    return_stats: bool = False,
    memory_limit: int | None = None,
):
    """Irradiance on the screen of an `EllipsoidScene` by forward photon tracing (ground
    truth), like `trace_mesh` with exact ray/ellipsoid intersections.

    The bounding rectangle of the generator's projection onto the plane through its
    centre perpendicular to the light (padded by 1e-9 of its largest semi-axis) is cut
    into a ``rows x cols`` grid of equal cells, one photon per cell (at its centre, or
    jittered in it); each starts on the light's line, before every ellipsoid, carrying
    ``A_perp / |d_z|`` (``A_perp`` the cell's area). Photons are traced (see the module
    docstring: refraction, total internal reflection, Fresnel, occluders, at most
    ``scene.interfaces`` events) and binned into the receiver's pixels; only photons
    that went through the generator count (no direct light). Photons are processed in
    batches of 65536, so memory stays small for any grid.

    **Arguments:**

    - `scene`: an `EllipsoidScene`, read by duck typing: ``generator`` and ``occluders``
      (``center``, ``radii``, ``rotation``), ``light`` (directional), ``receiver``,
      ``ior``, ``fresnel``, ``interfaces``.
    - `photons_per_axis`: the emission grid, an int or ``(rows, cols)``; an integer ``n``
      gives ``n x n``; default 512.
    - `jitter`: jitter each photon uniformly inside its cell
      (``numpy.random.default_rng(seed)``); default False.
    - `seed`: int seed for the jitter; default 0.
    - `return_stats`: also return a dict of photon counts (ints, or a tuple per channel
      for a sequence of indices), as `trace_mesh`; default False: ``emitted``,
      ``hit_generator``, ``missed``, ``blocked``, ``dropped``, ``upward``, ``landed``,
      ``on_receiver``, ``tir_photons``, ``tir_events``;
      ``emitted = missed + blocked + dropped + upward + landed``.
    - `memory_limit`: bytes of photons traced at a time, an int or None (``PHOTON_BYTES``
      = 1024 per photon, an estimate of its arrays and temporaries); default None: 2^16
      (64 MiB) photons at a time. The image does not depend on it (up to the order of
      float64 sums).

    **Returns:** a float64 `np.ndarray` of shape ``(rows, cols)`` for a scalar index,
    ``(rows, cols, C)`` for ``C`` indices: irradiance relative to the light's irradiance
    on a horizontal plane. With `return_stats`, ``(image, stats)``.
    """
    es = _read_scene(scene)
    rows, cols = _grid_shape(photons_per_axis)
    chunk = chunk_photons(memory_limit, _CHUNK)
    rng = _rng(jitter, seed)
    return_stats = _check_bool(return_stats, "return_stats")
    emitter = _emitter(es)
    rec = es.receiver
    c = len(es.iors)
    flux = np.zeros((c, rec.shape[0] * rec.shape[1]))
    keys: tuple[str, ...] = ("missed", "blocked", "dropped", "upward", "landed", "on_receiver")
    keys += ("hit_generator", "tir_photons", "tir_events")
    counts = {key: np.zeros(c, dtype=np.int64) for key in keys}
    codes = {"missed": MISSED, "blocked": BLOCKED, "dropped": DROPPED, "upward": UPWARD}
    codes["landed"] = LANDED
    total = rows * cols
    for lo in range(0, total, chunk):
        o, d, w = emitter.photons(rows, cols, lo, min(lo + chunk, total), rng)
        for k, ior in enumerate(es.iors):
            path = _trace_channel(es, o, d, w, ior, land=True)
            f, m = rec.bin(path.x, path.y, path.weight)
            flux[k] += f
            counts["on_receiver"][k] += m
            for key, code in codes.items():
                counts[key][k] += np.count_nonzero(path.status == code)
            counts["hit_generator"][k] += np.count_nonzero(path.events > 0)
            counts["tir_photons"][k] += np.count_nonzero(path.tir > 0)
            counts["tir_events"][k] += int(path.tir.sum())
    image = _image(rec, flux, es.multichannel)
    if not return_stats:
        return image
    stats = {"emitted": np.full(c, total, dtype=np.int64), **counts}
    return image, _finish_stats(stats, es.multichannel)
