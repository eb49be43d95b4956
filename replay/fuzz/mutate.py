"""The seeded log mutator: one function per kind of damage, each drawing from an explicit numpy Generator.

Mutant ``i`` of seed ``S`` comes from ``numpy.random.default_rng([S, i])`` alone, so any mutant of a run can be
rebuilt on its own (``python -m replay.fuzz --seed S --only i --keep DIR``). Kinds are dealt round-robin over
the mutant indices; each draws its clean input from the inputs it applies to.

Kinds (both formats unless marked):

* ``bitflip``, ``delete``, ``insert``, ``duplicate`` (1-16 bytes, half of them a single byte; a span of up
  to 300 bytes doubled), ``garbage`` (50-2000 random bytes between two records);
* ``truncate``: cut inside a record (dataflash) or a frame (tlog): the input is known to be damaged;
* ``concat``: two clean inputs of the same format end to end;
* dataflash: ``fmt_rename`` (a column of an FMT renamed), ``fmt_length`` (FMT Length +-1..20), ``fmt_format``
  (a format character replaced, by a valid or an invalid one), ``fmt_name`` (a decoded type renamed: the type
  vanishes), ``type_byte`` (one record's type byte), ``imu_float`` (an IMU Acc/Gyr float set to 1e22, NaN,
  inf, ..., in one record or a short run), ``fmt_header_only`` (an FMT redefining IMU/ATT as Length 3, no Format or
  Columns, then such a record);
* ``repeat_timestamps``: one IMU (or other timed) record repeated 20,000-200,000 times in place;
* ``time_one<d>`` / ``time_rest<d>``: the boot time of one record of a decoded type, or of every timed record
  from one on, moved by d = +1e3 s, +1e5 s, +4e6 s, to >= 2^64 ns (a 32-bit ms column cannot hold that: set to
  its maximum, and said), or back half-way to boot; the field is decoded and rewritten (tlog: the frame
  re-encoded with a valid CRC);
* tlog: ``stamp_one`` / ``stamp_rest`` (the 8-byte receive time, same deltas), ``frame_length`` (a frame's
  length byte), ``msgid_byte``, ``crc``, ``mix_v1v2`` (a run of frames re-encoded in the other MAVLink version),
  ``field_extreme`` (GPS_RAW_INT at lat +-90 / lon +-180 / alt +-2147 km, RAW_IMU at +-32767, SYSTEM_TIME
  4e16 us, ATTITUDE 1e22 / NaN / inf, ...).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from pymavlink.DFReader import FORMAT_TO_STRUCT

from replay.fuzz.logs import (
    FMT_BODY,
    FMT_TYPE,
    TLOG_TIME_FIELDS,
    WANTED_DF,
    CleanInput,
    DataflashLog,
    Tlog,
    reframe,
)

#: time deltas of the time kinds: seconds, or the special targets
DELTAS = {"+1e3s": 1e3, "+1e5s": 1e5, "+4e6s": 4e6, "2^64ns": "2^64ns", "back": "back"}
TWO64_NS_AS_US = (1 << 64) // 1000 + 1  # a time in us that is >= 2^64 ns
BAD_FLOATS = (1e22, -1e22, math.nan, math.inf, -math.inf, 3.4e38)
_UMAX = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF, "Q": (1 << 64) - 1}


class NotApplicable(Exception):
    """This kind cannot damage this input (e.g. no IMU records): draw another input."""


@dataclass(frozen=True)
class Mutant:
    index: int
    seed: int
    kind: str
    inputs: tuple[str, ...]  # names of the clean inputs it was built from
    desc: str
    data: bytes = field(repr=False)
    suffix: str  # ".bin" / ".tlog"
    damaged: bool = False  # known to end mid-record: exit 0 would hide the damage


@dataclass(frozen=True)
class Kind:
    fn: Callable  # (rng, clean, pool) -> (data, desc[, damaged[, extra input names]])
    formats: tuple[str, ...]


def _pick(rng, seq: Sequence):
    if not len(seq):
        raise NotApplicable("nothing to pick from")
    return seq[int(rng.integers(len(seq)))]


def _count(rng) -> int:
    """How many bytes: 1 half of the time, else 2..16."""
    return 1 if rng.random() < 0.5 else int(rng.integers(2, 17))


def _middle(rng, items: Sequence, lo: float = 0.1, hi: float = 0.9):
    """An element from the middle of a sequence (not the first or last records: the stream must be running)."""
    if not len(items):
        raise NotApplicable("no candidates")
    a, b = int(lo * len(items)), max(int(lo * len(items)) + 1, int(hi * len(items)))
    return items[int(rng.integers(a, min(b, len(items))))]


# ----------------------------------------------------------------------------------------------- generic
def bitflip(rng, c: CleanInput, pool):
    buf = bytearray(c.data)
    n = int(rng.integers(1, 9))
    where = sorted(int(rng.integers(len(buf))) for _ in range(n))
    for p in where:
        buf[p] ^= 1 << int(rng.integers(8))
    return bytes(buf), f"{n} bit(s) flipped at bytes {where}"


def delete(rng, c: CleanInput, pool):
    n, p = _count(rng), int(rng.integers(len(c.data)))
    return c.data[:p] + c.data[p + n:], f"{n} byte(s) deleted at {p}"


def insert(rng, c: CleanInput, pool):
    n, p = _count(rng), int(rng.integers(len(c.data)))
    return c.data[:p] + rng.bytes(n) + c.data[p:], f"{n} random byte(s) inserted at {p}"


def duplicate(rng, c: CleanInput, pool):
    n, p = int(rng.integers(1, 301)), int(rng.integers(len(c.data)))
    return c.data[:p + n] + c.data[p:p + n] + c.data[p + n:], f"{n} bytes at {p} duplicated"


def _boundaries(log) -> list[int]:
    if isinstance(log, DataflashLog):
        return [r.offset for r in log.records]
    return [f.offset for f in log.frames]


def garbage(rng, c: CleanInput, pool):
    p = _middle(rng, _boundaries(c.parsed()))
    n = int(rng.integers(50, 2001))
    return c.data[:p] + rng.bytes(n) + c.data[p:], f"{n} random bytes inserted between records at {p}"


def truncate(rng, c: CleanInput, pool):
    log = c.parsed()
    if isinstance(log, DataflashLog):
        k = int(rng.integers(min(10, len(log.records) - 1), len(log.records)))
        r = log.records[k]
        n = log.fmt(r).length
        cut = r.offset + int(rng.integers(1, n))
        return c.data[:cut], f"cut at {cut}, inside a {log.fmt(r).name} record ({cut - r.offset} of {n} bytes)", True
    k = int(rng.integers(min(10, len(log.frames) - 1), len(log.frames)))
    f = log.frames[k]
    cut = f.offset + int(rng.integers(1, 8 + f.length))
    what = "time stamp" if cut < f.start else "frame"
    return c.data[:cut], f"cut at {cut}, inside a record's {what} ({cut - f.offset} of {8 + f.length} bytes)", True


def concat(rng, c: CleanInput, pool):
    other = _pick(rng, [p for p in pool if p.kind == c.kind])
    return c.data + other.data, f"{c.name} + {other.name}", False, (other.name,)


# ----------------------------------------------------------------------------------------------- dataflash
def _fmt_records(log: DataflashLog, rng, wanted_p: float = 0.8):
    """An FMT record (offset) and the format it defines; of a decoded type most of the time."""
    defined = [f for t, f in log.formats.items() if f.offset >= 0]
    wanted = [f for f in defined if f.name in WANTED_DF and any(r.type == f.type for r in log.records)]
    f = _pick(rng, wanted if wanted and rng.random() < wanted_p else defined)
    return f.offset, f


def _put_fmt(buf: bytearray, off: int, **kw) -> None:
    ftype, length, name, fmt, cols = FMT_BODY.unpack_from(buf, off + 3)
    vals = dict(ftype=ftype, length=length, name=name, fmt=fmt, cols=cols)
    vals.update(kw)
    FMT_BODY.pack_into(buf, off + 3, vals["ftype"], vals["length"], vals["name"], vals["fmt"], vals["cols"])


_LETTERS = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789"


def fmt_rename(rng, c: CleanInput, pool):
    log = c.parsed()
    off, f = _fmt_records(log, rng)
    cols = list(f.columns)
    i = int(rng.integers(len(cols)))
    old = cols[i]
    if rng.random() < 0.3 and len(cols) > 1:
        new = cols[(i + 1) % len(cols)]  # a duplicate column name
    else:
        j = int(rng.integers(len(old)))
        new = old[:j] + chr(_LETTERS[int(rng.integers(len(_LETTERS)))]) + old[j + 1:]
        if new == old:
            new = old + "X"
    cols[i] = new
    text = ",".join(cols).encode()[:64]
    buf = bytearray(c.data)
    _put_fmt(buf, off, cols=text)
    return bytes(buf), f"FMT of {f.name}: column {old!r} renamed {new!r}"


def fmt_length(rng, c: CleanInput, pool):
    log = c.parsed()
    off, f = _fmt_records(log, rng)
    d = int(rng.integers(1, 21)) * (1 if rng.random() < 0.5 else -1)
    new = min(255, max(0, f.length + d))
    buf = bytearray(c.data)
    _put_fmt(buf, off, length=new)
    return bytes(buf), f"FMT of {f.name}: Length {f.length} -> {new}"


def fmt_format(rng, c: CleanInput, pool):
    log = c.parsed()
    off, f = _fmt_records(log, rng)
    i = int(rng.integers(len(f.format)))
    valid = [ch for ch in FORMAT_TO_STRUCT if ch != f.format[i]]
    new_ch = _pick(rng, valid) if rng.random() < 0.7 else _pick(rng, ["X", "?", "\0", "z"])
    new = f.format[:i] + new_ch + f.format[i + 1:]
    buf = bytearray(c.data)
    _put_fmt(buf, off, fmt=new.encode("latin-1"))
    return bytes(buf), f"FMT of {f.name}: format {f.format!r} -> {new!r}"


def fmt_name(rng, c: CleanInput, pool):
    log = c.parsed()
    off, f = _fmt_records(log, rng, wanted_p=0.9)
    j = int(rng.integers(len(f.name)))
    new = f.name[:j] + chr(_LETTERS[int(rng.integers(26))]) + f.name[j + 1:]
    if new == f.name:
        new = f.name[:-1] + ("X" if f.name[-1] != "X" else "Y")
    buf = bytearray(c.data)
    _put_fmt(buf, off, name=new.encode()[:4])
    return bytes(buf), f"FMT of {f.name} renamed {new!r}"


def fmt_header_only(rng, c: CleanInput, pool):
    """An FMT redefining a decoded type (IMU or ATT most of the time) as header only -- Length 3, empty Format and
    Columns -- inserted between two records, then a record of that type (its 3 header bytes)."""
    log = c.parsed()
    if not isinstance(log, DataflashLog):
        raise NotApplicable("dataflash only")
    _, f = _fmt_records(log, rng, wanted_p=1.0)
    named = [g for g in log.formats.values() if g.name in ("IMU", "ATT") and g.offset >= 0]
    if named and rng.random() < 0.8:
        f = _pick(rng, named)
    r = _middle(rng, log.records)
    fmt = bytes((0xA3, 0x95, FMT_TYPE)) + FMT_BODY.pack(f.type, 3, f.name.encode()[:4], b"", b"")
    data = c.data[:r.offset] + fmt + bytes((0xA3, 0x95, f.type)) + c.data[r.offset:]
    return data, f"header-only FMT (Length 3, no Format, no Columns) redefining {f.name} at {r.offset}, then one {f.name}"


def repeat_timestamps(rng, c: CleanInput, pool):
    """One record of a decoded type (IMU most of the time) repeated many times in place: the same time stamp
    tens of thousands of times (memory must stay flat)."""
    log = c.parsed()
    buf = bytes(c.data)
    n = int(rng.choice([20_000, 60_000, 200_000]))
    if isinstance(log, DataflashLog):
        imu = [r for r in log.records if log.formats[r.type].name.startswith("IMU")]
        timed = imu if imu and rng.random() < 0.8 else [r for r in log.records if log.formats[r.type].time_column()]
        if not timed:
            raise NotApplicable("no timed record")
        r = _middle(rng, timed)
        rec = buf[r.offset:r.offset + log.formats[r.type].length]
        name, at = log.fmt(r).name, r.offset
    else:
        frames = [f for f in log.frames if f.msgid in (27, 116, 30)]  # RAW_IMU, SCALED_IMU2, ATTITUDE
        if not frames:
            raise NotApplicable("no IMU or ATTITUDE frame")
        f = _middle(rng, frames)
        rec, name, at = buf[f.offset:f.end], f"msgid {f.msgid}", f.offset
        n = min(n, 60_000)  # (a tlog frame carries its own 8-byte stamp: the same one repeated)
    return buf[:at] + rec * n + buf[at:], f"one {name} record at {at} repeated {n} times (one time stamp)"


def type_byte(rng, c: CleanInput, pool):
    log = c.parsed()
    buf = bytearray(c.data)
    if isinstance(log, DataflashLog):
        r = _middle(rng, [r for r in log.records if r.type != 0x80])
        new = int(rng.integers(256))
        if new == r.type:
            new = (new + 1) % 256
        buf[r.offset + 2] = new
        known = f"{log.formats[new].name}" if new in log.formats else "unknown"
        return bytes(buf), f"type byte of a {log.fmt(r).name} record at {r.offset}: {r.type} -> {new} ({known})"
    f = _middle(rng, log.frames)
    p = f.start + (5 if f.version == 1 else 7)
    new = (buf[p] + int(rng.integers(1, 256))) % 256
    buf[p] = new
    return bytes(buf), f"msgid byte of frame at {f.offset} (id {f.msgid}) -> {new} (CRC no longer matches)"


def imu_float(rng, c: CleanInput, pool):
    log = c.parsed()
    if not isinstance(log, DataflashLog):
        raise NotApplicable("tlog")
    imus = log.records_named(("IMU", "IMU2", "IMU3"))
    if not imus:
        raise NotApplicable("no IMU records")
    k0 = _middle(rng, imus)
    n = 1 if rng.random() < 0.7 else int(rng.integers(2, 51))
    run = [k for k in imus if k >= k0][:n]
    col = _pick(rng, ["AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ"])
    val = _pick(rng, BAD_FLOATS)
    buf = bytearray(c.data)
    for k in run:
        r = log.records[k]
        log.put(buf, r, col, val)
    r0 = log.records[run[0]]
    return bytes(buf), f"{log.fmt(r0).name}.{col} = {val!r} in {len(run)} record(s) from byte {r0.offset}"


# ----------------------------------------------------------------------------------------------- time
def _df_new_time(log: DataflashLog, r, delta, base=None) -> tuple[int, str]:
    """New raw value of a record's time column for a delta; and a note when the column cannot hold it."""
    col = log.fmt(r).time_column()
    code = log.column_code(r, col)
    v = log.get(r, col) if base is None else base
    scale = log.time_scale_s(r)
    if delta == "2^64ns":
        target = TWO64_NS_AS_US if scale == 1e-6 else TWO64_NS_AS_US // 1000 + 1
    elif delta == "back":
        target = v - v // 2
    else:
        target = v + int(round(delta / scale))
    hi = _UMAX.get(code, (1 << 63) - 1)
    if target > hi:
        return hi, f" ({col} is {code}: set to its maximum)"
    return max(0, target), ""


