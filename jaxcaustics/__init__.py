"""jaxcaustics: differentiable, jit-compiled caustics in JAX.

The package is laid out by stage: `scene` (what is lit), `trace` (rays through it),
`reconstruct` (photons to pixels), `methods` (the five methods, `render`), `inverse`
(lens design, water recovery), `io` and `cli`; `reference` is the NumPy tracer (no JAX).

Methods, each an Equinox module of its knobs (and a function of the same knobs):
`TwoPass` / `two_pass` (Yuksel & Keyser, water), `CausticTriangles` / `caustic_triangles`
(Umenhoffer et al., lens and mesh scenes), `CausticsMapping` / `caustics_mapping` (Shah
et al.'s splatted caustic maps), `AdaptiveCausticMap` / `adaptive_caustic_map` (Wyman &
Nichols) and `SpotLightMethod` / `spot_lights` (Liu et al.'s caustic spot lights:
`fit_spot_lights`, `render_spot_lights`, and for a moving light `precompute_spot_lights`
/ `interpolate_spot_lights`), all reachable through `render(scene, method)` with an
instance or a name.

Build a scene (`WaterScene`: a `HeightField` water surface; `LensScene`: a glass slab
with a height-field top; `MeshScene`: a glass or mirror `Mesh` with optional occluders;
`EllipsoidScene`: a glass `Ellipsoid` or sphere; each with a `DirectionalLight` or
`PointLight` and a `PlaneReceiver`; `MirrorScene`: a height-field mirror with a screen
placed by a `ScreenPose`), then `render` it.

Inverse problems: `design` (a caustic lens or mirror for a target picture: a
`DesignProblem` of a `Lens` or a `Mirror`, an outline (`Rectangle`, `Ellipse`,
`Circle`, `Polygon`), a `Screen` (anywhere: `ScreenPose`) and a light, solved
by a `TransportStart` from the optimal transport `transport_map`, or `PoissonLevels`,
finished by an `ImageRefinement`; `design_lens` is its keyword form; `export_lens`
writes it for the workshop, `manufacturability` reports whether it can be milled,
`verify_lens` renders the exported solid with the reference) and `recover_surface` (a
water surface from its caustic).
"""

import importlib.metadata

from .devices import device_mesh, gather_to_host, map_sharded, stack_scenes, unstack_scenes
from .inverse.design import LensDesign, design, design_lens, fresnel_zones
from .inverse.export import (
    ManufacturabilityReport,
    export_lens,
    lens_height_map,
    lens_solid,
    manufacturability,
)
from .inverse.image_refine import ImageRefinement
from .inverse.poisson_levels import PoissonLevels
from .inverse.problem import (
    Circle,
    DesignProblem,
    Ellipse,
    Lens,
    Mirror,
    Polygon,
    Rectangle,
    Screen,
)
from .inverse.recover import RecoveryResult, recover_surface
from .inverse.sequence import SequenceResult, recover_sequence
from .inverse.transport import TransportMap, transport_map
from .inverse.transport_start import TransportStart
from .inverse.variants import design_lens_variants
from .inverse.verify import Verification, relative_l2, verify_lens
from .io.images import read_exr, read_image, write_exr, write_png, write_png_linear16
from .methods.base import Method, RenderResult
from .methods.batch import render_batch
from .methods.caustic_map.gbuffer import GeometryBuffers, geometry_buffers, ray_geo
from .methods.caustic_map.light_view import LightView, light_view
from .methods.caustic_map.method import (
    AdaptiveCausticMap,
    CausticMapResult,
    CausticsMapping,
    PinholeCamera,
    adaptive_caustic_map,
    camera_image,
    caustics_mapping,
    photon_bytes,
    project_caustic_map,
)
from .methods.choose import (
    Choice,
    accuracy_table,
    choose_method,
    image_error,
    method_support,
    reference_image,
)
from .methods.refine import ErrorEstimate, estimate_error, refine_to_tolerance
from .methods.render import render
from .methods.spot_lights.exit_rays import ExitRays, trace_exit_rays
from .methods.spot_lights.fit import FitInfo, fit_spot_lights, refine_axis
from .methods.spot_lights.lights import (
    Glossy,
    Lambertian,
    SpotLightRays,
    SpotLights,
    evaluate_spot_lights,
    render_spot_lights,
    shade_points,
)
from .methods.spot_lights.method import SpotLightMethod, SpotLightResult, spot_lights
from .methods.spot_lights.table import (
    SpotLightTable,
    icosphere_directions,
    interpolate_spot_lights,
    precompute_spot_lights,
)
from .methods.triangles.method import (
    CausticTriangles,
    CubeMapOptions,
    TrianglesResult,
    caustic_triangles,
    splat_photons,
    trace_photons,
    triangle_window,
    triangles_image,
)
from .methods.twopass import TwoPass, TwoPassResult, auto_window, two_pass
from .scene.ellipsoid import Ellipsoid, EllipsoidScene
from .scene.mesh import Mesh, MeshScene
from .scene.mirror import MirrorScene
from .scene.scene import (
    DirectionalLight,
    Effects,
    HeightField,
    LensScene,
    PlaneReceiver,
    PointLight,
    WaterScene,
)
from .scene.screen_pose import ScreenPose
from .scene.sources import AreaLight, SunLight
from .scene.surface import height_and_gradient
from .scene.waves import gaussian_bump, sine_sum, wave_heights
from .trace.optics import fresnel_transmittance, reflect, refract
from .trace.photons import Photons

