"""Umenhoffer et al.'s caustic triangles: `method.py` (the method and its knobs) with its
pieces `tracing.py` (the photon grid traced whole, shared checks), `rasterise.py` (the
triangles drawn on the screen), `sizing.py` (memory model, window and tiers), `bands.py`
(photon bands) and `visibility.py` (the distance-map pipeline); and `distance_map.py`
(layered distance maps and the light cube map) with its pieces `cube_faces.py`,
`layered_map.py`, `map_tracing.py` and `light_cube.py`."""