def _df_time(rng, c: CleanInput, delta, rest: bool):
    log = c.parsed()
    if not isinstance(log, DataflashLog):
        raise AssertionError
    cands = [k for k in log.timed(WANTED_DF) if log.fmt(log.records[k]).name != "MSG"]
    if delta == "2^64ns":  # only a 64-bit TimeUS column can hold it
        cands = [k for k in cands if log.time_scale_s(log.records[k]) == 1e-6]
    k0 = _middle(rng, cands, 0.2, 0.8)
    r0 = log.records[k0]
    buf = bytearray(c.data)
    col = log.fmt(r0).time_column()
    old = log.get(r0, col)
    new, note = _df_new_time(log, r0, delta)
    if not rest:
        log.put(buf, r0, col, new)
        return bytes(buf), f"{log.fmt(r0).name}.{col} at byte {r0.offset}: {old} -> {new}{note}"
    shift = new - old
    n = 0
    for k in log.timed():
        if k < k0:
            continue
        r = log.records[k]
        tc = log.fmt(r).time_column()
        v = log.get(r, tc)
        if log.fmt(r).name.startswith("GPS") and tc == "T" and v == 0:
            continue
        code = log.column_code(r, tc)
        shift_r = shift if tc == col else int(round(shift * log.time_scale_s(r0) / log.time_scale_s(r)))
        log.put(buf, r, tc, min(_UMAX.get(code, (1 << 63) - 1), max(0, v + shift_r)))
        n += 1
    return bytes(buf), f"from the {log.fmt(r0).name} record at byte {r0.offset} on, {n} times moved by {delta} ({col} {old} -> {new}){note}"


