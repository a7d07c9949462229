"""Verification of a lens design with the independent NumPy reference.

The exported solid (`lens_solid`: the height-field top as the renderer sees it, a flat
bottom, side walls) is placed in a `MeshScene` and traced by
`jaxcaustics.reference.trace_mesh`, which shares no code with the caustic-triangles
forward model the design was optimised with. The same is done with the screen moved
by plus and minus a few percent of the screen_distance, and under the Sun (a disc of 0.53 degrees
instead of a point at infinity), so a user sees how robust the design is.
"""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np

from .. import reference
from .._checks import check_int, check_real_array
from ..scene.mesh import Mesh, MeshScene
from ..scene.mirror import MirrorScene
from ..scene.scene import DirectionalLight, LensScene
from ..scene.sources import AreaLight, SunLight
from .export import lens_solid
from .lens_setup import check_mask

SUN_DIAMETER_DEG = 0.53
# most photons per axis of the reference traces (16384^2: hours through the solid) and
# most directions over the Sun's disc (each one a trace)
MAX_PHOTONS_PER_AXIS = 1 << 14
MAX_SUN_SAMPLES = 256


def default_photons(light, shape) -> int:
    """The reference's photons per axis that a verification takes by default: 8 per
    target pixel side (64 a pixel), or 32 under an extended source, whose samples share
    them out (measured on a 32^2 camera under the Sun, 64 directions: 64 photons a pixel
    judged the design 0.135 off, 1024 a pixel 0.0545, 4096 a pixel 0.053); at most
    `MAX_PHOTONS_PER_AXIS`."""
    per_side = 32 if isinstance(light, (SunLight, AreaLight)) else 8
    return min(per_side * max(shape), MAX_PHOTONS_PER_AXIS)


def _image(value, name: str, shape=None) -> np.ndarray:
    """`value` as a finite, non-negative float image (of `shape`), else a `ValueError`."""
    a = check_real_array(value, name).astype(float)
    if a.ndim == 0 or (shape is not None and a.shape != tuple(shape)):
        want = f"the shape {tuple(shape)}" if shape is not None else "an image's shape"
        raise ValueError(f"`{name}` must have {want}, got {a.shape}")
    if a.size == 0 or not np.all(np.isfinite(a)) or a.min() < 0:
        raise ValueError(f"`{name}` must be finite and non-negative")
    return a


def relative_l2(image, target, mask=None) -> float:
    """The relative L2 error of `image` against `target`,
    ``|a / mean(a) - b / mean(b)|_2 / |b / mean(b)|_2`` over `mask` (both images scaled
    to unit mean: the error does not depend on overall brightness).

    **Arguments:**

    - `image`: the image ``a``, finite and non-negative, of any shape (``(rows, cols)``
      or ``(rows, cols, channels)``); an all-zero image is left unscaled (error 1).
    - `target`: the image ``b``, finite and non-negative, of the shape of `image`; not
      all zero (inside `mask`).
    - `mask`: ``None`` (every pixel, the default) or a boolean (or 0/1) array of that
      shape: the pixels compared.

    **Returns:** the error, a Python float (0 for a perfect match).
    """
    b = _image(target, "target")
    a = _image(image, "image", b.shape)
    if mask is not None:
        m = check_mask(mask, b.shape)
        a, b = a[m], b[m]
    if not b.max() > 0:
        raise ValueError("`target` is zero everywhere (inside `mask`)")
    a = a / a.mean() if a.mean() > 0 else a
    b = b / b.mean()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def solid_scene(scene: LensScene, *, samples=None) -> MeshScene:
    """The exported solid of `scene`'s lens, in metres at its place above the screen, as a
    `MeshScene` with the same light, screen, index and Fresnel setting. The solid is
    exported unrotated (`export_lens`); a field's `rotation` turns it back about the
    centre of its extent, as the lens sits in its holder. A `MeshScene` holds float32
    vertices: at the solid's height their steps tilt fine facets (`verify_lens` traces the
    solid in float64 instead)."""

    vertices, faces = _solid_in_place(scene, samples)
    return MeshScene(
        Mesh(vertices, faces),
        scene.light,
        scene.receiver,
        ior=scene.ior,
        fresnel=scene.fresnel,
        interfaces=2,
        normals="flat",
    )


