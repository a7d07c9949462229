"""Stage 2, tracing: light leaves the source, meets the scene, and lands.

- `optics.py`: refraction, reflection and Fresnel transmittance of rays (vectors).
- `intersect.py`: rays against triangles (brute force and a bounding volume hierarchy).
- `photons.py`: photons through lens slabs and meshes (`Photons`, `trace_mesh_rays`).

Reads `scene`; the methods (stage 4) build on it.
"""
