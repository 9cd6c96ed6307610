"""What a command prints on stdout: one JSON document with ``--json``, else its text summary.

DESIGN section 5: ``--json`` prints one JSON document on stdout and nothing else there. While a
command runs with ``--json`` (see :func:`evpose.app.cli.errors.command`), stdout is reserved: anything
else printed to it (a library's message, a stray ``print``) goes to stderr, and :func:`emit` writes the
document to the real stdout. Messages, warnings and progress always go to stderr.
"""
from __future__ import annotations

import contextlib
import json
import sys
from contextvars import ContextVar

__all__ = ["emit", "dumps", "stdout_reserved_for_json"]

#: The stream the JSON document goes to while stdout is reserved (None: not reserved).
_document_stream: ContextVar = ContextVar("evpose_cli_document_stream", default=None)


def dumps(data) -> str:
    """The document as evpose prints it (indent 1)."""
    from evpose.core.data.json_values import to_jsonable   # (building the parser loads no engine module)

    return json.dumps(data, indent=1, default=to_jsonable)


@contextlib.contextmanager
def stdout_reserved_for_json(enabled: bool):
    """While the block runs, stdout belongs to the one JSON document (when ``enabled``): anything else
    printed to ``sys.stdout`` goes to stderr; :func:`emit` writes to the stdout of the caller."""
    if not enabled:
        yield
        return
    token = _document_stream.set(sys.stdout)
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        _document_stream.reset(token)


def emit(args, data: dict, text: str) -> None:
    """Print the command's result: ``data`` as one JSON document with ``--json``, else ``text``."""
    if getattr(args, "json", False):
        out = _document_stream.get() or sys.stdout
        out.write(dumps(data) + "\n")
        out.flush()
    else:
        sys.stdout.write(text.rstrip() + "\n")
