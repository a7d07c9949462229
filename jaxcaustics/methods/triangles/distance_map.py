"""Layered distance maps and light cube maps (Umenhoffer, Patow & Szirmay-Kalos).

T. Umenhoffer, G. Patow, L. Szirmay-Kalos, "Caustic Triangles on the GPU" (2008), and
"Robust Multiple Specular Reflections and Refractions" (GPU Gems 3, 2007).

The scene around a caustic generator is sampled from one *reference point* ``c`` (the
centre) into a cube map: every texel stores, per layer, the distance, normal and
material of a surface seen in the texel's direction (`build_distance_map`). Rays that
leave the generator are traced against this sampled scene (`trace_distance_map`): a
linear search along the ray for the first sample that passes from *undershooting*
(``|l - c| < |l' - c|``, the point is in front of the stored surface seen in its
direction) to *overshooting* in some layer, then a secant search inside that bracket.

Caustic triangles (terminal photon hits of three neighbouring photons) are then drawn
onto the faces of a *light cube map* around the same centre (`light_cube_map`), which
stores, per texel, the irradiance and the distance of the surface the caustic landed
on. The camera pass (`project_light_cube_map`) looks the light cube map up in the
direction of a shaded point and, like a shadow map, accepts the texel only when its
stored distance matches the point's: caustics do not leak behind occluders.

This module gathers their public names; the code is in `cube_faces.py` (the cube-map
convention: face frames and projections), `layered_map.py` (the layered distance map),
`map_tracing.py` (rays traced in it) and `light_cube.py` (the light cube map and the
camera pass).
"""

from .cube_faces import direction_face, face_coordinates, texel_directions
from .layered_map import (
    MATERIAL_EMPTY,
    MATERIAL_OCCLUDER,
    MATERIAL_RECEIVER,
    LayeredDistanceMap,
    build_distance_map,
)
from .light_cube import LightCubeMap, light_cube_map, project_light_cube_map
from .map_tracing import (
    DistanceMapHit,
    default_scale,
    exact_hits,
    trace_distance_map,
    tracing_error_table,
)

__all__ = [
    "MATERIAL_EMPTY",
    "MATERIAL_OCCLUDER",
    "MATERIAL_RECEIVER",
    "DistanceMapHit",
    "LayeredDistanceMap",
    "LightCubeMap",
    "build_distance_map",
    "default_scale",
    "direction_face",
    "exact_hits",
    "face_coordinates",
    "light_cube_map",
    "project_light_cube_map",
    "texel_directions",
    "trace_distance_map",
    "tracing_error_table",
]
