"""The container layout of an AEDAT4 file, checked before ``dv-processing`` reads it (:func:`scan_layout`).

An AEDAT 4.0 file is: the version line ``#!AER-DAT4.0\\r\\n``; an int32 size and the ``IOHeader`` flatbuffer
(compression, ``dataTablePosition`` int64 -- the byte offset of the packet table, -1 when the file has none --,
and the XML description of the streams); the packets, each an int32 stream id, an int32 size and that many bytes;
then, at ``dataTablePosition``, the packet table DV writes when it closes the file.

``dv-processing`` reads the packets through that table and never compares a packet's own size with the file, and
it refuses a file whose table was cut off. So the packet headers are walked here first (one 8-byte read per
packet): every declared size must fit in the file and the packets must end exactly where the table starts.
A file cut off at the end (the table gone, the last packet partial) is readable up to the cut: :class:`Layout`
says where the complete packets end, and :class:`~evpose.core.importers.aedat4_copy.ReadableCopy` writes a copy of
the file up to there with ``dataTablePosition = -1``, which ``dv-processing`` reads by scanning the packets (as it
reads a recording that was interrupted before DV wrote the table).

The ``IOHeader`` is read with a few ``struct`` calls (flatbuffers: root offset, vtable, field 1 of the table),
for the one field needed; ``dv-processing`` verifies the rest.
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

from evpose.core.importers.failure import ImportFailure

MAGIC = b"#!AER-DAT4.0\r\n"
#: An IOHeader is a few KB (compression, table position, the streams' XML): a larger size is corrupt.
MAX_IO_HEADER = 1 << 24
_PACKET = struct.Struct("<ii")
#: Index of ``dataTablePosition`` among the IOHeader table's fields (compression, dataTablePosition, infoNode).
_TABLE_FIELD = 1


@dataclass
class Layout:
    """Where things are in the file (byte offsets).

    ``first_packet``: the first packet header; ``packets_end``: the end of the last complete packet;
    ``n_packets``: complete packets; ``table_position``: ``dataTablePosition`` as written (-1: none) and
    ``table_field``: where that int64 is in the file (None: the field is absent, i.e. -1); ``cut``: a
    description of what is missing when the file is cut off, else None; ``file_size``.
    """

    first_packet: int
    packets_end: int
    n_packets: int
    table_position: int
    table_field: int | None
    cut: str | None
    file_size: int

    @property
    def table_usable(self) -> bool:
        """The packet table lies inside the file (dv-processing will read the packets through it)."""
        return 0 <= self.table_position < self.file_size


def _io_header_table_field(buf: bytes, at: int) -> tuple[int | None, int]:
    """``(file offset of dataTablePosition or None, its value)`` in the IOHeader flatbuffer ``buf`` that starts at
    file offset ``at``; ``struct.error`` when ``buf`` is too short for what it claims."""
    root = struct.unpack_from("<I", buf, 0)[0]
    vtable = root - struct.unpack_from("<i", buf, root)[0]
    vt_bytes = struct.unpack_from("<H", buf, vtable)[0]
    slot = 4 + 2 * _TABLE_FIELD
    field = struct.unpack_from("<H", buf, vtable + slot)[0] if slot + 2 <= vt_bytes else 0
    if field == 0:
        return None, -1
    return at + root + field, struct.unpack_from("<q", buf, root + field)[0]


def scan_layout(path: Path) -> Layout:
    """Check the version line, the IOHeader size and every packet header of ``path`` against the file size.

    Raises
    ------
    ImportFailure
        Naming the file, the record (``(header)`` or ``packet N at byte B``) and the field, when a declared size
        does not fit the file or the packets do not end where the table starts.
    """
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    try:
        size = os.fstat(fd).st_size
        first, field, table = _header(path, fd, size)
        return _walk_packets(path, fd, size, first, field, table)
    finally:
        os.close(fd)


def _header(path: Path, fd: int, size: int) -> tuple[int, int | None, int]:
    """``(first packet offset, dataTablePosition field offset or None, dataTablePosition)``."""
    head = os.pread(fd, len(MAGIC) + 4, 0)
    if size == 0 or not head.startswith(MAGIC):
        what = "empty file (0 bytes)" if size == 0 else f"it does not start with {MAGIC[:-2].decode()!r}"
        raise ImportFailure(path, "(header)", "version", f"{what}: not an AEDAT 4.0 file")
    if len(head) < len(MAGIC) + 4:
        raise ImportFailure(path, "(header)", "IOHeader size", f"the file ends after {size} bytes, inside the header")
    n_head = struct.unpack_from("<i", head, len(MAGIC))[0]
    first = len(head) + n_head
    if not 0 < n_head <= MAX_IO_HEADER or first > size:
        raise ImportFailure(path, "(header)", "IOHeader size", f"declares {n_head:,} bytes; the file has "
                            f"{size - len(head):,} after the size field")
    try:
        field, table = _io_header_table_field(os.pread(fd, n_head, len(head)), len(head))
    except struct.error:
        raise ImportFailure(path, "(header)", "IOHeader", "the header's flatbuffer points outside itself "
                            "(corrupt header)") from None
    return first, field, table


def _walk_packets(path: Path, fd: int, size: int, first: int, field: int | None, table: int) -> Layout:
    """Every packet header from ``first`` to the packet table (or the file end when the table is not in the
    file), one ``pread`` of 8 bytes each."""
    end = table if 0 <= table < size else size
    pos, n, cut = first, 0, None
    while pos < end:
        where = f"packet {n} at byte {pos:,}"
        if pos + _PACKET.size > end:
            if end != size:
                raise ImportFailure(path, where, "size", f"the packets end {end - pos} byte(s) before the packet "
                                    f"table at byte {end:,}, too few for a packet")
            cut = f"the file ends {end - pos} byte(s) into the header of packet {n} (byte {pos:,})"
            break
        stream, n_bytes = _PACKET.unpack(os.pread(fd, _PACKET.size, pos))
        if stream < 0 or n_bytes <= 0:
            raise ImportFailure(path, where, "stream id" if stream < 0 else "size",
                                f"{stream if stream < 0 else n_bytes} (corrupt packet header)")
        if pos + _PACKET.size + n_bytes > end:
            if end != size:                  # the table is in the file: a wrong size, not a cut
                raise ImportFailure(path, where, "size", f"declares {n_bytes:,} bytes, past the packet table at "
                                    f"byte {end:,} (file size {size:,})")
            cut = f"{where} declares {n_bytes:,} bytes; the file ends {size - pos - _PACKET.size:,} bytes into it"
            break
        pos += _PACKET.size + n_bytes
        n += 1
    if cut is None and table >= size:
        cut = f"the packet table (at byte {table:,}) is missing"
    return Layout(first, pos, n, table, field, cut, size)
