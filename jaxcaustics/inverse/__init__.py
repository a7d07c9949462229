"""Stage 6, inverse problems: from a target image back to a surface, with Optimistix.

- `design.py`: `design_lens` (a caustic lens for a target picture); `transport.py`: the
  optimal-transport start; `export.py`: the lens as a millable solid (STL/OBJ);
  `verify.py`: the exported lens traced by the NumPy reference.
- `recover.py`: `recover_surface` (water from its caustic), with `water_start.py` (the
  transport start), `water_refine.py` (folding caustics), `camera.py` (a photo's blur)
  and `sequence.py` (a video).
- `solvers.py`: the solvers both use and their loss convention (``0.5 sum r^2``);
  `checkpoint.py`: rounds, checkpoints, resume and progress of long optimisations.
"""
