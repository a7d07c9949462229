"""Liu et al.'s caustic spot lights: `exit_rays.py` (rays leaving the object), `fit.py`
(spot lights fitted to them), `lights.py` (the lights and their shading), `table.py` (a
moving light's precomputed table) and `method.py` (the method for a scene)."""
