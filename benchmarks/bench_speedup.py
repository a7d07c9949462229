"""Two-pass speed of this checkout against an older commit, measured in one run.

Each side runs its own ``bench_twopass.speed_table`` (N = 7, M = 6, 3 Newton steps, a
periodic sea at 30 degrees, float32: forward and gradient of a scalar loss, medians
after compilation) in a fresh process; the two sides alternate for `--rounds` rounds, so
that a drift of this machine's speed falls on both. The older commit is checked out into
a temporary git worktree (removed afterwards); each process imports its own side's
``jaxcaustics`` and says which file it imported.

Writes ``benchmarks/results/speedup.md`` and ``speedup.json``.

    python benchmarks/bench_speedup.py --against 4342f77      # the default sizes
    python benchmarks/bench_speedup.py --against HEAD --quick # tiny, to check it runs
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import RESULTS, ROOT, markdown, write_results  # noqa: E402

# run in a fresh process with the side's checkout first on the path
PROGRAM = """
import json, sys
root = sys.argv[1]
sys.path[:0] = [root, root + "/benchmarks"]
import warnings
warnings.simplefilter("ignore")
import bench_twopass, jaxcaustics
rows = bench_twopass.speed_table(json.loads(sys.argv[2]), int(sys.argv[3]))
print("ROWS", json.dumps({"rows": rows, "imported": jaxcaustics.__file__}))
"""


def measure(root: Path, sizes, repeats: int) -> dict:
    """One side's speed table, from a fresh process importing `root`'s package."""
    done = subprocess.run(
        [sys.executable, "-c", PROGRAM, str(root), json.dumps(sizes), str(repeats)],
        capture_output=True,
        text=True,
        check=True,
    )
    line = next(s for s in done.stdout.splitlines() if s.startswith("ROWS "))
    found = json.loads(line[5:])
    if not found["imported"].startswith(str(root)):
        raise RuntimeError(f"{root}: the process imported {found['imported']}")
    return found


def compare(old_root: Path, sizes, repeats: int, rounds: int) -> list[dict]:
    """Per size: each side's median over rounds of its forward and gradient medians, and
    the median over rounds of the per-round ratios old / new."""
    runs = {"old": [], "new": []}
    for k in range(rounds):
        for side, root in (("old", old_root), ("new", ROOT)):
            runs[side].append(measure(root, sizes, repeats)["rows"])
            print(f"round {k + 1} {side}: {runs[side][-1]}", flush=True)
    table = []
    for i, (cols, rows) in enumerate(sizes):

        def of(side, key, i=i):
            return np.array([run[i][key] for run in runs[side]])

        table.append(
            dict(
                size=f"{cols}x{rows}",
                old_fwd_ms=float(np.median(of("old", "fwd_ms"))),
                new_fwd_ms=float(np.median(of("new", "fwd_ms"))),
                fwd_speedup=float(np.median(of("old", "fwd_ms") / of("new", "fwd_ms"))),
                old_grad_ms=float(np.median(of("old", "grad_ms"))),
                new_grad_ms=float(np.median(of("new", "grad_ms"))),
                grad_speedup=float(np.median(of("old", "grad_ms") / of("new", "grad_ms"))),
                new_grad_over_fwd=float(np.median(of("new", "grad_ms") / of("new", "fwd_ms"))),
            )
        )
    return table


def git(*args) -> str:
    return subprocess.run(
        ["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True
    ).stdout.strip()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", required=True, help="the older commit (any git revision)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check it runs")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    sizes, repeats = ([(40, 30)], 3) if args.quick else ([(400, 300), (800, 600)], 15)
    rounds = 1 if args.quick else args.rounds
    old = git("rev-parse", "--short", args.against)
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "old"
        git("worktree", "add", "--detach", str(tree), old)
        try:
            table = compare(tree, sizes, repeats, rounds)
        finally:
            git("worktree", "remove", "--force", str(tree))
    text = [
        "# Two-pass speed against an older commit\n\n",
        f"This checkout against `{old}`, each running its own `bench_twopass.speed_table` "
        f"(N = 7, M = 6, 3 Newton steps, float32; medians of {repeats} calls after "
        f"compilation) in fresh processes, alternating for {rounds} rounds. Times are the "
        "median over rounds; speed-ups the median of the per-round ratios old / new.\n\n",
        markdown(
            table,
            list(table[0]),
            {k: "{:.1f}" if k.endswith("_ms") else "{:.2f}" for k in table[0] if k != "size"},
        ),
    ]
    write_results("speedup", table, "".join(text), dict(against=old, rounds=rounds), args.output)
    print("".join(text))


if __name__ == "__main__":
    main()
