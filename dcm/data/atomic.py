"""Atomic file writes: a reader sees the old file or the complete new one, never a partial write."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    """The process's file-creation mask (reading it means setting it; restored at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_problem(target: str | os.PathLike) -> str | None:
    """Why :func:`atomic_path` could not write ``target`` (None: it could), for a check before long work, so the
    work is not lost at the end. Creates ``target``'s folder, as the write would, and a file in it that is gone
    at once: permissions alone do not tell (a read-only file system, or root)."""
    path = Path(target)
    if path.is_dir():
        return f"{path} is a directory"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as err:
        return f"{path.parent} is not a writable directory ({err.strerror or err})"
    return None


@contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; when the block succeeds, fsync it and rename it onto
    ``target`` (``os.replace`` is atomic within a directory). On any error the temporary file is removed."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        # mkstemp makes the file private (0600); give it the mode a plain open() would, or the replaced file's,
        # so that a dataset written on a shared file system stays readable by the team.
        os.chmod(tmp, target.stat().st_mode & 0o7777 if target.exists() else 0o666 & ~_umask())
        yield Path(tmp)
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