__version__ = importlib.metadata.version("jaxcaustics")

# the public surface: everything above (`from jaxcaustics import *` takes these)
__all__ = [
    "accuracy_table",
    "AreaLight",
    "adaptive_caustic_map",
    "AdaptiveCausticMap",
    "auto_window",
    "camera_image",
    "caustic_triangles",
    "CausticMapResult",
    "caustics_mapping",
    "CausticsMapping",
    "CausticTriangles",
    "Choice",
    "choose_method",
    "Circle",
    "CubeMapOptions",
    "design",
    "design_lens",
    "design_lens_variants",
    "DesignProblem",
    "device_mesh",
    "DirectionalLight",
    "Effects",
    "Ellipse",
    "Ellipsoid",
    "EllipsoidScene",
    "ErrorEstimate",
    "estimate_error",
    "evaluate_spot_lights",
    "ExitRays",
    "export_lens",
    "fit_spot_lights",
    "FitInfo",
    "fresnel_transmittance",
    "fresnel_zones",
    "gather_to_host",
    "gaussian_bump",
    "geometry_buffers",
    "GeometryBuffers",
    "Glossy",
    "height_and_gradient",
    "HeightField",
    "icosphere_directions",
    "image_error",
    "ImageRefinement",
    "interpolate_spot_lights",
    "Lambertian",
    "Lens",
    "lens_height_map",
    "lens_solid",
    "LensDesign",
    "LensScene",
    "light_view",
    "LightView",
    "manufacturability",
    "ManufacturabilityReport",
    "map_sharded",
    "Mesh",
    "MeshScene",
    "Mirror",
    "MirrorScene",
    "Method",
    "method_support",
    "photon_bytes",
    "Photons",
    "PinholeCamera",
    "PlaneReceiver",
    "PointLight",
    "SunLight",
    "PoissonLevels",
    "Polygon",
    "precompute_spot_lights",
    "project_caustic_map",
    "ray_geo",
    "read_exr",
    "read_image",
    "recover_sequence",
    "recover_surface",
    "RecoveryResult",
    "Rectangle",
    "reference_image",
    "refine_axis",
    "refine_to_tolerance",
    "reflect",
    "refract",
    "relative_l2",
    "render",
    "render_batch",
    "render_spot_lights",
    "RenderResult",
    "Screen",
    "ScreenPose",
    "SequenceResult",
    "shade_points",
    "sine_sum",
    "splat_photons",
    "spot_lights",
    "SpotLightMethod",
    "SpotLightRays",
    "SpotLightResult",
    "SpotLights",
    "SpotLightTable",
    "stack_scenes",
    "trace_exit_rays",
    "trace_photons",
    "transport_map",
    "TransportMap",
    "TransportStart",
    "triangle_window",
    "triangles_image",
    "TrianglesResult",
    "two_pass",
    "TwoPass",
    "TwoPassResult",
    "unstack_scenes",
    "Verification",
    "verify_lens",
    "WaterScene",
    "wave_heights",
    "write_exr",
    "write_png",
    "write_png_linear16",
]
