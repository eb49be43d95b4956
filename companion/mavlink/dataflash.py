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
        mtype = msg.get_type()
        base = mtype
        d = msg.to_dict()
        instance = _INSTANCE.get(mtype, 0)
        if "I" in d and mtype in ("IMU", "GPS", "GPA"):
            instance = int(d["I"])
        if self._pending_gps and not base.startswith("GPA"):
            return self.flush() + self.decode(msg)  # GPA comes right after its GPS row or not at all
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
        boot = d.get("TimeUS")
        boot_s = boot * 1e-6 if boot is not None else d.get("TimeMS", 0) * 1e-3
        out: list[Event] = []
        acc = (d["AccX"], d["AccY"], d["AccZ"])
        gyr = (d["GyrX"], d["GyrY"], d["GyrZ"])
        if not all(math.isfinite(v) for v in acc + gyr):
            self._drop("IMU non-finite")
            return out
        t_s = self._time(boot_s, out)
        if t_s is None:
            return out
        out.append(ImuSample(t_s=t_s, accel_frd_mps2=acc, gyro_frd_radps=gyr, imu_index=instance))
        return out

    def _gps(self, d: dict, instance: int) -> list[Event]:
        out = self.flush_instance(instance)
        if "TimeUS" in d:  # AC 4.x
            boot_s = d["TimeUS"] * 1e-6
            tow_ms, week = d.get("GMS"), d.get("GWk")
        else:  # AC 3.x: TimeMS is GPS time of week, T is boot time
            boot_s = d.get("T", 0) * 1e-3
            tow_ms, week = d.get("TimeMS"), d.get("Week")
        if boot_s <= 0:
            self._drop("GPS row without boot time")
            return out
        status = int(d.get("Status", 0))
        lat, lon, alt = d.get("Lat", 0.0), d.get("Lng", 0.0), d.get("Alt")
        has_pos = (
            status >= FixType.FIX_2D
            and not (lat == 0 and lon == 0)
            and math.isfinite(lat)
            and math.isfinite(lon)
            and -90 <= lat <= 90
            and -180 <= lon <= 180
        )
        if status >= FixType.FIX_2D and not has_pos:
            status = int(FixType.NO_FIX)
        spd, crs, vz = d.get("Spd"), d.get("GCrs"), d.get("VZ")
        vn = ve = None
        if has_pos and spd is not None and crs is not None:
            vn = spd * math.cos(math.radians(crs))
            ve = spd * math.sin(math.radians(crs))
        hdop = d.get("HDop")
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
            satellites=d.get("NSats"),
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
        boot_s = d.get("TimeUS", 0) * 1e-6
        if abs(boot_s - pending["_boot_s"]) < 1e-3:
            vdop = d.get("VDop")
            pending["vdop"] = vdop if vdop and vdop < 99.0 else None
            for key, src in (("h_acc_m", "HAcc"), ("v_acc_m", "VAcc"), ("speed_acc_mps", "SAcc")):
                v = d.get(src)
                pending[key] = float(v) if v and math.isfinite(v) and v > 0 else None
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
        boot = d.get("TimeUS")
        boot_s = boot * 1e-6 if boot is not None else d.get("TimeMS", 0) * 1e-3
        r, p, y = d.get("Roll"), d.get("Pitch"), d.get("Yaw")
        if r is None or p is None or y is None or not all(math.isfinite(v) for v in (r, p, y)):
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
        boot = d.get("TimeUS")
        if boot is None:
            boot = d.get("TimeMS")
            boot_s = boot * 1e-3 if boot is not None else None
        else:
            boot_s = boot * 1e-6
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
