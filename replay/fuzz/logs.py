"""The clean inputs of the fuzzer and just enough of the two log formats to mutate them with intent.

Clean inputs are cut from the shared real logs (``<shared>/data/logs``, see its MANIFEST.md) so that one
replay takes about a second: a plain prefix of each log, and -- because a prefix of log171 ends before the
first GNSS fix, where the navigator has not started and a time jump exercises nothing -- a window from the
middle of the flight behind the log's own format records (dataflash) or on its own (tlog). Every cut is at
a record boundary, so the clean input replays with exit 0.

Formats (what pymavlink reads):

* dataflash ``.bin``: records ``A3 95 <type> <body>``; the body length and layout come from the FMT record
  of that type (type 0x80, itself 89 bytes: Type u8, Length u8, Name char[4], Format char[16], Columns
  char[64]). Format characters as :data:`pymavlink.DFReader.FORMAT_TO_STRUCT`.
* telemetry ``.tlog``: per record an 8-byte big-endian receive time (us since the Unix epoch), then one
  MAVLink frame (v1: ``FE len seq sys comp msgid payload crc16``; v2: ``FD len incompat compat seq sys comp
  msgid[3] payload crc16 [signature 13]``).
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

from pymavlink.DFReader import FORMAT_TO_STRUCT
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

HEAD = b"\xa3\x95"
FMT_TYPE = 0x80
FMT_BODY = struct.Struct("<BB4s16s64s")
FMT_LEN = 3 + FMT_BODY.size  # 89
#: record names whose formats ride along in front of a window (the reader needs them)
FORMAT_RECORDS = ("FMT", "FMTU", "UNIT", "MULT")
#: dataflash record types the replay decodes (companion.sources.dataflash.WANTED)
WANTED_DF = ("IMU", "IMU2", "IMU3", "GPS", "GPS2", "GPA", "GPA2", "ATT", "MSG")
#: MAVLink messages the replay decodes and that carry their own boot time, with that field
TLOG_TIME_FIELDS = {
    "ATTITUDE": "time_boot_ms",
    "SYSTEM_TIME": "time_boot_ms",
    "SCALED_IMU2": "time_boot_ms",
    "SCALED_IMU3": "time_boot_ms",
    "GLOBAL_POSITION_INT": "time_boot_ms",
    "RAW_IMU": "time_usec",
    "GPS_RAW_INT": "time_usec",
}


def shared_logs_dir() -> Path:
    """``<shared>/data/logs``: the project's shared-data location ($COMPANION_SHARED or ../shared)."""
    from companion.shared_data import shared_dir

    return shared_dir() / "data" / "logs"


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# ----------------------------------------------------------------------------------------------- dataflash
@dataclass(frozen=True)
class Format:
    type: int
    length: int  # whole record, 3 header bytes included
    name: str
    format: str
    columns: tuple[str, ...]
    offset: int  # byte offset of the FMT record that defined it (-1: built in)

    def column(self, name: str) -> tuple[int, str, float | None]:
        """(byte offset inside the record, struct code, multiplier) of a column; KeyError if absent."""
        off = 3
        for ch, col in zip(self.format, self.columns):
            code, mult, _ = FORMAT_TO_STRUCT[ch]
            if col == name:
                return off, code, mult
            off += struct.calcsize("<" + code)
        raise KeyError(name)

    def time_column(self) -> str | None:
        """The boot-time column: TimeUS (AC 4.x), TimeMS (AC 3.x), but T on AC 3.x GPS rows (TimeMS is GPS time)."""
        if self.name.startswith("GPS") and "T" in self.columns and "TimeUS" not in self.columns:
            return "T"
        for c in ("TimeUS", "TimeMS"):
            if c in self.columns:
                return c
        return None


_FMT_FORMAT = Format(FMT_TYPE, FMT_LEN, "FMT", "BBnNZ", ("Type", "Length", "Name", "Format", "Columns"), -1)


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


@dataclass(frozen=True)
class Record:
    offset: int
    type: int