def _tlog_timed(log: Tlog) -> list[int]:
    return log.of_type(TLOG_TIME_FIELDS)


def _tlog_boot(msg) -> tuple[str, int] | None:
    name = TLOG_TIME_FIELDS.get(msg.get_type())
    if name is None:
        return None
    v = int(getattr(msg, name))
    if name == "time_usec" and not 0 < v < 10**15:
        return None  # GPS_RAW_INT before a fix (0) or in UTC: no boot time
    return name, v


def _tlog_new(name: str, v: int, delta) -> tuple[int, str]:
    scale = 1e-3 if name == "time_boot_ms" else 1e-6
    if delta == "2^64ns":
        target = TWO64_NS_AS_US if scale == 1e-6 else TWO64_NS_AS_US // 1000 + 1
    elif delta == "back":
        target = v - v // 2
    else:
        target = v + int(round(delta / scale))
    hi = 0xFFFFFFFF if name == "time_boot_ms" else (1 << 64) - 1
    if target > hi:
        return hi, f" ({name} is 32-bit: set to its maximum)"
    return target, ""


def _tlog_time(rng, c: CleanInput, delta, rest: bool):
    log = c.parsed()
    cands = [k for k in _tlog_timed(log) if _tlog_boot(log.decode(log.frames[k])) is not None]
    if delta == "2^64ns":  # only a 64-bit time_usec can hold it
        cands = [k for k in cands if _tlog_boot(log.decode(log.frames[k]))[0] == "time_usec"]
    k0 = _middle(rng, cands, 0.2, 0.8)
    f0 = log.frames[k0]
    msg0 = log.decode(f0)
    name, old = _tlog_boot(msg0)
    new, note = _tlog_new(name, old, delta)
    out = bytearray()
    n = 0
    pos = 0
    targets = [k0] if not rest else [k for k in cands if k >= k0]
    shift_s = (new - old) * (1e-3 if name == "time_boot_ms" else 1e-6)
    for k in targets:
        f = log.frames[k]
        msg = log.decode(f)
        b = _tlog_boot(msg)
        if b is None:
            continue
        fname, v = b
        if k == k0:
            nv = new
        else:  # the same shift in seconds, in this field's unit, within its range
            fs = 1e-3 if fname == "time_boot_ms" else 1e-6
            hi = 0xFFFFFFFF if fname == "time_boot_ms" else (1 << 64) - 1
            nv = min(hi, max(0, v + int(round(shift_s / fs))))
        setattr(msg, fname, nv)
        out += c.data[pos:f.start] + reframe(log.frame_bytes(f), msg)
        pos = f.end
        n += 1
    out += c.data[pos:]
    where = f"{msg0.get_type()}.{name} at byte {f0.offset}: {old} -> {new}{note}"
    return bytes(out), (f"{n} message times from {where}, moved by {delta}" if rest else where)


