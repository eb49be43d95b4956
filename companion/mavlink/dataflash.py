"""ArduPilot dataflash ``.bin`` logs -> events (via pymavlink's DFReader).

Time bases handled (see companion.timebase):
- AC 3.1-3.3: ``TimeMS`` = ms since boot on IMU/ATT; on GPS rows ``TimeMS`` is GPS time of week (ms)
  with ``Week``, and ``T`` is the boot time.
- AC 4.x: ``TimeUS`` = µs since boot everywhere; GPS has ``GMS``/``GWk`` (GPS time) and the accuracy
  fields come in a separate GPA row with the same ``TimeUS`` (merged into one GnssFix here).
- Instances: AC 3.x/4.0 name them IMU/IMU2/IMU3, GPS/GPS2, GPA/GPA2; AC 4.1+ use one name with ``I``.

DFReader applies the format multipliers, so Lat/Lng arrive in degrees, Alt in metres (MSL), Spd in m/s,
GCrs in degrees, VZ in m/s (NED, down positive), Acc* in m/s², Gyr* in rad/s, ATT angles in degrees.
"""

from __future__ import annotations

import math

from companion.events import Attitude, Event, FixType, GnssFix, ImuSample, StatusText
from companion.timebase import HOLD_REASONS, VehicleClock
from companion.mavlink.dialect import mavlink

WANTED = ["IMU", "IMU2", "IMU3", "GPS", "GPS2", "GPA", "GPA2", "ATT", "MSG"]
#: beyond these an IMU row is not a measurement (ArduPilot's sensors saturate at 32 g and 2000-4000 deg/s); a
#: value like 1e22 would otherwise reach the filter's matrices
MAX_ACCEL_MPS2 = 1000.0
MAX_GYRO_RADPS = 100.0
MAX_SPEED_MPS = 1000.0
MIN_ALT_M, MAX_ALT_M = -1000.0, 100_000.0
_INSTANCE = {"IMU": 0, "IMU2": 1, "IMU3": 2, "GPS": 0, "GPS2": 1, "GPA": 0, "GPA2": 1}
MAV_SEVERITY_INFO = mavlink.MAV_SEVERITY_INFO


