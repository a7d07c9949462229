"""The solid of a lens with an elliptical or polygonal outline (a round lens, a star): a
watertight mesh in millimetres whose top is the designed surface over the outline,
sampled on rings.

The top is a polar mesh: a centre vertex and `rings` concentric copies of the outline
(the outline scaled by ``k / rings`` about the centre: it must be star-shaped), ring
``k`` with ``6 k`` vertices (so that its spacing along the rim stays about the spacing
between rings) and a polygon's corners; neighbouring rings are stitched by walking both
in angle. The rim is closed by a vertical wall down to the bottom face ``z = 0``, a fan
of triangles from the centre. The frame is `lens_solid`'s: the origin at the aperture's
corner ``(x_min, y_min)``. See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import numpy as np


def _stitch(inner: np.ndarray, t_in: np.ndarray, outer: np.ndarray, t_out: np.ndarray):
    """Triangles between two closed rings of vertex indices at angles `t_in`, `t_out`
    (each increasing from 0, below 2 pi: counter-clockwise seen from above, so the
    normals point up), ``(T, 3)``: a walk that advances on the ring whose next vertex
    comes first in angle."""
    n_in, n_out = len(inner), len(outer)
    faces = []
    i = j = 0
    while i < n_in or j < n_out:
        next_in = t_in[i + 1] if i + 1 < n_in else 2.0 * np.pi
        next_out = t_out[j + 1] if j + 1 < n_out else 2.0 * np.pi
        if j < n_out and (i == n_in or next_out <= next_in):
            faces.append((inner[i % n_in], outer[j], outer[(j + 1) % n_out]))
            j += 1
        else:
            faces.append((inner[i % n_in], outer[j % n_out], inner[(i + 1) % n_in]))
            i += 1
    return np.asarray(faces)


def ring_angles(rings: int, corners=()) -> list[np.ndarray]:
    """Each ring's angles: the centre (one vertex at 0), then ring ``k = 1 .. rings``
    with ``6 k`` even angles and the outline's `corners` (radians), so that every ring
    is the outline itself scaled, corners included."""
    corners = np.mod(np.asarray(corners, dtype=float), 2.0 * np.pi)
    angles = [np.zeros(1)]
    for k in range(1, rings + 1):
        even = 2.0 * np.pi * np.arange(6 * k) / (6 * k)
        step = 2.0 * np.pi / (6 * k)
        # a corner closer than a tenth of a step to an even angle takes its place
        near = np.abs(np.angle(np.exp(1j * (even[:, None] - corners[None, :])))) < 0.1 * step
        t = np.unique(np.concatenate([even[~near.any(axis=1)], corners]))
        angles.append(t[t >= 0.0] if len(t) else t)
    return angles


def ring_points(
    angles: list[np.ndarray], width: float, height: float, radius=None
) -> tuple[np.ndarray, np.ndarray]:
    """The top's vertices, ``(x, y)`` in the solid's frame (any length unit): the centre,
    then ring ``k`` at `angles` ``[k]``, at ``k / rings`` of the outline's radius
    (``radius(theta)`` in the frame normalised to ``[-1, 1]^2``; default 1: the
    inscribed ellipse)."""
    a, b = 0.5 * width, 0.5 * height
    rings = len(angles) - 1
    xs, ys = [np.array([a])], [np.array([b])]
    for k in range(1, rings + 1):
        theta = angles[k]
        r = (k / rings) * (1.0 if radius is None else radius(theta))
        xs.append(a + a * r * np.cos(theta))
        ys.append(b + b * r * np.sin(theta))
    return np.concatenate(xs), np.concatenate(ys)


def round_solid_arrays(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, angles: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)`` and faces ``(F, 3)`` of the closed solid whose top vertices
    are `ring_points` ``(x, y)`` (on rings at `angles`) at heights `z` (all > 0)."""
    n_top = len(x)
    top = np.stack([x, y, z], axis=1)
    starts = np.cumsum([0] + [len(t) for t in angles])
    ring = [starts[k] + np.arange(len(t)) for k, t in enumerate(angles)]
    top_faces = [
        _stitch(ring[k - 1], angles[k - 1], ring[k], angles[k]) for k in range(1, len(ring))
    ]
    # the first ring stitched to the centre is a fan: drop the degenerate triangles
    loop = ring[-1]
    n_loop = len(loop)
    bottom = np.concatenate([top[loop, :2], np.zeros((n_loop, 1))], axis=1)
    centre = np.array([[x[0], y[0], 0.0]])
    vertices = np.concatenate([top, bottom, centre])
    ta, tb = loop, np.roll(loop, -1)
    ba = n_top + np.arange(n_loop)
    bb = np.roll(ba, -1)
    walls = np.concatenate([np.stack([ta, ba, bb], 1), np.stack([ta, bb, tb], 1)])
    fan = np.stack([np.full(n_loop, n_top + n_loop), bb, ba], 1)
    faces = np.concatenate([*top_faces, walls, fan])
    keep = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    )
    return vertices, faces[keep]
