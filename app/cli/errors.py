"""Exit codes and error lines of the ``evpose`` command: the one place that turns an exception into
one line on stderr and an exit status.

Every command handler is wrapped by :func:`command`, so ``args.func(args)`` always returns an exit
status (tests call it directly) and ``main`` does nothing but parse and dispatch:

- bad input the user can fix -- any :class:`evpose.core.errors.InputError` (every reader and writer
  raises one, naming the file and the field), :class:`CliError` for options, and a path that is
  missing, exists already or is not a folder -- ``evpose CMD: error: MESSAGE``, exit :data:`EXIT_BAD_INPUT`;
- the system refused a read or write (full disk, read-only file system, permission): the line names
  the path (:func:`evpose.core.data.os_errors.describe_os_error`), exit :data:`EXIT_OS_ERROR`;
- Ctrl-C or a cancelled job: ``evpose CMD: interrupted`` (or the command's own hint), exit
  :data:`EXIT_INTERRUPTED`.

Anything else escapes with its traceback: it is a bug, not a user error. Importing this module is
cheap (no numpy): the heavy modules are imported only on the error path.
"""
from __future__ import annotations

import functools
import sys
from typing import Callable

from evpose.app.cli.json_output import stdout_reserved_for_json
from evpose.core.errors import InputError

__all__ = ["EXIT_OK", "EXIT_OS_ERROR", "EXIT_BAD_INPUT", "EXIT_PARTIAL", "EXIT_INTERRUPTED", "CliError", "command", "error_line",
           "exit_status"]

EXIT_OK = 0
#: The system refused a write or a read (full disk, read-only file system, permission).
EXIT_OS_ERROR = 1
#: Bad input: a file, a field or an option (also argparse's own status for a bad command line).
EXIT_BAD_INPUT = 2
#: A dataset command where some scenes failed (each named in ``failed`` and on stderr); the others completed.
EXIT_PARTIAL = 3
#: Interrupted (Ctrl-C, 128 + SIGINT) or cancelled.
EXIT_INTERRUPTED = 130

#: ``OSError`` subclasses that mean a wrong path on the command line rather than a refusing system.
PATH_ERRORS = (FileNotFoundError, FileExistsError, NotADirectoryError)


class CliError(InputError):
    """A bad option or argument of the command line (the message names the option)."""


def _is_cancelled(exc: BaseException) -> bool:
    """``exc`` is a :class:`evpose.core.data.events.Cancelled` (raised only once that module is loaded,
    so it is never imported here)."""
    events = sys.modules.get("evpose.core.data.events")
    return events is not None and isinstance(exc, events.Cancelled)


def exit_status(exc: BaseException, *, interrupted: str = "interrupted",
                cancelled: str | None = None) -> tuple[int, str] | None:
    """The exit status and message of an exception a command let escape; None for a bug.

    Parameters
    ----------
    exc : BaseException
        What the command raised.
    interrupted : str
        Message for Ctrl-C (``KeyboardInterrupt``).
    cancelled : str, optional
        Message for :class:`evpose.core.data.events.Cancelled`; default: the exception's own text.
    """
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED, interrupted
    if isinstance(exc, InputError):
        return EXIT_BAD_INPUT, f"error: {exc}"
    if isinstance(exc, OSError):
        from evpose.core.data.os_errors import describe_os_error

        if isinstance(exc, PATH_ERRORS):
            return EXIT_BAD_INPUT, f"error: {describe_os_error(exc) if exc.filename is not None else exc}"
        return EXIT_OS_ERROR, f"error: {describe_os_error(exc)}"
    if _is_cancelled(exc):
        return EXIT_INTERRUPTED, cancelled if cancelled is not None else str(exc)
    return None


def error_line(name: str, message: str) -> str:
    """The one line a command prints on stderr: ``evpose NAME: MESSAGE``."""
    return f"evpose {name}: {message}"


def command(name: str, *, interrupted: str = "interrupted", cancelled: str | None = None) -> Callable:
    """Wrap the handler of ``evpose NAME``: it returns the exit status (0 when the handler returns None),
    prints one error line for the exceptions of :func:`exit_status`, and with ``--json`` reserves
    stdout for the one JSON document (see :mod:`evpose.app.cli.json_output`)."""

    def wrap(handler: Callable) -> Callable:
        @functools.wraps(handler)
        def run(args) -> int:
            try:
                with stdout_reserved_for_json(bool(getattr(args, "json", False))):
                    return int(handler(args) or EXIT_OK)
            except BaseException as exc:       # noqa: BLE001 -- classified below; bugs are re-raised
                status = exit_status(exc, interrupted=interrupted, cancelled=cancelled)
                if status is None:
                    raise
                print(error_line(name, status[1]), file=sys.stderr)
                return status[0]

        return run

    return wrap
