"""The project's own error types: one clear message naming the file or key at fault; and the one
line every entry point (stage, study, ``msdepth`` command) prints for an exception no check foresaw,
its traceback written to a log file (:func:`unexpected_error`, :func:`run_main`)."""

from __future__ import annotations

import os
import re
import sys
import tempfile
import traceback
from typing import Callable, Sequence


class MsdepthError(Exception):
    """Base class of every error this package raises on purpose."""


class DataError(MsdepthError):
    """An input file is missing, unreadable or of the wrong shape/type (the message names it)."""


class ConfigError(MsdepthError):
    """A parameter in params.yaml has the wrong type or is out of range (the message names the key)."""


class PixelLimitError(DataError):
    """An image's header declares more pixels than the limit of the command reading it."""


class OutputError(MsdepthError):
    """An output may not be written where asked: it would replace an input, the model or a file the
    command did not write, two inputs map to it, or the output folder is not usable (it names the path)."""


# Where unexpected_error writes its log files: the system's temp folder unless this names another
# (never the working directory: a stage runs in the repository, whose tree DVC and git watch).
LOG_DIR_ENV = "MSDEPTH_LOG_DIR"
_SHOWN = 200  # characters of an exception's message, or of the arguments, in the one line


def _printable(text: str) -> str:
    """``text`` on one line, cut to :data:`_SHOWN` characters, with control and other unprintable
    characters escaped (a file name in the message must not move the terminal's cursor)."""
    flat = " ".join(text.split())
    shown = "".join(c if c.isprintable() else ascii(c)[1:-1] for c in flat)
    return shown if len(shown) <= _SHOWN else shown[: _SHOWN - 3] + "..."


def unexpected_error(command: str, exc: BaseException, argv: Sequence[str] = ()) -> str:
    """The one line an entry point prints for an exception no check foresaw (a bug, not a bad input):
    ``error: <command> <arguments>: unexpected <type>: <message>; traceback in <log file>``.

    The full traceback goes to a new file in :data:`LOG_DIR_ENV`'s folder (default: the system's
    temp folder), whose path the line names; if it cannot be written, the line says so instead.
    """
    try:
        fd, log = tempfile.mkstemp(
            prefix=f"msdepth-{re.sub(r'[^A-Za-z0-9_.-]+', '-', command)}-",
            suffix=".log",
            dir=os.environ.get(LOG_DIR_ENV) or None,
        )
        with os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace") as file:
            file.write(f"{command} {' '.join(argv)}\n{''.join(traceback.format_exception(exc))}")
        where = f"traceback in {log}"
    except OSError as err:
        where = f"its traceback could not be written ({err.strerror or err})"
    called = _printable(" ".join([command, *argv]))
    message = _printable(str(exc))
    return f"error: {called}: unexpected {type(exc).__name__}{': ' + message if message else ''}; {where}"


def run_main(command: str, main: Callable[[], int | None]) -> int | None:
    """``main()``'s exit code, for a script's ``sys.exit``: a MsdepthError it raises is its one line
    (``error: <message>``, exit 1), any other Exception :func:`unexpected_error`'s (exit 1).
    KeyboardInterrupt and SystemExit (argparse's usage errors, ``--help``) pass through."""
    try:
        return main()
    except MsdepthError as exc:
        print(f"error: {' '.join(str(exc).splitlines())}", file=sys.stderr)  # its own words, one line
        return 1
    except Exception as exc:  # the top of an entry point: one line, the traceback in a log file
        print(unexpected_error(command, exc, sys.argv[1:]), file=sys.stderr)
        return 1
