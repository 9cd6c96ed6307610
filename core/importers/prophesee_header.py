"""The text header of a Prophesee / Metavision recording (``%`` lines before the event words), and what is wrong
with a file that has none.

faery reads the header (format version, sensor size, DAT event type); this module says what the library cannot:
a file that is empty, has no ``%`` header at all (random bytes, another format), names no format version, or
lacks only the sensor size (then the sensor the header names gives it, :mod:`evpose.core.importers.prophesee_sensors`,
or ``--width/--height``). It also reads the header's ``t0`` (µs
added to every time, as faery does) and the header's length in bytes, and warns about a last word cut off.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.prophesee_sensors import size_from_header
from evpose.core.importers.report import ImportContext

#: Bytes per event word of each version; DAT has 2 more header bytes (event type and size) before them.
WORD_BYTES = {"evt2": 4, "evt3": 2, "dat1": 8, "dat2": 8}
_MAX_HEADER_BYTES = 1 << 20
_NOT_PROPHESEE = "not a Prophesee EVT 2.0 / EVT 3.0 or DAT recording"


@dataclass
class Header:
    """What the header says: ``version`` (evt2, evt3, dat1, dat2), ``size`` (width, height) in pixels,
    ``length`` (bytes of ``%`` lines), ``t0_us`` (µs added to every time) and ``payload`` (byte offset of the
    first event word)."""

    version: str
    size: tuple[int, int]
    length: int
    t0_us: int
    payload: int


def _raw_header_lines(rec: Path) -> list[bytes]:
    """The ``%`` lines at the start of ``rec``, as read (line ends included), at most ``_MAX_HEADER_BYTES``."""
    out, n = [], 0
    with open(rec, "rb") as f:
        while n < _MAX_HEADER_BYTES:
            line = f.readline(_MAX_HEADER_BYTES)
            if not line.startswith(b"%"):
                break
            n += len(line)
            out.append(line)
    return out


def read_text_header(rec: Path) -> tuple[int, int]:
    """``(length in bytes, t0 in µs)`` of the ``%`` lines at the start of ``rec``; refuses an empty file and one
    without such lines."""
    lines, t0 = _raw_header_lines(rec), 0
    for line in lines:
        words = line[1:].replace(b";", b" ").split()
        if len(words) > 1 and words[0] in (b"t0", b"T0") and words[1].isdigit():
            t0 = int(words[1])
    if not lines:
        what = "empty file (0 bytes)" if os.path.getsize(rec) == 0 else "no '%' header line at its start"
        raise ImportFailure(rec, "(header)", "-", f"{what}: {_NOT_PROPHESEE}")
    return sum(len(line) for line in lines), t0


def header_lines(rec: Path) -> list[str]:
    """The ``%`` lines at the start of ``rec`` (decoded as Latin-1, without line ends)."""
    return [line.decode("latin-1").rstrip("\r\n") for line in _raw_header_lines(rec)]


def open_decoder(rec: Path, ctx: ImportContext):
    """``(faery decoder, Header)``; the size from the header, else ``--width/--height``."""
    length, t0 = read_text_header(rec)
    opts = ctx.options
    fallback = (int(opts.width), int(opts.height)) if opts.width and opts.height else None
    is_dat = rec.suffix.lower() == ".dat"
    try:
        d = _faery_decoder(rec, is_dat, fallback)
    except _MissingSize:
        if not _has_version(rec, is_dat):
            raise _no_version(rec) from None
        named = size_from_header(header_lines(rec))
        if named is None:
            raise ImportFailure(rec, "(header)", "geometry", "the header gives no sensor size ('% geometry WxH', "
                                "'% format ...;width=W;height=H' or '% Width' and '% Height') and names no sensor "
                                "whose size is known (plugin_name, sensor_name, sensor_generation): pass --width and "
                                "--height") from None
        (w, h), line = named
        ctx.report.assume(f"{rec.name}: sensor {w}x{h} px from the header's '{line}' (it has no geometry line; "
                          "--width/--height override)")
        d = _faery_decoder(rec, is_dat, (w, h))
    except _MissingVersion:
        raise _no_version(rec) from None
    version, size = d.version, d.dimensions
    if is_dat and d.event_type not in ("cd", "2d"):
        raise ImportFailure(rec, "(header)", "event type", f"{d.event_type} events, not CD (change detection) events")
    if version not in WORD_BYTES:
        raise ImportFailure(rec, "(header)", "format", f"{version} is not supported (EVT 2.0, EVT 3.0 or DAT)")
    return d, Header(version, (int(size[0]), int(size[1])), length, t0, length + (2 if is_dat else 0))


def _no_version(rec: Path) -> ImportFailure:
    return ImportFailure(rec, "(header)", "version", f"the header names no format version: {_NOT_PROPHESEE}")


def _has_version(rec: Path, is_dat: bool) -> bool:
    """Whether faery finds a format version in the header (asked with a dummy sensor size)."""
    try:
        with _faery_decoder(rec, is_dat, (1, 1)):
            return True
    except _MissingVersion:
        return False


class _MissingSize(Exception):
    pass


class _MissingVersion(Exception):
    pass


def _faery_decoder(rec: Path, is_dat: bool, fallback):
    """faery's decoder of ``rec`` (it reads the header); its refusals as one-line ImportFailures, a missing size or
    version as the private exceptions above."""
    from faery.extension import dat, evt

    try:
        return (dat if is_dat else evt).Decoder(str(rec), fallback, None)
    except BaseException as exc:  # noqa: BLE001 - faery's Rust errors (and panics) become one line
        if not isinstance(exc, Exception) and type(exc).__name__ != "PanicException":
            raise
        msg = " ".join(str(exc).split())
        if "no size information" in msg:
            raise _MissingSize() from None
        if "no version information" in msg:
            raise _MissingVersion() from None
        raise ImportFailure(rec, "(header)", "-", f"not a readable Prophesee recording ({msg})") from None


def warn_partial_word(ctx: ImportContext, rec: Path, head: Header) -> None:
    """A warning when the payload does not end on a whole word (a recording stopped mid-write)."""
    payload = os.path.getsize(rec) - head.payload
    extra = payload % WORD_BYTES[head.version] if payload > 0 else 0
    if extra:
        ctx.report.warn(f"{rec.name}: the last {extra} byte(s) are not a whole {WORD_BYTES[head.version]}-byte "
                        f"{head.version.upper()} word (recording cut off?); ignored")
