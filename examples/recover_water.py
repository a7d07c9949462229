"""Recover a water surface from the caustic it casts on the pool floor.

Render the caustic of a known 128 x 128 sea with the NumPy photon tracer
(`jaxcaustics.reference`, not the model being inverted), forget the surface, and
recover it from the caustic alone with `recover_surface` (float32, its defaults: the
transport start and Gauss-Newton fits of the exact rays), then compare the recovered
heights with the truth (the mean height cannot be seen in a caustic, so it is removed
from both). Run: ``python examples/recover_water.py`` (about a minute on 2 CPU cores).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402

OUTPUT = Path("out")
OUTPUT.mkdir(exist_ok=True)

# 1. The truth: a 1 m x 1 m periodic patch of three swells, 0.5 m deep, lit 30 degrees
#    off vertical; its caustic (128 x 128 pixels) has no folds.
extent = (0.0, 1.0, 0.0, 1.0)
terms = [(3, 1, 0.004, 0.3), (-2, 3, 0.0035, 1.1), (1, -4, 0.003, 2.0)]
truth = np.asarray(jc.sine_sum((128, 128), extent, terms=terms), float)
light = jc.DirectionalLight.from_angles(30.0)
scene = jc.WaterScene(
    jc.HeightField(truth, extent), light, jc.PlaneReceiver(extent, (128, 128)), 0.5
)
caustic = reference.trace_water(scene, photons_per_axis=16)

# 2. Recover the heights from the caustic.
result = jc.recover_surface(caustic, extent=extent, rest_depth=0.5, light=light)
t = truth - truth.mean()
error = np.linalg.norm(result.heights - t) / np.linalg.norm(t)
found = jc.WaterScene(
    jc.HeightField(result.heights, extent), light, jc.PlaneReceiver(extent, (128, 128)), 0.5
)
again = reference.trace_water(found, photons_per_axis=16)
for stage in result.stages:
    print(f"{stage['stage']}: {stage['steps']} steps, {stage['seconds']:.1f} s")
print(f"relative height error {error:.2e}; the reference's caustic of the result is off by")
print(f"{jc.image_error(again, caustic):.2e} (relative L1, 1-pixel blur); {result.time_s:.1f} s")

fig, axes = plt.subplots(1, 3, figsize=(10, 3.4))
for ax, image, title in zip(
    axes,
    (t, result.heights, caustic),
    ("true heights (mean removed)", "recovered heights", "caustic used"),
    strict=True,
):
    shown = ax.imshow(image, origin="lower", extent=extent)
    ax.set_title(title)
    fig.colorbar(shown, ax=ax, shrink=0.8)
fig.tight_layout()
fig.savefig(OUTPUT / "recover_water.png", dpi=80)
print(f"wrote {OUTPUT / 'recover_water.png'}")
