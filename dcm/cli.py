"""Helpers shared by the command-line entry points, so that a user's mistake ends in one clear line.

* :func:`one_line`, :func:`error_line` and :func:`print_error` state a user error as the one ``error: ...``
  line every command ends with, whatever line breaks the message holds;
* :func:`resolve_device` turns a ``device=`` setting into a ``torch.device`` and refuses a device this machine
  does not have (instead of a CUDA traceback deep inside the first forward pass);
* :func:`load_json` reads a JSON file and reports a syntax error as ``file, line L, column C: ...``;
* :func:`config_diff` lists the settings that differ between two configurations, e.g. ``seed: 0 -> 3``;
* :func:`quiet_libraries` keeps library chatter out of an entry point's output;
* :func:`to_run_log` copies a line that ends a run (its error) into the run directory's log file;
* :func:`one_line_warnings` shows each warning as one ``warning: <Category>: <message>`` line on stderr, also
  in the run's log;
* the ``${dcm.config_groups:a,b}`` resolver lists config groups and their options for an entry's ``--help``
  (``conf/hydra/help/``), so it shows the groups that entry composes rather than every folder of ``conf/``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"  # the Hydra configs of the entry points
DEVICE_CHOICES = "auto, cpu, cuda, cuda:<index> or mps"
# Loggers that report at INFO what no user acts on: PyOpenGL runs without its optional accelerator module,
# matplotlib rebuilt its font cache. Their warnings still show.
QUIET_LOGGERS = ("OpenGL.acceleratesupport", "matplotlib.font_manager")


class DeviceError(ValueError):
    """A requested device is unknown or not present on this machine; names the option and the value."""


class JSONFileError(ValueError):
    """A JSON file that cannot be read or parsed; names the file, line and column."""


def resolve_device(name: str, option: str = "device") -> Any:
    """The ``torch.device`` for a setting (``auto``: cuda, else mps, else cpu).

    ``option`` is the setting's name as the user types it (``device``, ``trainer.accelerator`` ...) and appears
    in the error, e.g. ``device=cuda: CUDA is not available on this machine (torch <version>+cpu); use device=cpu
    or device=auto``.
    """
    import torch

    name = str(name).strip().lower()
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        return torch.device("mps" if _mps_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise DeviceError(f"{option}={name}: not a device; use {DEVICE_CHOICES}") from None
    if device.type not in ("cpu", "cuda", "mps"):
        raise DeviceError(f"{option}={name}: unsupported device type {device.type!r}; use {DEVICE_CHOICES}")
    _check_present(device.type, device.index, option, name)
    return device


def check_accelerator(name: str, option: str = "trainer.accelerator") -> None:
    """Refuse a Lightning accelerator this machine does not have (``gpu``/``cuda``/``mps``; others pass)."""
    name = str(name).strip().lower()
    if name in ("gpu", "cuda", "mps"):
        _check_present("mps" if name == "mps" else "cuda", None, option, name)


def _mps_available() -> bool:
    import torch

    mps = getattr(torch.backends, "mps", None)
    return mps is not None and mps.is_available()


def _check_present(kind: str, index: int | None, option: str, value: str) -> None:
    import torch

    fallback = f"use {option}=cpu or {option}=auto"
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise DeviceError(f"{option}={value}: CUDA is not available on this machine (torch {torch.__version__}); "
                              f"{fallback}")
        count = torch.cuda.device_count()
        if index is not None and index >= count:
            raise DeviceError(f"{option}={value}: this machine has {count} CUDA device(s), cuda:0..cuda:{count - 1}")
    elif kind == "mps" and not _mps_available():
        raise DeviceError(f"{option}={value}: Apple MPS is not available on this machine; {fallback}")


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


def one_line(text: object) -> str:
    """``text`` with every run of whitespace, line breaks included, made one space: a wrapped exception or a
    file's own text would otherwise break the one-line promise of every command's errors and warnings."""
    return " ".join(str(text).split())


def error_line(problem: object) -> str:
    """``error: <problem>`` as the one line a refused command ends with."""
    return "error: " + one_line(problem)


def print_error(problem: object) -> int:
    """Print :func:`error_line` on stderr; returns 1, the exit status of a command refused on bad input."""
    print(error_line(problem), file=sys.stderr)
    return 1


def check_number(value: Any, key: str, error: type[Exception] = ValueError) -> float:
    """``value`` as a float if it is a finite number, else ``error`` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise error(f"{key} = {value!r} must be a finite number")
    return float(value)


def quiet_libraries() -> None:
    """Hush :data:`QUIET_LOGGERS` and send log lines to stderr, so stdout carries only an entry point's results.

    Call it first in a Hydra main: Hydra's console log shows INFO, on stdout.
    """
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)
    for handler in logging.getLogger().handlers:
        if type(handler) is logging.StreamHandler and handler.stream is sys.stdout:
            handler.setStream(sys.stderr)


def to_run_log(message: str, level: int = logging.ERROR) -> None:
    """Write ``message`` to the run's log files only (Hydra's ``<job>.log``), not to the console.

    An entry point prints its error on stderr and exits; without this the run directory it leaves behind
    has a log that ends as if nothing went wrong.
    """
    record = logging.LogRecord("dcm", level, __file__, 0, message, None, None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


def one_line_warnings() -> None:
    """Show every warning of this process as one line on stderr (``warning: <Category>: <message>``) and in the
    run's log files: Python's default adds the source line that raised it, which tells a user nothing."""
    import warnings

    def show(message: Any, category: type[Warning], filename: str, lineno: int, file: Any = None,
             line: str | None = None) -> None:
        text = f"warning: {category.__name__}: {one_line(message)}"
        print(text, file=sys.stderr if file is None else file)
        to_run_log(text, logging.WARNING)

    warnings.showwarning = show


def config_groups(*groups: str) -> str:
    """``group: option, option`` per line for the named folders of :data:`CONF_DIR`, as Hydra's help shows them."""
    return "\n".join(f"{group}: {', '.join(sorted(p.stem for p in (CONF_DIR / group).glob('*.yaml')))}"
                     for group in sorted(groups))


def run_dir_of(resume: str | None, fresh_dir: str) -> str:
    """Where an invocation writes its own config and log: ``fresh_dir``, or, when it resumes the existing run
    directory ``resume``, ``<resume>/resumed/<fresh_dir's name>``, so that resuming a run adds no directory
    elsewhere and leaves the run's own config record as it was."""
    if resume and Path(resume).is_dir():
        return str(Path(resume) / "resumed" / Path(fresh_dir).name)
    return fresh_dir


def _register_resolvers() -> None:
    from omegaconf import OmegaConf

    OmegaConf.register_resolver("dcm.config_groups", config_groups, replace=True)
    OmegaConf.register_resolver("dcm.run_dir_of", run_dir_of, replace=True)


_register_resolvers()
