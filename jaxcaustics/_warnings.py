"""Warnings that point at the user's line: `warn_user` finds the first frame outside the
package, however deep in it the warning is raised (a public function that calls
another public function would otherwise shift a fixed `stacklevel`)."""

from __future__ import annotations

import sys
import warnings
from types import FrameType


def warn_user(message: str, category: type[Warning] = UserWarning) -> None:
    """`warnings.warn(message, category)` attributed to the first caller outside
    jaxcaustics."""
    frame: FrameType | None = sys._getframe(1)
    level = 2
    while frame is not None and frame.f_globals.get("__name__", "").startswith("jaxcaustics"):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level - 1 if frame is None else level)
