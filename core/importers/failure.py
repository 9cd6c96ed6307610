"""The one error an importer lets out for bad input, and the guard that turns parser crashes into it.

A parser of a corrupt file fails in many ways (struct errors, assertions, zlib/zstd errors, absurd sizes);
:func:`wrap_errors` turns each of them into one :class:`ImportFailure` whose message names the file, the record
and the field, so that the user sees one clear line instead of a traceback.
"""
from __future__ import annotations

import contextlib
import errno

from evpose.core.data.events import Cancelled
from evpose.core.errors import InputError


class ImportFailure(InputError):
    """Bad input to an importer. ``file``, ``record`` (message index / line / row / window) and ``field``
    say where; ``str(exc)`` is ``"{file}: {record}: {field}: {message}"``."""

    def __init__(self, file, record: str, fld: str, message: str):
        self.file, self.record, self.field, self.reason = str(file), str(record), str(fld), str(message)
        super().__init__(f"{self.file}: {self.record}: {self.field}: {self.reason}")


#: errno values that only writing causes (full disk, quota, read-only file system): they pass through
#: :func:`wrap_errors` and end as an error about ``--out``, not about the input being parsed.
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})


def _one_line(exc: BaseException) -> str:
    """The exception's text on one line (parsers such as YAML's report over several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


@contextlib.contextmanager
def wrap_errors(file, record: str = "(file)", fld: str = "-", what: str = ""):
    """Turn any exception raised inside into :class:`ImportFailure` naming ``file``/``record``/``field``.

    :class:`ImportFailure`, :class:`Cancelled`, ``KeyboardInterrupt`` and ``SystemExit`` pass through.
    Parsers of corrupt files fail in many ways (struct errors, assertions, zlib/zstd errors, absurd sizes);
    all of them become one clear error here.
    """
    try:
        yield
    except (ImportFailure, Cancelled):
        raise
    except OSError as exc:
        if exc.errno in _WRITE_ERRNOS:     # the output is full or read-only: not the input's fault
            raise
        msg = _one_line(exc)
        raise ImportFailure(file, record, fld, f"{what + ': ' if what else ''}{msg} ({type(exc).__name__})") from None
    except MemoryError:
        raise ImportFailure(file, record, fld, f"{what or 'data'} claims an impossible size (out of memory)") from None
    except RecursionError:
        raise ImportFailure(file, record, fld, f"{what or 'data'} is nested too deeply") from None
    except Exception as exc:  # noqa: BLE001 - the point is to catch everything a corrupt file can cause
        msg = _one_line(exc)
        if what:
            msg = f"{what}: {msg}"
        raise ImportFailure(file, record, fld, f"{msg} ({type(exc).__name__})") from None
