"""Caustic maps (Shah et al.; Wyman & Nichols): `method.py` (caustics mapping and the
adaptive caustic map), `light_view.py` (the light's projection) and `gbuffer.py` (geometry
buffers seen from the light)."""
