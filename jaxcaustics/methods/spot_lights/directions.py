"""The light directions of a moving-light table (`table.py`, Liu et al. 2008, Sect. 4): the
vertices and faces of a subdivided icosahedron (`icosphere_directions`), its edges
(`direction_edges`) and the spherical interpolation along an edge (`slerp`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._checks import check_int

MAX_SUBDIVISIONS = 6
"""Most subdivisions of the icosahedron of directions (6: 40962 directions)."""


def icosphere_directions(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Light directions at the vertices of a subdivided icosahedron (trimesh's icosphere).

    **Arguments:**

    - `subdivisions`: number of midpoint subdivisions of the icosahedron (0: 12 vertices,
      1: 42, 2: 162 as in the paper).

    **Returns:** ``(vertices, faces)``: ``(V, 3)`` float64 unit vectors (each the direction
    towards the light; the light travels along ``-vertex``) and ``(F, 3)`` int32 vertex
    indices, counter-clockwise seen from outside (normals point outwards).
    """
    subdivisions = check_int(subdivisions, "subdivisions", 0, MAX_SUBDIVISIONS)
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=1.0)
    vertices = np.asarray(mesh.vertices, np.float64)
    vertices = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    faces = np.asarray(mesh.faces, np.int32).copy()
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.einsum("fk,fk->f", normal, tri.sum(axis=1)) < 0
    faces[inward] = faces[inward][:, ::-1]
    return vertices, faces


def direction_edges(faces) -> np.ndarray:
    """The edges of a triangle mesh of directions, ``(E, 2)`` int32, each sorted
    (``a < b``), in lexicographic order: the edge order of `SpotLightTable`."""
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"`faces` must have shape (F, 3), got {faces.shape}")
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0).astype(np.int32)


def slerp(s0: Float[Array, "3"], s1: Float[Array, "3"], t) -> Float[Array, "3"]:
    """Spherical linear interpolation between unit vectors (not antipodal), ``t`` in [0, 1]."""
    cos = jnp.clip(jnp.dot(s0, s1), -1.0, 1.0)
    angle = jnp.arccos(cos)
    sin = jnp.sin(angle)
    small = sin < 1e-9
    safe = jnp.where(small, 1.0, sin)
    w0 = jnp.where(small, 1.0 - t, jnp.sin((1.0 - t) * angle) / safe)
    w1 = jnp.where(small, t, jnp.sin(t * angle) / safe)
    s = w0 * s0 + w1 * s1
    return s / jnp.linalg.norm(s)
