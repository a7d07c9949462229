"""Caustic maps: a glass ball's caustic by splatting, dense and adaptive.

Shah et al.'s caustics mapping (every photon of a dense grid over the light's view
splatted into a caustic map) and Wyman & Nichols' adaptive caustic maps (photons refined
only where the ball is, optionally merged where they converge), next to caustic
triangles and the NumPy reference. Prints each method's error against the reference,
time and photon counts, then renders the scene from a camera (the paper's final pass:
Lambertian floor, shadow map, caustic map projected). Writes ``out/caustic_maps.png``
and ``out/caustic_map_camera.png``. Run: ``python examples/caustic_maps.py`` (about a
minute on a laptop CPU).
"""

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # write files, no window; remove this line to use plt.show()
import jax  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402

OUTPUT = Path("out")
OUTPUT.mkdir(exist_ok=True)

# A glass ball (radius 0.5 m, index 1.5) 1 m above a 4 x 4 m floor, sun 20 degrees
# from vertical. The caustic maps work in the light's view, which covers the floor: the
# ball fills about 5% of it, as an object does in a game's light frustum.
ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
ball.apply_translation([0.0, 0.0, 1.0])
scene = jc.MeshScene(
    jc.Mesh.from_trimesh(ball),
    jc.DirectionalLight.from_angles(20.0),
    jc.PlaneReceiver((-2.0, 2.0, -2.0, 2.0), (128, 128)),
    ior=1.5,
    interfaces=4,
)

start = time.perf_counter()
truth = reference.trace_mesh(scene, 1024)  # exact photon tracing, ~1M photons
print(f"reference: {time.perf_counter() - start:.1f} s")


def error(image):
    """Relative L1 error against the reference (no blur)."""
    return float(np.abs(np.asarray(image) - truth).sum() / truth.sum())


def timed(label, render):
    render()  # compile
    start = time.perf_counter()
    result = render()
    jax.block_until_ready(result.image)
    seconds = time.perf_counter() - start
    line = f"{label:34s} error {error(result.image):.3f}  {seconds * 1000:7.0f} ms"
    if "generated" in getattr(result, "stats", {}):  # the caustic maps count their photons
        line += f", photons generated {result.stats['generated']}"
        line += f", splatted {result.stats['splatted']}"
    print(line)
    return result


knobs = dict(photons=1024, map_resolution=512)
dense = timed("caustics mapping, 1024^2 photons", lambda: jc.CausticsMapping(**knobs).trace(scene))
traversal = timed(
    "adaptive, maximal traversal", lambda: jc.AdaptiveCausticMap(**knobs).trace(scene)
)
merged = timed(
    "adaptive, maximal map error",
    lambda: jc.AdaptiveCausticMap(metric="error", **knobs).trace(scene),
)
triangles = timed(
    "caustic triangles, 129^2 photons", lambda: jc.CausticTriangles(photons=129).trace(scene)
)
print("adaptive photons per level (traversal):", traversal.stats["generated_per_level"])
print("adaptive photons per level (map error):", merged.stats["generated_per_level"])

# The camera's view of the floor: the ball itself is not drawn, its shadow and caustic
# are (radiance of a white floor, albedo 0.8).
camera = jc.PinholeCamera([0.0, -4.5, 3.0], [0.0, 0.3, 0.0], fov=50.0, up=(0, 0, 1))
view = np.asarray(jc.camera_image(scene, dense, camera))
jc.write_png(OUTPUT / "caustic_map_camera.png", view / np.percentile(view, 99.5))

fig, axes = plt.subplots(1, 5, figsize=(16, 3.4))
panels = [
    ("reference", truth),
    ("caustics mapping", dense.image),
    ("adaptive (map error)", merged.image),
    ("caustic triangles", triangles.image),
    ("camera view", view),
]
for ax, (title, image) in zip(axes, panels, strict=True):
    image = np.sqrt(np.asarray(image))  # square root: the faint halo shows
    ax.imshow(
        image,
        origin="upper" if title == "camera view" else "lower",
        cmap="gray",
        vmax=np.percentile(image, 99.8),
    )
    ax.set_title(title)
    ax.axis("off")
fig.tight_layout()
fig.savefig(OUTPUT / "caustic_maps.png", dpi=80)
print(f"wrote {OUTPUT / 'caustic_maps.png'} and {OUTPUT / 'caustic_map_camera.png'}")
