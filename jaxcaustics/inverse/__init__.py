"""Stage 6, inverse problems: from a target image back to a surface, with Optimistix.

Lens design, a problem stated as data and solved by strategies:

- `problem.py`: what is made (`DesignProblem`: `Lens`, `Rectangle`, `Screen`, a light);
  `design.py`: `design` (and `design_lens`, its keyword form) and the result
  `LensDesign`; `design_setup.py` / `lens_setup.py`: the checked set-up;
  `design_rounds.py`: the design's rounds, checkpointed; `variants.py`: designs for
  several screen distances over devices.
- the strategies, a Module of settings each: `transport_start.py` (`TransportStart`,
  over the optimal transport of `transport.py`), `poisson_levels.py` (`PoissonLevels`),
  `image_refine.py` (`ImageRefinement`); `lens_model.py`: the lens's exact optics for
  the solvers.
- `export.py`: the lens as a millable solid (STL/OBJ); `verify.py`: the exported lens
  traced by the NumPy reference.

Water recovery: `recover.py` (`recover_surface`, results in `recover_result.py`), with
`water_target.py` (the caustic read and checked), `water_start.py` (the transport
start), `water_refine.py` (folding caustics), `camera.py` (a photo's blur),
`sequence.py` (a video) and `compare_solvers.py`.

Shared: `driver.py` (the solvers stepped from Python: a loss per step, callbacks, the
best iterate), `numerics.py` (Poisson solves, Laplacians, resampling, area averages),
`solvers.py` (the solvers' names and loss convention, ``0.5 sum r^2``), `checkpoint.py`
(rounds, checkpoints, resume and progress of long optimisations).
"""
