"""jaxcaustics: differentiable, jit-compiled caustics in JAX.

Methods: `two_pass` (Yuksel & Keyser, water), `caustic_triangles` (Umenhoffer et al.,
lens and mesh scenes), `caustics_mapping` (Shah et al.'s splatted caustic maps),
`adaptive_caustic_map` (Wyman & Nichols) and `spot_lights` (Liu et al.'s caustic spot
lights: `fit_spot_lights`, `render_spot_lights`, and for a moving light
`precompute_spot_lights` / `interpolate_spot_lights`), all reachable through `render`.

Build a scene (`WaterScene`: a `HeightField` water surface; `LensScene`: a glass slab
with a height-field top; `MeshScene`: a glass or mirror `Mesh` with optional occluders;
`EllipsoidScene`: a glass `Ellipsoid` or sphere; each with a `DirectionalLight` or
`PointLight` and a `PlaneReceiver`), then `render` it.
The NumPy reference lives in `jaxcaustics.reference` and imports no JAX.

Inverse problems: `design_lens` (a caustic lens for a target picture, started from the
optimal transport `transport_map`; `export_lens`
writes it for the workshop, `manufacturability` reports whether it can be milled,
`verify_lens` renders the exported solid with the reference) and `recover_surface` (a
water surface from its caustic).
"""

import importlib.metadata