def _solid_in_place(scene: LensScene, samples=None) -> tuple[np.ndarray, np.ndarray]:
    """The exported solid's vertices ``(V, 3)``, metres, at its place above the screen (a
    field's `rotation` turned back about its extent's centre), and its faces ``(F, 3)``."""
    solid = lens_solid(scene, samples=samples)  # millimetres, origin at the corner
    x0, x1, y0, y1 = (float(v) for v in np.asarray(scene.surface.extent))
    vertices = np.asarray(solid.vertices) / 1000.0 + [x0, y0, float(scene.screen_distance)]
    angle = float(np.asarray(scene.surface.rotation))
    if angle != 0.0:  # (it was traced unrotated: 0.69 off a lens that met its target)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        c, s = math.cos(angle), math.sin(angle)
        dx, dy = vertices[:, 0] - cx, vertices[:, 1] - cy
        vertices = np.c_[cx + c * dx - s * dy, cy + s * dx + c * dy, vertices[:, 2]]
    return vertices, np.asarray(solid.faces)


def _solid_for_reference(vertices, faces, lens: LensScene, light) -> types.SimpleNamespace:
    """The exported solid (`vertices` in place, metres, `faces`) as the reference reads a
    mesh scene (by duck typing), in float64: a `MeshScene` holds float32 vertices, whose
    steps at the solid's height (6e-8 m at 0.5 m) tilt 0.1 mm facets by 6e-4 rad, 0.3 mm
    on a screen 0.5 m away (on the quickstart lens its facets judged 0.034 against 0.020
    in float64). Also no `MeshScene` to build: 25 s for that lens's 2.1M faces."""
    return types.SimpleNamespace(
        generator=types.SimpleNamespace(vertices=vertices, faces=faces),
        light=light,
        receiver=lens.receiver,
        ior=lens.ior,
        fresnel=lens.fresnel,
        material="refractor",
        occluders=(),
        interfaces=2,
        normals="flat",
    )


def _facets_image(vertices, faces, lens: LensScene, direction) -> np.ndarray:
    """The exported solid under parallel light travelling along `direction`, by
    `reference.trace_solid_facets` (exact for its flat facets)."""
    light = types.SimpleNamespace(direction=np.asarray(direction, float))
    return reference.trace_solid_facets(_solid_for_reference(vertices, faces, lens, light))


def _sun_directions(light: DirectionalLight, samples: int) -> list[np.ndarray]:
    """`samples` directions spread evenly (sunflower pattern) over the Sun's disc
    (`reference.disc_directions`, which the reference and `SunLight` sample by)."""
    radius = math.radians(SUN_DIAMETER_DEG / 2)
    return list(reference.disc_directions(np.asarray(light.direction, float), radius, samples)[0])


@dataclasses.dataclass(frozen=True)
class Verification:
    """Relative L2 errors (unit-mean images) of a design rendered by the reference.

    - `nominal`: the exported solid, as specified, under the design's light (a
      `SunLight`'s disc sampled: `jaxcaustics.reference.trace_mesh`).
    - `screen_near`, `screen_far`: the screen moved towards / away from the lens by
      `screen_shift` of the screen distance.
    - `sun`: lit by a disc of the Sun's angular size (0.53 degrees) instead of a point;
      None for a design under a point light (the Sun is not its light); `nominal` for a
      design under a `SunLight`.
    - `image`: the nominal reference image.
    """

    nominal: float
    screen_near: float
    screen_far: float
    sun: float | None
    screen_shift: float
    image: np.ndarray = dataclasses.field(repr=False)

    def __str__(self) -> str:
        pct = f"{100 * self.screen_shift:.0f}%"
        return (
            f"relative L2 error against the target (reference tracer, unit-mean images):\n"
            f"  as designed            {self.nominal:.4f}\n"
            f"  screen {pct} nearer      {self.screen_near:.4f}\n"
            f"  screen {pct} farther     {self.screen_far:.4f}\n"
            + (
                f"  Sun ({SUN_DIAMETER_DEG} deg disc)   {self.sun:.4f}"
                if self.sun is not None
                else "  Sun                    not its light (a point light)"
            )
        )


