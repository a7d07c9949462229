"""The outline of a lens blank (`LensScene.outline`): the light outside it is stopped by
the mount, and the exported solid is cut to it.

An outline is inscribed in the aperture (the height field's extent) and given in the
aperture's normalised frame, ``x = (u - centre) / half-width`` and likewise ``y``, so
that the aperture is ``[-1, 1]^2``:

- ``"rectangle"``: the whole aperture;
- ``"ellipse"``: the ellipse inscribed in it;
- a polygon: a tuple of ``(x, y)`` vertices in ``[-1, 1]^2``, star-shaped about the centre
  (every ray from the centre leaves it once: a convex polygon about its centre, a star, a
  triangle), counter-clockwise.

Values are static (hashable): `jit` specialises on the outline. A boolean mask over the
blank becomes a polygon by `mask_vertices` (its boundary traced and simplified).
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi
import skimage.measure

OUTLINES = ("rectangle", "ellipse")  # by name; a tuple of vertices is a polygon


def check_outline(outline, name: str = "outline"):
    """`outline` as `LensScene` keeps it (a name, or a polygon's vertices as a tuple of
    float pairs, counter-clockwise), or a `ValueError` naming `name`."""
    if isinstance(outline, str):
        if outline not in OUTLINES:
            raise ValueError(
                f"`{name}` must be one of {OUTLINES} or a polygon's vertices, got {outline!r}"
            )
        return outline
    try:
        v = np.asarray(outline, dtype=float)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`{name}` must be a name or (x, y) vertices, got {outline!r}") from err
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or v.shape[0] > 1024:
        raise ValueError(f"`{name}`: a polygon needs 3 to 1024 (x, y) vertices, got {v.shape}")
    if not np.all(np.isfinite(v)) or np.abs(v).max() > 1.0 + 1e-9:
        raise ValueError(f"`{name}`: the vertices must lie in the aperture, [-1, 1]^2")
    cross = v[:, 0] * np.roll(v[:, 1], -1) - v[:, 1] * np.roll(v[:, 0], -1)
    if np.all(cross < 0):  # clockwise: the same polygon turned round
        v, cross = v[::-1], -cross[::-1]
    if not np.all(cross > 0):
        raise ValueError(
            f"`{name}`: the polygon must be star-shaped about the aperture's centre (its "
            "vertices in angular order round the centre, which lies inside)"
        )
    angles = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    if abs(angles[-1] - angles[0]) >= 2 * np.pi or not np.all(np.diff(angles) > 0):
        raise ValueError(f"`{name}`: the polygon's vertices must go once round the centre")
    return tuple((float(x), float(y)) for x, y in v)


def inside_outline(outline, extent, u, v):
    """Whether the points ``(u, v)`` (the aperture's own, unrotated frame) lie inside the
    blank's `outline` (as `check_outline` gives it) over `extent` ``(x_min, x_max,
    y_min, y_max)``: the rectangle, the ellipse inscribed in it (rim included) or the
    polygon (crossing-number test). Works on NumPy and JAX arrays alike."""
    x0, x1, y0, y1 = extent
    if isinstance(outline, str) and outline == "rectangle":
        return (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1)
    a, b = 0.5 * (x1 - x0), 0.5 * (y1 - y0)
    x, y = (u - 0.5 * (x0 + x1)) / a, (v - 0.5 * (y0 + y1)) / b
    if isinstance(outline, str):  # "ellipse"
        return x * x + y * y <= 1.0
    inside = (x != x) & False  # all False, of the points' kind and shape
    for (xa, ya), (xb, yb) in zip(outline, outline[1:] + outline[:1], strict=True):
        if ya == yb:  # a horizontal edge crosses no horizontal ray
            continue
        crosses = (ya > y) != (yb > y)
        inside = inside ^ (crosses & (x < xa + (y - ya) * ((xb - xa) / (yb - ya))))
    return inside


def outline_radius(outline, theta: np.ndarray) -> np.ndarray:
    """The distance from the centre to the outline along the directions `theta`
    (radians, in the normalised frame): 1 for the ellipse, the boundary of a polygon.
    NumPy (the exported solid's rings)."""
    theta = np.asarray(theta, dtype=float)
    if isinstance(outline, str):
        if outline != "ellipse":
            raise ValueError("a rectangle's outline is exported as a grid, not on rings")
        return np.ones_like(theta)
    dx, dy = np.cos(theta), np.sin(theta)
    radius = np.full(theta.shape, np.inf)
    for (xa, ya), (xb, yb) in zip(outline, outline[1:] + outline[:1], strict=True):
        ex, ey = xb - xa, yb - ya
        det = dx * -ey - dy * -ex  # solve t d = a + s e for (t, s)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (xa * -ey - ya * -ex) / det
            s = (dx * ya - dy * xa) / det
        hit = (np.abs(det) > 1e-15) & (t > 0) & (s >= -1e-12) & (s <= 1 + 1e-12)
        radius = np.where(hit, np.minimum(radius, t), radius)
    return radius


MASK_SMOOTHING = 0.7  # pixels: the mask's Gaussian blur before its boundary is traced
MAX_VERTICES = 1024  # `check_outline`'s limit


def mask_vertices(mask, name: str = "mask") -> np.ndarray:
    """The boundary of a boolean `mask` ``(rows, cols)`` (indexed ``[y, x]``, row 0 at
    ``y_min``, as the library's heights) as polygon vertices ``(N, 2)`` in pixel units
    ``(x, y)`` from the mask's lower-left corner (so the mask spans ``[0, cols] x [0,
    rows]``), counter-clockwise, simplified to within half a pixel.

    The mask must be one region without holes, star-shaped about the centre of its
    bounding box (`check_outline`); anything else is a `ValueError` naming `name`. The
    boundary is traced with scikit-image's marching squares (`find_contours`) on the mask
    blurred by `MASK_SMOOTHING` pixels, which rounds the pixel staircase into the shape
    it draws, then simplified by Douglas-Peucker (`approximate_polygon`)."""
    m = np.asarray(mask)
    if m.ndim != 2 or min(m.shape) < 3 or m.dtype == object:
        raise ValueError(f"`{name}` must be a 2-D boolean mask, 3 x 3 or larger, got {m.shape}")
    if m.dtype != bool:
        if not np.issubdtype(m.dtype, np.number) or not np.all(np.isin(m, (0, 1))):
            raise ValueError(f"`{name}` must be boolean (or 0 and 1)")
        m = m.astype(bool)
    if m.sum() < 4:
        raise ValueError(f"`{name}` holds fewer than 4 pixels inside the outline")
    soft = ndi.gaussian_filter(np.pad(m, 2).astype(float), MASK_SMOOTHING)
    _, regions = ndi.label(soft > 0.5)  # counted on what is traced (a pixel-wide
    _, holes = ndi.label(soft <= 0.5)  # neck joins or parts as the blur has it)
    if regions != 1 or holes != 1:
        raise ValueError(
            f"`{name}` must be one region without holes, got {regions} region(s) and "
            f"{holes - 1} hole(s)"
        )
    (contour,) = skimage.measure.find_contours(soft, 0.5)  # (row, col), closed
    xy = contour[:, ::-1] - 2.0 + 0.5  # pixel centres at + 0.5; the padding removed
    for tolerance in (0.5, 1.0, 2.0, 4.0):
        v = skimage.measure.approximate_polygon(xy, tolerance)[:-1]  # open ring
        if len(v) <= MAX_VERTICES:
            break
    return v
