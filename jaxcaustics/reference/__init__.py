"""Reference photon tracers (water, lens, mesh, ellipsoid scenes): plain NumPy, ground truth.

This package imports no JAX (nor anything from the library's private ``jaxcaustics._*``
modules), only NumPy and the standard library, so it shares no code with the methods it
checks. It reads a `jaxcaustics.WaterScene`, `LensScene` or `MeshScene` by duck typing
(``np.asarray`` on its fields) and computes everything in float64. It favours exactness
over speed, but is vectorised (its throughput: see the design notes,
``docs/design-notes.md``).

Public functions
----------------
- `trace_water`: irradiance on the ground by forward photon tracing.
- `area_ratio_water`: a second, independent estimator mapping triangles of a rest-plane
  grid to the ground and spreading their flux over their images.
- `trace_photons`: trace given rest-plane start points to the ground (both estimators use
  it).
- `surface_height`: the bicubic height field and its analytic gradient.
- `trace_lens`, `trace_lens_photons`, `emit_lens_photons`: the lens scene (a glass slab
  with a height-field top over a screen): image, photon by photon, emission grid.
- `trace_mesh`, `trace_mesh_photons`, `emit_mesh_photons`: the mesh scene (a refracting
  or mirroring triangle mesh, occluders): image (and photon counts), photon by photon,
  emission grid.
- `intersect_mesh`: nearest ray/triangle hits (exact Möller–Trumbore, float64).
- `trace_lens_triangles`: the lens scene's caustic by triangles of traced vertices
  spread over the pixels by area: no photon noise, second-order in the grid's spacing.
- `trace_solid_facets`: the exact caustic of a faceted height-field solid on a flat
  bottom face (an exported lens) under parallel light, facet by facet: no photon grid.
- `chunk_photons`, `PHOTON_BYTES`: photons traced at a time under a `memory_limit`
  (bytes; the tracers' `memory_limit` argument).
- `trace_ellipsoid`, `trace_ellipsoid_rays`: the ellipsoid scene (an analytic glass
  ellipsoid or sphere, ellipsoid occluders, directional light): image (and photon
  counts), and given rays traced to where they leave the ellipsoid.

Conventions (shared exactly with the JAX side)
----------------------------------------------
- The ground (receiver) is the plane ``z = 0``; the water surface is
  ``z = rest_depth + H(x, y)``. Arrays are indexed ``[row, col] = [y, x]``.
- An extent ``(x_min, x_max, y_min, y_max)`` covers pixel edges: sample ``(i, j)`` of an
  array of shape ``(rows, cols)`` sits at ``x = x_min + (j + 0.5) dx``,
  ``y = y_min + (i + 0.5) dy`` with ``dx = (x_max - x_min) / cols``,
  ``dy = (y_max - y_min) / rows``.
- ``H`` is the Catmull-Rom bicubic interpolant of the heights: with
  ``u = (x - x_min) / dx - 0.5``, ``j0 = floor(u)``, ``t = u - j0``, taps
  ``j0 - 1 .. j0 + 2`` get weights ``(-t^3 + 2t^2 - t)/2``, ``(3t^3 - 5t^2 + 2)/2``,
  ``(-3t^3 + 4t^2 + t)/2``, ``(t^3 - t^2)/2`` (the same along rows). Tap indices wrap
  (``"periodic"``) or are clipped to ``[0, n - 1]`` (``"clamp"``); with
  ``"extrapolate"`` a tap ``k`` outside is ``2 h[edge] - h[mirror]`` (odd reflection
  about the edge sample) and ``u`` is clipped to ``[-2, n + 1]``. The gradient is the
  analytic derivative of the interpolant; the upward normal is ``(-Hx, -Hy, 1) / |.|``.
- A height field may be rotated (``surface.rotation``, radians, counter-clockwise seen
  from above, about the centre of its extent): world points are mapped into the field's
  own frame before sampling, and gradients rotated back. Periodic wrapping of landing
  points is used only for unrotated fields; rotated ones are emitted with a margin.
- Light is collimated with unit direction of travel ``d`` (``d_z < 0``). Photons start on
  the rest plane ``z = rest_depth`` and hit the surface at the first root of
  ``z(t) - rest_depth - H(x(t), y(t))`` along the whole line (``t`` may be negative),
  found by a march whose steps are provably safe (rigorous per-cell bounds on the slope
  and curvature of the bicubic; only dips shallower than 1e-10 of the height range can be
  stepped over) and refined by safeguarded Newton iteration to machine precision.
- Refraction from index 1 into ``n``: ``eta = 1 / n``, ``cos_i = -d.n``,
  ``sin2_t = eta^2 (1 - cos_i^2)`` (``> 1``: total internal reflection, photon lost),
  ``T = eta d + (eta cos_i - sqrt(1 - sin2_t)) n``; Fresnel transmittance
  ``1 - (Rs + Rp) / 2``. Photons land at ``P - (P_z / T_z) T``.
- Photons start on a grid aligned so that under flat water they land at the centres of
  sub-cells of the receiver's pixels (start = landing + ``rest_depth T0_xy / T0_z``, ``T0``
  the refracted direction through flat water); each carries the horizontal area of its
  grid cell (times the Fresnel transmittance). For a periodic surface and a receiver of
  whole periods, landing points wrap into the receiver (energy is conserved exactly);
  otherwise the emission window is padded by a margin and photons landing off the
  receiver are dropped.
- Images are binned flux divided by the receiver's pixel area: irradiance relative to
  the light's irradiance on a horizontal plane, so flat water (Fresnel off) gives exactly
  1.0 at any light angle. A scalar ``scene.ior`` gives an image of shape
  ``(rows, cols)``; a sequence gives ``(rows, cols, C)``.

Conventions of the lens and mesh scenes
---------------------------------------
- Receiver (screen) ``z = 0`` and pixel grid as above. Images are binned photon flux
  divided by the pixel area. Directional light (unit direction of travel ``d``): flux
  relative to the light's irradiance on a horizontal plane, i.e. a bundle crossing
  horizontal area ``A`` carries ``A``, one crossing beam-perpendicular area ``A_perp``
  carries ``A_perp / |d_z|`` (times Fresnel factors). Point light (position ``p``,
  intensity ``I`` W/sr): a bundle through a small area ``A`` with unit normal ``m`` at
  distance ``r``, ray direction ``w``, carries ``I |w.m| A / r^2``; images in W/m^2.
- Refraction from ``n1`` into ``n2`` at a unit normal ``m`` oriented against ``d``:
  ``eta = n1 / n2``, ``cos_i = -d.m``, ``sin2_t = eta^2 (1 - cos_i^2)`` (``> 1``: total
  internal reflection), ``T = eta d + (eta cos_i - cos_t) m``; Fresnel transmittance
  ``1 - (Rs + Rp) / 2`` with ``Rs = ((eta cos_i - cos_t) / (eta cos_i + cos_t))^2``,
  ``Rp = ((cos_i - eta cos_t) / (cos_i + eta cos_t))^2``.
- One image channel per index of refraction: a scalar ``scene.ior`` gives
  ``(rows, cols)``, a sequence ``(rows, cols, C)`` (a mirror: always ``(rows, cols)``).

Lens (`LensScene`): top surface ``z = screen_distance + thickness + H(x, y)`` (``H`` as above,
rotation included), flat bottom face ``z = screen_distance`` (an infinite plane, no side walls),
glass of index ``n``.

- The aperture: a photon belongs to the lens iff its line crosses the top rest plane
  ``z = screen_distance + thickness`` inside ``surface.extent`` (half-open: ``x_min <= x < x_max``,
  ``y_min <= y < y_max``, in the field's own frame for a rotated field). Photons start
  there: a grid of equal cells over the extent (in the field's frame), each carrying its
  cell's area times the flux density (1 for a directional light, ``I |w_z| / r^2`` for a
  point light, ``r`` the distance from the light to the start point).
- The hit with the top surface is the first root along the whole line (``t`` may be
  negative), by the same safe march and Newton as for water (per-ray directions for a
  point light). Refract air -> glass (``eta = 1 / n``, upward normal; total internal
  reflection, only for ``n < 1``, loses the photon), go straight to ``z = screen_distance`` (the
  top surface is not met again; a ray that does not go down, or a hit at or below the
  bottom face, loses the photon), refract glass -> air (normal ``(0, 0, 1)``,
  ``eta = n``; total internal reflection loses the photon), land on ``z = 0``.
- Fresnel on: the photon carries the product of both faces' transmittances.
- A screen pose (``scene.screen_pose``: centre ``c``, unit normal ``n`` of the lit face,
  up ``u`` made perpendicular to ``n``): the ray leaving the bottom face lands where it
  meets the plane through ``c`` if ``d.n < 0`` and the meeting lies ahead; the screen's
  coordinates are ``s = (p - c).(u x n)``, ``t = (p - c).u`` and the receiver's extent
  is read in them. Otherwise the screen is ``z = 0``.

Mirror (`MirrorScene`): face ``z = H(x, y)`` about the rest plane ``z = 0``, the aperture
and start points as for lenses on that plane, the first root along the whole line (a hit
outside the extent or the outline misses the blank: lost), reflection ``d - 2 (d.m) m``
about the face's unit normal ``m``, landing on the screen pose's plane as above; each
photon carries the lens's flux density times ``scene.reflectance``.

Mesh (`MeshScene`): a generator mesh (triangles counter-clockwise seen from outside), a
``"refractor"`` of index ``n`` (each of ``scene.ior``) or a ``"mirror"``, and opaque
occluder meshes.

- Normals: ``"flat"``: the face's geometric normal; ``"smooth"``: vertex normals are the
  normalised sums of the unnormalised face normals ``(v1 - v0) x (v2 - v0)`` (area
  weighted) of the faces around each vertex, and the shading normal at a hit of
  barycentrics ``(b0, b1, b2)`` is ``normalise(b0 n0 + b1 n1 + b2 n2)``. Entering or
  leaving is decided by the geometric normal: ``d.n_face < 0`` enters.
- A path has at most ``scene.interfaces`` events. At each step the nearest generator hit
  (``t > 1e-9`` of the scene's size, and never the face the ray leaves) and the nearest
  occluder hit are found; an occluder hit nearer than the generator hit kills the
  photon. Mirror: reflect about the shading normal (reflectance 1). Refractor: refract
  about the shading normal oriented against ``d``, from 1 into ``n`` entering, from
  ``n`` into 1 leaving; under total internal reflection reflect instead (factor 1) and
  stay on the same side. Fresnel on: the transmittance of every refraction multiplies
  the photon.
- A photon that never met the generator is not rendered (no direct light). One still
  inside after ``interfaces`` events, or outside but about to meet the generator again,
  is dropped. After its last event a photon must go down (``d_z < 0``) and reach
  ``z = 0`` without meeting an occluder; it lands there.
- Emission: the generator's vertices are projected onto the plane through the centre of
  its bounding box perpendicular to the light (directional: parallel projection;
  point light: central projection onto the plane perpendicular to the axis light ->
  centre); the bounding rectangle of the projections is cut into a grid of equal cells,
  one photon per cell. Directional photons start before every vertex along the light
  and carry ``A_perp / |d_z|``; point-light photons start at the light and carry
  ``I |w . axis| A / r^2`` for the cell area ``A`` at distance ``r``.
- Ray/triangle hits: Möller–Trumbore in float64, with a barycentric slack of 1e-12 so
  that rays through shared edges do not leak; a bounding volume hierarchy only culls.

Ellipsoid (`EllipsoidScene`): a glass ellipsoid (``center``, semi-axes ``radii``,
orthonormal ``rotation`` whose columns are its axes) of index ``n`` (each of
``scene.ior``), opaque ellipsoid occluders, a directional light.

- Intersections are exact: the quadric ``(x - c)^T Q (x - c) = 1``,
  ``Q = R diag(radii)^-2 R^T``, solved in world coordinates (cancellation-free roots);
  from outside the smaller root counts, from inside the larger (roots within 1e-9 of the
  largest semi-axis are ignored). The normal is ``Q (x - c)`` normalised.
- Paths follow the mesh rules above (events, total internal reflection, Fresnel,
  occluders, dropping, landing), with "entering" meaning "outside before the event".
- Emission: the bounding rectangle of the generator's parallel projection onto the plane
  through its centre perpendicular to the light (from support functions), cut into a
  grid of equal cells; photons start before every ellipsoid and carry
  ``A_perp / |d_z|``, as for meshes.

Extended sources
----------------
A directional light with an ``angular_radius`` (radians: `jaxcaustics.SunLight`) is a
disc of directions: `trace_lens`, `trace_mesh` and `trace_mirror` trace
``source_samples`` of them (default `SOURCE_SAMPLES`, spread by `disc_directions`),
each with ``photons_per_axis / sqrt(source_samples)`` photons per axis, and average the
images with the disc's weights (`_sources.py`).
"""

