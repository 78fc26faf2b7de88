"""The files dcm ships with: the Hydra configs (``conf/``), the shipped models (``models/``), the example demos
(``data/demos/``) and waypoints (``data/waypoints/``).

In a clone (and its editable install) they are the source tree's top-level folders. A wheel, or ``pip install .``,
carries a copy of them under ``dcm/_shipped/`` (copied at build time by setup.py), since an installed package has
no source tree. Either way :data:`SHIPPED_ROOT` holds them at the same relative paths, so ``models/x.ckpt`` names
the same file in both.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

_PACKAGE = Path(__file__).resolve().parent
_BUNDLED = _PACKAGE / "_shipped"
INSTALLED = _BUNDLED.is_dir()  # a built install (wheel): no source tree around the package
SHIPPED_ROOT = _BUNDLED if INSTALLED else _PACKAGE.parent
SHIPPED_DIRS = ("conf", "models", "data/demos", "data/waypoints")  # what a relative path may name in SHIPPED_ROOT


def shipped_path(path: str | os.PathLike) -> str:
    """A user's file path, resolved as a user expects: as given when it exists from the working directory (or is
    absolute), else the shipped copy when it names a shipped file (``models/dcm_diverse_contact.ckpt``,
    ``data/waypoints/example.csv``). Anything else is returned as given, so its error names what the user typed,
    and a user's own file is never replaced by a shipped one."""
    given = Path(path)
    if given.is_absolute() or given.exists():
        return str(path)
    relative = given.as_posix()
    candidate = SHIPPED_ROOT / given
    if any(relative.startswith(f"{folder}/") for folder in SHIPPED_DIRS) and candidate.is_file():
        return str(candidate)
    return str(path)


FILE_SETTINGS = ("ckpt", "prior", "reference", "demo_file", "init_from")  # the entries' settings that name an input file


def with_shipped_paths(cfg: Any, keys: Iterable[str] = FILE_SETTINGS) -> Any:
    """``cfg`` (an OmegaConf config) with each set file setting of ``keys`` (dotted; absent ones skipped) resolved
    by :func:`shipped_path`, in place; a setting that resolves to itself is left as written. (A waypoint file is
    resolved where it is read, since a demo spec names it from many places.)"""
    from omegaconf import OmegaConf

    for key in keys:
        value = OmegaConf.select(cfg, key, default=None, throw_on_missing=False)
        if isinstance(value, str) and value and (resolved := shipped_path(value)) != value:
            OmegaConf.update(cfg, key, resolved, merge=False)
    return cfg


def work_root() -> Path:
    """Where a file that a command writes by default (``data/<preset>.h5``) goes: the source tree in a clone, as
    the guides' commands assume; the working directory of an installed package, never site-packages."""
    return Path.cwd() if INSTALLED else SHIPPED_ROOT
