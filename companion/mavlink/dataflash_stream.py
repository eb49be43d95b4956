"""Dataflash ``.bin`` records read as a stream: block by block, the wanted types decoded with numpy, nothing indexed.

pymavlink's DFReader maps the whole file and indexes the offset of every record before the first one is read
(memory grows with the flight: 1.6 MiB a minute). Here the file is read in blocks of ``block_bytes``; the record
boundaries of a block are walked once (a record is ``A3 95 type`` + the length its FMT gives), FMT records define
the formats as they come, and the records of the wanted types are gathered per format and decoded at once through a
numpy structured dtype built from the FMT's format characters. Values are those DFReader gives (tested against it
on every shared log): integers as int, floats as float, the scaled types (``c C e E L``) divided by ``1/mult`` as
DFReader divides them, strings decoded as UTF-8 (else Latin-1) and cut at the first NUL.

Damage, as pymavlink's own parser and companion's resynchronising index handled it:

* bytes that are no record (a bad header, an unknown type) are skipped up to the next ``A3 95``; counted in
  ``skipped_bytes`` / ``skipped_stretches`` unless they lie in the last 528 bytes (block logs end in padding);
* an FMT record that cannot be read (unsupported format character) is one skipped byte; a format whose fields do not
  fill its length makes its records unreadable: counted per name in ``unfit``;
* a record cut short by the end of the file: ``truncated`` = (its offset, its length); more than 528 bytes after the
  last record that are no records: ``trailing_garbage`` = (offset, bytes);
* a second FMT block far into the file (logs one after another): the formats restart; ``segment_starts`` says where.

Pure I/O and decoding: no events, no clocks (companion.mavlink.dataflash turns the rows into events).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field

import numpy as np

HEAD = b"\xa3\x95"
FMT_TYPE = 0x80
FMT_LEN = 89
#: the FMT record that defines FMT itself: the first record of every dataflash log (again: logs one after another)
FMT_OF_FMT_BODY = b"\x80\x59FMT\x00"
#: a new FMT block this far after the current log's start is a new log (a log's own FMT block is contiguous)
NEW_LOG_AFTER = 2048
#: garbage within this many bytes of the end of the file is a block log's padding, not damage (DFReader's allowance)
PADDING = 528
BLOCK_BYTES = 1 << 18

# format character -> (numpy dtype, multiplier): pymavlink's DFReader.FORMAT_TO_STRUCT
_DTYPES = {
    "a": (("<i2", (32,)), None), "b": ("i1", None), "B": ("u1", None), "g": ("<f2", None), "h": ("<i2", None),
    "H": ("<u2", None), "i": ("<i4", None), "I": ("<u4", None), "f": ("<f4", None), "n": ("S4", None),
    "N": ("S16", None), "Z": ("S64", None), "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01),
    "E": ("<u4", 0.01), "L": ("<i4", 1.0e-7), "d": ("<f8", None), "M": ("i1", None), "q": ("<i8", None),
    "Q": ("<u8", None),
}
_FMT_BODY = struct.Struct("<BB4s16s64s")


def _text(b: bytes) -> str:
    """DFReader's string: UTF-8, else Latin-1, cut at the first NUL."""
    try:
        s = b.decode("utf-8")
    except UnicodeDecodeError:
        s = b.decode("ISO-8859-1")
    i = s.find("\0")
    return s if i < 0 else s[:i]


