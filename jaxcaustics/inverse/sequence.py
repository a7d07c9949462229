"""Water surfaces from a video of their caustic: `recover_sequence`.

The frames are recovered in order with `recover_surface`, each warm-started from the one
before (and done again cold where the warm start cannot follow), as checkpointed rounds,
one a frame: a progress bar, ``resume=True``, and Ctrl-C keeps the frames done.
See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from .._checks import check_bool, check_int, check_shape
from ..io.images import READ_EXTENSIONS
from ..methods.twopass import auto_window
from ..scene.scene import check_ior
from .checkpoint import check_checkpoint, fingerprint, refuse_another_run, run_rounds
from .recover import MIN_WINDOW, START_MISFIT, WINDOW_MARGIN, recover_surface
from .water_target import load_target


@dataclasses.dataclass(frozen=True)
class SequenceResult:
    """What `recover_sequence` found, per frame (the first axis; only the first `done`
    frames are filled after an interruption).

    - `heights`: ``(frames, rows, cols)`` metres, each frame's mean removed.
    - `images`: ``(frames, *receiver shape[, channels])``: each frame's recovered caustic.
    - `misfit`: ``(frames,)``: the irradiance fit's misfit (RMS of log irradiance per
      cell; above `START_MISFIT` the caustic may fold).
    - `image_error`: ``(frames,)``: `RecoveryResult.image_error` per frame.
    - `warm`: ``(frames,)`` bool: whether the frame kept its warm start (False: the
      first frame, and frames done again cold).
    - `seconds`: ``(frames,)`` wall time per frame (the first includes compilation).
    - `window`: the two-pass window ``(N, M)`` of the images.
    - `done`: frames recovered; `interrupted`: whether Ctrl-C stopped the run.
    """

    heights: np.ndarray
    images: np.ndarray
    misfit: np.ndarray
    image_error: np.ndarray
    warm: np.ndarray
    seconds: np.ndarray
    window: tuple[int, int]
    done: int
    interrupted: bool


def frame_paths(folder: str | os.PathLike) -> list[Path]:
    """The image files (PNG, JPEG, TIFF, EXR) in `folder`, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"`frames` {str(folder)!r} is not a folder")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in READ_EXTENSIONS)
    if not paths:
        raise ValueError(f"`frames`: no PNG, JPEG, TIFF or EXR files in {str(folder)!r}")
    return paths


def load_frames(frames, ior) -> list[np.ndarray]:
    """Every frame read and checked (`load_target`) before any is recovered; files
    are scaled to unit mean (their scale is arbitrary)."""
    if isinstance(frames, (str, os.PathLike)):
        frames = frame_paths(frames)
    elif isinstance(frames, np.ndarray) or hasattr(frames, "__array__"):
        frames = list(np.asarray(frames))
    elif not isinstance(frames, Sequence):
        raise ValueError(
            f"`frames` must be a folder, a sequence of images or paths, or an array "
            f"(frames, rows, cols); got {type(frames).__name__}"
        )
    if len(frames) == 0:
        raise ValueError("`frames` is empty")
    loaded: list[np.ndarray] = []
    for k, frame in enumerate(frames):
        try:
            image = load_target(frame, ior)
        except FileNotFoundError as err:
            raise FileNotFoundError(f"`frames[{k}]`: {err}") from err
        except ValueError as err:
            raise ValueError(f"`frames[{k}]`: {err}") from err
        if isinstance(frame, (str, os.PathLike)):
            image = image / image.mean()
        if loaded and image.shape != loaded[0].shape:
            raise ValueError(
                f"`frames[{k}]` has shape {image.shape}, the first frame {loaded[0].shape}"
            )
        loaded.append(image)
    return loaded


