"""Chunk CRCs of a finalised MCAP file, checked by streaming each chunk (bounded memory, one block at a time).

A finalised file's summary section says where every chunk is; its data can still be damaged (a flipped bit on an
SD card, a copy cut short and patched). Each chunk record carries the CRC-32 of its uncompressed records: the
chunk is read in blocks, decompressed incrementally, and the CRC and size compared with what the chunk says.
"""

from __future__ import annotations

import struct
import zlib
from typing import BinaryIO

BLOCK_BYTES = 1 << 20
_CHUNK_OPCODE = 0x06
_HEAD = struct.Struct("<BQQQQII")  # opcode, record length, start, end, uncompressed size, uncompressed CRC, len(compression)


class _Window:
    """Reads at most ``n`` bytes of ``f`` from where it is (the chunk's compressed records)."""

    def __init__(self, f: BinaryIO, n: int):
        self._f, self._left = f, n

    def read(self, size: int = -1) -> bytes:
        size = self._left if size is None or size < 0 else min(size, self._left)
        data = self._f.read(size)
        self._left -= len(data)
        return data

    def readable(self) -> bool:
        return True


def _blocks(compression: str, raw: _Window):
    if compression == "":
        while block := raw.read(BLOCK_BYTES):
            yield block
    elif compression == "zstd":
        import zstandard

        with zstandard.ZstdDecompressor().stream_reader(raw, read_size=BLOCK_BYTES, closefd=False) as r:
            while block := r.read(BLOCK_BYTES):
                yield block
    elif compression == "lz4":
        import lz4.frame

        with lz4.frame.open(raw, "rb") as r:
            while block := r.read(BLOCK_BYTES):
                yield block
    else:
        raise ValueError(f"unknown compression {compression!r}")


def chunk_damage(f: BinaryIO, offset: int, size: int) -> str:
    """"" when the chunk record at ``offset`` of ``f`` (a file of ``size`` bytes) is whole; else what is wrong."""
    f.seek(offset)
    head = f.read(_HEAD.size)
    if len(head) < _HEAD.size:
        return "cut short"
    opcode, rec_len, _, _, usize, crc, clen = _HEAD.unpack(head)
    if opcode != _CHUNK_OPCODE:
        return f"no chunk record at byte {offset} (opcode 0x{opcode:02x})"
    if offset + 9 + rec_len > size or clen > rec_len:
        return "cut short"
    try:
        compression = f.read(clen).decode()
    except UnicodeDecodeError:
        return "unreadable compression name"
    (data_len,) = struct.unpack("<Q", f.read(8) or b"\0" * 8)
    if data_len > rec_len:
        return "cut short"
    n, got = 0, 0
    try:
        for block in _blocks(compression, _Window(f, data_len)):
            n += len(block)
            got = zlib.crc32(block, got)
            if n > usize:
                break
    except Exception as exc:  # noqa: BLE001 - a corrupt compressed stream is the finding
        return f"does not decompress ({type(exc).__name__})"
    if n != usize:
        return f"{n} bytes decompressed, the chunk says {usize}"
    if crc != 0 and got != crc:  # 0: the writer computed no CRC
        return "CRC mismatch"
    return ""
