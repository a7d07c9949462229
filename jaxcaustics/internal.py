"""The stages' building blocks, with no promise that they stay.

The public API is `jaxcaustics.__all__`. These are the pieces the methods and the inverse
problems are built from, for those who build their own (a graphics engineer who wants Shah
et al.'s light view, Liu et al.'s spot-light fit, or the photon grid of caustic triangles)
and for the tests: the methods' functions with their fuller results, ray tracing and
splatting, the design's transport map and solid, the accuracy tables. A name here may be
renamed, moved or removed in any release.
"""

from .inverse.design import fresnel_zones
from .inverse.export import ManufacturabilityReport, lens_height_map, lens_solid
from .inverse.numerics import area_average
from .inverse.transport import TransportMap, transport_map
from .inverse.variants import design_lens_variants
from .inverse.verify import exported_error, exported_image
from .methods.caustic_map.adaptive import adaptive_caustic_map
from .methods.caustic_map.gbuffer import (
    GeometryBuffers,
    geometry_buffers,
    intersection_errors,
    raster_window,
    ray_geo,
)
from .methods.caustic_map.light_view import LightView, light_view
from .methods.caustic_map.method import (
    CausticMapResult,
    caustics_mapping,
    photon_bytes,
    project_caustic_map,
)
from .methods.choose import (
    DEFAULT_MARGIN,
    Choice,
    accuracy_table,
    allowed_rows,
    as_mesh_scene,
    choose_method,
    method_support,
    resolve_knobs,
)
from .methods.refine import ErrorEstimate, estimate_error, refine_to_tolerance
from .methods.registry import METHODS, method_class
from .methods.spot_lights.bundles import refine_axis
from .methods.spot_lights.exit_rays import ExitRays, trace_exit_rays
from .methods.spot_lights.fit import FitInfo, fit_spot_lights
from .methods.spot_lights.lights import (
    SpotLightRays,
    SpotLights,
    evaluate_spot_lights,
    render_spot_lights,
    shade_points,
)
from .methods.spot_lights.method import SpotLightResult, spot_lights
from .methods.spot_lights.table import (
    direction_edges,
    fit_direction,
    icosphere_directions,
    interpolate_spot_lights,
)
from .methods.triangles.method import (
    CubeMapOptions,
    TrianglesResult,
    caustic_triangles,
    splat_photons,
    trace_photons,
    triangle_window,
    triangles_image,
)
from .methods.twopass import TwoPassResult, auto_window, two_pass
from .scene.surface import height_and_gradient
from .scene.waves import gaussian_bump
from .trace.intersect import brute_force_limit
from .trace.optics import fresnel_transmittance, orthonormal_basis, reflect, refract
from .trace.photons import Photons

__all__ = [
    # the methods' functions and their results
    "two_pass",
    "TwoPassResult",
    "auto_window",
    "caustic_triangles",
    "TrianglesResult",
    "CubeMapOptions",
    "trace_photons",
    "splat_photons",
    "triangle_window",
    "triangles_image",
    "caustics_mapping",
    "adaptive_caustic_map",
    "CausticMapResult",
    "project_caustic_map",
    "photon_bytes",
    "light_view",
    "LightView",
    "geometry_buffers",
    "GeometryBuffers",
    "ray_geo",
    "raster_window",  # the light view's raster window, and rayGeo's error per iteration
    "intersection_errors",
    "spot_lights",
    "SpotLightResult",
    "SpotLights",
    "SpotLightRays",
    "trace_exit_rays",
    "ExitRays",
    "fit_spot_lights",
    "FitInfo",
    "refine_axis",
    "evaluate_spot_lights",
    "render_spot_lights",
    "shade_points",
    "icosphere_directions",
    "direction_edges",
    "interpolate_spot_lights",
    "fit_direction",  # one direction's fit of a spot-light table
    # accuracy
    "accuracy_table",
    "method_support",
    "choose_method",
    "Choice",
    "estimate_error",
    "ErrorEstimate",
    "refine_to_tolerance",
    # the methods by name, and the accuracy table's rows as the chooser reads them
    "METHODS",
    "method_class",
    "resolve_knobs",
    "allowed_rows",
    "as_mesh_scene",
    "DEFAULT_MARGIN",
    # optics and surfaces
    "Photons",
    "reflect",
    "refract",
    "fresnel_transmittance",
    "orthonormal_basis",
    "height_and_gradient",
    "gaussian_bump",
    "brute_force_limit",  # mesh search by brute force, for timing it against the tree
    # design
    "transport_map",
    "TransportMap",
    "lens_height_map",
    "lens_solid",
    "ManufacturabilityReport",
    "design_lens_variants",
    "fresnel_zones",
    "area_average",  # a picture averaged down to a target's pixels
    "exported_image",  # the exported solid's caustic by its facets, exactly
    "exported_error",
]