class DataflashDecoder:
    """Stateful: GPS rows wait for their GPA row (same TimeUS) so one GnssFix carries both."""

    def __init__(self) -> None:
        self.clock = VehicleClock()
        self._pending_gps: dict[int, dict] = {}  # instance -> GnssFix kwargs waiting for GPA
        self.firmware: str | None = None
        self.dropped: dict[str, int] = {}

    def _drop(self, why: str) -> None:
        self.dropped[why] = self.dropped.get(why, 0) + 1

    def _time(self, boot_s: float, out: list[Event]) -> float | None:
        """Vehicle time (None: drop the row, its time jumped back unconfirmed); Reboot events into ``out``."""
        t_s, reboot = self.clock.to_vehicle(boot_s)
        if reboot is not None:
            out.append(reboot)
        if t_s is None:
            self._drop(HOLD_REASONS[self.clock.last_hold])
        return t_s

    def decode(self, msg) -> list[Event]:
        try:
            return self._decode(msg)
        except (KeyError, TypeError, ValueError, OverflowError, AttributeError) as err:  # a row unlike its type's
            self._drop(f"{msg.get_type()} malformed ({err.__class__.__name__})")
            return []

    def _decode(self, msg) -> list[Event]:
        mtype = msg.get_type()
        base = mtype
        d = msg.to_dict()
        instance = _INSTANCE.get(mtype, 0)
        if "I" in d and mtype in ("IMU", "GPS", "GPA"):
            instance = d["I"]
            if not isinstance(instance, int) or not 0 <= instance <= 3:
                self._drop(f"{mtype} instance out of range")
                return []
        if self._pending_gps and not base.startswith("GPA"):
            return self.flush() + self._decode(msg)  # GPA comes right after its GPS row or not at all
        if base.startswith("IMU"):
            return self._imu(d, instance)
        if base.startswith("GPS"):
            return self._gps(d, instance)
        if base.startswith("GPA"):
            return self._gpa(d, instance)
        if base == "ATT":
            return self._att(d)
        if base == "MSG":
            return self._msg(d)
        return []

    def _imu(self, d: dict, instance: int) -> list[Event]:
        boot_s = _boot_s(d)
        out: list[Event] = []
        acc = tuple(d.get(k) for k in ("AccX", "AccY", "AccZ"))
        gyr = tuple(d.get(k) for k in ("GyrX", "GyrY", "GyrZ"))
        if boot_s is None or not all(isinstance(v, (int, float)) for v in acc + gyr):
            self._drop("IMU without its time or axes (columns missing or renamed)")
            return out
        if not all(math.isfinite(v) for v in acc + gyr):
            self._drop("IMU non-finite")
            return out
        if max(abs(v) for v in acc) > MAX_ACCEL_MPS2 or max(abs(v) for v in gyr) > MAX_GYRO_RADPS:
            self._drop("IMU beyond any sensor's range (non-physical)")
            return out
        t_s = self._time(boot_s, out)
        if t_s is None:
            return out
        out.append(ImuSample(t_s=t_s, accel_frd_mps2=acc, gyro_frd_radps=gyr, imu_index=instance))
        return out

    def _gps(self, d: dict, instance: int) -> list[Event]:
        out = self.flush_instance(instance)
        if "TimeUS" in d:  # AC 4.x
            boot_s = _num(d["TimeUS"], 1e-6)
            tow_ms, week = _num(d.get("GMS")), _num(d.get("GWk"))
        else:  # AC 3.x: TimeMS is GPS time of week, T is boot time
            boot_s = _num(d.get("T", 0), 1e-3)
            tow_ms, week = _num(d.get("TimeMS")), _num(d.get("Week"))
        if boot_s is None or boot_s <= 0:
            self._drop("GPS row without boot time")
            return out
        status = _num(d.get("Status", 0))
        status = int(status) if status is not None and 0 <= status <= 8 else 0
        lat, lon, alt = _num(d.get("Lat", 0.0)), _num(d.get("Lng", 0.0)), _num(d.get("Alt"))
        has_pos = (
            status >= FixType.FIX_2D
            and lat is not None
            and lon is not None
            and alt is not None
            and not (lat == 0 and lon == 0)
            and -90 < lat < 90
            and -180 < lon < 180
            and MIN_ALT_M <= alt <= MAX_ALT_M
        )
        if status >= FixType.FIX_2D and not has_pos:
            status = int(FixType.NO_FIX)
        spd, crs, vz = _num(d.get("Spd")), _num(d.get("GCrs")), _num(d.get("VZ"))
        if spd is not None and abs(spd) > MAX_SPEED_MPS or vz is not None and abs(vz) > MAX_SPEED_MPS:
            self._drop("GPS velocity beyond any vehicle's (non-physical)")
            spd = crs = vz = None
        if week is not None and not 0 < week < 65536:
            week = None
        if tow_ms is not None and not 0 <= tow_ms < 604_800_000:
            tow_ms = None
        vn = ve = None
        if has_pos and spd is not None and crs is not None:
            vn = spd * math.cos(math.radians(crs))
            ve = spd * math.sin(math.radians(crs))
        hdop = _num(d.get("HDop"))
        if hdop is not None and hdop < 0:
            hdop = None
        t_s = self._time(boot_s, out)
        if t_s is None:
            return out
        kwargs = dict(
            t_s=t_s,
            fix_type=status,
            lat_deg=lat if has_pos else None,
            lon_deg=lon if has_pos else None,
            alt_msl_m=alt if has_pos else None,
            vel_n_mps=vn,
            vel_e_mps=ve,
            vel_d_mps=vz if has_pos else None,
            ground_speed_mps=spd if has_pos else None,
            course_deg=crs if has_pos else None,
            satellites=int(d["NSats"]) if isinstance(d.get("NSats"), int) and 0 <= d["NSats"] < 255 else None,
            hdop=hdop if hdop is not None and hdop < 99.0 else None,  # 99.99 = unknown
            vdop=None,
            h_acc_m=None,
            v_acc_m=None,
            speed_acc_mps=None,
            gps_week=int(week) if week else None,
            gps_tow_s=tow_ms * 1e-3 if (tow_ms and week) else None,
            instance=instance,
        )
        if "TimeUS" not in d:  # AC 3.x logs have no GPA rows: nothing to wait for
            return out + [GnssFix(**kwargs)]
        kwargs["_boot_s"] = boot_s
        self._pending_gps[instance] = kwargs
        return out

    def _gpa(self, d: dict, instance: int) -> list[Event]:
        pending = self._pending_gps.pop(instance, None)
        if pending is None:
            return []
        boot_s = _num(d.get("TimeUS", 0), 1e-6)
        if boot_s is not None and abs(boot_s - pending["_boot_s"]) < 1e-3:
            vdop = _num(d.get("VDop"))
            pending["vdop"] = vdop if vdop and 0 < vdop < 99.0 else None
            for key, src in (("h_acc_m", "HAcc"), ("v_acc_m", "VAcc"), ("speed_acc_mps", "SAcc")):
                v = _num(d.get(src))
                pending[key] = float(v) if v and 0 < v < 1e6 else None
        pending.pop("_boot_s")
        return [GnssFix(**pending)]

    def flush_instance(self, instance: int) -> list[Event]:
        pending = self._pending_gps.pop(instance, None)
        if pending is None:
            return []
        pending.pop("_boot_s")
        return [GnssFix(**pending)]

    def flush(self) -> list[Event]:
        out: list[Event] = []
        for instance in sorted(self._pending_gps):
            out += self.flush_instance(instance)
        return out

    def _att(self, d: dict) -> list[Event]:
        boot_s = _boot_s(d)
        r, p, y = _num(d.get("Roll")), _num(d.get("Pitch")), _num(d.get("Yaw"))
        if boot_s is None or r is None or p is None or y is None or max(abs(r), abs(p), abs(y)) > 1e4:
            self._drop("ATT incomplete")
            return []
        out: list[Event] = []
        t_s = self._time(boot_s, out)
        if t_s is None:
            return out
        yaw = (y + 180.0) % 360.0 - 180.0
        out.append(
            Attitude(t_s=t_s, roll_rad=math.radians(r), pitch_rad=math.radians(p), yaw_rad=math.radians(yaw))
        )
        return out

    def _msg(self, d: dict) -> list[Event]:
        text = str(d.get("Message", ""))
        if self.firmware is None and ("Copter" in text or "Plane" in text or "Rover" in text):
            self.firmware = text
        boot_s = _boot_s(d, None)
        if boot_s is None:
            if self.clock.max_boot_s is None:
                return []
            boot_s = self.clock.max_boot_s  # AC 3.x MSG rows carry no time: place at latest
        out: list[Event] = []
        t_s = self._time(boot_s, out)
        if t_s is None:
            return out
        out.append(StatusText(t_s=t_s, severity=MAV_SEVERITY_INFO, text=text))
        return out


