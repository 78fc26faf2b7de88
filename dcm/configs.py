"""Reading a user's settings and files: the entry points' Hydra configs, JSON files whose syntax errors name
the line, the numbers a setting must hold, and the differences between two configurations (``seed: 0 -> 3``).
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from dcm.shipped import SHIPPED_ROOT

CONF_DIR = SHIPPED_ROOT / "conf"  # the Hydra configs of the entry points (the source tree's, or an install's copy)


class JSONFileError(ValueError):
    """A JSON file that cannot be read or parsed; names the file, line and column."""


def load_json(path: str | os.PathLike) -> Any:
    """Parse a JSON file; a syntax error becomes one line naming the file, line and column."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise JSONFileError(f"{path}: cannot read ({err.strerror or err})") from None
    except UnicodeDecodeError as err:
        raise JSONFileError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise JSONFileError(f"{path}, line {err.lineno}, column {err.colno}: invalid JSON ({err.msg})") from None


def flatten(config: Any, prefix: str = "") -> dict[str, Any]:
    """``{a: {b: 1}}`` -> ``{"a.b": 1}``; lists stay whole values."""
    if isinstance(config, Mapping):
        out: dict[str, Any] = {}
        for key, value in config.items():
            out.update(flatten(value, f"{prefix}{key}."))
        return out if out or not prefix else {prefix[:-1]: {}}
    return {prefix[:-1]: config}


def config_diff(old: Mapping[str, Any], new: Mapping[str, Any], ignore: Iterable[str] = (),
                limit: int = 6) -> list[str]:
    """``key: old -> new`` for every flattened setting that differs (``ignore`` lists keys or key prefixes)."""
    ignore = tuple(ignore)
    flat_old, flat_new = flatten(old), flatten(new)
    missing = object()
    lines = []
    for key in sorted(set(flat_old) | set(flat_new)):
        if any(key == i or key.startswith(f"{i}.") for i in ignore):
            continue
        a, b = flat_old.get(key, missing), flat_new.get(key, missing)
        if a != b:
            before, after = ("(absent)" if v is missing else _short(v) for v in (a, b))
            lines.append(f"{key}: {before} -> {after}")
    if len(lines) > limit:
        lines = [*lines[:limit], f"... {len(lines) - limit} more"]
    return lines


def _short(value: Any, width: int = 60) -> str:
    text = json.dumps(value, default=str) if isinstance(value, (list, dict)) else str(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def check_integer(value: Any, key: str, minimum: int, error: type[Exception] = ValueError, note: str = "") -> int:
    """``value`` if it is an integer >= ``minimum`` (bools and floats refused), else ``error`` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise error(f"{key} = {value!r} must be an integer >= {minimum}{note}")
    return value


def check_number(value: Any, key: str, error: type[Exception] = ValueError) -> float:
    """``value`` as a float if it is a finite number, else ``error`` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise error(f"{key} = {value!r} must be a finite number")
    return float(value)


def config_groups(*groups: str) -> str:
    """``group: option, option`` per line for the named folders of :data:`CONF_DIR`, as Hydra's help shows them."""
    return "\n".join(f"{group}: {', '.join(sorted(p.stem for p in (CONF_DIR / group).glob('*.yaml')))}"
                     for group in sorted(groups))


def group_choice_problem(argv: Iterable[str]) -> str | None:
    """What is wrong with the first ``group=option`` of a command line that names no file of its group (a folder
    of :data:`CONF_DIR`, or of a ``--config-dir``), in one line; None when every one exists. Hydra's own message
    for it spans a dozen lines and lists its search path."""
    argv = list(argv)
    dirs = [CONF_DIR]
    for i, arg in enumerate(argv):
        if arg == "--config-dir" and i + 1 < len(argv):
            dirs.append(Path(argv[i + 1]))
        elif arg.startswith("--config-dir="):
            dirs.append(Path(arg.split("=", 1)[1]))
    for arg in argv:
        group, sep, option = arg.partition("=")
        if not sep or not option or "," in option or group.startswith(("-", "+", "~")) or "/" in group or "." in group:
            continue  # not a group choice, or a sweep, an addition or a deletion: Hydra's own business
        folders = [d / group for d in dirs if (d / group).is_dir()]
        options = sorted({p.stem for folder in folders for p in folder.glob("*.yaml")})
        if options and option not in options:
            return f"{group}={option}: the {group} group has no option {option!r}; expected one of {', '.join(options)}"
    return None


def run_dir_of(resume: str | None, fresh_dir: str) -> str:
    """Where an invocation writes its own config and log: ``fresh_dir``, or, when it resumes the existing run
    directory ``resume``, ``<resume>/resumed/<fresh_dir's name>``, so that resuming a run adds no directory
    elsewhere and leaves the run's own config record as it was."""
    if resume and Path(resume).is_dir():
        return str(Path(resume) / "resumed" / Path(fresh_dir).name)
    return fresh_dir


def discard_resumed_dir(resume: str | None, output_dir: str | os.PathLike) -> None:
    """Remove the ``<resume>/resumed/<time>`` folder :func:`run_dir_of` gave an invocation that was refused, and
    ``resumed/`` if that empties it: a refused resume leaves the run it names as it was. A folder that holds more
    than Hydra's record (``.hydra/``) and the log is kept."""
    out = Path(output_dir)
    if not resume or not out.is_dir() or out.parent.resolve() != (Path(resume) / "resumed").resolve():
        return
    if all(p.name == ".hydra" or p.suffix == ".log" for p in out.iterdir()):
        shutil.rmtree(out)
        if not any(out.parent.iterdir()):
            out.parent.rmdir()


def register_resolvers() -> None:
    """Make ``${dcm.config_groups:...}`` (an entry's ``--help``) and ``${dcm.run_dir_of:...}`` (a resumed run's
    directory) resolvable; each Hydra entry calls it before Hydra reads its config."""
    from omegaconf import OmegaConf

    OmegaConf.register_resolver("dcm.config_groups", config_groups, replace=True)
    OmegaConf.register_resolver("dcm.run_dir_of", run_dir_of, replace=True)

