"""Reference photon tracer for the water scene: plain NumPy, the ground truth for tests.

This package imports no JAX (nor anything from the library's private ``jaxcaustics._*``
modules), only NumPy and the standard library, so it shares no code with the methods it
checks. It reads a `jaxcaustics.WaterScene` by duck typing (``np.asarray`` on its fields)
and computes everything in float64. It favours exactness over speed, but is vectorised:
a few million photons take seconds.

Public functions
----------------
- `trace_water`: irradiance on the ground by forward photon tracing.
- `area_ratio_water`: a second, independent estimator mapping triangles of a rest-plane
  grid to the ground and spreading their flux over their images.
- `trace_photons`: trace given rest-plane start points to the ground (both estimators use
  it).
- `surface_height`: the bicubic height field and its analytic gradient.

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
  (``"periodic"``) or are clipped to ``[0, n - 1]`` (``"clamp"``). The gradient is the
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
"""

from ._surface import surface_height
from ._water import area_ratio_water, trace_photons, trace_water

__all__ = ["area_ratio_water", "surface_height", "trace_photons", "trace_water"]