from ._ellipsoid import trace_ellipsoid, trace_ellipsoid_rays
from ._facets import trace_solid_facets
from ._lens import emit_lens_photons, trace_lens, trace_lens_photons
from ._lens_triangles import trace_lens_triangles
from ._mesh import emit_mesh_photons, intersect_mesh, trace_mesh, trace_mesh_photons
from ._mirror import trace_mirror, trace_mirror_photons
from ._optics import PHOTON_BYTES, chunk_photons
from ._sources import SOURCE_SAMPLES, disc_directions, over_source
from ._surface import surface_height
from ._water import area_ratio_water, trace_photons, trace_water

# under a disc source (the Sun) these integrate over it
trace_lens = over_source(trace_lens)
trace_mesh = over_source(trace_mesh)
trace_mirror = over_source(trace_mirror)

__all__ = [
    "PHOTON_BYTES",
    "SOURCE_SAMPLES",
    "disc_directions",
    "area_ratio_water",
    "chunk_photons",
    "emit_lens_photons",
    "emit_mesh_photons",
    "intersect_mesh",
    "surface_height",
    "trace_ellipsoid",
    "trace_ellipsoid_rays",
    "trace_lens",
    "trace_lens_photons",
    "trace_mesh",
    "trace_mesh_photons",
    "trace_mirror",
    "trace_mirror_photons",
    "trace_solid_facets",
    "trace_lens_triangles",
    "trace_photons",
    "trace_water",
]
