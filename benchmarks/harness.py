"""What the benchmarks share: timing after compilation, and Markdown tables.

A benchmark script imports it beside itself (``sys.path`` holds the script's folder
when it runs as ``python benchmarks/bench_x.py``; a script loaded by path, as the smoke
tests do, puts its folder there first).
"""

from __future__ import annotations

import statistics
import time

import jax


def timed(fn, *args, repeats: int = 7, budget_s: float = float("inf")) -> tuple[float, float]:
    """``(first, median)``: the seconds of the first call of ``fn(*args)`` (compilation
    included) and the median of up to `repeats` calls after it (`jax.block_until_ready`
    on each; at least 3, fewer than `repeats` once they took more than `budget_s`)."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    times: list[float] = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
        if len(times) >= 3 and sum(times) > budget_s:
            break
    return first, statistics.median(times)


def markdown(rows: list[dict], columns: list[str], fmt: dict[str, str]) -> str:
    """A Markdown table of `rows` (dicts) in `columns`, each cell by its format in `fmt`
    (``"{}"`` if none; ``-`` for a missing or None value)."""
    head = "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n"
    body = "".join(
        "| "
        + " | ".join(
            fmt.get(c, "{}").format(r[c]) if r.get(c) is not None else "-" for c in columns
        )
        + " |\n"
        for r in rows
    )
    return head + body
