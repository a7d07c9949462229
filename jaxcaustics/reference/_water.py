"""Photon tracing and area-ratio estimators for `WaterScene` (plain NumPy, float64)."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence

import numpy as np

from ._optics import (
    MAX_PHOTONS,
    _check_count,
    _check_int,
    _check_points,
    _Receiver,
    _rng,
    chunk_photons,
    refract,
)
from ._surface import _Surface, intersect_surface

# Photons (or triangles' samples) handled per vectorised batch: bounds the memory in use.
_CHUNK = 1 << 18
# An automatic margin grows (x2) up to this many times the receiver's larger side.
_MAX_AUTO_MARGIN = 2.0


# --------------------------------------------------------------------------- scene


@dataclasses.dataclass(frozen=True)
class _Water:
    """A `WaterScene` read into float64 NumPy values (duck typed, validated)."""

    surface: _Surface
    direction: np.ndarray  # (3,) unit, direction of travel, z < 0
    rest_depth: float
    iors: tuple[float, ...]
    multichannel: bool
    fresnel: bool
    receiver_extent: tuple[float, float, float, float]
    receiver_shape: tuple[int, int]

    @property
    def pixel_size(self) -> tuple[float, float]:
        e, (rows, cols) = self.receiver_extent, self.receiver_shape
        return (e[1] - e[0]) / cols, (e[3] - e[2]) / rows


def _read_scene(scene) -> _Water:
    try:
        surface, light, receiver = scene.surface, scene.light, scene.receiver
        heights, extent, boundary = surface.heights, surface.extent, surface.boundary
        direction = light.direction
        rest_depth, ior, fresnel = scene.rest_depth, scene.ior, scene.fresnel
    except AttributeError as err:
        raise ValueError(f"`scene` must be a WaterScene-like object: {err}") from err
    rotation = getattr(surface, "rotation", 0.0)  # absent: an unrotated field
    surf = _Surface.build(heights, extent, boundary, rotation)

    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (3,) or not np.all(np.isfinite(d)):
        raise ValueError(f"`scene.light.direction` must be 3 finite numbers, got {d!r}")
    norm = float(np.linalg.norm(d))
    if not norm > 0.0 or not d[2] / norm < 0.0:
        raise ValueError(f"`scene.light.direction` must point down (z < 0), got {d.tolist()}")
    d = d / norm

    rec = _Receiver.read(receiver)

    depth = float(np.asarray(rest_depth, dtype=np.float64))
    if not (math.isfinite(depth) and depth > 0.0):
        raise ValueError(f"`scene.rest_depth` must be finite and positive, got {depth}")

    multichannel = np.ndim(ior) > 0
    iors = tuple(float(v) for v in np.atleast_1d(np.asarray(ior, dtype=np.float64)))
    if not iors or not all(math.isfinite(v) and v > 0.0 for v in iors):
        raise ValueError(f"`scene.ior` must be finite positive indices, got {ior!r}")
    return _Water(
        surf,
        d,
        depth,
        iors,
        multichannel,
        bool(fresnel),
        rec.extent,
        rec.shape,
    )


def _check_margin(margin) -> float | None:
    if margin is None:
        return None
    if isinstance(margin, (str, bytes, bool, np.bool_)):
        raise ValueError(f"`margin` must be None or a number (metres), got {margin!r}")
    try:
        m = float(margin)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`margin` must be None or a number (metres), got {margin!r}") from err
    if not (math.isfinite(m) and m >= 0.0):
        raise ValueError(f"`margin` must be finite and >= 0 (metres), got {margin!r}")
    return m


# --------------------------------------------------------------------------- tracing


def _trace(
    w: _Water, xs: np.ndarray, ys: np.ndarray, iors: Sequence[float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Trace rest-plane start points to the ground for each index in `iors`."""
    n, c = xs.shape[0], len(iors)
    gx, gy = np.zeros((c, n)), np.zeros((c, n))
    transmittance, valid = np.zeros((c, n)), np.zeros((c, n), dtype=bool)
    d = w.direction
    for lo in range(0, n, _CHUNK):
        sl = slice(lo, min(lo + _CHUNK, n))
        cx, cy = xs[sl], ys[sl]
        t, hx, hy = intersect_surface(w.surface, w.rest_depth, d, cx, cy)
        px, py, pz = cx + t * d[0], cy + t * d[1], w.rest_depth + t * d[2]
        for k, ior in enumerate(iors):
            tx, ty, tz, tr, ok = refract(d, hx, hy, ior, w.fresnel)
            ok &= pz > 0.0  # a surface at or below the ground plane: no water to cross
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(ok, -pz / tz, 0.0)
            gx[k, sl] = px + s * tx
            gy[k, sl] = py + s * ty
            transmittance[k, sl] = np.where(ok, tr, 0.0)
            valid[k, sl] = ok
    return gx, gy, transmittance, valid