from ._choose import (
    Choice as Choice,
)
from ._choose import (
    accuracy_table as accuracy_table,
)
from ._choose import (
    choose_method as choose_method,
)
from ._choose import (
    image_error as image_error,
)
from ._choose import (
    method_support as method_support,
)
from ._choose import (
    reference_image as reference_image,
)
from ._ellipsoid import (
    Ellipsoid as Ellipsoid,
)
from ._ellipsoid import (
    EllipsoidScene as EllipsoidScene,
)
from ._ellipsoid import (
    ExitRays as ExitRays,
)
from ._ellipsoid import (
    trace_exit_rays as trace_exit_rays,
)
from ._export import (
    ManufacturabilityReport as ManufacturabilityReport,
)
from ._export import (
    export_lens as export_lens,
)
from ._export import (
    lens_height_map as lens_height_map,
)
from ._export import (
    lens_solid as lens_solid,
)
from ._export import (
    manufacturability as manufacturability,
)
from ._gbuffer import (
    GeometryBuffers as GeometryBuffers,
)
from ._gbuffer import (
    geometry_buffers as geometry_buffers,
)
from ._gbuffer import (
    ray_geo as ray_geo,
)
from ._inverse.design import (
    LensDesign as LensDesign,
)
from ._inverse.design import (
    design_lens as design_lens,
)
from ._inverse.design import (
    design_lens_variants as design_lens_variants,
)
from ._inverse.design import (
    fresnel_zones as fresnel_zones,
)
from ._inverse.recover import (
    RecoveryResult as RecoveryResult,
)
from ._inverse.recover import (
    recover_surface as recover_surface,
)
from ._inverse.sequence import (
    SequenceResult as SequenceResult,
)
from ._inverse.sequence import (
    recover_sequence as recover_sequence,
)
from ._inverse.verify import (
    Verification as Verification,
)
from ._inverse.verify import (
    relative_l2 as relative_l2,
)
from ._inverse.verify import (
    verify_lens as verify_lens,
)
from ._io import (
    read_exr as read_exr,
)
from ._io import (
    read_image as read_image,
)
from ._io import (
    write_exr as write_exr,
)
from ._io import (
    write_png as write_png,
)
from ._io import (
    write_png_linear16 as write_png_linear16,
)
from ._light_view import (
    LightView as LightView,
)
from ._light_view import (
    light_view as light_view,
)
from ._mesh import (
    Mesh as Mesh,
)
from ._mesh import (
    MeshScene as MeshScene,
)
from ._methods.caustic_map import (
    CausticMapResult as CausticMapResult,
)
from ._methods.caustic_map import (
    PinholeCamera as PinholeCamera,
)
from ._methods.caustic_map import (
    adaptive_caustic_map as adaptive_caustic_map,
)
from ._methods.caustic_map import (
    camera_image as camera_image,
)
from ._methods.caustic_map import (
    caustics_mapping as caustics_mapping,
)
from ._methods.caustic_map import (
    photon_bytes as photon_bytes,
)
from ._methods.caustic_map import (
    project_caustic_map as project_caustic_map,
)
from ._methods.spot_lights import (
    SpotLightResult as SpotLightResult,
)
from ._methods.spot_lights import (
    spot_lights as spot_lights,
)
from ._methods.triangles import (
    CubeMapOptions as CubeMapOptions,
)
from ._methods.triangles import (
    TrianglesResult as TrianglesResult,
)
from ._methods.triangles import (
    caustic_triangles as caustic_triangles,
)
from ._methods.triangles import (
    splat_photons as splat_photons,
)
from ._methods.triangles import (
    trace_photons as trace_photons,
)
from ._methods.triangles import (
    triangle_window as triangle_window,
)
from ._methods.triangles import (
    triangles_image as triangles_image,
)
from ._methods.twopass import (
    TwoPassResult as TwoPassResult,
)
from ._methods.twopass import (
    auto_window as auto_window,
)
from ._methods.twopass import (
    two_pass as two_pass,
)
from ._optics import (
    fresnel_transmittance as fresnel_transmittance,
)
from ._optics import (
    reflect as reflect,
)
from ._optics import (
    refract as refract,
)
from ._photons import (
    Photons as Photons,
)
from ._render import render as render
from ._render_batch import (
    render_batch as render_batch,
)
from ._scene import (
    DirectionalLight as DirectionalLight,
)
from ._scene import (
    Effects as Effects,
)
from ._scene import (
    HeightField as HeightField,
)
from ._scene import (
    LensScene as LensScene,
)
from ._scene import (
    PlaneReceiver as PlaneReceiver,
)
from ._scene import (
    PointLight as PointLight,
)
from ._scene import (
    WaterScene as WaterScene,
)
from ._sharding import (
    device_mesh as device_mesh,
)
from ._sharding import (
    gather_to_host as gather_to_host,
)
from ._sharding import (
    map_sharded as map_sharded,
)
from ._sharding import (
    stack_scenes as stack_scenes,
)
from ._sharding import (
    unstack_scenes as unstack_scenes,
)
from ._spot_light_fit import (
    FitInfo as FitInfo,
)
from ._spot_light_fit import (
    fit_spot_lights as fit_spot_lights,
)
from ._spot_light_fit import (
    refine_axis as refine_axis,
)
from ._spot_light_table import (
    SpotLightTable as SpotLightTable,
)
from ._spot_light_table import (
    icosphere_directions as icosphere_directions,
)
from ._spot_light_table import (
    interpolate_spot_lights as interpolate_spot_lights,
)
from ._spot_light_table import (
    precompute_spot_lights as precompute_spot_lights,
)
from ._spot_lights import (
    Glossy as Glossy,
)
from ._spot_lights import (
    Lambertian as Lambertian,
)
from ._spot_lights import (
    SpotLightRays as SpotLightRays,
)
from ._spot_lights import (
    SpotLights as SpotLights,
)
from ._spot_lights import (
    evaluate_spot_lights as evaluate_spot_lights,
)
from ._spot_lights import (
    render_spot_lights as render_spot_lights,
)
from ._spot_lights import (
    shade_points as shade_points,
)
from ._surface import height_and_gradient as height_and_gradient
from ._transport import (
    TransportMap as TransportMap,
)
from ._transport import (
    transport_map as transport_map,
)
from ._waves import (
    gaussian_bump as gaussian_bump,
)
from ._waves import (
    sine_sum as sine_sum,
)
from ._waves import (
    wave_heights as wave_heights,
)

__version__ = importlib.metadata.version("jaxcaustics")
