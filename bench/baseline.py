"""The code before issue 25 (the budget work), checked out beside this one, so that ``make bench`` measures
"before" and "after" in one run on one machine: a ratio of two figures taken hours apart on a shared machine
would measure the machine.

The baseline is a fixed commit of this repository's history, checked out once with ``git worktree`` under
``out/bench/baseline-src`` (a fresh clone has the history; a tarball without it cannot run the comparison and
says so). Its code runs with that checkout first on ``PYTHONPATH``: the installed dependencies are shared.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

__all__ = ["BASELINE_REF", "baseline_checkout", "python_env"]

# the last commit before the budget work (docs/performance.md): f19fd71, 2026-11-26
BASELINE_REF = "f19fd71"
REPO = Path(__file__).resolve().parent.parent


def baseline_checkout(out: Path = REPO / "out" / "bench" / "baseline-src") -> Path:
    """The baseline's source tree (checked out on the first call). RuntimeError naming the reason when this
    is not a git checkout holding :data:`BASELINE_REF`."""
    if (out / "vdm_aero").is_dir():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(out), BASELINE_REF],
                       capture_output=True, text=True, check=False)  # fmt: skip
    if r.returncode != 0:
        raise RuntimeError(f"the baseline {BASELINE_REF} cannot be checked out: {r.stderr.strip()}")
    return out


def python_env(tree: Path) -> dict[str, str]:
    """The environment that runs ``tree``'s packages with this interpreter's dependencies."""
    return {**os.environ, "PYTHONPATH": str(tree)}


def run_python(tree: Path, args: list[str]) -> str:
    """``python ARGS`` on ``tree``'s code; its stdout (RuntimeError with stderr's tail on failure)."""
    r = subprocess.run([sys.executable, *args], capture_output=True, text=True, check=False, env=python_env(tree),
                       cwd=tree)  # fmt: skip
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} on {tree}: {r.stderr[-2000:]}")
    return r.stdout