def trace_photons(scene, xs, ys) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Trace photons from the rest plane to the ground, one channel per index of refraction.

    Each photon starts at ``(x, y, rest_depth)``, travels along the light's direction to
    its first intersection with the water surface (which may lie above the rest plane,
    i.e. behind the start point), refracts, and lands on the ground ``z = 0``.

    **Arguments:**

    - `scene`: a `WaterScene`, read by duck typing (see the module docstring).
    - `xs`, `ys`: array-likes of shape ``(N,)``: start points on the rest plane
      ``z = rest_depth``, metres.

    **Returns:** ``(ground_x, ground_y, transmittance, valid)``:

    - `ground_x`, `ground_y`: `np.ndarray` of shape ``(C, N)``, landing points on the
      ground in metres (0 where not valid), ``C = len(scene.iors)``.
    - `transmittance`: `np.ndarray` of shape ``(C, N)``, the fraction of the photon's flux
      that reaches the ground: the Fresnel transmittance if ``scene.fresnel`` else 1, and
      0 where not valid.
    - `valid`: `np.ndarray` of bools, shape ``(C, N)``, False for total internal
      reflection or a refracted ray that does not reach the ground.
    """
    w = _read_scene(scene)
    x, y = _check_points(xs, ys)
    return _trace(w, x, y, w.iors)


# --------------------------------------------------------------------------- emission


@dataclasses.dataclass(frozen=True)
class _Layout:
    """A regular lattice of cells on the rest plane: cell (i, j) spans
    ``[x0 + j hx, x0 + (j+1) hx] x [y0 + i hy, y0 + (i+1) hy]``."""

    x0: float
    y0: float
    hx: float
    hy: float
    nx: int
    ny: int
    wrap: bool  # wrap landing points into the receiver (periodic, whole periods)
    ring: int  # width in cells of the outermost one-pixel ring of the padding (0: none)

    def in_ring(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        r = self.ring
        if r == 0:
            return np.zeros(np.broadcast(i, j).shape, dtype=bool)
        return (i < r) | (i >= self.ny - r) | (j < r) | (j >= self.nx - r)


def _flat_offset(w: _Water, ior: float) -> tuple[float, float]:
    """``rest_depth * T0_xy / T0_z``: start point minus landing point under flat water."""
    zero = np.zeros(1)
    tx, ty, tz, _, ok = refract(w.direction, zero, zero, ior, False)
    if not ok[0]:  # flat water reflects everything: no offset is better than another
        return 0.0, 0.0
    return float(w.rest_depth * tx[0] / tz[0]), float(w.rest_depth * ty[0] / tz[0])


def _whole_periods(w: _Water) -> bool:
    """Periodic, unrotated surface and a receiver spanning a whole number of periods along
    x and y (a rotated field tiles the plane along its own axes: no wrapping)."""
    if not w.surface.periodic or w.surface.rotation != 0.0:
        return False
    se, re = w.surface.extent, w.receiver_extent
    for span, period in ((re[1] - re[0], se[1] - se[0]), (re[3] - re[2], se[3] - se[2])):
        k = round(span / period)
        if k < 1 or abs(span / period - k) > 1e-9 * k:
            return False
    return True


def _default_margin(w: _Water, ior: float) -> float:
    """A first guess at how far photons stray from their flat-water landing points.

    Refracts the light through normals of the largest sampled slope (x1.5) in 16 azimuths
    and takes the largest change of the landing point, plus the shift of the hit along an
    oblique ray and one pixel. The caller caps it, and grows it while photons from the
    outermost pixel ring of the padding still land on the receiver.
    """
    h = w.surface.heights
    if w.surface.periodic:
        sx = (np.roll(h, -1, 1) - np.roll(h, 1, 1)) / (2.0 * w.surface.dx)
        sy = (np.roll(h, -1, 0) - np.roll(h, 1, 0)) / (2.0 * w.surface.dy)
    else:
        sx = np.gradient(h, w.surface.dx, axis=1)
        sy = np.gradient(h, w.surface.dy, axis=0)
    slope = 1.5 * float(np.hypot(sx, sy).max())
    h_abs = float(np.abs(h).max())
    depth = w.rest_depth + max(float(h.max()), 0.0)
    ox, oy = _flat_offset(w, ior)
    ox, oy = ox * depth / w.rest_depth, oy * depth / w.rest_depth
    phi = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    mag = np.repeat([0.5 * slope, slope], phi.size)
    phi = np.tile(phi, 2)
    tx, ty, tz, _, ok = refract(w.direction, mag * np.cos(phi), mag * np.sin(phi), ior, False)
    with np.errstate(divide="ignore", invalid="ignore"):
        dev = np.hypot(depth * tx / tz - ox, depth * ty / tz - oy)
    dev = float(dev[ok].max()) if ok.any() else 0.0
    tan_i = float(np.hypot(w.direction[0], w.direction[1]) / -w.direction[2])
    return dev + h_abs * tan_i + max(w.pixel_size)


def _layout(
    w: _Water, offset: tuple[float, float], per_axis: int, margin: float, wrap: bool
) -> _Layout:
    rows, cols = w.receiver_shape
    pdx, pdy = w.pixel_size
    pad_x = 0 if wrap else math.ceil(margin / pdx)
    pad_y = 0 if wrap else math.ceil(margin / pdy)
    e = w.receiver_extent
    return _Layout(
        x0=e[0] + offset[0] - pad_x * pdx,
        y0=e[2] + offset[1] - pad_y * pdy,
        hx=pdx / per_axis,
        hy=pdy / per_axis,
        nx=(cols + 2 * pad_x) * per_axis,
        ny=(rows + 2 * pad_y) * per_axis,
        wrap=wrap,
        ring=per_axis if (pad_x > 0 and pad_y > 0) else 0,
    )


def _bin(
    w: _Water, wrap: bool, gx: np.ndarray, gy: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Flat receiver pixel index of landing points, and whether each one counts."""
    rows, cols = w.receiver_shape
    x_min, x_max, y_min, y_max = w.receiver_extent
    pdx, pdy = w.pixel_size
    gx = np.where(valid, gx, x_min)
    gy = np.where(valid, gy, y_min)
    if wrap:
        gx = x_min + np.mod(gx - x_min, x_max - x_min)
        gy = y_min + np.mod(gy - y_min, y_max - y_min)
        inside = valid
    else:
        inside = valid & (gx >= x_min) & (gx < x_max) & (gy >= y_min) & (gy < y_max)
    col = np.clip(np.floor((gx - x_min) / pdx), 0, cols - 1).astype(np.int64)
    row = np.clip(np.floor((gy - y_min) / pdy), 0, rows - 1).astype(np.int64)
    return row * cols + col, inside