def time_kind(delta_key: str, rest: bool):
    delta = DELTAS[delta_key]

    def fn(rng, c: CleanInput, pool):
        if c.kind == "dataflash":
            return _df_time(rng, c, delta, rest)
        return _tlog_time(rng, c, delta, rest)

    fn.__name__ = f"time_{'rest' if rest else 'one'}{delta_key}"
    return fn


# ----------------------------------------------------------------------------------------------- tlog
def _stamp(rng, c: CleanInput, rest: bool):
    log = c.parsed()
    key = _pick(rng, list(DELTAS))
    delta = DELTAS[key]
    k0 = _middle(rng, list(range(len(log.frames))), 0.2, 0.8)
    buf = bytearray(c.data)
    old = log.frames[k0].stamp_us
    for k in range(k0, len(log.frames) if rest else k0 + 1):
        f = log.frames[k]
        if delta == "2^64ns":
            v = TWO64_NS_AS_US + (f.stamp_us - old)
        elif delta == "back":
            v = f.stamp_us - int(1e9)  # 1000 s back
        else:
            v = f.stamp_us + int(delta * 1e6)
        struct.pack_into(">Q", buf, f.offset, min(max(v, 0), (1 << 64) - 1))
    what = "the rest of the log" if rest else "one record"
    return bytes(buf), f"receive time of {what} from byte {log.frames[k0].offset} moved by {key}"