def verify_heights(scene, target, *, mask=None, photons_per_axis: int = 512) -> tuple:
    """The designed surface of a `MirrorScene`, or of a `LensScene` with a posed screen,
    traced by the NumPy reference (`trace_mirror`, `trace_lens`) and compared with
    `target` ``(rows, cols)`` on its receiver: ``(relative L2 at unit means, image)``.
    The heights are what the workshop mills (the exported solid samples them)."""
    if not isinstance(scene, (LensScene, MirrorScene)):
        raise ValueError(
            f"`scene` must be a LensScene or a MirrorScene, got {type(scene).__name__}"
        )
    target = _image(target, "target", scene.receiver.shape)
    if not target.max() > 0:
        raise ValueError("`target` must be finite, non-negative and not all zero")
    check_int(photons_per_axis, "photons_per_axis", 2, MAX_PHOTONS_PER_AXIS)
    trace = reference.trace_mirror if isinstance(scene, MirrorScene) else reference.trace_lens
    image = trace(scene, photons_per_axis)
    return relative_l2(image, target, mask), image


def verify_lens(
    scene: LensScene,
    target,
    *,
    mask=None,
    photons_per_axis: int = 512,
    screen_shift: float = 0.05,
    sun_samples: int = 7,
    samples=None,
) -> Verification:
    """Render the exported solid of `scene` with the reference and compare with `target`.

    **Arguments:**

    - `scene`: the designed `LensScene` (collimated light for the Sun test).
    - `target`: the target image on `scene.receiver`'s grid, ``(rows, cols)``.
    - `mask`: optional boolean ``(rows, cols)``: pixels the error is measured on.
    - `photons_per_axis`: the reference's photon grid per axis (accuracy knob), at most
      `MAX_PHOTONS_PER_AXIS`, for a design under a point light or with Fresnel. Under
      parallel light (a `DirectionalLight` or `SunLight`) without Fresnel the solid's
      flat facets are followed exactly instead (`reference.trace_solid_facets`: a photon
      grid aliases against facets a tenth of a pixel wide; on the quickstart lens 1024^2
      photons judged 0.060 where the facets give 0.034) and it is unused.
    - `screen_shift`: relative change of the screen distance for the screen tests (0.05: 5%).
    - `sun_samples`: directions over the Sun's disc (by photons, each traced with
      ``photons_per_axis / sqrt(sun_samples)`` photons per axis), at most
      `MAX_SUN_SAMPLES`; under a `SunLight` design followed by facets, every figure
      samples the disc with this many directions.
    - `samples`: the exported solid's top-surface grid (`lens_solid`).

    **Returns:** a `Verification`.
    """

    if not isinstance(scene, LensScene):
        raise ValueError(f"`scene` must be a LensScene, got {type(scene).__name__}")
    if scene.screen_pose is not None:
        raise ValueError(
            "`scene` has a posed screen: the solid is traced onto the ground only; judge "
            "its heights with `verify_heights`"
        )
    # checked before any tracing: a NaN target made every error NaN, sun_samples=0 a
    # ZeroDivisionError after the nominal trace
    target = _image(target, "target", scene.receiver.shape)  # the screen's
    if not target.max() > 0:
        raise ValueError("`target` must be finite, non-negative and not all zero")
    if mask is not None and not np.any(target[check_mask(mask, target.shape)] > 0):
        raise ValueError("`target` is zero everywhere inside `mask`")
    check_int(photons_per_axis, "photons_per_axis", 2, MAX_PHOTONS_PER_AXIS)
    check_int(sun_samples, "sun_samples", 1, MAX_SUN_SAMPLES)
    number = isinstance(screen_shift, (int, float, np.number))
    if isinstance(screen_shift, bool) or not (number and 0.0 < float(screen_shift) < 1.0):
        raise ValueError(f"`screen_shift` must be a number in (0, 1), got {screen_shift!r}")
    if isinstance(scene.light, DirectionalLight) and not scene.fresnel:
        return _verify_by_facets(scene, target, mask, screen_shift, sun_samples, samples)
    # a point light, or Fresnel: photons through the solid (float64, built once)
    vertices, faces = _solid_in_place(scene, samples)
    distance = float(scene.screen_distance)

    def traced(shift: float, light, per_axis: int) -> np.ndarray:
        solid = _solid_for_reference(vertices + [0.0, 0.0, shift], faces, scene, light)
        return reference.trace_mesh(solid, per_axis)

    nominal = traced(0.0, scene.light, photons_per_axis)
    sun_error = None  # a point light's design: no figure (it was NaN)
    if isinstance(scene.light, SunLight):  # the nominal trace was under the Sun
        sun_error = relative_l2(nominal, target, mask)
    elif isinstance(scene.light, DirectionalLight):
        per_axis = max(16, int(photons_per_axis / math.sqrt(sun_samples)))
        images = [
            traced(0.0, types.SimpleNamespace(direction=d), per_axis)
            for d in _sun_directions(scene.light, sun_samples)
        ]
        sun_error = relative_l2(np.mean(images, axis=0), target, mask)
    return Verification(
        nominal=relative_l2(nominal, target, mask),
        screen_near=relative_l2(
            traced(-screen_shift * distance, scene.light, photons_per_axis), target, mask
        ),
        screen_far=relative_l2(
            traced(screen_shift * distance, scene.light, photons_per_axis), target, mask
        ),
        sun=sun_error,
        screen_shift=screen_shift,
        image=nominal,
    )