# The estimator callback: (layout, iors) -> (flux per pixel, shape (C, rows*cols); the flux
# that photons from the layout's outer ring put on the receiver).
_Estimator = Callable[[_Layout, Sequence[float]], tuple[np.ndarray, float]]


def _check_work(w: _Water, per_axis: int, margin: float | None, per_cell: int, what: str):
    """Refuse an emission lattice (the padding of `margin`, or of the largest automatic
    margin) whose cells times `per_cell` exceed `MAX_PHOTONS`, before any tracing."""
    e = w.receiver_extent
    m = margin if margin is not None else _MAX_AUTO_MARGIN * max(e[1] - e[0], e[3] - e[2])
    lay = _layout(w, (0.0, 0.0), per_axis, m, _whole_periods(w))
    _check_count(lay.nx * lay.ny * per_cell, MAX_PHOTONS, what)


def _render(w: _Water, per_axis: int, margin: float | None, estimate: _Estimator) -> np.ndarray:
    """Run an estimator on each group of channels sharing an emission lattice; normalise."""
    rows, cols = w.receiver_shape
    pdx, pdy = w.pixel_size
    wrap = _whole_periods(w)
    groups: dict[tuple[float, float], list[int]] = {}
    for k, ior in enumerate(w.iors):
        groups.setdefault(_flat_offset(w, ior), []).append(k)
    image = np.zeros((rows * cols, len(w.iors)))
    for offset, channels in groups.items():
        iors = [w.iors[k] for k in channels]
        if wrap or margin is not None:
            flux, _ = estimate(_layout(w, offset, per_axis, margin or 0.0, wrap), iors)
        else:
            e = w.receiver_extent
            cap = _MAX_AUTO_MARGIN * max(e[1] - e[0], e[3] - e[2])
            m = min(max(_default_margin(w, ior) for ior in iors), cap)
            while True:
                flux, ring_flux = estimate(_layout(w, offset, per_axis, m, wrap), iors)
                if ring_flux == 0.0:
                    break
                if m >= cap:
                    warnings.warn(
                        f"light from {m:.3g} m outside the receiver still reaches it; pass a "
                        f"larger `margin`",
                        RuntimeWarning,
                        stacklevel=3,
                    )
                    break
                m = min(2.0 * m, cap)
        image[:, channels] = flux.T
    out = (image / (pdx * pdy)).reshape(rows, cols, len(w.iors))
    return out if w.multichannel else out[..., 0]


