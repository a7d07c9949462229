"""Refraction through the water surface and Fresnel transmittance (plain NumPy, float64)."""

from __future__ import annotations

import dataclasses
import numbers

import numpy as np


def refract(
    direction: np.ndarray, hx: np.ndarray, hy: np.ndarray, ior: float, fresnel: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Refract unit direction `direction` from index 1 into index `ior` at slopes (hx, hy).

    **Arguments:**

    - `direction`: `np.ndarray` of shape ``(3,)``, the unit direction of travel of the
      incoming light (``z < 0``).
    - `hx`, `hy`: `np.ndarray` of shape ``(N,)``, surface slopes at the hit points; the
      upward normal is ``(-hx, -hy, 1) / |.|``.
    - `ior`: index of refraction below the surface (a float; above is 1).
    - `fresnel`: whether to compute the unpolarised dielectric transmittance (a bool;
      else 1).

    **Returns:** ``(tx, ty, tz, transmittance, ok)``:

    - `tx`, `ty`, `tz`: `np.ndarray` of shape ``(N,)``, the unit refracted direction
      (vector Snell, ``eta = 1 / ior``).
    - `transmittance`: `np.ndarray` of shape ``(N,)``, ``1 - (Rs + Rp) / 2`` if `fresnel`
      else 1; 0 where the photon is lost.
    - `ok`: `np.ndarray` of bools, shape ``(N,)``, False for total internal reflection
      (``sin^2 theta_t > 1``) or a refracted ray that does not go down (``tz >= 0``).
    """
    d_x, d_y, d_z = (float(c) for c in direction)
    norm = np.sqrt(1.0 + hx * hx + hy * hy)
    n_x, n_y, n_z = -hx / norm, -hy / norm, 1.0 / norm
    cos_i = -(d_x * n_x + d_y * n_y + d_z * n_z)
    eta = 1.0 / ior
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    tir = sin2_t > 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    k = eta * cos_i - cos_t
    tx = eta * d_x + k * n_x
    ty = eta * d_y + k * n_y
    tz = eta * d_z + k * n_z
    ok = ~tir & (tz < 0.0)
    if fresnel:
        with np.errstate(divide="ignore", invalid="ignore"):
            rs = ((cos_i - ior * cos_t) / (cos_i + ior * cos_t)) ** 2
            rp = ((ior * cos_i - cos_t) / (ior * cos_i + cos_t)) ** 2
            transmittance = 1.0 - 0.5 * (rs + rp)
        # 0/0 only at exact grazing incidence with ior == 1: nothing is transmitted there.
        transmittance = np.where(np.isfinite(transmittance), transmittance, 0.0)
    else:
        transmittance = np.ones_like(cos_i)
    transmittance = np.where(ok, transmittance, 0.0)
    return tx, ty, tz, transmittance, ok


# --------------------------------------------------------------------------- checks
# The reference imports nothing of the library (not `jaxcaustics._checks`): its own small
# checks, worded as the library's.

# most photons of one trace (traced in chunks: some 7e10, hours to days), and most
# photons an emitter returns at once (float64 arrays of 2^26 photons: 1.5 to 3.5 GB)
MAX_PHOTONS = 1 << 36
MAX_EMITTED = 1 << 26


def _check_int(value, name: str, minimum: int = 1) -> int:
    """`value` as an int (bools and floats refused) ``>= minimum``, else a `ValueError`
    (worded as `jaxcaustics._checks.check_int`)."""
    whole = isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if not whole or value < minimum:
        raise ValueError(f"`{name}` must be an int >= {minimum}, got {value!r}")
    return int(value)


def _check_bool(value, name: str) -> bool:
    """`value` if it is ``True`` or ``False`` (Python or NumPy), else a `ValueError`."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"`{name}` must be True or False, got {value!r}")
    return bool(value)


def _rng(jitter, seed) -> np.random.Generator | None:
    """The jitter's generator (None without jitter); `jitter` and `seed` checked."""
    if not _check_bool(jitter, "jitter"):
        return None
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`seed` must be a non-negative int, got {seed!r}") from err


def _check_count(count: int, limit: int, what: str) -> None:
    """Refuse `count` photons over `limit` (`what` names the knob)."""
    if count > limit:
        raise ValueError(f"{what} gives {count} photons, over the limit {limit}")


def _real(value, name: str) -> np.ndarray:
    """`value` as a float64 array of finite real numbers, else a `ValueError` naming it
    (strings, bools, complex numbers, NaN and infinities are refused)."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as err:  # ragged sequences
        what = type(value).__name__
        raise ValueError(f"`{name}` must be finite real numbers, got {what}") from err
    if a.dtype.kind not in "iuf" or not np.all(np.isfinite(a)):
        raise ValueError(f"`{name}` must be finite real numbers")
    return a.astype(np.float64)


def _check_points(xs, ys) -> tuple[np.ndarray, np.ndarray]:
    """`xs`, `ys` as flat float64 arrays of one size: finite real numbers, else a
    `ValueError` naming them."""
    out = [_real(xs, "xs").ravel(), _real(ys, "ys").ravel()]
    if out[0].shape != out[1].shape:
        raise ValueError(
            f"`xs` and `ys` must have the same size, got {out[0].size} and {out[1].size}"
        )
    return out[0], out[1]


# memory of one photon in a chunk of the reference tracers: its arrays and the tracers'
# NumPy temporaries, bytes (an estimate: about 128 float64 numbers)
PHOTON_BYTES = 1024


def chunk_photons(memory_limit, default: int) -> int:
    """Photons traced at a time under `memory_limit` bytes (`PHOTON_BYTES` each);
    ``None``: the tracer's `default`. Raises a `ValueError` naming `memory_limit` unless
    it is ``None`` or an int ``>= 1``."""
    _check_int(default, "default")
    if memory_limit is None:
        return default
    if isinstance(memory_limit, bool) or not isinstance(memory_limit, (int, np.integer)):
        raise ValueError(f"`memory_limit` must be None or an int >= 1, got {memory_limit!r}")
    if memory_limit < 1:
        raise ValueError(f"`memory_limit` must be None or an int >= 1, got {memory_limit!r}")
    return max(1, int(memory_limit) // PHOTON_BYTES)


@dataclasses.dataclass(frozen=True)
class _Receiver:
    """A receiver (pixel grid on ``z = 0``) read into float64 values."""

    extent: tuple[float, float, float, float]
    shape: tuple[int, int]

    @classmethod
    def read(cls, receiver) -> _Receiver:
        try:
            rec_extent, rec_shape = receiver.extent, receiver.shape
        except AttributeError as err:
            raise ValueError(f"`scene.receiver` must have `extent` and `shape`: {err}") from err
        ext = np.asarray(rec_extent, dtype=np.float64)
        if (
            ext.shape != (4,)
            or not np.all(np.isfinite(ext))
            or not (ext[1] > ext[0] and ext[3] > ext[2])
        ):
            raise ValueError(
                f"`scene.receiver.extent` must be (x_min, x_max, y_min, y_max) with "
                f"max > min, got {ext!r}"
            )
        try:
            shape = tuple(int(s) for s in rec_shape)
        except TypeError as err:
            raise ValueError(
                f"`scene.receiver.shape` must be (rows, cols), got {rec_shape!r}"
            ) from err
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"`scene.receiver.shape` must be (rows, cols) >= 1, got {rec_shape!r}")
        return cls((float(ext[0]), float(ext[1]), float(ext[2]), float(ext[3])), shape)  # type: ignore[arg-type]

    @property
    def pixel_area(self) -> float:
        e, (rows, cols) = self.extent, self.shape
        return (e[1] - e[0]) / cols * ((e[3] - e[2]) / rows)

    def bin(self, x: np.ndarray, y: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, int]:
        """Flux per pixel (flat, ``rows * cols``) of photons landing at (x, y) with
        `weight` (0 for photons that did not land), and how many landed on the receiver
        (``x_min <= x < x_max``, ``y_min <= y < y_max``) with a non-zero weight."""
        rows, cols = self.shape
        x_min, x_max, y_min, y_max = self.extent
        inside = (weight != 0.0) & (x >= x_min) & (x < x_max) & (y >= y_min) & (y < y_max)
        xs, ys = np.where(inside, x, x_min), np.where(inside, y, y_min)
        col = np.clip(np.floor((xs - x_min) / ((x_max - x_min) / cols)), 0, cols - 1)
        row = np.clip(np.floor((ys - y_min) / ((y_max - y_min) / rows)), 0, rows - 1)
        pix = row.astype(np.int64) * cols + col.astype(np.int64)
        flux = np.bincount(pix, np.where(inside, weight, 0.0), minlength=rows * cols)
        return flux, int(np.count_nonzero(inside))


@dataclasses.dataclass(frozen=True)
class _Pose:
    """A screen's pose (`ScreenPose`) read into float64 unit vectors: the screen's
    coordinates of ``p`` are ``s = (p - centre) . right``, ``t = (p - centre) . up``,
    ``right = up x normal``."""

    centre: np.ndarray
    normal: np.ndarray
    up: np.ndarray

    @classmethod
    def read(cls, pose) -> _Pose | None:
        if pose is None:
            return None
        try:
            values = [np.asarray(v, dtype=np.float64) for v in (pose.centre, pose.normal, pose.up)]
        except AttributeError as err:
            raise ValueError(f"`scene.screen_pose` needs centre, normal and up: {err}") from err
        if any(v.shape != (3,) or not np.all(np.isfinite(v)) for v in values):
            raise ValueError("`scene.screen_pose`: centre, normal and up must be 3 finite numbers")
        centre, normal, up = values
        normal = normal / np.linalg.norm(normal)
        up = up - (up @ normal) * normal
        norm = float(np.linalg.norm(up))
        if not norm > 0.0:
            raise ValueError("`scene.screen_pose.up` is parallel to its normal")
        return cls(centre, normal, up / norm)

    def land(self, p: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rays from points `p` (3, N) along `d` (3, N) on the screen's plane: ``(s, t,
        reached)``; `reached` is false for rays that do not meet its lit face ahead."""
        towards = self.normal @ d
        with np.errstate(divide="ignore", invalid="ignore"):
            run = (self.normal @ (self.centre[:, None] - p)) / towards
        reached = (towards < 0.0) & (run > 0.0)
        q = p + np.where(reached, run, 0.0) * d - self.centre[:, None]
        right = np.cross(self.up, self.normal)
        return right @ q, self.up @ q, reached
