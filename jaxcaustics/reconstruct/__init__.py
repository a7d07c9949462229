"""Stage 3, reconstruction: landed photons (points, triangles) to an image.

- `raster.py`: differentiable kernels shared by the methods: exact triangle coverage,
  Gouraud triangles, Gaussian splats, and sums over photon batches under a memory limit.
"""