def stamp_one(rng, c, pool):
    return _stamp(rng, c, False)


def stamp_rest(rng, c, pool):
    return _stamp(rng, c, True)


def frame_length(rng, c: CleanInput, pool):
    log = c.parsed()
    f = _middle(rng, log.frames)
    buf = bytearray(c.data)
    d = int(rng.integers(1, 11)) * (1 if rng.random() < 0.5 else -1)
    old = buf[f.start + 1]
    buf[f.start + 1] = (old + d) % 256
    return bytes(buf), f"length byte of frame at {f.offset} (id {f.msgid}): {old} -> {buf[f.start + 1]}"


def msgid_byte(rng, c, pool):
    return type_byte(rng, c, pool)


def crc(rng, c: CleanInput, pool):
    log = c.parsed()
    n = 1 if rng.random() < 0.7 else int(rng.integers(2, 30))
    k0 = _middle(rng, list(range(len(log.frames))))
    buf = bytearray(c.data)
    for f in log.frames[k0:k0 + n]:
        end = f.end - (13 if f.version == 2 and buf[f.start + 2] & 1 else 0)
        buf[end - 1 - int(rng.integers(2))] ^= 1 + int(rng.integers(255))
    return bytes(buf), f"CRC of {n} frame(s) from byte {log.frames[k0].offset} broken"


