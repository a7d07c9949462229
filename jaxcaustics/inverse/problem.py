"""What is being made, as data: the element, the blank's outline, the light, the screen.

A `DesignProblem` says what `jaxcaustics.design` designs; how it is solved (the
transport start, the image refinement, the Poisson levels) is said apart, by the
strategies. Every part is an Equinox Module checked when it is built, so a bad problem
is refused by name before anything is compiled.

Lengths are metres. The blank's outline is centred on ``x = y = 0``. A lens's bottom
face lies at ``z = screen.distance`` above the ground ``z = 0``, which is its screen
unless the `Screen` is posed (facing the refracted beam, or any normal); light travels
down through it. A mirror's face rests on ``z = 0``, facing up: light comes down onto it
and its screen stands in the reflected beam, facing the mirror.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import numpy as np

from .._checks import check_real_array
from ..scene.outline import check_outline, mask_vertices
from ..scene.scene import DirectionalLight, PointLight
from ..scene.sources import AreaLight, SunLight


def _length(value, name: str) -> float:
    """A positive, finite length in metres, or a `ValueError` naming `name`."""
    if isinstance(value, (str, bytes, bool)):
        raise ValueError(f"`{name}` must be a positive number (metres), got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`{name}` must be a positive number (metres), got {value!r}") from err
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"`{name}` must be positive and finite (metres), got {value!r}")
    return v


class Lens(eqx.Module):
    """A refractive lens milled into a blank of glass or acrylic.

    **Arguments:**

    - `thickness`: the blank's thickness (metres), from the flat bottom face to the
      highest point of the designed top surface; the relief is milled into it.
    - `ior`: index of refraction (> 1; one number: design one colour at a time).
    """

    thickness: float = eqx.field(static=True)
    ior: float = eqx.field(static=True)
    kind: ClassVar[str] = "lens"

    def __init__(self, thickness, ior=1.5):
        self.thickness = _length(thickness, "thickness")
        if isinstance(ior, (list, tuple, np.ndarray)):
            raise ValueError("`ior` must be a single number (design one channel at a time)")
        self.ior = _length(ior, "ior")
        if self.ior <= 1.0:
            raise ValueError(f"`ior` must be > 1 for a glass lens in air, got {ior}")


class Mirror(eqx.Module):
    """A reflecting caustic surface (polished metal, or a mirror-coated face) milled into
    a blank.

    **Arguments:**

    - `thickness`: the blank's thickness (metres), from its flat back to the highest
      point of the designed face; the relief is milled into it.
    """

    thickness: float = eqx.field(static=True)
    kind: ClassVar[str] = "mirror"

    def __init__(self, thickness):
        self.thickness = _length(thickness, "thickness")


Element = Lens | Mirror


def _centred_extent(width: float, height: float) -> np.ndarray:
    """``(x_min, x_max, y_min, y_max)`` of a blank of `width` by `height`, centred."""
    return np.array([-width / 2, width / 2, -height / 2, height / 2])


class Rectangle(eqx.Module):
    """A rectangular blank, `width` along x by `height` along y (metres), centred."""

    width: float = eqx.field(static=True)
    height: float = eqx.field(static=True)
    kind: ClassVar[str] = "rectangle"
    lens_outline: ClassVar[str] = "rectangle"  # what `LensScene.outline` takes

    def __init__(self, width, height):
        self.width, self.height = _length(width, "width"), _length(height, "height")

    @property
    def extent(self) -> np.ndarray:
        """``(x_min, x_max, y_min, y_max)`` of the blank."""
        return _centred_extent(self.width, self.height)


class Ellipse(eqx.Module):
    """An elliptical blank, `width` along x by `height` along y (metres), centred: light
    outside it is stopped (a round mount), and the exported solid is elliptical."""

    width: float = eqx.field(static=True)
    height: float = eqx.field(static=True)
    kind: ClassVar[str] = "ellipse"
    lens_outline: ClassVar[str] = "ellipse"

    def __init__(self, width, height):
        self.width, self.height = _length(width, "width"), _length(height, "height")

    @property
    def extent(self) -> np.ndarray:
        """``(x_min, x_max, y_min, y_max)`` of the blank."""
        return _centred_extent(self.width, self.height)


def Circle(diameter) -> Ellipse:  # noqa: N802 (reads as the class it builds)
    """A round blank of `diameter` (metres), centred: an `Ellipse` of equal axes."""
    d = _length(diameter, "diameter")
    return Ellipse(d, d)


class Polygon(eqx.Module):
    """A polygonal blank (a triangle, a hexagon, a star): `vertices` ``(N, 2)`` in metres,
    in order round the centre of their bounding box, which must see every edge from
    inside (the polygon is star-shaped about it: the exported solid is built on rings
    about it). The blank is placed with that bounding box centred on ``x = y = 0``."""

    vertices: tuple[tuple[float, float], ...] = eqx.field(static=True)
    kind: ClassVar[str] = "polygon"

    def __init__(self, vertices):
        v = check_real_array(vertices, "vertices").astype(float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"`vertices` must be (N, 2) finite metres, N >= 3, got {v.shape}")
        v = v - 0.5 * (v.min(axis=0) + v.max(axis=0))  # the bounding box centred
        if not np.all(v.max(axis=0) > 0):
            raise ValueError("`vertices` span no area")
        check_outline(v / v.max(axis=0), "vertices")  # star-shaped about the centre
        self.vertices = tuple((float(x), float(y)) for x, y in v)

    @classmethod
    def from_mask(cls, mask, width, height=None) -> Polygon:
        """The outline a boolean `mask` over the blank draws: `mask` ``(rows, cols)``,
        indexed ``[y, x]`` with row 0 at the blank's ``y_min`` (as heights are), spans
        `width` by `height` metres (default: square pixels). The mask must be one
        region without holes, star-shaped about the centre of its bounding box; its
        boundary is traced and simplified to within half a pixel (`mask_vertices`), and
        the blank is that boundary's bounding box."""
        v = mask_vertices(mask, "mask")
        rows, cols = np.shape(mask)
        width = _length(width, "width")
        height = width * rows / cols if height is None else _length(height, "height")
        try:
            return cls(v * np.array([width / cols, height / rows]))
        except ValueError as err:
            raise ValueError(f"`mask`: {err}") from err

    @property
    def width(self) -> float:
        return 2.0 * max(abs(x) for x, _ in self.vertices)

    @property
    def height(self) -> float:
        return 2.0 * max(abs(y) for _, y in self.vertices)

    @property
    def lens_outline(self) -> tuple:
        """The vertices in the aperture's frame normalised to ``[-1, 1]^2`` (as
        `LensScene.outline` takes them), counter-clockwise."""
        a, b = 0.5 * self.width, 0.5 * self.height
        return check_outline([(x / a, y / b) for x, y in self.vertices], "vertices")

    @property
    def extent(self) -> np.ndarray:
        """``(x_min, x_max, y_min, y_max)`` of the blank."""
        return _centred_extent(self.width, self.height)


