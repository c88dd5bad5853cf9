"""Atomic replacement of a directory: every writer (data sets, models, flight logs) builds its output in a
sibling temporary directory and moves it into place here, so a reader never sees a half-written one."""

from __future__ import annotations

import os
import shutil
import uuid
from pathlib import Path

__all__ = ["install_directory"]


def install_directory(tmp: Path, dest: Path) -> None:
    """Move the finished directory ``tmp`` to ``dest``, replacing an existing ``dest`` (restored if the move
    fails)."""
    if not (dest.exists() or dest.is_symlink()):
        os.rename(tmp, dest)
        return
    old = dest.parent / f".{dest.name}.old-{uuid.uuid4().hex[:12]}"
    os.rename(dest, old)
    try:
        os.rename(tmp, dest)
    except OSError:
        os.rename(old, dest)
        raise
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old, ignore_errors=True)
    else:
        old.unlink(missing_ok=True)
