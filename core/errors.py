"""The one base class of every error a user can cause with bad input.

Every reader and writer of evpose raises a subclass of :class:`InputError` whose message names the
file and the field (or the option) at fault; frontends (the CLI, the app) catch ``InputError`` and
show the message as one line, without a traceback. Anything else that escapes is a bug.
"""
from __future__ import annotations


class InputError(ValueError):
    """Bad input the user can fix: the message names the file and the field (or the option)."""


class NotOursError(InputError, FileExistsError):
    """An output folder holds something evpose may not remove (the message names it)."""
