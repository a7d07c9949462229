"""Stage 1, the scene: what is lit, by what, and where the light lands.

- `scene.py`: `HeightField`, `DirectionalLight`, `PointLight`, `PlaneReceiver`, `Effects`,
  `WaterScene` and `LensScene` (plain data: Equinox modules).
- `sources.py`: `SunLight`, a `DirectionalLight` with the Sun's disc, and `AreaLight`, a
  `PointLight` with a flat emitter's size.
- `mesh.py`: `Mesh` and `MeshScene`; `ellipsoid.py`: `Ellipsoid` and `EllipsoidScene`.
- `surface.py`: the height field between its samples (Catmull-Rom bicubic) and rays
  meeting it; `waves.py`: procedural water surfaces.
- `checks.py`: a scene's values checked where a method starts rendering (under `jit`).

Imports only `jaxcaustics._checks` (and the reference's NumPy disc sampling): every later
stage reads the scene, none is read here.
"""
