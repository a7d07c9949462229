"""What every caustic method is: an Equinox module of its knobs (`Method`), and the one
result type it renders to (`RenderResult`).

A method, in the way Optimistix solvers are: ``TwoPass(samples_x="auto")`` holds its knobs
(their defaults are the class's field defaults, the one place they are written), says
which scenes it can render (`Method.support`), sizes its ``"auto"`` knobs for concrete
scenes (`Method.sized_for`) and renders a scene (``method(scene)``) to a `RenderResult`
whose image has one channel layout for every method (`channels_last`). The method's
function (`two_pass`, `caustic_triangles`, ...) is its kernel: it takes the same knobs as
keywords, with the class's defaults, and returns the method's own, fuller result.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


class RenderResult(eqx.Module):
    """What ``method(scene)`` and `render` return.

    - `image`: irradiance relative to what the light gives a horizontal plane: ``(rows,
      cols)`` for a scalar index of refraction (or a mirror), ``(rows, cols, channels)``
      for a sequence of indices (one channel per index, also for a sequence of one).
    - `missed_flux_fraction`: ``(channels,)``, the fraction of the light the method left
      out (see each method's result).
    - `stats`: the method's diagnostics (photon counts, buffer sizes, ...), a dict.
    """

    image: Float[Array, "rows cols *channels"]
    missed_flux_fraction: Float[Array, " channels"]
    stats: dict[str, Any]


def worst(fractions) -> float:
    """The largest of per-channel `fractions` (missed flux, ...), 0 for none."""
    return float(np.nanmax(np.asarray(fractions, float), initial=0.0))


def is_multichannel(scene) -> bool:
    """Whether `scene`'s image has a channel axis: its index of refraction is a sequence
    (dispersion; a sequence of one too) and it refracts (a mirror's image does not depend
    on the index)."""
    return (
        isinstance(getattr(scene, "ior", None), tuple)
        and getattr(scene, "material", "refractor") == "refractor"
    )


def channels_last(scene, images: Array) -> Array:
    """``(channels, rows, cols)`` images to `scene`'s layout: ``(rows, cols, channels)``
    when `is_multichannel`, else the first channel, ``(rows, cols)``."""
    return jnp.moveaxis(images, 0, -1) if is_multichannel(scene) else images[0]


class Method(eqx.Module):
    """A caustic method and its knobs (the subclass's fields).

    Subclasses set `name` (the string `render` also accepts), `scene_types` (the scene
    classes it renders) and implement `trace` (the kernel's own result); they may refine
    `support` (effects or shapes they cannot do) and `sized_for` (``"auto"`` knobs).
    """

    name: ClassVar[str]
    scene_types: ClassVar[tuple[type, ...]]
    #: knobs (photon grids) that must grow with the receiver's pixels for the same error
    #: (the accuracy tables store them per pixel)
    resolution_knobs: ClassVar[tuple[str, ...]] = ()
    #: for methods whose missed flux is light their model leaves out (not light landing
    #: off the receiver), what to change when `render` warns of it; else ``None``
    missed_advice: ClassVar[str | None] = None
    #: whether `estimate_error` (two settings of the accuracy knob) was measured never to
    #: under-state the error by more than 1.5x on held-out scenes
    #: (``benchmarks/bench_estimate.py``); only such methods are refined to a tolerance
    estimate_is_reliable: ClassVar[bool] = False

    def knobs(self) -> dict[str, Any]:
        """The knobs as keywords of the method's function."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def knob_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def check_knob_names(cls, knobs: dict[str, Any]) -> None:
        """A `ValueError` naming the first of `knobs` the method does not take."""
        unknown = sorted(set(knobs) - set(cls.knob_names()))
        if unknown:
            raise ValueError(
                f"`{unknown[0]}` is not a knob of method {cls.name!r} (its knobs: "
                f"{', '.join(sorted(cls.knob_names()))})"
            )

    @classmethod
    def from_knobs(cls, **knobs: Any) -> Method:
        """The method with `knobs` (keywords of its function), names checked."""
        cls.check_knob_names(knobs)
        return cls(**knobs)

    def support(self, scene) -> str | None:
        """``None`` if the method can render everything `scene` calls for, else why not
        (an effect it does not simulate, a shape it cannot represent)."""
        if not isinstance(scene, self.scene_types):
            kinds = " and ".join(t.__name__ for t in self.scene_types)
            return f"{self.name} takes {kinds} scenes, not a {type(scene).__name__}"
        return None

    def needs_sizing(self) -> bool:
        """Whether some knob is ``"auto"`` and sized from scene values (`sized_for`)."""
        return False

    def sized_for(self, scenes: Sequence) -> Method:
        """The method with its ``"auto"`` knobs sized for every one of `scenes` (concrete
        scenes: the largest size any needs), so that one program renders them all."""
        return self

    def refined(self) -> Method:
        """The next finer setting of the method's accuracy knob (twice the samples along
        each side): rendering both estimates the error (`estimate_error`)."""
        raise NotImplementedError(f"{type(self).__name__} has no finer setting")

    def coarsened(self) -> Method | None:
        """The next coarser setting (`refined` undone), or ``None`` at the coarsest."""
        return None

    def rounded(self) -> Method:
        """The method with a photon count asked for (a table's per-pixel grid) rounded to
        one it runs; most methods run any count."""
        return self

    def trace(self, scene):
        """The method's function on `scene` with these knobs: its own result type."""
        raise NotImplementedError

    def __call__(self, scene) -> RenderResult:
        result = self.trace(scene)
        return RenderResult(
            result.image, result.missed_flux_fraction, dict(getattr(result, "stats", {}))
        )