def _num(v, scale: float = 1.0) -> float | None:
    """A finite number from a row's field (None: missing, not a number, or non-finite)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    x = v * scale
    return x if math.isfinite(x) else None


def _boot_s(d: dict, default: float | None = 0.0) -> float | None:
    """Boot time of a row from ``TimeUS`` (AC 4.x) or ``TimeMS`` (AC 3.x); ``default`` when it has neither."""
    if "TimeUS" in d:
        return _num(d["TimeUS"], 1e-6)
    if "TimeMS" in d:
        return _num(d["TimeMS"], 1e-3)
    return default


#: the FMT record that defines FMT itself: the first record of every dataflash log (a second one: logs one after another)
FMT_OF_FMT = b"\xa3\x95\x80\x80\x59FMT\x00"


def log_starts(path: str) -> list[int]:
    """Byte offsets where a dataflash log starts in the file: [0] for one log, more for logs concatenated."""
    with open(path, "rb") as f:
        data = f.read()
    starts, i = [0], data.find(FMT_OF_FMT, 1)
    while i > 0:
        if i - starts[-1] > 2048:  # (a log's own FMT block is contiguous: only a new block far on is a new log)
            starts.append(i)
        i = data.find(FMT_OF_FMT, i + 1)
    return starts


def resync_reader(path: str, window: tuple[int, int] | None = None):
    """pymavlink's DFReader_binary whose index resynchronises: a record of an unknown type (a bad type byte) or
    bytes that are no record are skipped up to the next record header, and the rest of the log is read, like
    pymavlink's own parser skips bad data between records (its indexer stops at the first unknown type and drops
    everything after it). ``skipped_bytes`` / ``skipped_stretches`` count what was passed over; ``fmt_blocks``
    how many times the formats were defined from scratch (a second FMT block: logs one after another)."""
    import struct

    from pymavlink import DFReader

    class ResyncDFReader(DFReader.DFReader_binary):
        def __init__(self, filename, window=None):
            if window is None:
                super().__init__(filename, zero_time_base=False)
                return
            # one log of several in the file: its bytes alone, so its own FMT records define its formats
            DFReader.DFReader.__init__(self)
            self.filehandle = open(filename, "rb")
            self.filehandle.seek(window[0])
            self.data_map = self.filehandle.read(window[1] - window[0])
            self.data_len = len(self.data_map)
            self.HEAD1, self.HEAD2 = 0xA3, 0x95
            self.unpackers = {}
            self.formats = {0x80: DFReader.DFFormat(0x80, "FMT", 89, "BBnNZ", "Type,Length,Name,Format,Columns")}
            self._zero_time_base = False
            self.prev_type = None
            self.init_arrays_fast()
            self.init_clock()
            self.prev_type = None
            self._rewind(keep_messages=True)

        def close(self):
            if isinstance(self.data_map, bytes):
                self.filehandle.close()
                return
            super().close()

        def init_arrays_fast(self, progress_callback=None):
            """pymavlink's compiled indexer, and this one when that stopped before the end of the file."""
            initial = dict(self.formats)
            with _c_stdout_silenced():  # the compiled indexer printf()s "unknown msg type" to stdout
                super().init_arrays_fast(progress_callback=progress_callback)
            self.skipped_bytes = self.skipped_stretches = self.fmt_blocks = 0
            last_end = max((o[-1] + self.formats[t].len for t, o in enumerate(self.offsets) if o and t in self.formats),
                           default=0)
            if self.data_len - last_end > 528:
                self.formats = initial
                self.unit_lookup, self.mult_lookup = {}, {}
                self.init_arrays(progress_callback)

        def init_arrays(self, progress_callback=None):
            self.skipped_bytes = self.skipped_stretches = 0
            self.fmt_blocks = 0
            offsets: list[list[int]] = [[] for _ in range(256)]
            counts = [0] * 256
            formats = self.formats
            self._count = 0
            self.name_to_id, self.id_to_name = {}, {}
            fmt_type, special = 0x80, {}
            data, n = self.data_map, self.data_len
            h1, h2 = self.HEAD1, self.HEAD2
            header = bytes((h1, h2))
            parsed: set[tuple[int, bytes]] = set()
            unpack_fmt = struct.Struct(formats[fmt_type].msg_struct).unpack
            ofs, seen_fmt_at = 0, -1
            while ofs + 3 <= n:
                if data[ofs] != h1 or data[ofs + 1] != h2 or data[ofs + 2] not in formats:
                    nxt = data.find(header, ofs + 1)
                    nxt = n if nxt < 0 else nxt
                    if n - ofs >= 528 or n < 528:  # (block logs end in up to 528 bytes of padding)
                        self.skipped_bytes += nxt - ofs
                        self.skipped_stretches += 1
                    ofs = nxt
                    continue
                mtype = data[ofs + 2]
                fmt = formats[mtype]
                mlen = fmt.len
                if mlen < 3 or ofs + mlen > n:
                    break  # a record cut short by the end of the file
                body = data[ofs + 3:ofs + mlen]
                try:
                    if mtype == fmt_type:
                        elements = list(unpack_fmt(body))
                        ftype = elements[0]
                        if ftype == fmt_type and seen_fmt_at < 0 or ftype == fmt_type and ofs > seen_fmt_at + mlen:
                            self.fmt_blocks += 1
                        if ftype == fmt_type:
                            seen_fmt_at = ofs
                        mfmt = DFReader.DFFormat(ftype, DFReader.null_term(elements[2]), elements[1],
                                                 DFReader.null_term(elements[3]), DFReader.null_term(elements[4]),
                                                 oldfmt=formats.get(ftype))
                        formats[ftype] = mfmt
                        self.name_to_id[mfmt.name] = mfmt.type
                        self.id_to_name[mfmt.type] = mfmt.name
                        if mfmt.name in ("FMTU", "UNIT", "MULT"):
                            special[mfmt.type] = mfmt.name
                    elif mtype in special:
                        elements = list(struct.unpack(fmt.msg_struct, body))
                        kind = special[mtype]
                        if kind == "UNIT":
                            self.unit_lookup[chr(elements[1])] = DFReader.null_term(elements[2])
                        elif kind == "MULT":
                            self.mult_lookup[chr(elements[1])] = float("%.7g" % elements[2])
                        elif kind == "FMTU" and int(elements[1]) in formats:
                            fmt2 = formats[int(elements[1])]
                            if "UnitIds" in fmt.colhash:
                                fmt2.set_unit_ids(DFReader.null_term(elements[fmt.colhash["UnitIds"]]), self.unit_lookup)
                            if "MultIds" in fmt.colhash:
                                fmt2.set_mult_ids(DFReader.null_term(elements[fmt.colhash["MultIds"]]), self.mult_lookup)
                except Exception:  # noqa: BLE001 - a corrupt FMT/UNIT/MULT body: that record is bad data
                    self.skipped_bytes += 1
                    self.skipped_stretches += 1
                    ofs += 1
                    continue
                offsets[mtype].append(ofs)
                counts[mtype] += 1
                key = (mtype, bytes(body[fmt.instance_ofs:fmt.instance_ofs + fmt.instance_len])
                       if fmt.instance_field is not None else b"")
                if key not in parsed:  # the first record of each type (and instance) is parsed, as pymavlink does
                    parsed.add(key)
                    self.offset = ofs
                    self.remaining = n - ofs
                    self._parse_next()
                ofs += mlen
            self.offsets, self.counts, self.formats = offsets, counts, formats
            self._count = sum(counts)
            self.offset = 0

    DFReader.print = _pymavlink_said  # its own diagnostics would break the one-line error promise: counted instead
    return ResyncDFReader(path, window)