def _parallel_directions(light: DirectionalLight, sun_samples: int):
    """The directions a parallel light's figure is traced along, and their weights: the
    light's own, or `sun_samples` over a `SunLight`'s disc."""
    if isinstance(light, SunLight):
        return reference.disc_directions(
            np.asarray(light.direction, float),
            light.angular_radius,
            sun_samples,
            light.limb_darkening,
        )
    return np.asarray(light.direction, float)[None], np.ones(1)


def _facets_sum(vertices, faces, scene: LensScene, directions, weights) -> np.ndarray:
    """The solid's caustic by its facets, summed over parallel `directions` with
    `weights`."""
    return sum(
        w * _facets_image(vertices, faces, scene, d)
        for d, w in zip(directions, weights, strict=True)
    )


def exported_image(scene, *, samples=None, sun_samples: int = 7) -> np.ndarray | None:
    """The caustic of the exported solid of `scene`'s lens (its top sampled as
    `export_lens` writes it, or on `samples`) at the nominal screen, its flat facets
    traced exactly (`reference.trace_solid_facets`, float64), ``(rows, cols)``. For a
    `LensScene` over the ground under parallel light (a `DirectionalLight`, or a
    `SunLight`'s disc in `sun_samples` directions) without Fresnel; None for any other
    scene (trace it with `verify_lens`)."""
    parallel = isinstance(scene, LensScene) and isinstance(scene.light, DirectionalLight)
    if not parallel or scene.screen_pose is not None or scene.fresnel:
        return None
    vertices, faces = _solid_in_place(scene, samples)
    directions, weights = _parallel_directions(scene.light, sun_samples)
    return _facets_sum(vertices, faces, scene, directions, weights)


def exported_error(scene, target, *, mask=None, samples=None, sun_samples: int = 7):
    """The relative L2 error against `target` of `exported_image`: the design's error as
    exported, facets included (the nominal figure of `verify_lens`); None where
    `exported_image` does not apply."""
    target = _image(target, "target", scene.receiver.shape)
    image = exported_image(scene, samples=samples, sun_samples=sun_samples)
    return None if image is None else relative_l2(image, target, mask)


def _verify_by_facets(scene, target, mask, screen_shift, sun_samples, samples) -> Verification:
    """`verify_lens` under parallel light (a `DirectionalLight` or `SunLight`, no Fresnel):
    the solid built once, each figure its flat facets followed exactly
    (`reference.trace_solid_facets`: no photon grid to alias against them), the screen
    moved by shifting the solid, a disc source by `sun_samples` of its directions."""
    vertices, faces = _solid_in_place(scene, samples)
    light = scene.light

    def disc(direction, radius, darkening=0.0):
        return reference.disc_directions(
            np.asarray(direction, float), radius, sun_samples, darkening
        )

    directions, weights = _parallel_directions(light, sun_samples)

    def image(shift: float, directions, weights) -> np.ndarray:
        return _facets_sum(vertices + [0.0, 0.0, shift], faces, scene, directions, weights)

    distance = float(scene.screen_distance)
    nominal = image(0.0, directions, weights)
    near = image(-screen_shift * distance, directions, weights)
    far = image(screen_shift * distance, directions, weights)
    if isinstance(light, SunLight):
        sun = relative_l2(nominal, target, mask)
    else:
        sun_directions, sun_weights = disc(light.direction, math.radians(SUN_DIAMETER_DEG / 2))
        sun = relative_l2(image(0.0, sun_directions, sun_weights), target, mask)
    return Verification(
        nominal=relative_l2(nominal, target, mask),
        screen_near=relative_l2(near, target, mask),
        screen_far=relative_l2(far, target, mask),
        sun=sun,
        screen_shift=screen_shift,
        image=nominal,
    )
