"""Files written whole or not at all: every writer in the package writes to a temporary
name beside its file and renames it into place (`os.replace`, atomic within a folder),
so a failure (a full disk, an interrupt, a bad array) leaves the earlier file, or none,
never half of one. See the design notes (``docs/design-notes.md``).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def written_whole(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`, with its suffix (writers that choose a
    format by the suffix still do); when the block ends without an error, rename it onto
    `path`, else remove it.

    **Arguments:**

    - `path`: the file to write; its folder must exist.

    **Returns:** (yields) the temporary `Path` to write to.
    """
    path = Path(path)
    handle, name = tempfile.mkstemp(prefix=f".{path.stem}.partial-", suffix=path.suffix,
                                    dir=path.parent)  # fmt: skip
    os.close(handle)
    tmp = Path(name)
    try:
        yield tmp
        # `mkstemp` makes the file readable by its owner alone: give it the permissions
        # of a file opened for writing (0o666 less the umask), as `open` would
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text(path: str | os.PathLike, text: str) -> None:
    """`text` written whole to `path` (UTF-8)."""
    with written_whole(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json(path: str | os.PathLike, data) -> None:
    """`data` as indented JSON, written whole to `path`."""
    write_text(path, json.dumps(data, indent=2) + "\n")


def save_figure(figure, path: str | os.PathLike, **kwargs) -> None:
    """A matplotlib `figure` saved whole to `path` (`kwargs` to `savefig`; the format
    from the suffix)."""
    with written_whole(path) as tmp:
        figure.savefig(tmp, **kwargs)
