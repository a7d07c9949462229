"""jaxcaustics: differentiable, jit-compiled caustics in JAX."""

import importlib.metadata

from ._scene import (
    DirectionalLight as DirectionalLight,
    Effects as Effects,
    HeightField as HeightField,
    PlaneReceiver as PlaneReceiver,
    WaterScene as WaterScene,
)

__version__ = importlib.metadata.version("jaxcaustics")