class _c_stdout_silenced:
    """File descriptors 1 and 2 to /dev/null for a moment (the C-level fprintf of pymavlink's compiled indexer),
    flushed before they are given back."""

    def __enter__(self):
        import ctypes
        import os
        import sys

        self._libc = ctypes.CDLL(None)
        for f in (sys.stdout, sys.stderr):
            try:
                f.flush()
            except (OSError, ValueError, AttributeError):
                pass
        self._saved = [os.dup(1), os.dup(2)]
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.dup2(null, 2)
        os.close(null)
        return self

    def __exit__(self, *exc):
        import os

        self._libc.fflush(None)
        for fd, saved in zip((1, 2), self._saved):
            os.dup2(saved, fd)
            os.close(saved)
        return False


#: what pymavlink's DFReader printed (its "Skipped N bad bytes", "bad header", ... lines), by first word
PYMAVLINK_SAID: dict[str, int] = {}


def _pymavlink_said(*args, **_kw) -> None:
    text = str(args[0]) if args else ""
    first = text.split(" ", 1)[0]
    PYMAVLINK_SAID[first] = PYMAVLINK_SAID.get(first, 0) + 1
    if text.startswith("Failed to parse "):  # "Failed to parse IMU/<struct> with len ..."
        key = "Failed " + text[len("Failed to parse "):].split("/", 1)[0]
        PYMAVLINK_SAID[key] = PYMAVLINK_SAID.get(key, 0) + 1
