"""What an entry point prints: a user's mistake as one ``error: ...`` line, warnings as one line each, and
library chatter kept off stdout, so that a command's output is its results and one line that says why it stopped.
"""

from __future__ import annotations

import logging
import sys
from typing import Any

# Loggers that report at INFO what no user acts on: PyOpenGL runs without its optional accelerator module,
# matplotlib rebuilt its font cache. Their warnings still show.
QUIET_LOGGERS = ("OpenGL.acceleratesupport", "matplotlib.font_manager")


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