class Format:
    """One FMT record: name, length, format characters, columns, and the dtype of its whole record (header too)."""

    __slots__ = ("type", "name", "length", "format", "columns", "dtype", "fits", "chars")

    def __init__(self, mtype: int, length: int, name: str, fmt: str, columns: str) -> None:
        self.type, self.length, self.name, self.format = mtype, length, name, fmt
        self.columns = [c for c in columns.split(",")] if columns else []
        names, formats, offsets, ofs = [], [], [], 3
        self.chars: list[str] = []
        for i, ch in enumerate(fmt):
            dt = np.dtype(_DTYPES[ch][0])  # KeyError: a character DFReader does not know either
            names.append(f"f{i}")
            formats.append(dt)
            offsets.append(ofs)
            self.chars.append(ch)
            ofs += dt.itemsize
        # pymavlink cannot unpack a record whose fields do not fill it; a header-only record (Length 3, no Format)
        # has no field to read either
        self.fits = ofs == length and bool(self.chars)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                               "itemsize": max(length, ofs, 3)}) if self.fits else None

    def decode(self, records: np.ndarray) -> dict[str, list]:
        """Column name -> values (DFReader's types) of ``records`` ((n, length) uint8)."""
        arr = records.view(self.dtype).reshape(-1)
        cols: dict[str, list] = {}
        for i, (name, ch) in enumerate(zip(self.columns, self.chars)):
            col = arr[f"f{i}"]
            mult = _DTYPES[ch][1]
            if mult is not None:
                values = (col.astype(np.float64) / (1 / mult)).tolist()  # DFReader: v /= 1/mult
            elif ch in "nNZ":
                values = [_text(b) for b in col.tolist()]
            elif ch == "a":
                import array

                values = [array.array("h", row) for row in col.tolist()]
            else:
                values = col.tolist()
            cols[name] = values
        return cols


