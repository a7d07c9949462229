"""Running a test script in a fresh Python process (for example with several simulated
CPU devices, which XLA fixes when JAX starts: the script sets ``XLA_FLAGS`` itself)."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def run_python(tmp_path, source: str, *args: str, timeout: float = 900) -> str:
    """Run `source` as a script in `tmp_path` with the repository importable and JAX on
    the CPU; assert it exits 0 (showing the end of its stderr otherwise) and return its
    stdout."""
    script = tmp_path / "script.py"
    script.write_text(source)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["JAX_PLATFORMS"] = "cpu"
    result = subprocess.run(
        [sys.executable, str(script), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    return result.stdout
