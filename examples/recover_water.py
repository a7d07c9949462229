"""Recover a water surface from the caustic it casts on the pool floor.

Render the caustic of a known surface with the two-pass method, forget the surface,
and recover it from the caustic alone with `recover_surface` (Optimistix
Levenberg-Marquardt, matrix-free), then compare the recovered heights with the truth
(the mean height cannot be seen in a caustic, so it is removed from both). Run:
``python examples/recover_water.py`` (under a minute on a laptop CPU).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window
import jax  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics._inverse.recover import recover_surface  # noqa: E402

# Levenberg-Marquardt's inner conjugate-gradient solves need float64 for now (in float32
# they can return NaN on this problem; a known limitation).
jax.config.update("jax_enable_x64", True)

OUTPUT = Path("out")
OUTPUT.mkdir(exist_ok=True)

# 1. The truth: a 1 m x 1 m patch of gentle swell, 0.5 m deep, lit 20 degrees off vertical.
extent = (0.0, 1.0, 0.0, 1.0)
x = (np.arange(16) + 0.5) / 16
xx, yy = np.meshgrid(x, x)
truth = (
    0.004 * np.sin(2 * np.pi * xx)
    + 0.003 * np.cos(2 * np.pi * (xx + yy))
    + 0.002 * np.sin(2 * np.pi * 2 * yy)
)
light = jc.DirectionalLight.from_angles(20.0)
scene = jc.WaterScene(jc.HeightField(truth, extent), light, jc.PlaneReceiver(extent, (32, 32)), 0.5)
caustic = np.asarray(jc.two_pass(scene, samples_x="auto", channels_y="auto").image)

# 2. Recover the heights from the caustic (32 x 32 pixels) on a 16 x 16 grid.
result = recover_surface(
    caustic, extent=extent, rest_depth=0.5, light=light, heights_shape=(16, 16), max_steps=100
)
t = truth - truth.mean()
error = np.linalg.norm(result.heights - t) / np.linalg.norm(t)
print(f"solver steps {result.steps}, loss {result.loss:.3g}, success {result.success}")
print(f"relative height error {error:.2e}; caustic error {result.image_error:.2e}")

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