Outline = Rectangle | Ellipse | Polygon


def _direction(value, name: str) -> tuple[float, float, float]:
    v = check_real_array(value, name).astype(float)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or not np.linalg.norm(v) > 0:
        raise ValueError(f"`{name}` must be a non-zero 3-vector, got {value!r}")
    return tuple(float(c) for c in v / np.linalg.norm(v))  # type: ignore[return-value]


class Screen(eqx.Module):
    """The screen the caustic falls on.

    **Arguments:**

    - `distance`: metres from the element to the screen's centre: for a lens under the
      default (horizontal) screen, from its bottom face straight down to the ground; for
      a posed screen, along the beam's central ray (from where it leaves the lens's
      bottom face, or from the mirror's centre).
    - `extent`: ``(s_min, s_max, t_min, t_max)`` of the screen in its own frame
      (metres; ``x, y`` for the horizontal screen); ``None``: the flat element's
      footprint (the outline traced to the screen under the light).
    - `normal`: ``None``: a lens's screen is horizontal, a mirror's faces the beam;
      ``"beam"``: the screen faces the outgoing beam (its normal is the central ray,
      reversed); a 3-vector: the normal of the screen's lit face (towards the element).
    - `up`: the screen's up direction (made perpendicular to its normal; default
      ``(0, 1, 0)``): the target's rows run along it.

    The pixel grid is the target's.
    """

    distance: float = eqx.field(static=True)
    extent: tuple[float, float, float, float] | None = eqx.field(static=True)
    normal: str | tuple[float, float, float] | None = eqx.field(static=True)
    up: tuple[float, float, float] = eqx.field(static=True)

    def __init__(self, distance, extent=None, *, normal=None, up=(0.0, 1.0, 0.0)):
        self.distance = _length(distance, "screen_distance")
        if extent is not None:
            e = check_real_array(extent, "screen_extent").astype(float)
            ordered = e.shape == (4,) and e[1] > e[0] and e[3] > e[2]
            if not (ordered and np.isfinite(e).all()):
                raise ValueError(
                    f"`screen_extent` must be (x_min, x_max, y_min, y_max), got {extent!r}"
                )
            extent = tuple(float(v) for v in e)
        self.extent = extent
        if isinstance(normal, str):
            if normal != "beam":
                raise ValueError(f"`normal` must be None, 'beam' or a 3-vector, got {normal!r}")
        elif normal is not None:
            normal = _direction(normal, "normal")
        self.normal = normal
        self.up = _direction(up, "up")
        if isinstance(normal, tuple) and abs(float(np.dot(normal, self.up))) > 1 - 1e-9:
            raise ValueError(f"`up` {up!r} is parallel to the screen's `normal`")


