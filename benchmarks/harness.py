"""What the benchmarks share: timing, the environment of a run, and its results files.

A benchmark script imports it beside itself (``sys.path`` holds the script's folder
when it runs as ``python benchmarks/bench_x.py``; a script loaded by path, as the smoke
tests do, puts its folder there first).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"


class Timing(NamedTuple):
    """What `timed` measured: ``first`` the seconds of the first call (compilation
    included), ``times`` those of the calls after it, ``out`` the last call's output."""

    first: float
    times: list[float]
    out: Any

    @property
    def median(self) -> float:
        return statistics.median(self.times)

    @property
    def runs(self) -> int:
        return len(self.times)

    @property
    def compile_s(self) -> float:
        """The first call minus the median."""
        return self.first - self.median


def once(fn, *args) -> tuple[float, Any]:
    """``(seconds, output)`` of one call of ``fn(*args)``, `jax.block_until_ready` on it."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return time.perf_counter() - start, out


def timed(
    fn,
    *args,
    repeats: int = 7,
    budget_s: float = float("inf"),
    long_s: float = float("inf"),
    first: float | None = None,
) -> Timing:
    """A first call of ``fn(*args)`` (it compiles; not made when its seconds are given as
    `first`), then up to `repeats` timed calls (`jax.block_until_ready` on each): fewer
    once they took more than `budget_s` (after 3 calls) or `long_s` (after 2)."""
    out = None
    if first is None:
        first, out = once(fn, *args)
    times: list[float] = []
    while len(times) < repeats:
        took, out = once(fn, *args)
        times.append(took)
        total = sum(times)
        if (len(times) >= 3 and total > budget_s) or (len(times) >= 2 and total > long_s):
            break
    return Timing(first, times, out)


def compile_time(fn, *args) -> tuple[Any, float]:
    """``(compiled, seconds)``: ``fn`` (jitted with `jax.jit` unless it has ``.lower``
    already, as `jax.jit` and `equinox.filter_jit` functions do) lowered and compiled for
    `args`, and the seconds that took."""
    lower = fn.lower if hasattr(fn, "lower") else jax.jit(fn).lower
    start = time.perf_counter()
    compiled = lower(*args).compile()
    return compiled, time.perf_counter() - start


def load() -> list[float]:
    """The load average (1, 5, 15 minutes)."""
    return [round(x, 2) for x in os.getloadavg()]


def git_commit() -> str | None:
    """``git rev-parse --short HEAD`` of this repository, ``+dirty`` when its tracked
    files differ from it; None when git cannot tell."""

    def git(*args):
        return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("diff", "--quiet", "HEAD").returncode != 0
    except OSError:
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+dirty" if dirty else "")


def environment() -> dict:
    """Where and when a benchmark ran."""
    import jaxlib

    device = jax.devices()[0]
    return dict(
        date=datetime.datetime.now().isoformat(timespec="seconds"),
        commit=git_commit(),
        platform=platform.platform(),
        machine=platform.machine(),
        python=platform.python_version(),
        jax=jax.__version__,
        jaxlib=jaxlib.__version__,
        x64=bool(jax.config.jax_enable_x64),
        cpus=os.cpu_count(),
        backend=device.platform,
        device=str(device),
        device_kind=device.device_kind,
        devices=jax.device_count(),
        load=load(),
    )


def _plain(x):
    """NumPy and JAX values as JSON: arrays as lists, scalars as numbers."""
    if hasattr(x, "tolist"):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def write_results(
    name: str,
    rows,
    text: str,
    extra: dict | None = None,
    out: Path = RESULTS,
    env: dict | None = None,
) -> Path:
    """Write ``<out>/<name>.md`` (`text`) and beside it ``<out>/<name>.json``: the run's
    `environment` (`env`, when one is given: a report redone from stored rows keeps its
    run's), `extra` and the raw `rows`. Returns the Markdown's path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    data = {"environment": environment() if env is None else env, **(extra or {}), "rows": rows}
    (out / f"{name}.json").write_text(json.dumps(data, indent=1, default=_plain) + "\n")
    (out / f"{name}.md").write_text(text)
    return out / f"{name}.md"


def read_results(name: str, out: Path = RESULTS) -> dict | None:
    """What `write_results` wrote to ``<out>/<name>.json``; None when there is none."""
    path = Path(out) / f"{name}.json"
    return json.loads(path.read_text()) if path.exists() else None


def run_rows(name: str, script: str, rows_arg: str, one, report, argv_one=None) -> None:
    """A benchmark of rows, each measured by ``script --one ROW`` in a fresh process
    (compilation counted), its JSON result merged into ``results/NAME.json`` and the
    report rewritten after every row. `argv_one`: run `one` here instead (the child)."""
    if argv_one:
        print(json.dumps(one(argv_one)))
        return
    rows = (read_results(name) or {}).get("rows", {})
    env = environment()
    for row in rows_arg.split(","):
        proc = subprocess.run(
            [sys.executable, script, "--one", row], capture_output=True, text=True
        )
        if proc.returncode != 0:
            print(proc.stderr[-2000:])
            continue
        rows[row] = json.loads(proc.stdout.strip().splitlines()[-1])
        print(row, f"{rows[row]['total_s']:.1f} s", rows[row]["reference"], flush=True)
        write_results(name, rows, report(rows), env=env)


def rows_main(name: str, script: str, rows, one, report, doc: str, argv=None) -> None:
    """The command line of a benchmark of `rows` (`run_rows`): ``--rows A,B`` (default
    all), and the hidden ``--one ROW`` its child processes run."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--rows", default=",".join(rows))
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    run_rows(name, script, args.rows, one, report, args.one)


def judge(image, goal) -> dict:
    """A design's image against its target, both at unit mean: relative L2, 1 - SSIM
    (scikit-image) and the fraction of the flux on pixels where the target is below 5%
    of its mean (``l2``, ``ssim``, ``dark``)."""
    import numpy as np
    from skimage.metrics import structural_similarity

    a = image / image.mean()
    b = goal / goal.mean()
    return dict(
        l2=float(np.linalg.norm(a - b) / np.linalg.norm(b)),
        ssim=float(1 - structural_similarity(a, b, data_range=float(b.max()))),
        dark=float(a[b < 0.05].sum() / a.sum()),
    )


def pick(parser, text: str, known, what: str) -> list[str]:
    """The comma-separated names in `text`; `parser.error` if one is not in `known`."""
    names = [n for n in text.split(",") if n]
    unknown = [n for n in names if n not in known]
    if unknown:
        parser.error(f"unknown {what} {unknown}; known: {list(known)}")
    return names


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