def mix_v1v2(rng, c: CleanInput, pool):
    log = c.parsed()
    n = int(rng.integers(1, 201))
    k0 = _middle(rng, list(range(len(log.frames))))
    out, pos, conv = bytearray(), 0, 0
    for f in log.frames[k0:k0 + n]:
        msg = log.decode(f)
        if msg is None or (f.version == 2 and f.msgid > 255):
            continue
        out += c.data[pos:f.start] + reframe(log.frame_bytes(f), msg, 1 if f.version == 2 else 2)
        pos = f.end
        conv += 1
    out += c.data[pos:]
    return bytes(out), f"{conv} frames from byte {log.frames[k0].offset} re-encoded in the other MAVLink version"


#: (message, field, values) of field_extreme
EXTREMES = (
    ("GPS_RAW_INT", "lat", (900000000, -900000000, 2147483647, -2147483648)),
    ("GPS_RAW_INT", "lon", (1800000000, -1800000000, 2147483647)),
    ("GPS_RAW_INT", "alt", (2147483647, -2147483648)),
    ("GPS_RAW_INT", "eph", (0, 65535)),
    ("GPS_RAW_INT", "vel", (65534,)),
    ("GPS_RAW_INT", "fix_type", (255, 9)),
    ("GPS_RAW_INT", "satellites_visible", (255,)),
    ("RAW_IMU", "xacc", (32767, -32768)),
    ("RAW_IMU", "zacc", (32767, -32768)),
    ("RAW_IMU", "xgyro", (32767, -32768)),
    ("SCALED_IMU2", "zacc", (32767, -32768)),
    ("SYSTEM_TIME", "time_unix_usec", (40_000_000_000_000_000, (1 << 64) - 1, 1)),
    ("ATTITUDE", "roll", BAD_FLOATS),
    ("ATTITUDE", "yaw", BAD_FLOATS),
    ("ATTITUDE", "yawspeed", BAD_FLOATS),
    ("GLOBAL_POSITION_INT", "alt", (2147483647, -2147483648)),
)


