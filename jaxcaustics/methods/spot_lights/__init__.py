"""Liu et al.'s caustic spot lights: `exit_rays.py` (rays leaving the object), `fit.py`
(spot lights fitted to them; its steps in `ray_set.py`, `bundles.py`, `focus_law.py`,
`splat.py` and `fit_common.py`), `lights.py` (the lights and their shading), `table.py` (a
moving light's precomputed table; its pieces in `directions.py`, `light_table.py`,
`frames.py` and `matching.py`) and `method.py` (the method for a scene)."""
