"""Caustics of glass: a lens slab and a glass ball, by caustic triangles.

Two scenes rendered with Umenhoffer et al.'s caustic triangles: a 10 cm acrylic-like
slab whose top surface carries two smooth bumps (the scene of caustic lens design), and
a glass ball (a trimesh icosphere) over the floor with an opaque slab hiding part of its
caustic. Each is checked against the NumPy reference photon tracer, and the lens image's
gradient with respect to the surface heights is taken. Run:
``python examples/glass_caustics.py`` (about a minute on a laptop CPU).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window; remove this line to use plt.show()
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402

OUTPUT = Path("out")
OUTPUT.mkdir(exist_ok=True)

# 1. A lens slab: 10 cm square, 1 cm thick, index 1.5, 30 cm above the screen. Its top
#    surface has a bump (a converging lenslet) and a dimple (a diverging one), 1.5 mm and
#    1 mm deep, sampled on a 32 x 32 grid ("clamp": flat-ish beyond the edge samples).
aperture = (0.0, 0.1, 0.0, 0.1)  # metres: x_min, x_max, y_min, y_max
x = (np.arange(32) + 0.5) / 32 * 2 - 1
xx, yy = np.meshgrid(x, x)
heights = 1.5e-3 * np.exp(-((xx - 0.2) ** 2 + (yy + 0.1) ** 2) / 0.15) - 1e-3 * np.exp(
    -((xx + 0.3) ** 2 + (yy - 0.3) ** 2) / 0.1
)
lens = jc.LensScene(
    jc.HeightField(heights, aperture, boundary="clamp"),
    jc.DirectionalLight.from_angles(zenith_deg=0.0),
    jc.PlaneReceiver((-0.02, 0.12, -0.02, 0.12), (128, 128)),  # the screen's pixels
    thickness=0.01,
    screen_distance=0.3,
    ior=1.5,
)
# 129 x 129 photons make 2 x 128 x 128 caustic triangles, each spreading the light of its
# half cell exactly over the pixels it covers ("exact" reconstruction).
result = jc.CausticTriangles(photons=129)(lens)
truth = reference.trace_lens(lens, 1024)  # 1024^2 photons binned into the pixels
error = float(np.abs(np.asarray(result.image) - truth).sum() / truth.sum())
print(f"lens: relative L1 error against the reference {error:.4f}")
print(f"      missed flux fraction {float(result.missed_flux_fraction[0]):.2e}")

# 2. The gradient of a loss on the image with respect to the lens heights: how to push
#    the surface to brighten the centre of the screen.
#    `method_for` fixes the splat window from the scene's photons, so that the method
#    runs under `jax.grad` (and `jax.jit`).
method = jc.method_for(lens, jc.CausticTriangles(photons=65))


def brightness_at_centre(h):
    scene = eqx.tree_at(lambda s: s.surface.heights, lens, h)
    image = jc.render(scene, method)
    return jnp.sum(image[56:72, 56:72])


grad = jax.grad(brightness_at_centre)(jnp.asarray(heights))
print(f"lens: gradient of the centre brightness, max |d/dh| = {float(jnp.abs(grad).max()):.3g}")

# 3. A glass ball (radius 0.5 m, centre 1 m up) lit 10 degrees off vertical, with a thin
#    opaque slab below it that catches part of the light.
ball = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
ball.apply_translation([0.0, 0.0, 1.0])
slab = trimesh.creation.box((0.8, 2.0, 0.05))
slab.apply_translation([0.55, 0.0, 0.12])
sphere = jc.MeshScene(
    jc.Mesh.from_trimesh(ball),
    jc.DirectionalLight.from_angles(10.0),
    jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (96, 96)),
    ior=1.5,
    occluders=[jc.Mesh.from_trimesh(slab)],
)
ball_image = jc.render(sphere, jc.CausticTriangles(photons=65))
ball_truth = reference.trace_mesh(sphere, 512)

fig, axes = plt.subplots(2, 2, figsize=(8, 8))
panels = [
    (result.image, "lens: caustic triangles"),
    (truth, "lens: reference"),
    (ball_image, "ball + occluder: caustic triangles"),
    (ball_truth, "ball + occluder: reference"),
]
for ax, (image, title) in zip(axes.ravel(), panels, strict=True):
    ax.imshow(np.sqrt(np.asarray(image)), cmap="gray", origin="lower")  # gamma 2
    ax.set_title(title)
    ax.axis("off")
fig.tight_layout()
fig.savefig(OUTPUT / "glass_caustics.png", dpi=80)
jc.write_png(OUTPUT / "lens.png", result.image)
print(f"wrote {OUTPUT / 'glass_caustics.png'} and {OUTPUT / 'lens.png'}")
