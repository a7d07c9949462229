"""Umenhoffer et al.'s caustic triangles: `method.py` (the method, its knobs and
photon bands) and `distance_map.py` (layered distance maps and the light cube map)."""