class DataflashLog:
    """Records and formats of a dataflash log (bytes that are not a record are skipped and counted)."""

    kind = "dataflash"

    def __init__(self, data: bytes) -> None:
        self.data = bytes(data)
        self.formats: dict[int, Format] = {FMT_TYPE: _FMT_FORMAT}
        self.records: list[Record] = []
        self.skipped = 0
        self.end = 0  # end of the last complete record
        d, n, i = self.data, len(self.data), 0
        while i + 3 <= n:
            t = d[i + 2]
            f = self.formats.get(t)
            if d[i] != 0xA3 or d[i + 1] != 0x95 or f is None or f.length < 3:
                self.skipped += 1
                i += 1
                continue
            if i + f.length > n:
                break
            self.records.append(Record(i, t))
            if t == FMT_TYPE:
                self._add_format(i)
            i += f.length
            self.end = i

    def _add_format(self, i: int) -> None:
        ftype, length, name, fmt, cols = FMT_BODY.unpack_from(self.data, i + 3)
        fmt_s, cols_s = _text(fmt), _text(cols)
        columns = tuple(cols_s.split(",")) if cols_s else ()
        if all(ch in FORMAT_TO_STRUCT for ch in fmt_s) and len(columns) == len(fmt_s):
            self.formats[ftype] = Format(ftype, length, _text(name), fmt_s, columns, i)

    def fmt(self, rec: Record) -> Format:
        return self.formats[rec.type]

    def records_named(self, names) -> list[int]:
        """Indices (into ``records``) of the records of these message names."""
        names = set(names)
        return [k for k, r in enumerate(self.records) if self.formats[r.type].name in names]

    def timed(self, names=None) -> list[int]:
        """Indices of records with a boot-time column (of these names, default every name)."""
        out = []
        for k, r in enumerate(self.records):
            f = self.formats[r.type]
            if (names is None or f.name in names) and f.time_column() is not None:
                out.append(k)
        return out

    def get(self, rec: Record, column: str, data: bytes | None = None):
        off, code, _ = self.fmt(rec).column(column)
        return struct.unpack_from("<" + code, self.data if data is None else data, rec.offset + off)[0]

    def put(self, buf: bytearray, rec: Record, column: str, value) -> None:
        """Write a column's raw value (struct.error when it does not fit the column's type)."""
        off, code, _ = self.fmt(rec).column(column)
        struct.pack_into("<" + code, buf, rec.offset + off, value)

    def column_code(self, rec: Record, column: str) -> str:
        return self.fmt(rec).column(column)[1]

    def time_scale_s(self, rec: Record) -> float:
        """Seconds per unit of the record's time column."""
        return 1e-6 if self.fmt(rec).time_column() == "TimeUS" else 1e-3

    def window(self, start: int, size: int) -> bytes:
        """The format records before byte ``start`` followed by whole records from there, ``size`` bytes in all."""
        head = bytearray()
        first = None
        for k, r in enumerate(self.records):
            if r.offset < start:
                if self.formats[r.type].name in FORMAT_RECORDS:
                    head += self.data[r.offset:r.offset + self.formats[r.type].length]
            elif first is None:
                first = k
                break
        if first is None:
            return bytes(head)
        out = bytearray(head)
        for r in self.records[first:]:
            n = self.formats[r.type].length
            if len(out) + n > size:
                break
            out += self.data[r.offset:r.offset + n]
        return bytes(out)

    def prefix(self, size: int) -> bytes:
        """The first whole records, at most ``size`` bytes."""
        end = 0
        for r in self.records:
            e = r.offset + self.formats[r.type].length
            if e > size:
                break
            end = e
        return self.data[:end]


# ----------------------------------------------------------------------------------------------- tlog
@dataclass(frozen=True)
class Frame:
    offset: int  # of the 8-byte time stamp
    stamp_us: int
    version: int  # 1 or 2
    length: int  # frame bytes (from STX to the end of CRC / signature)
    msgid: int

    @property
    def start(self) -> int:
        """Offset of the frame's STX."""
        return self.offset + 8

    @property
    def end(self) -> int:
        return self.offset + 8 + self.length