def recover_sequence(
    frames,
    *,
    warm: bool = True,
    progress: bool = True,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    callback: Callable[[int, Any], Any] | None = None,
    **options: Any,
) -> SequenceResult:
    """Recover the water surface of every frame of a caustic video, in order.

    **Arguments:**

    - `frames`: a folder of image files (sorted by name), a sequence of images or
      paths, or an array ``(frames, rows, cols)``; each frame as `recover_surface`'s
      `target` (files are scaled to unit mean).
    - `warm`: warm-start each frame from the previous one (see the module); False
      recovers every frame cold.
    - `progress`: a progress bar over the frames.
    - `checkpoint`: a file written after every frame (None: none; its folder is created
      if missing and must be writable); `resume`: continue from it (if it exists; needs
      a `checkpoint`).
    - `callback`: called as ``callback(index, result)`` with each frame's
      `RecoveryResult`.
    - `options`: `recover_surface`'s keyword arguments (`extent`, `rest_depth`,
      `light`, ...), the same for every frame; not `initial`.

    **Returns:** a `SequenceResult`.

    **Raises:** `ValueError` naming the frame for an unreadable or invalid one, before
    any frame is recovered.
    """
    if "initial" in options or "target" in options:
        raise ValueError("`recover_sequence` sets each frame's `target` and `initial` itself")
    parameters = inspect.signature(recover_surface).parameters
    unknown = sorted(set(options) - set(parameters))
    if unknown:
        raise ValueError(f"unknown arguments of recover_surface: {unknown}")
    for name, p in parameters.items():
        if name != "target" and p.default is p.empty and name not in options:
            raise ValueError(f"`{name}` is required (an argument of recover_surface)")
    if callback is not None and not callable(callback):
        raise ValueError(f"`callback` must be callable or None, got {type(callback).__name__}")
    warm = check_bool(warm, "warm")
    progress = check_bool(progress, "progress")
    resume = check_bool(resume, "resume")
    check_checkpoint(checkpoint, resume)
    if options.get("heights_shape") is not None:
        check_shape(options["heights_shape"], "heights_shape", 2)
    if options.get("samples_x", "auto") != "auto":
        check_int(options["samples_x"], "samples_x", 1)
        if options.get("channels_y") is not None:
            check_int(options["channels_y"], "channels_y", 0)
    ior = check_ior(options.get("ior", 1.333))
    images = load_frames(frames, ior)
    options = {**options, "normalize": False}  # files were scaled when read
    count = len(images)
    window: list[tuple[int, int]] = []
    if options.get("samples_x", "auto") != "auto":
        window.append((options["samples_x"], options.get("channels_y") or options["samples_x"] - 1))

    def frame_round(k: int):
        def run(state):
            previous = state["heights"][k - 1] if k > 0 and warm else None
            knobs = {**options}
            if not window and int(state["window"][0]) > 0:  # resumed: the saved window
                window.append(tuple(int(v) for v in state["window"]))
            if window:
                knobs["samples_x"], knobs["channels_y"] = window[0]
            t0 = time.perf_counter()
            result, kept_warm = None, False
            if previous is not None:  # the warm start, quiet: a miss is done again cold
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = recover_surface(images[k], initial=np.asarray(previous), **knobs)
                kept_warm = not _misfit(result) > START_MISFIT  # NaN: no start to judge
            if not kept_warm:
                result = recover_surface(images[k], **knobs)
            if not window:  # fixed after the first frame: one compilation of the images
                n, m = auto_window(
                    result.scene, options.get("hit_iterations", 3), options.get("supersample", 1)
                )
                n, m = (
                    max(n + 2 * WINDOW_MARGIN, MIN_WINDOW[0]),
                    max(m + 2 * WINDOW_MARGIN, MIN_WINDOW[1]),
                )
                window.append((n, m))
            if callback is not None:
                callback(k, result)
            new = dict(state)
            for key, value in (
                ("heights", result.heights),
                ("images", result.image),
                ("misfit", _misfit(result)),
                ("image_error", result.image_error),
                ("warm", kept_warm),
                ("seconds", time.perf_counter() - t0),
            ):
                new[key] = state[key].at[k].set(jnp.asarray(value, state[key].dtype))
            new["window"] = jnp.asarray(window[0])
            return new

        return run

    rows_cols = _heights_shape(images[0], options)
    state = {
        "heights": jnp.zeros((count, *rows_cols), np.float32),
        "images": jnp.zeros((count, *images[0].shape), np.float32),
        "misfit": jnp.full(count, np.nan, np.float32),
        "image_error": jnp.full(count, np.nan, np.float32),
        "warm": jnp.zeros(count, bool),
        "seconds": jnp.zeros(count, np.float32),
        "window": jnp.zeros(2, np.int32),
        "fingerprint": fingerprint(
            {
                "frames": np.stack(images).astype(np.float64),
                "options": {k: options[k] for k in sorted(options)},
                "warm": np.asarray(warm),
            }
        ),
    }
    refuse_another_run(checkpoint, resume, state, ("frames", "options", "warm"), "recovery")
    state, done, interrupted = run_rounds(
        [frame_round(k) for k in range(count)],
        state,
        checkpoint=checkpoint,
        resume=resume,
        describe=lambda s: f"worst misfit {np.nanmax(np.asarray(s['misfit'])):.3g}",
        progress=progress,
        label="frames",
    )
    if not window and int(state["window"][0]) > 0:  # resumed after the last frame
        window.append((int(state["window"][0]), int(state["window"][1])))
    return SequenceResult(
        heights=np.asarray(state["heights"], float),
        images=np.asarray(state["images"], float),
        misfit=np.asarray(state["misfit"], float),
        image_error=np.asarray(state["image_error"], float),
        warm=np.asarray(state["warm"]),
        seconds=np.asarray(state["seconds"], float),
        window=window[0] if window else (0, 0),
        done=done,
        interrupted=interrupted,
    )


def _misfit(result) -> float:
    """The irradiance fit's misfit of a `RecoveryResult` (NaN without a transport start)."""
    return float(result.stages[-1]["rms"]) if result.stages else float("nan")


def _heights_shape(image: np.ndarray, options: dict) -> tuple[int, int]:
    shape = options.get("heights_shape")
    return tuple(int(s) for s in (image.shape[:2] if shape is None else shape))  # type: ignore[return-value]
