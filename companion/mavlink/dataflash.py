"""ArduPilot dataflash ``.bin`` logs -> events (rows from companion.mavlink.dataflash_stream).

Time bases handled (see companion.timebase):
- AC 3.1-3.3: ``TimeMS`` = ms since boot on IMU/ATT; on GPS rows ``TimeMS`` is GPS time of week (ms)
  with ``Week``, and ``T`` is the boot time.
- AC 4.x: ``TimeUS`` = µs since boot everywhere; GPS has ``GMS``/``GWk`` (GPS time) and the accuracy
  fields come in a separate GPA row with the same ``TimeUS`` (merged into one GnssFix here).
- Instances: AC 3.x/4.0 name them IMU/IMU2/IMU3, GPS/GPS2, GPA/GPA2; AC 4.1+ use one name with ``I``.

Rows carry DFReader's values: the format multipliers applied, so Lat/Lng arrive in degrees, Alt in metres (MSL), Spd in m/s,
GCrs in degrees, VZ in m/s (NED, down positive), Acc* in m/s², Gyr* in rad/s, ATT angles in degrees.
"""

from __future__ import annotations

import math

import numpy as np

from companion.events import Attitude, AutopilotPosition, Event, FixType, GnssFix, ImuSample, StatusText
from companion.timebase import HOLD_REASONS, VehicleClock
from companion.mavlink.dialect import mavlink

WANTED = ["IMU", "IMU2", "IMU3", "GPS", "GPS2", "GPA", "GPA2", "ATT", "MSG", "POS"]
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

    def decode_block(self, block) -> list[Event]:
        """The events of a companion.mavlink.dataflash_stream.Block, in file order. IMU rows take a path prepared
        once per block (the checks of ``_imu`` done on whole columns); every other row goes through ``decode``."""
        out: list[Event] = []
        for rows, k in block.order:
            if rows is None:  # another log starts: a GPS row waiting for its GPA does not wait across logs
                out += self.flush()
                continue
            imu = rows.imu if hasattr(rows, "imu") else _prepare_imu(rows)
            if imu is None:
                out += self.decode(_Row(rows.fmt.name, dict(zip(rows.cols, rows.tuples[k]))))
            else:
                self._imu_prepared(imu, k, out)
        return out

    def _imu_prepared(self, imu, k: int, out: list[Event]) -> None:
        """``decode`` of one IMU row of a prepared block: same checks, same order, same counts."""
        boot, acc, gyr, inst, status = imu
        st = status[k]
        if st == _OUT_OF_RANGE_INSTANCE:
            self._drop(f"{imu.name} instance out of range")
            return
        if self._pending_gps:
            out += self.flush()
        if st:
            self._drop(_IMU_DROPS[st])
            return
        t_s = self._time(boot[k], out)
        if t_s is not None:
            out.append(ImuSample(t_s=t_s, accel_frd_mps2=acc[k], gyro_frd_radps=gyr[k], imu_index=inst[k]))

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
        if base == "POS":
            return self._pos(d)
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

    def _pos(self, d: dict) -> list[Event]:
        """POS: the autopilot's own position (its AHRS/EKF output; logs of older ArduPilot have none)."""
        boot_s = _boot_s(d, None)
        lat, lon, alt = _num(d.get("Lat")), _num(d.get("Lng")), _num(d.get("Alt"))
        if boot_s is None or lat is None or lon is None or alt is None:
            self._drop("POS without its time or position")
            return []
        if lat == 0 and lon == 0:  # no position yet (the EKF has no origin): normal, not counted
            return []
        if not (-90 < lat < 90 and -180 < lon < 180 and MIN_ALT_M <= alt <= MAX_ALT_M):
            self._drop("POS position out of range")
            return []
        out: list[Event] = []
        t_s = self._time(boot_s, out)
        if t_s is not None:
            out.append(AutopilotPosition(t_s=t_s, lat_deg=lat, lon_deg=lon, alt_msl_m=alt, source="POS"))
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


class _Row:
    """A dataflash row as the decoder reads it (pymavlink's DFMessage interface: get_type, to_dict)."""

    __slots__ = ("name", "d")

    def __init__(self, name: str, d: dict) -> None:
        self.name, self.d = name, d

    def get_type(self) -> str:
        return self.name

    def to_dict(self) -> dict:
        return self.d


_NON_FINITE, _BEYOND, _OUT_OF_RANGE_INSTANCE = 1, 2, 3
_IMU_DROPS = {_NON_FINITE: "IMU non-finite", _BEYOND: "IMU beyond any sensor's range (non-physical)"}
_INT_CHARS = set("bBhHiIqQM")
_NUM_CHARS = _INT_CHARS | set("fdgcCeEL")


class _PreparedImu(tuple):
    """(boot_s, accel, gyro, instance, status) per row of one block's IMU rows; ``name`` the message name."""

    name: str


def _prepare_imu(rows):
    """The column-wise checks of ``_imu`` for one format's rows of a block, or None when its columns are not the
    plain numeric ones (renamed, missing, text): those rows take the row-by-row path. Cached on ``rows``."""
    fmt, cols = rows.fmt, rows.cols
    rows.imu = None
    rows.tuples = None
    name = fmt.name
    if not name.startswith("IMU"):
        rows.tuples = list(zip(*cols.values()))
        return None
    chars = dict(zip(fmt.columns, fmt.chars))
    axes = ("AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ")
    tcol = "TimeUS" if "TimeUS" in cols else "TimeMS" if "TimeMS" in cols else None
    icol = "I" if name == "IMU" and "I" in cols else None
    if (tcol is None or chars.get(tcol) not in _INT_CHARS or any(chars.get(a) not in _NUM_CHARS for a in axes)
            or icol is not None and chars.get(icol) not in _INT_CHARS):
        rows.tuples = list(zip(*cols.values()))
        return None
    scale = 1e-6 if tcol == "TimeUS" else 1e-3
    boot = [v * scale for v in cols[tcol]]  # as _num: int * float, the same rounding as one at a time
    a = np.array([cols[c] for c in axes], dtype=float)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(a).all(axis=0)
        beyond = (np.abs(a[:3]).max(axis=0) > MAX_ACCEL_MPS2) | (np.abs(a[3:]).max(axis=0) > MAX_GYRO_RADPS)
    status = np.where(finite, np.where(beyond, _BEYOND, 0), _NON_FINITE)
    if icol is not None:
        inst = cols[icol]
        status = np.where((np.array(inst) >= 0) & (np.array(inst) <= 3), status, _OUT_OF_RANGE_INSTANCE)
    else:
        inst = [_INSTANCE.get(name, 0)] * len(boot)
    prepared = _PreparedImu((boot, list(zip(*(cols[c] for c in axes[:3]))), list(zip(*(cols[c] for c in axes[3:]))),
                             inst, status.tolist()))
    prepared.name = name
    rows.imu = prepared
    return prepared
