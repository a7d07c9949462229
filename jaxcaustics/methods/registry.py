"""The methods by name: the strings `render`, `render_batch`, `choose_method` and the
accuracy tables use, each naming a `Method` class (whose fields are its knobs)."""

from __future__ import annotations

from typing import Any

import jax

from .._checks import check_choice
from ..scene.ellipsoid import EllipsoidScene
from ..scene.mesh import MeshScene
from ..scene.mirror import MirrorScene
from ..scene.scene import LensScene, WaterScene
from .base import Method
from .caustic_map.adaptive import AdaptiveCausticMap
from .caustic_map.method import CausticsMapping
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


def method_for(scenes, method: str | Method | None = None, **knobs: Any) -> Method:
    """The method that `render` runs on `scenes`, with every knob that depends on the
    scene's values fixed: the one call to make before `jax.jit` or `jax.vmap`.

    The defaults size some knobs from the scene's values (the two-pass window, the
    triangles' splat window: ``"auto"``), and values are not known under a
    transformation. Fix them first, on concrete scenes, then transform:

    ```pycon
    >>> extent = (0.0, 1.0, 0.0, 1.0)
    >>> heights = jc.wave_heights((32, 32), extent, amplitude=0.002, depth=0.5)
    >>> light, floor = jc.DirectionalLight.from_angles(0.0), jc.PlaneReceiver(extent, (32, 32))
    >>> scene = jc.WaterScene(jc.HeightField(heights, extent), light, floor, rest_depth=0.5)
    >>> method = jc.method_for(scene)  # the scene's method, its "auto" window sized
    >>> method
    TwoPass(samples_x=3, channels_y=2)
    >>> image = jax.jit(lambda s: jc.render(s, method))(scene)
    >>> batch = jc.devices.stack_scenes([scene, scene])  # or sized for several scenes
    >>> jax.vmap(lambda s: jc.render(s, method))(batch).shape
    (2, 32, 32)

    ```

    **Arguments:**

    - `scenes`: a concrete scene, or a sequence of scenes of one type (the knobs are
      then sized for the most demanding of them).
    - `method`, `**knobs`: as for `render`: a method name and its knobs, a `Method`, or
      ``None`` for the scene type's natural method.

    **Returns:** a `Method` with no ``"auto"`` knob left that depends on scene values;
    ``render(scene, method)`` then composes with `jit`, `vmap` and `grad` (under `grad`
    the sized knobs stay constants).
    """
    many = isinstance(scenes, (list, tuple))
    batch = list(scenes) if many else [scenes]
    if not batch:
        raise ValueError("`scenes` is empty: pass a scene or a sequence of scenes")
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(batch)):
        raise ValueError(
            "`scenes` must be concrete (call `method_for` outside `jit`/`vmap`, then "
            "transform `render(scene, method)`)"
        )
    chosen = as_method(method, knobs, batch[0])
    reason = chosen.support(batch[0])
    if reason and not isinstance(batch[0], chosen.scene_types):
        raise ValueError(f"`method`: {reason}")
    return chosen.sized_for(batch) if chosen.needs_sizing() else chosen
