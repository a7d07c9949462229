"""Caustic spot lights: a glass ball's caustic from a few fitted spot lights.

Liu et al.'s caustic spot lights (CSLs): rays traced through the ball are grouped into
bundles, each bundle becomes a spot light whose rays cross its axis at
``alpha / (1 + beta r)`` with an intensity image on its light plane, and the floor is
lit by those lights directly: shadows of a sphere are an analytic test per ray, and the
known ray directions allow a glossy floor. Prints the fitted lights, the error against
the NumPy reference and the times, then renders a moving light from a precomputed table.
Writes ``out/spot_lights.png``. Run: ``python examples/spot_lights.py`` (about a minute
and a half on a laptop CPU).
"""

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window; remove this line to use plt.show()
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402

OUTPUT = Path("out")
OUTPUT.mkdir(exist_ok=True)

# A glass ball (radius 0.3 m, index 1.5) 1 m above a 2 x 2 m floor, sun 20 degrees from
# vertical; a small opaque ball hangs in the light below it (the paper's Fig. 10).
ball = jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.3)
blocker = jc.Ellipsoid.sphere([0.3, 0.15, 0.45], 0.05)
receiver = jc.PlaneReceiver((-1.2, 0.8, -1.0, 1.0), (128, 128))
scene = jc.EllipsoidScene(ball, jc.DirectionalLight.from_angles(20.0), receiver, ior=1.5)
shadowed = jc.EllipsoidScene(ball, scene.light, receiver, ior=1.5, occluders=[blocker])

start = time.perf_counter()
result = jc.SpotLightMethod(rays_per_axis=256, fit={"max_lights": 8}).trace(scene)
result.image.block_until_ready()
fit_time = time.perf_counter() - start
lights, info = result.lights[0], result.fit_info[0]
print(f"traced 256^2 rays, fitted and rendered in {fit_time:.1f} s (compilation included)")
print(f"{int(jnp.sum(lights.active))} lights carry {float(info.fraction):.1%} of the light")
for k in np.flatnonzero(np.asarray(lights.active)):
    print(
        f"  light {k}: alpha {float(lights.alpha[k]):.3f} m, beta {float(lights.beta[k]):.3f}"
        f" 1/m, {float(info.energy[k] / info.total_energy):.1%} of the energy,"
        f" Eq. 5 rms {1e3 * float(info.rms[k]):.1f} mm"
    )

start = time.perf_counter()
ref = reference.trace_ellipsoid(scene, 2048)
ref_time = time.perf_counter() - start


print(f"reference (2048^2 photons): {ref_time:.1f} s")
print(f"error against the reference (1-px blur): {jc.image_error(result.image, ref):.3f}")

# the same lights with the occluder (an analytic shadow test per ray) and a glossy floor
with_shadow = jc.render(shadowed, jc.SpotLightMethod(lights=lights))
eye = jnp.array([0.0, -2.5, 2.0])
glossy = jc.render(scene, jc.SpotLightMethod(lights=lights, shading=jc.Glossy(eye, 0.3, 0.7, 60.0)))

# a moving light: lights for the vertices of an icosahedron, interpolated in between
start = time.perf_counter()
table = jc.precompute_spot_lights(
    scene, subdivisions=1, rays_per_axis=64, tracking_steps=5, max_lights=4, progress=False
)
print(f"table over {len(table.directions)} light directions: {time.perf_counter() - start:.0f} s")
moving = jc.DirectionalLight.from_angles(27.0, 40.0)
frame_lights = table.interpolate(moving.unit_direction)
frame_scene = jc.EllipsoidScene(ball, moving, receiver, ior=1.5)
frame = jc.render(frame_scene, jc.SpotLightMethod(lights=frame_lights))
frame_ref = reference.trace_ellipsoid(frame_scene, 1024)
print(f"interpolated frame, error against the reference: {jc.image_error(frame, frame_ref):.3f}")

panels = [
    ("reference", ref),
    ("spot lights", result.image),
    ("occluder shadow", with_shadow),
    ("glossy floor", glossy),
    ("moving light (interpolated)", frame),
]
fig, axes = plt.subplots(1, len(panels), figsize=(3 * len(panels), 3.2))
top = float(np.percentile(ref, 99.5))
for ax, (title, image) in zip(axes, panels, strict=True):
    image = np.asarray(image)
    scale = top if title != "glossy floor" else float(np.percentile(image, 99.5))
    ax.imshow(np.sqrt(np.clip(image / scale, 0, 1)), cmap="gray", origin="lower")
    ax.set_title(title, fontsize=9)
    ax.axis("off")
fig.tight_layout()
fig.savefig(OUTPUT / "spot_lights.png", dpi=80)
print(f"wrote {OUTPUT / 'spot_lights.png'}")
jax.clear_caches()