class Tlog:
    """Records of a telemetry log; stops at the first byte that is not a frame start."""

    kind = "tlog"

    def __init__(self, data: bytes) -> None:
        self.data = bytes(data)
        self.frames: list[Frame] = []
        d, n, i = self.data, len(self.data), 0
        while i + 8 + 8 <= n:
            stx = d[i + 8]
            if stx == 0xFE:
                flen, msgid = 6 + d[i + 9] + 2, d[i + 13]
                ver = 1
            elif stx == 0xFD:
                flen = 10 + d[i + 9] + 2 + (13 if d[i + 10] & 1 else 0)
                msgid = d[i + 15] | d[i + 16] << 8 | d[i + 17] << 16
                ver = 2
            else:
                break
            if i + 8 + flen > n:
                break
            self.frames.append(Frame(i, struct.unpack_from(">Q", d, i)[0], ver, flen, msgid))
            i += 8 + flen
        self.end = self.frames[-1].end if self.frames else 0

    def frame_bytes(self, f: Frame, data: bytes | None = None) -> bytes:
        return (self.data if data is None else data)[f.start:f.end]

    def of_type(self, names) -> list[int]:
        ids = {getattr(mavlink2, f"MAVLINK_MSG_ID_{n}") for n in names}
        return [k for k, f in enumerate(self.frames) if f.msgid in ids]

    def decode(self, f: Frame):
        """The pymavlink message of a frame (None when it does not decode)."""
        return decode_frame(self.frame_bytes(f))

    def prefix(self, size: int) -> bytes:
        end = 0
        for f in self.frames:
            if f.end > size:
                break
            end = f.end
        return self.data[:end]

    def window(self, start: int, size: int) -> bytes:
        first = next((f for f in self.frames if f.offset >= start), None)
        if first is None:
            return b""
        end = first.offset
        for f in self.frames:
            if f.offset < first.offset:
                continue
            if f.end - first.offset > size:
                break
            end = f.end
        return self.data[first.offset:end]


_PARSER = mavlink2.MAVLink(None)
_PARSER.robust_parsing = True
_PACKER = mavlink2.MAVLink(None)


def decode_frame(frame: bytes):
    try:
        return _PARSER.decode(bytearray(frame))
    except Exception:  # noqa: BLE001 - pymavlink raises assorted errors on bad frames
        return None


def x25(data: bytes, crc_extra: int) -> int:
    crc = mavlink2.x25crc(data)
    crc.accumulate(bytes([crc_extra]))
    return crc.crc


def reframe(frame: bytes, msg, version: int | None = None) -> bytes:
    """``frame`` (v1 or v2, unsigned) carrying ``msg``'s current field values with a valid CRC; sequence, system and
    component kept. ``version`` 1 or 2 converts the frame (pymavlink's own encoding; v1 only for ids < 256)."""
    old_v = 1 if frame[0] == 0xFE else 2
    v = version or old_v
    seq, sysid, comp = (frame[2], frame[3], frame[4]) if old_v == 1 else (frame[4], frame[5], frame[6])
    _PACKER.seq, _PACKER.srcSystem, _PACKER.srcComponent = seq, sysid, comp
    if not (v == 1 and old_v == 1):
        return bytes(msg.pack(_PACKER, force_mavlink1=v == 1))
    msg.pack(_PACKER)  # fills msg._payload (MAVLink 2 trims trailing zeros): back to the frame's own v1 length
    payload = bytes(msg._payload).ljust(frame[1], b"\0")[: frame[1]]
    hdr = bytes([0xFE, len(payload), seq, sysid, comp, msg.get_msgId()])
    return hdr + payload + struct.pack("<H", x25(hdr[1:] + payload, msg.crc_extra))


# ----------------------------------------------------------------------------------------------- inputs
def parse(data: bytes) -> DataflashLog | Tlog:
    return DataflashLog(data) if data[:2] == HEAD else Tlog(data)


def short_name(path: Path) -> str:
    parts = path.stem.split("_")
    return f"{parts[0]}-{parts[-1]}"


@dataclass(frozen=True)
class CleanInput:
    """A clean input: bytes cut from a real log at record boundaries."""

    name: str  # e.g. "ac33dev-log171@45%"
    source: Path
    data: bytes = field(repr=False)
    kind: str  # "dataflash" | "tlog"

    @property
    def suffix(self) -> str:
        return ".bin" if self.kind == "dataflash" else ".tlog"

    def parsed(self) -> DataflashLog | Tlog:
        return _parsed(self.data)


@lru_cache(maxsize=32)
def _parsed(data: bytes) -> DataflashLog | Tlog:
    return parse(data)


#: (fraction of the file where the cut starts; 0 = plain prefix)
WINDOW_STARTS = (0.0, 0.45)


def clean_inputs(size: int = 200_000, logs_dir: Path | None = None, starts=WINDOW_STARTS) -> list[CleanInput]:
    """Prefixes and mid-flight windows of every shared log (``size`` bytes at most each)."""
    logs_dir = logs_dir or shared_logs_dir()
    out = []
    for path in sorted(logs_dir.glob("*.bin")) + sorted(logs_dir.glob("*.tlog")):
        data = path.read_bytes()
        log = parse(data)
        for frac in starts:
            cut = log.prefix(size) if frac == 0 else log.window(int(frac * len(data)), size)
            if len(cut) < 1000:
                continue
            out.append(CleanInput(f"{short_name(path)}@{frac:.0%}", path, cut, log.kind))
    return out