# --------------------------------------------------------------------------- estimators


def trace_water(
    scene,
    *,
    photons_per_axis: int = 4,
    jitter: bool = False,
    seed=0,
    margin: float | None = None,
    memory_limit: int | None = None,
) -> np.ndarray:
    """Irradiance on the ground by forward photon tracing (the reference ground truth).

    Photons start on a regular grid on the rest plane ``z = rest_depth``, aligned so that
    under flat water they would land at the centres of ``photons_per_axis**2`` sub-cells of
    each receiver pixel; each carries the flux of its grid cell's horizontal area (times
    the Fresnel transmittance if ``scene.fresnel``). Each is traced exactly (first hit on
    the bicubic surface, refraction, landing on ``z = 0``) and binned.

    For a periodic, unrotated surface and a receiver spanning whole periods, one emission
    window the size of the receiver is traced and landing points wrap into the receiver
    (energy is conserved exactly). Otherwise the emission window is padded by `margin` on
    each side and photons landing off the receiver are dropped.

    **Arguments:**

    - `scene`: a `WaterScene`, read by duck typing (see the module docstring).
    - `photons_per_axis`: photons per receiver pixel along each axis (an int, ``>= 1``);
      default 4.
    - `jitter`: jitter each photon uniformly inside its cell
      (``numpy.random.default_rng(seed)``); default False.
    - `seed`: int seed for the jitter; default 0.
    - `margin`: padding of the emission window in metres, a float or None (rounded up to
      whole pixels; clamp boundary or receivers that are not whole periods only); default
      None: picks one from the surface's slopes and doubles it while photons from its
      outermost pixel ring still reach the receiver, up to twice the receiver's larger
      side (then warns).
    - `memory_limit`: bytes of photons traced at a time, an int or None (``PHOTON_BYTES``
      = 1024 per photon, an estimate of its arrays and temporaries); default None: 2^18
      (256 MiB) photons at a time. The image does not depend on it (up to the order of
      float64 sums).

    **Returns:** a float64 `np.ndarray`: irradiance relative to the light's irradiance on a
    horizontal plane (flat water, Fresnel off: exactly 1), shape ``(rows, cols)`` for a
    scalar ``scene.ior`` or ``(rows, cols, C)`` for a sequence of ``C`` indices.
    """
    w = _read_scene(scene)
    per_axis = _check_int(photons_per_axis, "photons_per_axis")
    margin = _check_margin(margin)
    chunk = chunk_photons(memory_limit, _CHUNK)
    _rng(jitter, seed)  # checked
    _check_work(w, per_axis, margin, 1, "`photons_per_axis` (and `margin`)")
    rows, cols = w.receiver_shape

    def estimate(lay: _Layout, iors: Sequence[float]) -> tuple[np.ndarray, float]:
        rng = _rng(jitter, seed)
        flux = np.zeros((len(iors), rows * cols))
        ring_flux = 0.0
        block = max(1, chunk // lay.nx)
        for r0 in range(0, lay.ny, block):
            i, j = (
                a.ravel()
                for a in np.meshgrid(
                    np.arange(r0, min(r0 + block, lay.ny)), np.arange(lay.nx), indexing="ij"
                )
            )
            fx: float | np.ndarray
            fy: float | np.ndarray
            if rng is None:
                fx = fy = 0.5
            else:
                fx, fy = rng.random(i.size), rng.random(i.size)
            xs = lay.x0 + (j + fx) * lay.hx
            ys = lay.y0 + (i + fy) * lay.hy
            gx, gy, tr, valid = _trace(w, xs, ys, iors)
            ring = lay.in_ring(i, j)
            for k in range(len(iors)):
                pix, inside = _bin(w, lay.wrap, gx[k], gy[k], valid[k])
                weight = np.where(inside, tr[k], 0.0) * (lay.hx * lay.hy)
                flux[k] += np.bincount(pix, weight, minlength=rows * cols)
                ring_flux += float(weight[ring].sum())
        return flux, ring_flux

    return _render(w, per_axis, margin, estimate)


def _stratified_barycentric(samples: int) -> np.ndarray:
    """Centroids of the ``m**2`` congruent sub-triangles of a triangle, ``samples = m**2``.

    Returns barycentric weights of shape ``(samples, 3)``; each point stands for the same
    area, so they sample the triangle uniformly.
    """
    m = math.isqrt(samples)
    pts = [((3 * i + 1) / (3 * m), (3 * j + 1) / (3 * m)) for i in range(m) for j in range(m - i)]
    pts += [
        ((3 * i + 2) / (3 * m), (3 * j + 2) / (3 * m))
        for i in range(m - 1)
        for j in range(m - 1 - i)
    ]
    b = np.array(pts, dtype=np.float64)
    return np.column_stack([1.0 - b[:, 0] - b[:, 1], b[:, 0], b[:, 1]])


def area_ratio_water(
    scene,
    *,
    vertices_per_axis: int = 2,
    samples_per_triangle: int = 16,
    margin: float | None = None,
) -> np.ndarray:
    """Irradiance on the ground by mapping a triangulated rest-plane grid (second estimator).

    The vertices of a regular grid on the rest plane (the same emission window as
    `trace_water`, spacing = pixel / `vertices_per_axis`) are traced to the ground. Each
    grid cell is split into two triangles; a triangle carries the flux of its rest-plane
    area times the mean transmittance of its three vertices, spread uniformly over its
    image on the ground through a fixed stratified set of barycentric sample points.
    Fold-overs and degenerate (zero-area) images are handled alike, since nothing divides
    by the image's area. Triangles with a vertex lost to total internal reflection (or
    not reaching the ground) are dropped.

    **Arguments:**

    - `scene`: a `WaterScene`, read by duck typing (see the module docstring).
    - `vertices_per_axis`: grid cells per receiver pixel along each axis (an int,
      ``>= 1``); default 2.
    - `samples_per_triangle`: sample points per triangle, an int, a perfect square
      ``m**2`` (the centroids of the triangle's regular subdivision into ``m**2``
      sub-triangles); default 16.
    - `margin`: a float or None, as in `trace_water`; default None.

    **Returns:** a float64 `np.ndarray`: relative irradiance, shape ``(rows, cols)`` or
    ``(rows, cols, C)`` as in `trace_water`.
    """
    w = _read_scene(scene)
    per_axis = _check_int(vertices_per_axis, "vertices_per_axis")
    samples = _check_int(samples_per_triangle, "samples_per_triangle")
    if math.isqrt(samples) ** 2 != samples:
        raise ValueError(f"`samples_per_triangle` must be a perfect square, got {samples}")
    margin = _check_margin(margin)
    _check_work(w, per_axis, margin, 2 * samples, "`vertices_per_axis` x `samples_per_triangle`")
    bary = _stratified_barycentric(samples)
    rows, cols = w.receiver_shape

    def estimate(lay: _Layout, iors: Sequence[float]) -> tuple[np.ndarray, float]:
        flux = np.zeros((len(iors), rows * cols))
        ring_flux = 0.0
        tri_area = 0.5 * lay.hx * lay.hy
        stride = lay.nx + 1
        block = max(1, _CHUNK // (2 * samples * lay.nx))
        for r0 in range(0, lay.ny, block):
            r1 = min(r0 + block, lay.ny)
            # Vertex rows r0..r1 (the shared edge row is traced again by the next block).
            vi, vj = np.meshgrid(np.arange(r0, r1 + 1), np.arange(stride), indexing="ij")
            gx, gy, tr, valid = _trace(
                w, lay.x0 + vj.ravel() * lay.hx, lay.y0 + vi.ravel() * lay.hy, iors
            )
            ci, cj = (
                a.ravel() for a in np.meshgrid(np.arange(r0, r1), np.arange(lay.nx), indexing="ij")
            )
            v00 = (ci - r0) * stride + cj
            v01, v10, v11 = v00 + 1, v00 + stride, v00 + stride + 1
            tris = np.stack(
                [np.concatenate([v00, v00]), np.concatenate([v01, v11]), np.concatenate([v11, v10])]
            )  # (3, T)
            ring = np.tile(lay.in_ring(ci, cj), 2)
            for k in range(len(iors)):
                ok = valid[k][tris].all(axis=0)
                tri_flux = np.where(ok, tr[k][tris].mean(axis=0), 0.0) * tri_area
                sx = bary @ gx[k][tris]  # (S, T)
                sy = bary @ gy[k][tris]
                pix, inside = _bin(w, lay.wrap, sx, sy, np.broadcast_to(ok, sx.shape))
                weight = np.where(inside, tri_flux / samples, 0.0)
                flux[k] += np.bincount(pix.ravel(), weight.ravel(), minlength=rows * cols)
                ring_flux += float(weight[:, ring].sum())
        return flux, ring_flux

    return _render(w, per_axis, margin, estimate)
