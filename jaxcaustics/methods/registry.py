"""The methods by name: the strings `render`, `render_batch`, `choose_method` and the
accuracy tables use, each naming a `Method` class (whose fields are its knobs)."""

from __future__ import annotations

from typing import Any

from .._checks import check_choice
from ..scene.ellipsoid import EllipsoidScene
from ..scene.mesh import MeshScene
from ..scene.mirror import MirrorScene
from ..scene.scene import LensScene, WaterScene
from .base import Method
from .caustic_map.method import AdaptiveCausticMap, CausticsMapping
from .spot_lights.method import SpotLightMethod
from .triangles.method import CausticTriangles
from .twopass import TwoPass

#: name -> method class, in the order the tables and `method_support` list them
METHODS: dict[str, type[Method]] = {
    cls.name: cls
    for cls in (TwoPass, CausticTriangles, CausticsMapping, AdaptiveCausticMap, SpotLightMethod)
}
#: the method a scene type gets when none is named
DEFAULT_METHOD: dict[type, str] = {
    WaterScene: "twopass",
    LensScene: "triangles",
    MirrorScene: "triangles",
    MeshScene: "triangles",
    EllipsoidScene: "spot_lights",
}


def method_class(name: str) -> type[Method]:
    """The `Method` class called `name` (a `ValueError` naming `method` otherwise)."""
    return METHODS[check_choice(name, "method", tuple(METHODS))]


def as_method(method: str | Method | None, knobs: dict[str, Any], scene) -> Method:
    """The `Method` that `render(scene, method, **knobs)` runs.

    `method`: an instance (then no `knobs`: they are its fields), a name (built with
    `knobs`; a knob it does not take is refused by name) or ``None`` (the scene type's
    `DEFAULT_METHOD`, twopass for an unknown type)."""
    if isinstance(method, Method):
        if knobs:
            raise ValueError(
                f"`method` is a {type(method).__name__}: set {sorted(knobs)} on it, not as "
                "keywords of render"
            )
        return method
    if method is None:
        method = next((n for t, n in DEFAULT_METHOD.items() if isinstance(scene, t)), "twopass")
    elif not isinstance(method, str):
        raise ValueError(
            f"`method` must be a method name {tuple(METHODS)} or a Method, got "
            f"{type(method).__name__}"
        )
    return method_class(method).from_knobs(**knobs)