class DesignProblem(eqx.Module):
    """A caustic element to design: what it is, its outline, its light and its screen.

    **Arguments:**

    - `element`: a `Lens` (index, blank thickness) or a `Mirror` (blank thickness).
    - `outline`: the blank's outline: a `Rectangle`, an `Ellipse`, a `Circle` or a
      `Polygon` (light outside it is stopped by the mount).
    - `screen`: a `Screen` (its distance from the element, its extent, its pose).
    - `light`: a `DirectionalLight` (any angle, travelling down) or a `PointLight` above
      the element; default: collimated, straight down.

    For example, the quickstart's lens: ``DesignProblem(Lens(thickness=0.02),
    Rectangle(0.1, 0.1), Screen(distance=0.5))``.
    """

    element: Element
    outline: Outline
    screen: Screen
    light: DirectionalLight | PointLight

    def __init__(self, element, outline, screen, light=None):
        if not isinstance(element, (Lens, Mirror)):
            raise ValueError(f"`element` must be a Lens or a Mirror, got {type(element).__name__}")
        if not isinstance(outline, (Rectangle, Ellipse, Polygon)):
            raise ValueError(
                f"`outline` must be a Rectangle, an Ellipse, a Circle or a Polygon, got "
                f"{type(outline).__name__}"
            )
        if not isinstance(screen, Screen):
            raise ValueError(f"`screen` must be a Screen, got {type(screen).__name__}")
        if light is None:
            light = DirectionalLight(np.array([0.0, 0.0, -1.0]))
        elif not isinstance(light, (DirectionalLight, PointLight)):
            raise ValueError(
                f"`light` must be a DirectionalLight or a PointLight, got {type(light).__name__}"
            )
        if isinstance(light, PointLight):
            top = screen.distance + element.thickness if isinstance(element, Lens) else 0.0
            height = float(np.asarray(light.position)[2])
            if not height > top:
                raise ValueError(
                    f"`light`: the point light at z = {height:.4g} m is not above the "
                    f"element's top (z = {top:.4g} m): light must come from above"
                )
        self.element, self.outline, self.screen, self.light = element, outline, screen, light

    @property
    def top(self) -> float:
        """Height of the element's top rest plane (metres): a lens's above the ground, a
        mirror's face rests on ``z = 0``."""
        if isinstance(self.element, Mirror):
            return 0.0
        return self.screen.distance + self.element.thickness

    @property
    def posed(self) -> bool:
        """Whether the screen is placed by a pose (a mirror's always; a lens's when its
        `Screen` has a `normal`), rather than the ground ``z = 0``."""
        return isinstance(self.element, Mirror) or self.screen.normal is not None


# ----------------------------------------------------------------- as JSON

PROBLEM_FORMAT = "jaxcaustics-problem-1"


def _outline_to_dict(outline) -> dict:
    if isinstance(outline, Polygon):
        return {"kind": "polygon", "vertices": [list(v) for v in outline.vertices]}
    return {"kind": outline.kind, "width": outline.width, "height": outline.height}


