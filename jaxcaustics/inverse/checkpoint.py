"""Long optimisations in rounds: checkpoints, resume, a progress bar, clean Ctrl-C.

An optimisation is written as a deterministic sequence of *rounds*, each a function
``state -> state`` (for example a few solver steps at one resolution). After every
round the state is written to a checkpoint file (atomically: a temporary file renamed
over the old one). A run that is interrupted (Ctrl-C, a killed job) and started again
with ``resume=True`` loads the last checkpoint and goes on with the next round, so it
ends at exactly the state an uninterrupted run reaches.

States are pytrees of arrays and Python scalars (dicts, lists, tuples, Equinox modules
with array leaves). A checkpoint file holds a header (format, the state's tree structure,
rounds done; NumPy ``.npy`` records) and then the leaves, written by
`equinox.tree_serialise_leaves` and read back by `equinox.tree_deserialise_leaves` into
the structure of the state a run starts from; the structure and every leaf's shape are
checked on load (Equinox reads leaves in order and checks neither), and each leaf takes
the dtype of the starting state's.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._warnings import warn_user
from ..io.files import written_whole
from ..io.images import check_folder

FORMAT = "jaxcaustics-checkpoint-2"


def check_checkpoint(checkpoint, resume: bool) -> None:
    """Checks a `checkpoint` argument (a file path or None) before any work: not a
    folder, in a folder that is writable (created if missing), and not a file of
    another kind (a checkpoint is never written over a picture); `resume` needs it."""
    if checkpoint is None:
        if resume:
            raise ValueError("`resume=True` needs a `checkpoint` file to continue from")
        return
    if not isinstance(checkpoint, (str, os.PathLike)) or str(checkpoint) == "":
        raise ValueError(f"`checkpoint` must be a file path or None, got {checkpoint!r}")
    path = Path(checkpoint)
    if path.is_dir():
        raise ValueError(f"`checkpoint` {str(path)!r} is a directory, not a file")
    if path.is_file():
        with open(path, "rb") as f:
            head = f.read(256)
        if FORMAT.encode() not in head.replace(b"\x00", b""):
            raise ValueError(
                f"`checkpoint` {str(path)!r} exists and is not a jaxcaustics checkpoint: "
                "it is not written over (give another path)"
            )
        if not resume:  # a fresh run over a half-done one: said, not silent
            warn_user(
                f"`checkpoint` {str(path)!r} holds an earlier run: this one starts afresh "
                "and writes over it (`resume=True`, the CLI's --resume, continues it)"
            )
    folder = check_folder(path.parent, "checkpoint")  # writable, or can be made
    folder.mkdir(parents=True, exist_ok=True)


def fingerprint(parts: dict[str, Any]) -> np.ndarray:
    """A digest of each of a run's `parts` (what changes its result: its target, frames,
    options, strategies), ``(len(parts), 8)`` uint32 (SHA-256), kept in its state as
    ``"fingerprint"`` so that a resume can name the part that differs
    (`refuse_another_run`). A part is bytes, a NumPy array or any pytree (its structure
    and its leaves' values)."""
    rows = []
    for value in parts.values():
        if isinstance(value, bytes):
            data = value
        elif isinstance(value, np.ndarray):
            data = f"{value.dtype.str}{value.shape}".encode() + value.tobytes()
        else:
            leaves, treedef = jax.tree_util.tree_flatten(value)
            data = (str(treedef) + repr([np.asarray(x).tolist() for x in leaves])).encode()
        rows.append(np.frombuffer(hashlib.sha256(data).digest(), np.uint32))
    return np.stack(rows)


def refuse_another_run(checkpoint, resume: bool, state: Any, names: Sequence[str], what: str):
    """Before resuming from `checkpoint`: a `ValueError` naming the parts (`names`, in
    `fingerprint`'s order) in which the run that wrote it differs from this one
    (`state`, with its ``"fingerprint"``), or whose state does not fit this one's."""
    if not (resume and checkpoint is not None and Path(checkpoint).is_file()):
        return
    advice = "remove it, or run without `resume`"
    written = f"`checkpoint` {str(checkpoint)!r} was written by another {what}"
    try:
        saved, _ = load_checkpoint(checkpoint, state)
    except ValueError as err:
        raise ValueError(f"{written}: {err}; {advice}") from err
    differ = [
        name
        for name, old, new in zip(names, saved["fingerprint"], state["fingerprint"], strict=True)
        if not np.array_equal(np.asarray(old), np.asarray(new))
    ]
    if differ:
        raise ValueError(f"{written}: its {', '.join(differ)} differ from this one's; {advice}")


def save_checkpoint(path: str | os.PathLike, state: Any, round_index: int) -> Path:
    """Write `state` (after `round_index` rounds) to `path` atomically; returns the path."""
    path = Path(path)
    with written_whole(path) as tmp, open(tmp, "wb") as f:
        for header in (FORMAT, str(jax.tree_util.tree_structure(state)), round_index):
            np.save(f, np.array(header), allow_pickle=False)
        eqx.tree_serialise_leaves(f, state)
    return path


def load_checkpoint(path: str | os.PathLike, like: Any) -> tuple[Any, int]:
    """Read a checkpoint written by `save_checkpoint` into the structure of `like`.

    **Returns:** ``(state, rounds_done)``. Raises `ValueError` naming `path` if the file
    is missing, unreadable, or holds a state of another structure or shape.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"`path` {str(path)!r}: no checkpoint there")

    mismatch = []  # Equinox wraps what a leaf raises: the message is kept here

    def leaf(f, old):
        # the leaves `eqx.tree_serialise_leaves` wrote (arrays and numbers), each read
        # back in the type and dtype of `like`'s (a state built afresh may hold int32
        # where the saved one held int64)
        if not eqx.is_array_like(old):
            return old
        new = np.load(f, allow_pickle=False)
        if new.shape != np.shape(old):
            mismatch.append(
                f"`path` {str(path)!r} holds an array of shape {new.shape} where "
                f"{np.shape(old)} is expected"
            )
            raise ValueError(mismatch[-1])
        if isinstance(old, jax.Array):
            return jnp.asarray(new, dtype=old.dtype)
        if isinstance(old, np.ndarray):
            return new.astype(old.dtype)
        return type(old)(new.item())

    try:
        with open(path, "rb") as f:
            if str(np.load(f, allow_pickle=False)) != FORMAT:
                raise ValueError(f"not a jaxcaustics checkpoint of format {FORMAT!r}")
            if str(np.load(f, allow_pickle=False)) != str(jax.tree_util.tree_structure(like)):
                raise ValueError(f"`path` {str(path)!r} holds a state of another structure")
            rounds_done = int(np.load(f, allow_pickle=False))
            state = eqx.tree_deserialise_leaves(f, like, filter_spec=leaf)
    except Exception as err:  # noqa: BLE001 (unreadable files raise many kinds)
        if mismatch or str(err).startswith("`path`"):
            raise ValueError(mismatch[0] if mismatch else str(err)) from err
        raise ValueError(f"`path` {str(path)!r} is not a readable checkpoint: {err}") from err
    return state, rounds_done


def run_rounds(
    rounds: Sequence[Callable[..., Any]],  # ``round(state[, report])``, see `live`
    state: Any,
    *,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    describe: Callable[[Any], str] | None = None,
    progress: bool = True,
    label: str = "optimising",
    live: bool = False,
) -> tuple[Any, int, bool]:
    """Run `rounds` in order from `state`, checkpointing after each.

    **Arguments:**

    - `rounds`: functions ``state -> state``; deterministic, so that a resumed run ends
      where an uninterrupted one does.
    - `state`: the initial state (also the structure a checkpoint is read into).
    - `checkpoint`: file to write after every round (``None``: no checkpoints).
    - `resume`: start from `checkpoint` if it exists (its rounds are skipped).
    - `describe`: ``state -> str`` for the progress bar (for example the loss).
    - `progress`: show a progress bar (tqdm) with rounds, elapsed time and `describe`.
    - `label`: the progress bar's label.
    - `live`: call each round as ``round(state, report)``, where ``report(text)`` shows
      `text` on the progress bar while the round runs (for example the solver step and
      its loss).

    **Returns:** ``(state, rounds_done, interrupted)``. On Ctrl-C (`KeyboardInterrupt`)
    the run stops after saving nothing new (the last checkpoint stays valid) and returns
    the last completed state with ``interrupted=True``.
    """
    done = 0
    if resume and checkpoint is not None and Path(checkpoint).is_file():
        state, done = load_checkpoint(checkpoint, state)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(rounds), initial=done, desc=label, unit="round")
    start = time.perf_counter()

    def report(text: str) -> None:
        if bar is not None:
            bar.set_postfix_str(f"{text} {time.perf_counter() - start:.1f} s")

    interrupted = False
    try:
        for index in range(done, len(rounds)):
            new_state = rounds[index](state, report) if live else rounds[index](state)
            jax.block_until_ready(new_state)
            state, done = new_state, index + 1
            if checkpoint is not None:
                save_checkpoint(checkpoint, state, done)
            if bar is not None:
                info = describe(state) if describe is not None else ""
                bar.set_postfix_str(f"{info} {time.perf_counter() - start:.1f} s".strip())
                bar.update(1)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if bar is not None:
            bar.close()
    return state, done, interrupted
