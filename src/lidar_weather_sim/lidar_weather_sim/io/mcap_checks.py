"""Checksums and time-bounded chunks for the MCAP files of our rosbag2 recordings.

rosbags' MCAP writer leaves every CRC at 0 ("not computed") and closes a chunk only at 1 MiB, so a
flipped bit goes unnoticed and a killed writer loses up to a MiB of data, however long that took
to record. :func:`checksum_chunks` hooks a writer's storage (rosbags' ``McapWriter``) so that
each chunk record carries the CRC-32 of its uncompressed records, a chunk holds at most
:data:`CHUNK_SPAN_NS` of log time (it is closed before a message that would make it longer) and
is flushed to the OS when closed: a SIGKILL loses at most that span. :func:`seal` writes the
summary CRC into the footer after the file is closed. Readers: rosbags checks chunk CRCs when
they are set; :func:`check_summary` checks the summary CRC (cheap: the summary is small) and
:func:`first_damage` walks the records to name the offset of the first one that is broken.

Record layout (MCAP specification): opcode (1 byte), length (uint64 LE), body. A chunk body
starts with message_start_time, message_end_time, uncompressed_size (uint64 each) and
uncompressed_crc (uint32); the footer body is summary_start, summary_offset_start (uint64) and
summary_crc (uint32), the CRC-32 of the bytes from summary_start through summary_offset_start.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

try:  # the zstd rosbags reads compressed chunks with
    from compression import zstd
except ImportError:  # Python < 3.14
    from backports import zstd

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_CHUNK = 0x02, 0x06
FOOTER_RECORD = 1 + 8 + 20  # opcode, length, body
CHUNK_CRC_AT = 1 + 8 + 24  # from the chunk record's opcode
#: A chunk holds at most this much log time (ns): a killed writer loses at most this span.
CHUNK_SPAN_NS = 500_000_000


def checksum_chunks(storage) -> None:
    """Make rosbags' MCAP storage writer ``storage`` write chunk CRCs and chunks of at most
    :data:`CHUNK_SPAN_NS` of log time, flushed when closed (see the module doc)."""
    close_chunk, write = storage.close_chunk, storage.write

    def close_with_crc() -> None:
        crc = zlib.crc32(storage.chunk.bio.getvalue())
        start = storage.bio.tell()
        close_chunk()
        end = storage.bio.tell()
        storage.bio.seek(start + CHUNK_CRC_AT)
        storage.bio.write(struct.pack("<I", crc))
        storage.bio.seek(end)
        storage.bio.flush()

    def write_in_span(connection, timestamp: int, data) -> None:
        chunk = storage.chunk
        if chunk.msgs and max(chunk.message_end_time, timestamp) - min(chunk.message_start_time, timestamp) > CHUNK_SPAN_NS:
            storage.close_chunk()
        write(connection, timestamp, data)

    storage.close_chunk, storage.write = close_with_crc, write_in_span


def _footer(stream) -> tuple[int, int, int, int]:
    """(footer offset, summary_start, summary_offset_start, summary_crc) of an MCAP with a footer."""
    size = stream.seek(0, 2)
    at = size - len(MAGIC) - FOOTER_RECORD
    stream.seek(at)
    raw = stream.read(FOOTER_RECORD)
    if at < len(MAGIC) or raw[0] != OP_FOOTER:
        raise ValueError("no footer record before the closing magic")
    summary_start, offset_start, crc = struct.unpack("<QQI", raw[9:])
    return at, summary_start, offset_start, crc


def _summary_crc(stream, footer_at: int, summary_start: int) -> int:
    stream.seek(summary_start)
    return zlib.crc32(stream.read(footer_at + FOOTER_RECORD - 4 - summary_start))


def seal(file: Path) -> None:
    """Write the summary CRC of a closed MCAP ``file`` into its footer."""
    with file.open("r+b") as stream:
        footer_at, summary_start, _, _ = _footer(stream)
        if summary_start:
            crc = _summary_crc(stream, footer_at, summary_start)
            stream.seek(footer_at + FOOTER_RECORD - 4)
            stream.write(struct.pack("<I", crc))


def check_summary(file: Path) -> str | None:
    """Why the summary of the MCAP ``file`` (with a footer) is damaged, or None (also when it has no
    summary CRC)."""
    with file.open("rb") as stream:
        footer_at, summary_start, _, crc = _footer(stream)
        if not crc or not summary_start:
            return None
        if not 0 < summary_start <= footer_at:
            return f"damaged at offset {footer_at}: footer points its summary to offset {summary_start}"
        if _summary_crc(stream, footer_at, summary_start) != crc:
            return f"damaged at offset {summary_start}: summary checksum mismatch"
    return None


def first_damage(file: Path) -> str | None:
    """The first broken record of the MCAP ``file`` (its offset and why), walking the records from the
    start: a length past the end of the file, or a chunk whose uncompressed records do not match their
    CRC; None if every record up to the end (or a truncated tail) is whole."""
    with file.open("rb") as stream:
        size = stream.seek(0, 2)
        stream.seek(0)
        if stream.read(len(MAGIC)) != MAGIC:
            return "damaged at offset 0: not an MCAP file (bad magic)"
        at = len(MAGIC)
        while at + 9 <= size:
            stream.seek(at)
            op, length = struct.unpack("<BQ", stream.read(9))
            if op == OP_FOOTER:
                return None
            if length > size - at - 9:
                return f"damaged at offset {at}: record length {length} runs past the end of the file ({size} bytes)"
            if op == OP_CHUNK:
                problem = _chunk_problem(stream.read(length))
                if problem:
                    return f"damaged at offset {at}: {problem}"
            at += 9 + length
    return None


def _chunk_problem(body: bytes) -> str | None:
    if len(body) < 40:
        return "chunk record too short"
    uncompressed_size, crc = struct.unpack_from("<QI", body, 16)
    (name_length,) = struct.unpack_from("<I", body, 28)
    compression = body[32 : 32 + name_length]
    (compressed_size,) = struct.unpack_from("<Q", body, 32 + name_length) if len(body) >= 40 + name_length else (-1,)
    data = body[40 + name_length : 40 + name_length + compressed_size]
    if compression not in (b"", b"zstd") or compressed_size != len(data):
        return "chunk header does not match its data"
    if compression == b"zstd":
        try:
            data = zstd.decompress(data)
        except zstd.ZstdError as err:
            return f"chunk data cannot be decompressed ({err})"
    if len(data) != uncompressed_size:
        return "chunk size mismatch"
    if crc and zlib.crc32(data) != crc:
        return "chunk checksum mismatch"
    return None
