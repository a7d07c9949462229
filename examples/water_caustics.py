"""Caustics of a water surface on the pool floor: the basic workflow.

Build a scene, render its caustic map with the two-pass method, check how much light
the method's window missed, save the image (PNG for viewing, EXR with the linear
values) and plot it. Run: ``python examples/water_caustics.py`` (a few seconds).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window; remove this line to use plt.show()
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402

OUTPUT = Path("out")

# 1. The scene. Lengths are in metres, arrays are indexed [row, col] = [y, x], and an
#    extent (x_min, x_max, y_min, y_max) covers the outer edges of the pixels.
extent = (0.0, 2.0, 0.0, 1.5)  # a 2 m x 1.5 m patch of the pool
# Ripples of 2 mm RMS with wavelengths of 10-50 cm, sampled every centimetre (the
# surface is interpolated bicubically, so it need not match the caustic map's grid).
heights = jc.wave_heights(
    (150, 200), extent, time=0.0, amplitude=0.002, depth=0.5, wavelength_range=(0.1, 0.5), seed=1
)
surface = jc.HeightField(heights, extent, boundary="periodic")  # the sea tiles the plane
light = jc.DirectionalLight.from_angles(zenith_deg=25.0, azimuth_deg=45.0)  # the Sun
floor = jc.PlaneReceiver(extent, (300, 400))  # caustic map: 300 rows x 400 columns
scene = jc.WaterScene(surface, light, floor, rest_depth=0.5, ior=1.333)
print("simulated effects:", scene.effects)

# 2. Render. The image is irradiance relative to a horizontal plane in the light: flat
#    water gives exactly 1.0. `method_for` sizes the two-pass gather window (N, M) from
#    the scene (what samples_x="auto" does) so that no light is lost, and fixes it, so the
#    method can also be used under `jax.jit`; the paper's fixed N=7, M=6 is faster but
#    misses light when the waves move it more than 3 pixels.
method = jc.method_for(scene)
N, M = method.samples_x, method.channels_y
image, stats = jc.render(scene, method, return_stats=True)
image = np.asarray(image)
missed = float(stats["missed_flux_fraction"][0])
print(f"N = {N}, M = {M}: missed flux {100 * missed:.3g}%, mean irradiance {image.mean():.4f}")
if missed > 0.01:
    print("warning: over 1% of the light fell outside the window; use a larger N, M")

# 3. Save: a tone-mapped PNG to look at, a linear EXR to compute with.
jc.write_png(OUTPUT / "water_caustics.png", image)
jc.io.write_exr(OUTPUT / "water_caustics.exr", image)
assert np.allclose(jc.io.read_exr(OUTPUT / "water_caustics.exr"), image)

# 4. Plot in metres (origin="lower": y points up, as in the scene).
fig, ax = plt.subplots(figsize=(6, 4.2), constrained_layout=True)
shown = ax.imshow(image, origin="lower", extent=extent, cmap="gray", vmin=0.0)
fig.colorbar(shown, ax=ax, label="relative irradiance (flat water = 1)")
ax.set(xlabel="x (m)", ylabel="y (m)", title="caustics on the pool floor")
fig.savefig(OUTPUT / "water_caustics_plot.png", dpi=100)
print(
    "wrote",
    *(OUTPUT / n for n in ("water_caustics.png", "water_caustics.exr", "water_caustics_plot.png")),
)