FMT_FORMAT = Format(FMT_TYPE, FMT_LEN, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")


@dataclass
class Rows:
    """The decoded records of one format in one block: ``cols[name][k]`` is the k-th record's value."""

    fmt: Format
    offsets: list[int] = field(default_factory=list)
    cols: dict[str, list] = field(default_factory=dict)


@dataclass
class Block:
    """The wanted records of one stretch of the file in file order: ``order`` holds (rows, k), or (None, offset)
    where a new log starts (the formats restarted there)."""

    order: list[tuple[Rows | None, int]]
    end_offset: int


class DataflashStream:
    """``next_block()`` until it returns None; the damage found is in the attributes (see the module docstring).

    ``wanted``: the record types to decode; None: every type, the FMT records too (a whole-log conversion)."""

    def __init__(self, path: str | os.PathLike, wanted, block_bytes: int = BLOCK_BYTES) -> None:
        self._f = open(path, "rb")
        self.size = os.fstat(self._f.fileno()).st_size
        self._wanted = None if wanted is None else frozenset(wanted)
        self._block = int(block_bytes)
        self._buf = b""
        self._base = 0  # file offset of _buf[0]
        self._eof = False
        self.done = False
        self.skipped_bytes = 0
        self.skipped_stretches = 0
        self._in_skip = False  # a skipped stretch goes on into the next block
        self.unfit: dict[str, int] = {}
        self.truncated: tuple[int, int] | None = None
        self.trailing_garbage: tuple[int, int] | None = None
        self.segment_starts = [0]
        self.offset = 0  # bytes of the file walked so far
        self.last_end = 0  # end of the last whole record
        self._reset_formats()

    def _reset_formats(self) -> None:
        self.formats: dict[int, Format] = {FMT_TYPE: FMT_FORMAT}
        self._len = [0] * 256
        self._len[FMT_TYPE] = FMT_LEN
        self._want: list[Format | None] = [None] * 256

    @property
    def has_formats(self) -> bool:
        return len(self.formats) > 1

    def close(self) -> None:
        self._f.close()

    # ------------------------------------------------------------------ walking
    def next_block(self) -> Block | None:
        """The wanted records of the next block of the file, decoded; None once the file is read."""
        if self.done:
            return None
        chunk = self._f.read(self._block)
        if not chunk:
            self._eof = True
        data = self._buf + chunk if self._buf else chunk
        base = self._base
        buckets: dict[int, Rows] = {}  # id(format) -> its rows
        order: list[tuple[Rows | None, int]] = []
        stop = self._walk(data, base, buckets, order)
        self._buf, self._base = data[stop:], base + stop
        self.offset = base + stop
        if self._eof:
            self._finish(data, base, stop)
        arr = np.frombuffer(data, np.uint8)
        for rows in buckets.values():
            fmt = rows.fmt
            idx = np.asarray(rows.offsets, dtype=np.intp)[:, None] + np.arange(fmt.length)
            rows.cols = fmt.decode(np.ascontiguousarray(arr[idx]))
        return Block(order, self.offset)

    def _walk(self, data: bytes, base: int, buckets: dict, order: list) -> int:
        """Walk the records of ``data`` (file offset ``base``); returns where the unread rest starts."""
        n = len(data)
        lens, want = self._len, self._want
        ofs = 0
        while ofs + 3 <= n:
            if data[ofs] == 0xA3 and data[ofs + 1] == 0x95:
                t = data[ofs + 2]
                L = lens[t]
                if L:
                    if ofs + L > n:
                        return ofs  # the rest of this record is in the next block (or cut by the end of the file)
                    self._in_skip = False
                    if t == FMT_TYPE:
                        if not self._define(data, ofs, base, order):
                            self._skip(base + ofs, 1, new=True)
                            ofs += 1
                            continue
                        lens, want = self._len, self._want  # (a new log: new tables)
                        if self._wanted is None:  # every record, FMT too
                            rows = buckets.get(id(FMT_FORMAT))
                            if rows is None:
                                rows = buckets[id(FMT_FORMAT)] = Rows(FMT_FORMAT)
                            order.append((rows, len(rows.offsets)))
                            rows.offsets.append(ofs)
                    else:
                        fmt = want[t]
                        if fmt is not None:
                            if fmt.dtype is None:
                                self.unfit[fmt.name] = self.unfit.get(fmt.name, 0) + 1
                            else:
                                rows = buckets.get(id(fmt))
                                if rows is None:
                                    rows = buckets[id(fmt)] = Rows(fmt)
                                order.append((rows, len(rows.offsets)))
                                rows.offsets.append(ofs)
                    ofs += L
                    self.last_end = base + ofs
                    continue
            # no record here: skip to the next record header
            nxt = data.find(HEAD, ofs + 1)
            if nxt < 0:
                if not self._eof:  # keep the last byte: it may be the first of a header
                    self._skip(base + ofs, n - 1 - ofs, new=not self._in_skip)
                    self._in_skip = True
                    return n - 1
                nxt = n
            self._skip(base + ofs, nxt - ofs, new=not self._in_skip)
            self._in_skip = False
            ofs = nxt
        return ofs

    def _skip(self, at: int, nbytes: int, new: bool) -> None:
        if nbytes <= 0:
            return
        if self.size - at >= PADDING or self.size < PADDING:
            self.skipped_bytes += nbytes
            self.skipped_stretches += new

    def _define(self, data: bytes, ofs: int, base: int, order: list) -> bool:
        """An FMT record: define (or redefine) a format; False when it cannot be read."""
        body = data[ofs + 3:ofs + FMT_LEN]
        if body[:6] == FMT_OF_FMT_BODY and base + ofs - self.segment_starts[-1] > NEW_LOG_AFTER:
            self.segment_starts.append(base + ofs)  # another log after this one: its own formats from here
            self._reset_formats()
            order.append((None, base + ofs))
        try:
            mtype, length, name, fmt, cols = _FMT_BODY.unpack(body)
            f = Format(mtype, length, _text(name), _text(fmt), _text(cols))
        except (KeyError, ValueError, TypeError, struct.error):
            return False
        if mtype == FMT_TYPE and (length != FMT_LEN or f.format != FMT_FORMAT.format):
            return True  # a damaged redefinition of FMT itself would lose every format after it: keep ours
        self.formats[mtype] = f
        self._len[mtype] = length if length >= 3 else 0
        self._want[mtype] = f if self._wanted is None or f.name in self._wanted else None
        return True

    def _finish(self, data: bytes, base: int, stop: int) -> None:
        """At the end of the file: a record cut short, or bytes after the last record that are none."""
        self.done = True
        rest = len(data) - stop
        if rest >= 3 and data[stop] == 0xA3 and data[stop + 1] == 0x95 and self._len[data[stop + 2]] > rest:
            self.truncated = (base + stop, self._len[data[stop + 2]])
        elif 0 < rest < 3 and base + stop == self.last_end:
            self.truncated = (base + stop, 3)
        tail = self.size - self.last_end
        if self.truncated is None and tail > PADDING:
            self.trailing_garbage = (self.last_end, tail)
        self.offset = self.size
