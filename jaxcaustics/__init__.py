"""jaxcaustics: differentiable, jit-compiled caustics in JAX, and caustic lenses, mirrors
and water surfaces found with Optimistix.

The public names are those of `__all__`, grouped as the documentation's API pages are:
rendering (`render` and the five methods), scenes and lights, design (a lens or mirror
for a picture), water recovery, and pictures in and out. Public submodules:
`jaxcaustics.io` (pictures and height maps), `jaxcaustics.devices` (several devices),
`jaxcaustics.reference` (the NumPy photon tracer, no JAX). The stages' building blocks
(ray tracing, splatting, spot-light fits, ...) are in `jaxcaustics.internal`, without a
promise that they stay.
"""

import importlib.metadata

from . import devices as devices
from . import internal as internal
from . import io as io
from . import reference as reference
from .inverse.design import LensDesign, design, design_lens
from .inverse.export import export_lens, manufacturability
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
from .inverse.transport_start import TransportStart
from .inverse.verify import Verification, relative_l2, verify_lens
from .io.images import read_image, write_png
from .methods.base import Method, RenderResult
from .methods.batch import render_batch
from .methods.caustic_map.adaptive import AdaptiveCausticMap
from .methods.caustic_map.camera import PinholeCamera, camera_image
from .methods.caustic_map.method import CausticsMapping
from .methods.choose import image_error, reference_image
from .methods.registry import method_for
from .methods.render import render
from .methods.spot_lights.lights import Glossy, Lambertian
from .methods.spot_lights.method import SpotLightMethod
from .methods.spot_lights.table import SpotLightTable, precompute_spot_lights
from .methods.triangles.method import CausticTriangles
from .methods.twopass import TwoPass
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
from .scene.waves import sine_sum, wave_heights

__version__ = importlib.metadata.version("jaxcaustics")

# the public names, grouped as the API pages are (`from jaxcaustics import *` takes these)
__all__ = [
    # rendering
    "render",
    "render_batch",
    "method_for",
    "Method",
    "RenderResult",
    "TwoPass",
    "CausticTriangles",
    "CausticsMapping",
    "AdaptiveCausticMap",
    "SpotLightMethod",
    "SpotLightTable",
    "precompute_spot_lights",
    "Lambertian",
    "Glossy",
    "PinholeCamera",
    "camera_image",
    "reference_image",
    "image_error",
    "relative_l2",
    # scenes and lights
    "WaterScene",
    "LensScene",
    "MeshScene",
    "EllipsoidScene",
    "MirrorScene",
    "HeightField",
    "Mesh",
    "Ellipsoid",
    "PlaneReceiver",
    "ScreenPose",
    "Effects",
    "DirectionalLight",
    "PointLight",
    "SunLight",
    "AreaLight",
    "wave_heights",
    "sine_sum",
    # design
    "design",
    "design_lens",
    "DesignProblem",
    "Lens",
    "Mirror",
    "Rectangle",
    "Ellipse",
    "Circle",
    "Polygon",
    "Screen",
    "TransportStart",
    "PoissonLevels",
    "ImageRefinement",
    "LensDesign",
    "export_lens",
    "manufacturability",
    "verify_lens",
    "Verification",
    # water recovery
    "recover_surface",
    "RecoveryResult",
    "recover_sequence",
    "SequenceResult",
    # pictures
    "read_image",
    "write_png",
]