def problem_to_dict(problem: DesignProblem) -> dict:
    """`problem` as plain JSON-ready data (metres), read back by `problem_from_dict`."""
    light = problem.light
    if isinstance(light, SunLight):
        light_data = {
            "kind": "sun",
            "direction": np.asarray(light.direction).tolist(),
            "angular_radius_deg": light.angular_radius_deg,
            "limb_darkening": light.limb_darkening,
        }
    elif isinstance(light, DirectionalLight):
        light_data = {"kind": "directional", "direction": np.asarray(light.direction).tolist()}
    elif isinstance(light, AreaLight):
        light_data = {
            "kind": "area",
            "position": np.asarray(light.position).tolist(),
            "size": list(light.size),
            "shape": light.shape,
            "intensity": float(np.asarray(light.intensity)),
            "lambertian": light.lambertian,
        }
    else:
        light_data = {
            "kind": "point",
            "position": np.asarray(light.position).tolist(),
            "intensity": float(np.asarray(light.intensity)),
        }
    screen = problem.screen
    return {
        "format": PROBLEM_FORMAT,
        "units": "metres",
        "element": (
            {"kind": "lens", "thickness": problem.element.thickness, "ior": problem.element.ior}
            if isinstance(problem.element, Lens)
            else {"kind": "mirror", "thickness": problem.element.thickness}
        ),
        "outline": _outline_to_dict(problem.outline),
        "light": light_data,
        "screen": {
            "distance": screen.distance,
            "extent": None if screen.extent is None else list(screen.extent),
            "normal": list(screen.normal) if isinstance(screen.normal, tuple) else screen.normal,
            "up": list(screen.up),
        },
    }


def problem_from_dict(data) -> DesignProblem:
    """The `DesignProblem` that `problem_to_dict` wrote; a `ValueError` naming the entry
    that is missing or wrong."""
    if not isinstance(data, dict) or data.get("format") != PROBLEM_FORMAT:
        raise ValueError(f"`problem` is not a {PROBLEM_FORMAT!r} description")
    try:
        element, outline = data["element"], data["outline"]
        light, screen = data["light"], data["screen"]
        if element.get("kind") not in ("lens", "mirror"):
            raise ValueError(f"`element` kind {element.get('kind')!r} is not 'lens' or 'mirror'")
        shapes = {"rectangle": Rectangle, "ellipse": Ellipse, "polygon": Polygon}
        if outline.get("kind") not in shapes:
            raise ValueError(f"`outline` kind {outline.get('kind')!r} is not one of {list(shapes)}")
        if outline["kind"] == "polygon":
            built_outline = Polygon(outline["vertices"])
        else:
            built_outline = shapes[outline["kind"]](outline["width"], outline["height"])
        built_light: DirectionalLight | PointLight
        if light.get("kind") == "directional":
            built_light = DirectionalLight(np.asarray(light["direction"], float))
        elif light.get("kind") == "sun":
            built_light = SunLight(
                np.asarray(light["direction"], float),
                light["angular_radius_deg"],
                light.get("limb_darkening", 0.0),
            )
        elif light.get("kind") == "area":
            built_light = AreaLight(
                np.asarray(light["position"], float),
                light["size"] if light.get("shape") != "disc" else light["size"][0],
                light.get("shape"),
                light.get("intensity", 1.0),
                light.get("lambertian", True),
            )
        elif light.get("kind") == "point":
            position = np.asarray(light["position"], float)
            built_light = PointLight(position, light.get("intensity", 1.0))
        else:
            raise ValueError(
                f"`light` kind {light.get('kind')!r} is not directional, sun, point or area"
            )
        built_element = (
            Lens(element["thickness"], element["ior"])
            if element["kind"] == "lens"
            else Mirror(element["thickness"])
        )
        built_screen = Screen(
            screen["distance"],
            screen.get("extent"),
            normal=screen.get("normal"),
            up=screen.get("up", (0.0, 1.0, 0.0)),
        )
        return DesignProblem(built_element, built_outline, built_screen, built_light)
    except (KeyError, TypeError, AttributeError) as err:
        raise ValueError(f"`problem` description is incomplete or malformed: {err!r}") from err