def field_extreme(rng, c: CleanInput, pool):
    log = c.parsed()
    present = [e for e in EXTREMES if log.of_type([e[0]])]
    mtype, fname, values = _pick(rng, present)
    val = _pick(rng, values)
    frames = log.of_type([mtype])
    k0 = _middle(rng, frames)
    n = 1 if rng.random() < 0.6 else int(rng.integers(2, 21))
    run = [k for k in frames if k >= k0][:n]
    out, pos = bytearray(), 0
    for k in run:
        f = log.frames[k]
        msg = log.decode(f)
        if msg is None:
            continue
        setattr(msg, fname, val)
        out += c.data[pos:f.start] + reframe(log.frame_bytes(f), msg)
        pos = f.end
    out += c.data[pos:]
    return bytes(out), f"{mtype}.{fname} = {val!r} in {len(run)} message(s) from byte {log.frames[k0].offset}"


# ----------------------------------------------------------------------------------------------- registry
DF, TL = ("dataflash",), ("tlog",)
BOTH = DF + TL

KINDS: dict[str, Kind] = {
    "bitflip": Kind(bitflip, BOTH),
    "delete": Kind(delete, BOTH),
    "insert": Kind(insert, BOTH),
    "duplicate": Kind(duplicate, BOTH),
    "garbage": Kind(garbage, BOTH),
    "truncate": Kind(truncate, BOTH),
    "concat": Kind(concat, BOTH),
    "fmt_rename": Kind(fmt_rename, DF),
    "fmt_length": Kind(fmt_length, DF),
    "fmt_format": Kind(fmt_format, DF),
    "fmt_name": Kind(fmt_name, DF),
    "type_byte": Kind(type_byte, BOTH),
    "imu_float": Kind(imu_float, DF),
    "fmt_header_only": Kind(fmt_header_only, DF),
    "repeat_timestamps": Kind(repeat_timestamps, BOTH),
    **{f"time_one{k}": Kind(time_kind(k, False), BOTH) for k in DELTAS},
    **{f"time_rest{k}": Kind(time_kind(k, True), BOTH) for k in DELTAS},
    "stamp_one": Kind(stamp_one, TL),
    "stamp_rest": Kind(stamp_rest, TL),
    "frame_length": Kind(frame_length, TL),
    "crc": Kind(crc, TL),
    "mix_v1v2": Kind(mix_v1v2, TL),
    "field_extreme": Kind(field_extreme, TL),
}


def make_mutant(index: int, seed: int, inputs: Sequence[CleanInput], kinds: Sequence[str] | None = None) -> Mutant:
    """Mutant ``index`` of ``seed``: kind ``kinds[index % len(kinds)]``, everything else from its own Generator."""
    kinds = list(kinds or KINDS)
    kind = kinds[index % len(kinds)]
    k = KINDS[kind]
    rng = np.random.default_rng([seed, index])
    pool = [c for c in inputs if c.kind in k.formats]
    if not pool:
        raise NotApplicable(f"{kind}: no clean input of format {k.formats}")
    order = list(rng.permutation(len(pool)))
    for j in order:
        c = pool[int(j)]
        try:
            res = k.fn(rng, c, pool)
        except NotApplicable:
            continue
        data, desc = res[0], res[1]
        damaged = bool(res[2]) if len(res) > 2 else False
        extra = tuple(res[3]) if len(res) > 3 else ()
        return Mutant(index, seed, kind, (c.name, *extra), desc, data, c.suffix, damaged)
    raise NotApplicable(f"{kind}: applies to none of the inputs")
