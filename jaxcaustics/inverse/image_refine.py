"""The image refinement that finishes a design (`ImageRefinement`): a few L-BFGS steps on
the image misfit (caustic triangles, plus a penalty on the flux on dark pixels), for
targets with dark regions. See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._checks import check_int
from ..methods.triangles.method import caustic_triangles
from ..scene.mirror import MirrorScene
from ..scene.scene import LensScene
from .design_setup import DARK_LEVEL, Setup, has_dark_regions
from .driver import iterate
from .lens_model import fit_symbol


def _resolved_modes(shape, modes: int) -> np.ndarray:
    """The DCT-II modes of a ``shape`` grid of heights below `modes` half-cycles along
    each axis (the refinement moves these). ``(rows, cols)`` bool."""
    rows, cols = shape
    return (np.arange(rows)[:, None] < modes) & (np.arange(cols)[None, :] < modes)


class _ImageRefine(eqx.Module):
    """The image-space finish of the transport start: ``0.5 |E / mean(E) - T|^2 / |T|^2
    + dark_weight * (flux on dark pixels) / (all flux)``, ``E`` the caustic-triangles
    image of the heights ``h = C^-1/2 u`` (`C` the landing fit's DCT symbol: ``u`` is in
    pixels of displacement, so that L-BFGS sees a well-scaled problem)."""

    scene: LensScene | MirrorScene
    goal: jax.Array  # (rows, cols) target at unit mean (as seen under the source)
    dark: jax.Array  # (rows, cols) bool: the target below 5% of its mean
    root_symbol: jax.Array  # (hrows, hcols)
    resolved: jax.Array  # (hrows, hcols) bool: the DCT modes the refinement moves
    photons: int = eqx.field(static=True)
    window: int = eqx.field(static=True)
    dark_weight: float = eqx.field(static=True)
    kernel: jax.Array | None = None  # an extended source's image on the screen
    # the caustic triangles' buffers (bytes): `refine_memory`
    memory_limit: int = eqx.field(static=True, default=4 << 30)

    def heights(self, u):
        coef = jax.scipy.fft.dctn(u, type=2, norm="ortho") / self.root_symbol
        # the other modes stay as they are (`ImageRefinement.refine` says which and why)
        coef = jnp.where(self.resolved, coef, jax.lax.stop_gradient(coef))
        return jax.scipy.fft.idctn(coef, type=2, norm="ortho")

    def variable(self, h):
        coef = jax.scipy.fft.dctn(h, type=2, norm="ortho") * self.root_symbol
        return jax.scipy.fft.idctn(coef, type=2, norm="ortho")

    def image(self, u):

        h = self.heights(u)
        scene = eqx.tree_at(lambda sc: sc.surface.heights, self.scene, h - jnp.max(h))
        e = caustic_triangles.unchecked(
            scene, photons=self.photons, window=self.window, memory_limit=self.memory_limit
        ).image
        if self.kernel is not None:  # as seen under the source
            e = jax.scipy.signal.convolve2d(e, self.kernel, mode="same")
        return e / jnp.mean(e)

    def loss(self, u):
        e = self.image(u)
        misfit = 0.5 * jnp.sum((e - self.goal) ** 2) / jnp.sum(self.goal**2)
        return misfit + self.dark_weight * jnp.sum(jnp.where(self.dark, e, 0.0)) / jnp.sum(e)


# the refinement's caustic-triangles buffers (bytes): one rasteriser batch at 513^2
# photons (2.7 GB peak with the gradient; at the 1 GiB default, two batches and a
# checkpointed scan cost 1.6x the time per step)
_REFINE_MEMORY = 4 << 30


def refine_memory(memory_limit: int) -> int:
    """The refinement's rasteriser budget (bytes) within a design's `memory_limit`:
    `_REFINE_MEMORY`, or half the limit where that is less."""
    return min(_REFINE_MEMORY, memory_limit // 2)


# jitted: eager, the DCTs at 512^2 cost seconds in per-op compilations
@eqx.filter_jit
def _refine_variable(refine: _ImageRefine, h):
    return refine.variable(h)


@eqx.filter_jit
def _refine_heights(refine: _ImageRefine, u):
    return refine.heights(u)


@jax.custom_jvp
def _image_loss(u, refine: _ImageRefine):
    return refine.loss(u)


@_image_loss.defjvp
def _image_loss_jvp(primals, tangents):
    """The gradient by reverse mode where the loss is linearised: L-BFGS linearises it
    and transposes the linearisation inside a `lax.cond` (accept or reject the step),
    which cost 2.3-3.0 s a step against 1.3-1.8 s this way (20-degree light, 513^2
    photons). Tangents of `refine` are not taken."""
    u, refine = primals
    loss, grad = jax.value_and_grad(lambda u: refine.loss(u))(u)
    return loss, jnp.sum(grad * tangents[0])


# the quickstart lens's landing gain, pixels per unit slope (index 1.5, 10 mm blank,
# screen 500 mm, 100 mm across 128 pixels), for which the variable's scale was tuned
_LENS_GAIN = 0.5 * (0.5 + 0.01 / 1.5) / (0.1 / 128)


def _variable_scale(setup: Setup) -> float:
    """The refinement variable's scale: a lens's landing gain (pixels per unit slope)
    over the quickstart lens's at 128 pixels, for which it was tuned, and at least 1;
    for a mirror, twice its landing gain over the quickstart lens's.

    A finer screen moves more pixels per unit slope: at scale 1 the camera at 512
    pixels (gain 4.3 times the tuned one) spent its first four L-BFGS steps on rejected
    line searches (the misfit 0.00096 unchanged, then 0.00047 after eight); at scale 4
    it fell at every step, to 0.00048 after four. A mirror moves its light 8 times as
    far per unit slope as a lens of index 1.5 at the same screen distance: at scale 1
    L-BFGS overshot and every step was rejected (measured on the silhouette off a
    mirror, 30 degrees, 1 m: the misfit 0.00745 unchanged in 8 steps; at scales 3, 8,
    12, 20 it fell to 0.0047, 0.0039, 0.0036, 0.0035, the predicted error from 0.092 to
    0.061, 0.054, 0.050, 0.047; at 20 this rule's 18)."""
    pixel = (setup.screen[1] - setup.screen[0]) / setup.target_shape[1]
    gain = (setup.weak / pixel) / _LENS_GAIN
    return 2.0 * gain if setup.is_mirror else max(1.0, gain)


STEPS = 8  # under vertical light onto a lens over the ground
# the refinement's photons per side by default: 4 per target pixel side, at most this
# many. Measured at 512 pixels, judged by the exported solid's facets (relative L2, 1 -
# SSIM, flux on dark pixels, design time), 1025^2 photons against 2049^2: the silhouette
# 0.071, 0.147, 0.75%, 160 s against 0.070, 0.152, 0.74%, 318 s; the lettering 0.075,
# 0.032, 1.33%, 170 s against 0.067, 0.028, 1.24%, 292 s
MAX_DEFAULT_PHOTONS = 1025
LEANING_STEPS = 24  # anywhere else (measured: see `ImageRefinement`)
# under vertical light onto a lens over the ground, for a target with dark regions whose
# heights grid has fewer than four samples a pixel side (`_coarse_grid`: 512 pixels and
# up). There the transport's map leaves the edges ramping over 2-3 pixels (80% of the
# squared error within a pixel of an edge, measured on the silhouette at 512 pixels),
# and after `STEPS` the misfit still fell about 6% a step. Measured at 512 pixels
# (1025^2 photons), judged on the exported solid's facets (the height map in brackets):
# the silhouette 0.066 and 1 - SSIM 0.119 (0.062, 0.104) in 149 s after 8 steps, 0.053
# and 0.108 (0.048, 0.091) in 222 s after 24; the lettering 0.078 and 0.035 (0.076,
# 0.033) in 171 s, 0.060 and 0.038 (0.057, 0.034) in 248 s
COARSE_STEPS = 24
# for a photograph (no dark regions) under vertical light, where the heights grid has
# fewer than four samples a target pixel side (`_fine_detail`)
PHOTO_STEPS = 4


def _fine_detail(setup: Setup, photons: int) -> bool:
    """A photograph's heights grid with fewer than four samples a target pixel side
    (512- and 1024-pixel targets on 1024^2), refined with at least two photons a pixel
    side (`ImageRefinement.photons_for`): the
    transport leaves edges and fine texture a fraction of a pixel off there, which the
    image misfit puts back (measured on the camera at 512 pixels, height map judged by
    `reference.trace_lens_triangles`: relative L2 0.035 and 1 - SSIM 0.101 without,
    0.018 and 0.034 after eight steps at scale 1; with one photon a pixel side, 0.045
    and 0.147: worse)."""
    return _coarse_grid(setup) and photons >= 2 * max(setup.target_shape) + 1


def _coarse_grid(setup: Setup) -> bool:
    """Fewer than four heights samples a target pixel side."""
    return max(setup.shapes[-1]) < 4 * max(setup.target_shape)


def _straight(setup: Setup) -> bool:
    """Vertical light from a point at infinity onto a lens over the ground: the map the
    transport finds is one the lens can make (an extended source's blur is not in it)."""
    return setup.vertical and not setup.is_mirror and setup.pose is None and setup.kernel is None


def _photograph(setup: Setup) -> bool:
    """`_straight` light onto a target without dark regions (`has_dark_regions`)."""
    return _straight(setup) and not has_dark_regions(setup.seen_goal)


class ImageRefinement(eqx.Module):
    """L-BFGS (Optimistix) on the image misfit: for targets with dark regions, and for
    every element under leaning light, off a mirror or before a posed screen.

    The misfit of the caustic-triangles image at unit mean plus 0.3 times the fraction
    of the flux on dark pixels (the target below 5% of its mean), moving the heights' DCT
    modes up to two per target pixel; the result is kept only if the misfit fell.

    Under vertical light onto a lens over the ground it runs when the target is dark on
    more than 10% of the screen (there the transport map jumps and the fitted surface
    spreads light across the gaps), and on a photograph whose heights grid has fewer
    than four samples a target pixel side (`_fine_detail`: 512- and 1024-pixel
    targets); else the transport start is as good.
    Anywhere else the landing fit cannot make the transport's map exactly (the map the
    element makes is then not a gradient: `prediction.py`), and leaves the target's
    edges a fraction of a pixel off, which the image misfit puts back (measured on the
    camera, 128^2, predicted relative L2: a mirror under 30-degree light 0.034 -> 0.013,
    under a point light 1 m away 0.063 -> 0.015 in 16 steps; the point light's
    silhouette 0.086, 0.061, 0.054 after 8, 16, 24 steps).

    **Arguments:**

    - `steps`: L-BFGS steps (a budget: the misfit is polished, not solved); 0: none;
      ``None`` (default): under vertical light onto a lens over the ground `STEPS`
      (8), `COARSE_STEPS` (24) where the heights grid has fewer than four samples a
      target pixel side (512 pixels and up), `PHOTO_STEPS` (4) for a photograph;
      `LEANING_STEPS` (24) otherwise.
    - `photons`: photons per side of the caustic-triangles image; ``None``: 4 per
      target pixel side, at most `MAX_DEFAULT_PHOTONS` (1025), but at least 2 for a
      photograph on a coarse grid (2049 at 1024 pixels).

    Measured on the white-lettering target (128 x 128), judged by the reference:
    relative L2 0.049 and 2.6% of the flux on dark pixels after 8 steps (0.085 and 3.2%
    without them, measured in an earlier version).
    """

    steps: int | None = None
    photons: int | None = None

    def __init__(self, steps=None, photons=None):
        self.steps = None if steps is None else check_int(steps, "steps", 0)
        self.photons = None if photons is None else check_int(photons, "photons", 2)

    def budget(self, setup: Setup) -> int:
        """The steps for `setup`: `steps`, or its default."""
        if self.steps is not None:
            return self.steps
        if not _straight(setup):
            return LEANING_STEPS
        if _photograph(setup):
            return PHOTO_STEPS
        return COARSE_STEPS if _coarse_grid(setup) else STEPS

    def photons_for(self, setup: Setup) -> int:
        """Photons per side of the refinement's image: `photons`, or its default (for a
        photograph on a coarse grid at least two a pixel side, `_fine_detail`: the
        camera at 1024 pixels with 2049^2 photons judged 0.034 and 1 - SSIM 0.144 on
        its height map, in 146 s and 8.7 GB, with the multiscale transport)."""
        if self.photons:
            return self.photons
        side = max(setup.target_shape)
        n = min(4 * side + 1, MAX_DEFAULT_PHOTONS)
        return max(n, 2 * side + 1) if _coarse_grid(setup) and _photograph(setup) else n

    def refine(self, setup: Setup, h: np.ndarray, history: list, callback):
        """Refine heights `h` ``(rows, cols)`` (metres) of `setup`'s lens. Returns
        ``(heights, report or None)``: None when there was nothing to refine."""
        dtype = jnp.result_type(float)
        goal = setup.seen_goal / setup.seen_goal.mean()
        steps = self.budget(setup)
        n = self.photons_for(setup)
        # straight light with no large dark regions: few jumps of the map to clean up,
        # unless the grid is coarse for the picture's detail
        if steps == 0 or (_photograph(setup) and not _fine_detail(setup, n)):
            return h, None
        setup.check_thickness(h)  # before its scene is built
        # modes the photon grid resolves (finer ones it sees aliased, as coarser ones,
        # and grows into a texture), and at most two per target pixel (finer ones the
        # image does not resolve: measured, all 512 modes of a 128^2 target under
        # 20-degree light gave 1 - SSIM 0.160 against 0.152 with 256)
        modes = min(n - 1, 2 * max(setup.target_shape))
        rows, cols = h.shape
        # the variable: heights scaled by the landing fit's symbol without its gain
        # (u ~ slope x samples; measured: with the gain L-BFGS barely moved in 12 steps)
        scale = _variable_scale(setup)
        symbol = fit_symbol(h.shape, setup.width / cols, setup.height / rows, scale, scale)
        refine = _ImageRefine(
            setup.element_scene(np.asarray(h)),
            jnp.asarray(goal, dtype),
            jnp.asarray(goal < DARK_LEVEL),
            jnp.asarray(np.sqrt(symbol), dtype),
            jnp.asarray(_resolved_modes(symbol.shape, modes)),
            n,
            4,
            0.3,
            None if setup.kernel is None else jnp.asarray(setup.kernel, dtype),
            refine_memory(setup.memory_limit),
        )
        u0 = _refine_variable(refine, jnp.asarray(h, dtype))
        t0 = time.perf_counter()
        # Armijo's classic sufficient decrease (1e-4 of the linear prediction), not
        # Optimistix's 0.1: the caustic of a tiny triangle (a bright dot) is far from
        # linear in its vertices, and a first step that cut the misfit 13% was rejected
        # eight times (measured on the dots at 513^2 photons: 3-7% of the decrease the
        # gradient predicts at every step length from 1 to 0.001)
        solver = eqx.tree_at(
            lambda s: s.search,
            optx.LBFGS(rtol=1e-6, atol=1e-9),
            optx.BacktrackingArmijo(slope=1e-4),
        )
        before = len(history)
        info = {"level": 1, "shape": tuple(h.shape), "residuals": 1}
        run = iterate(
            _image_loss, solver, u0, refine, max_steps=steps, history=history,
            callback=callback, info=info,
        )  # fmt: skip
        losses = history[before:]
        kept = bool(losses) and losses[-1] < losses[0]
        h_new = np.asarray(_refine_heights(refine, run.y)) if kept else h
        h_new = h_new - h_new.max()
        report = {
            "stage": "image refinement",
            "shape": tuple(h.shape),
            "steps": run.steps,
            "photons": n,  # per side
            "loss": losses[-1] if losses else float("nan"),
            "loss_per_pixel": losses[-1] if losses else float("nan"),
            "first_loss": losses[0] if losses else float("nan"),
            "kept": kept,
            "result": run.result,
            # a step budget (the fit's misfit polished), not a convergence target: its
            # `max_steps_reached` is no shortfall
            "budget": True,
            "seconds": time.perf_counter() - t0,
            "first_step_seconds": run.compile_seconds,
        }
        return h_new, report
