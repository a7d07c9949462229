"""The solid of a lens with an elliptical outline (a round lens): a watertight mesh in
millimetres whose top is the designed surface over the ellipse, sampled on rings.

The top is a polar mesh: a centre vertex and `rings` concentric ellipses, ring ``k`` with
``6 k`` vertices (so that its spacing along the rim stays about the spacing between
rings); neighbouring rings are stitched by walking both in angle. The rim is closed by a
vertical wall down to the bottom face ``z = 0``, a fan of triangles from the centre. The
frame is `lens_solid`'s: the origin at the aperture's corner ``(x_min, y_min)``.

Written by hand: trimesh builds such solids through shapely and a triangulator
(`trimesh.creation.extrude_polygon`), which are not dependencies here, and its extrusion
has a flat top; a polar grid needs neither.
"""

from __future__ import annotations

import numpy as np


def _stitch(inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """Triangles between two closed rings of vertex indices, each ordered by angle from
    0 (counter-clockwise seen from above: the normals point up), ``(T, 3)``."""
    n_in, n_out = len(inner), len(outer)
    faces = []
    i = j = 0
    while i < n_in or j < n_out:
        # advance on the ring whose next vertex comes first in angle
        if j < n_out and (i == n_in or (j + 1) / n_out <= (i + 1) / n_in):
            faces.append((inner[i % n_in], outer[j], outer[(j + 1) % n_out]))
            j += 1
        else:
            faces.append((inner[i % n_in], outer[j % n_out], inner[(i + 1) % n_in]))
            i += 1
    return np.asarray(faces)


def ring_points(rings: int, width: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """The top's vertices, ``(x, y)`` in the solid's frame (any length unit): the centre,
    then ring ``k = 1 .. rings`` with ``6 k`` points from angle 0 counter-clockwise."""
    a, b = 0.5 * width, 0.5 * height
    xs, ys = [np.array([a])], [np.array([b])]
    for k in range(1, rings + 1):
        theta = 2.0 * np.pi * np.arange(6 * k) / (6 * k)
        xs.append(a + a * (k / rings) * np.cos(theta))
        ys.append(b + b * (k / rings) * np.sin(theta))
    return np.concatenate(xs), np.concatenate(ys)


def round_solid_arrays(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, rings: int
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)`` and faces ``(F, 3)`` of the closed solid whose top vertices
    are `ring_points` ``(x, y)`` at heights `z` (all > 0)."""
    n_top = len(x)
    top = np.stack([x, y, z], axis=1)
    starts = [0] + [1 + 3 * k * (k - 1) for k in range(1, rings + 1)]  # ring k's first
    ring = [np.array([0])] + [starts[k] + np.arange(6 * k) for k in range(1, rings + 1)]
    top_faces = [_stitch(ring[0], ring[1])] if rings else []
    top_faces += [_stitch(ring[k - 1], ring[k]) for k in range(2, rings + 1)]
    # the first ring stitched to the centre is a fan: drop the degenerate triangles
    loop = ring[rings]
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
