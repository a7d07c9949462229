"""The values of a scene, checked where a method starts rendering.

The scene constructors check their arguments, but a scene can be changed after it was
built: ``eqx.tree_at`` replaces a field without calling the constructor, and under
``jax.jit``, ``jax.grad`` or ``jax.vmap`` the fields are tracers whose values the
constructors could not see. A NaN height, an upward light or water below the floor then
rendered an all-black image without a word. `check_scene_values` runs the same rules on
the scene a method is given:

- concrete values: a `ValueError` naming the field (``scene.surface.heights``) at once,
  before anything is compiled;
- traced values: `equinox.error_if` on the field, so the compiled render raises an
  `EquinoxRuntimeError` with the same message when it runs (or gives NaN under
  ``EQX_ON_ERROR=nan``, Equinox's switch), never a black image.

Rules: every floating field finite; a directional light travelling down; a point light of
positive intensity; extents with ``max > min``; water depth, lens thickness and screen distance
positive, the surface above what lies beneath it, a point light above a lens; meshes and
ellipsoids above the screen, a point light outside the generator's bounding box, a
refracting mesh wound outwards (positive signed volume), ellipsoid radii positive.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Protocol, cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .ellipsoid import Ellipsoid, EllipsoidScene, lowest_z
from .mesh import Mesh, MeshScene
from .mirror import MirrorScene
from .scene import DirectionalLight, LensScene, PointLight, WaterScene

# a rule: (where: the field the error is attached to, bad: a scalar bool, message)
Rule = tuple[Callable, jax.Array, str]


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _getter(path) -> Callable:
    """``scene -> the leaf at `path``` (a key path of `jax.tree_util`)."""

    def get(tree):
        for key in path:
            if isinstance(key, jax.tree_util.GetAttrKey):
                tree = getattr(tree, key.name)
            else:
                tree = tree[key.idx]
        return tree

    return get


def _finite_rules(scene, xp) -> list[Rule]:
    rules = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(scene)[0]:
        if hasattr(leaf, "dtype") and jnp.issubdtype(leaf.dtype, jnp.floating):
            name = "scene" + jax.tree_util.keystr(path)
            bad = xp.logical_not(xp.all(xp.isfinite(leaf)))
            rules.append((_getter(path), bad, f"`{name}` contains NaN or infinite values"))
    return rules


def _light_rules(light, where: Callable, name: str, xp) -> list[Rule]:
    if isinstance(light, DirectionalLight):
        d = light.direction
        down = d[2] < -1e-6 * xp.linalg.norm(d)
        message = f"`{name}.direction` is the direction of travel and must point down (z < 0)"
        return [(lambda s: where(s).direction, xp.logical_not(down), message)]
    if isinstance(light, PointLight):
        message = f"`{name}.intensity` must be positive"
        return [(lambda s: where(s).intensity, light.intensity <= 0, message)]
    return []


def _extent_rule(extent, where: Callable, name: str, xp) -> Rule:
    bad = xp.logical_or(extent[1] <= extent[0], extent[3] <= extent[2])
    return (where, bad, f"`{name}` must have x_max > x_min and y_max > y_min")


def _water_rules(scene: WaterScene, xp) -> list[Rule]:
    depth = scene.rest_depth
    return [
        (lambda s: s.rest_depth, depth <= 0, "`scene.rest_depth` must be positive"),
        (
            lambda s: s.surface.heights,
            depth + xp.min(scene.surface.heights) <= 0,
            "`scene.surface` reaches the ground: rest_depth + min(heights) <= 0 "
            "(impossible geometry)",
        ),
    ]


def _lens_rules(scene: LensScene, xp) -> list[Rule]:
    h = scene.surface.heights
    rules = [
        (lambda s: s.thickness, scene.thickness <= 0, "`scene.thickness` must be positive"),
        (
            lambda s: s.screen_distance,
            scene.screen_distance <= 0,
            "`scene.screen_distance` must be positive",
        ),
        (
            lambda s: s.surface.heights,
            scene.thickness + xp.min(h) <= 0,
            "`scene.surface` dips through the bottom face: thickness + min(heights) <= 0 "
            "(impossible geometry)",
        ),
    ]
    if isinstance(scene.light, PointLight):
        top = scene.screen_distance + scene.thickness + xp.max(h)
        message = "`scene.light` must be above the lens (position z > top of the lens)"
        rules.append((lambda s: s.light.position, scene.light.position[2] <= top, message))
    return rules


def _mesh_rules(scene: MeshScene, xp) -> list[Rule]:
    rules = []
    meshes: list[tuple[Mesh, Callable, str]] = [
        (scene.generator, lambda s: s.generator.vertices, "scene.generator")
    ]
    for k, occluder in enumerate(scene.occluders):
        meshes.append((occluder, lambda s, k=k: s.occluders[k].vertices, f"scene.occluders[{k}]"))
    for mesh, where, name in meshes:
        below = xp.min(mesh.vertices[:, 2]) < 0
        rules.append((where, below, f"`{name}` reaches below the screen (z < 0)"))
    v = scene.generator.vertices
    if scene.material == "refractor":
        a, b, c = (v[scene.generator.faces[:, k]] for k in range(3))
        volume = xp.sum(a * xp.cross(b, c)) / 6.0
        message = (
            "`scene.generator` is inside out: its faces are wound inwards (signed volume <= 0)"
        )
        rules.append((lambda s: s.generator.vertices, volume <= 0, message))
    if isinstance(scene.light, PointLight):
        p, lo, hi = scene.light.position, xp.min(v, axis=0), xp.max(v, axis=0)
        bad = xp.logical_or(p[2] < lo[2], xp.all((p >= lo) & (p <= hi)))
        message = (
            "`scene.light` is below or inside the bounding box of the generator: it must "
            "light the object from outside its bounding box, not from below"
        )
        rules.append((lambda s: s.light.position, bad, message))
    return rules


def _ellipsoid_rules(scene: EllipsoidScene, xp) -> list[Rule]:
    rules = []
    ellipsoids: list[tuple[Ellipsoid, Callable, str]] = [
        (scene.generator, lambda s: s.generator, "scene.generator")
    ]
    for k, occluder in enumerate(scene.occluders):
        ellipsoids.append((occluder, lambda s, k=k: s.occluders[k], f"scene.occluders[{k}]"))
    for ell, where, name in ellipsoids:
        rules.append(
            (
                lambda s, where=where: where(s).radii,
                xp.any(ell.radii <= 0),
                f"`{name}.radii` must be positive",
            )
        )
        below = lowest_z(ell) < -1e-9 * xp.max(xp.abs(ell.radii))
        rules.append(
            (
                lambda s, where=where: where(s).center,
                below,
                f"`{name}` reaches below the screen (z < 0)",
            )
        )
    return rules


def _mirror_rules(scene: MirrorScene, xp) -> list[Rule]:
    r = scene.reflectance
    rules = [
        (
            lambda s: s.reflectance,
            xp.logical_or(r <= 0, r > 1),
            "`scene.reflectance` must be in (0, 1]",
        )
    ]
    if isinstance(scene.light, PointLight):
        top = xp.max(scene.surface.heights)
        message = "`scene.light` must be above the mirror (position z > top of its face)"
        rules.append((lambda s: s.light.position, scene.light.position[2] <= top, message))
    return rules


def _rules(scene, xp) -> list[Rule]:
    rules = _finite_rules(scene, xp)
    rules += _light_rules(scene.light, lambda s: s.light, "scene.light", xp)
    rules.append(
        _extent_rule(
            scene.receiver.extent, lambda s: s.receiver.extent, "scene.receiver.extent", xp
        )
    )
    if isinstance(scene, (WaterScene, LensScene, MirrorScene)):
        extent = scene.surface.extent
        rules.append(_extent_rule(extent, lambda s: s.surface.extent, "scene.surface.extent", xp))
    if isinstance(scene, WaterScene):
        rules += _water_rules(scene, xp)
    elif isinstance(scene, LensScene):
        rules += _lens_rules(scene, xp)
    elif isinstance(scene, MirrorScene):
        rules += _mirror_rules(scene, xp)
    elif isinstance(scene, MeshScene):
        rules += _mesh_rules(scene, xp)
    elif isinstance(scene, EllipsoidScene):
        rules += _ellipsoid_rules(scene, xp)
    return rules


def check_scene_values(scene):
    """`scene`, its values checked by the rules above (a scene of another type is
    returned as it is: the method's own type check refuses it).

    A rule whose values are all concrete raises its `ValueError` now if broken; a rule
    that depends on a traced value is attached to its field with `equinox.error_if`, so
    the compiled render raises (at run time) if it is broken. Returns the scene, with
    those checks attached (unchanged when every value is concrete).
    """
    if not isinstance(scene, (WaterScene, LensScene, MirrorScene, MeshScene, EllipsoidScene)):
        return scene
    if any(_is_traced(leaf) for leaf in jax.tree_util.tree_leaves(scene)):
        rules = _rules(scene, jnp)
    else:  # NumPy: a few microseconds, where eager JAX dispatch took a millisecond
        rules = _rules(jax.tree.map(np.asarray, scene), np)
    traced = []
    for where, bad, message in rules:
        if _is_traced(bad):
            traced.append((where, bad, message))
        elif bool(bad):
            raise ValueError(message)
    for where, bad, message in traced:
        scene = eqx.tree_at(where, scene, eqx.error_if(where(scene), bad, message))
    return scene


class SceneMethod(Protocol):
    """A method decorated by `checks_scene_values`: the checked call, and the method
    itself as ``.unchecked``."""

    unchecked: Callable[..., Any]

    def __call__(self, *args: Any, **kwargs: Any) -> Any: ...


def checks_scene_values(method: Callable) -> SceneMethod:
    """Decorate a method ``method(scene, ...)``: the public function checks the scene's
    values first (`check_scene_values`). ``method.unchecked`` skips them, for the
    library's own solvers: a trial step of an optimisation may leave the physical
    scenes, and its solver, not an error, must handle that."""

    @functools.wraps(method)
    def checked(scene, *args, **kwargs):
        return method(check_scene_values(scene), *args, **kwargs)

    checked.unchecked = method  # type: ignore[attr-defined]
    return cast(SceneMethod, checked)
