"""MAVLink messages -> events. One decoder for telemetry logs and live links.

Only messages from the autopilot are used: the first HEARTBEAT whose ``autopilot`` is not
MAV_AUTOPILOT_INVALID names the vehicle (system id, component id); messages from other systems or
components (ground stations, gimbals, this companion itself) are counted in ``dropped`` and skipped.

Time: messages with ``time_boot_ms`` (or a boot-time ``time_usec``) are placed by it. Others — and
GPS_RAW_INT, whose ``time_usec`` is 0 until the first fix and UTC in newer firmware — take the last
boot time seen plus the receive-time difference since then (tlog record time, or the live link's
receive time), so every event lands on the one vehicle clock.
"""

from __future__ import annotations

import math
from collections import Counter

from companion import units
from companion.events import (
    AirData,
    Attitude,
    MagField,
    AutopilotAltitude,
    AutopilotPosition,
    Event,
    FixType,
    GnssFix,
    Heartbeat,
    ImuSample,
    StatusText,
    SystemTime,
)
from companion.mavlink.dialect import mavlink
from companion.timebase import HOLD_REASONS, VehicleClock

MAV_AUTOPILOT_INVALID = mavlink.MAV_AUTOPILOT_INVALID
MAV_TYPE_GCS = mavlink.MAV_TYPE_GCS
MAV_MODE_FLAG_SAFETY_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
UINT16_MAX = 65535

#: Message types the decoder uses (a live link requests these; file readers skip the rest).
WANTED_TYPES = (
    "HEARTBEAT",
    "GPS_RAW_INT",
    "GPS2_RAW",
    "RAW_IMU",
    "SCALED_IMU",
    "SCALED_IMU2",
    "SCALED_IMU3",
    "HIGHRES_IMU",
    "ATTITUDE",
    "SYSTEM_TIME",
    "STATUSTEXT",
    "GLOBAL_POSITION_INT",
    "VFR_HUD",
)

_IMU_INDEX = {"RAW_IMU": 0, "SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
#: HIGHRES_IMU (ArduPilot: its primary IMU, in floats: RAW_IMU's int16 mrad/s truncates rates towards zero) is an IMU
#: index of its own, so that it never mixes with RAW_IMU's samples of the same sensor
HIGHRES_IMU_INDEX = 3
#: time_usec above this is a Unix epoch (after 2001), not a boot time.
_EPOCH_US = 1e15


#: the altitudes (m above mean sea level) a GNSS fix of a vehicle can have; beyond them the message is corrupt
MIN_ALT_M, MAX_ALT_M = -1000.0, 100_000.0
#: RAW_IMU's compass field goes out at most this often (s): a heading at 5 Hz; at the IMU's rate it would split the
#: runs of IMU samples the live loop coalesces when behind
MAG_PERIOD_S = 0.2
#: an IMU field at an int16 limit is a clamped value, not a reading (ArduPilot's IMUs span 16-32 g and 2000 deg/s:
#: 16000-32000 mG, 34907 mrad/s; the packer clamps what overflows), so the sample is unknown, not 32.8 g
INT16_MIN, INT16_MAX = -32768, 32767


def _finite(*vals: float) -> bool:
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals)


class MavlinkDecoder:
    """Stateful decoder: feed ``decode(msg, recv_s)``; it returns zero or more events."""

    def __init__(self, target_system: int | None = None, target_component: int | None = None, *, gravity=None,
                 speed_log=None) -> None:
        self.clock = VehicleClock()
        self.target_system = target_system
        self.target_component = target_component
        #: a companion.mavlink.gravimeter.NamedValueGravityDecoder (None: gravimeter readings are not decoded)
        self.gravity = gravity
        #: a companion.mavlink.speed_log.NamedValueSpeedLogDecoder (None: no water-speed log)
        self.speed_log = speed_log
        self._mag_t_s = -math.inf  # the last MagField sent (RAW_IMU compass, MAG_PERIOD_S apart)
        #: message type -> handler; and the message types taken from any component of the autopilot's system
        #: rather than from the autopilot component alone (source policy)
        self.handlers = dict(_HANDLERS)
        self.from_system: set[str] = set()
        if gravity is not None or speed_log is not None:
            # an autopilot Lua script sends as the autopilot, a sensor as its own component of the vehicle
            self.handlers["NAMED_VALUE_FLOAT"] = MavlinkDecoder._named_value
            self.from_system.add("NAMED_VALUE_FLOAT")
        self.dropped: Counter[str] = Counter()
        self._last_boot_s: float | None = None
        self._last_boot_recv_s: float | None = None

    # -- time ---------------------------------------------------------------------------------
    def _stamp(self, boot_s: float | None, recv_s: float, out: list[Event]) -> float | None:
        """Vehicle time for a message (None: drop it); emits a Reboot event into ``out`` when one is confirmed."""
        derived = boot_s is None
        if derived:
            if self._last_boot_s is None:
                return None
            boot_s = self._last_boot_s + max(0.0, recv_s - (self._last_boot_recv_s or recv_s))
        t_s, reboot = self.clock.to_vehicle(boot_s, derived=derived, recv_s=recv_s)
        if reboot is not None:
            out.append(reboot)
        if t_s is None:
            self.dropped[HOLD_REASONS[self.clock.last_hold]] += 1
            return None
        if not derived:
            self._last_boot_s = boot_s
            self._last_boot_recv_s = recv_s
        return t_s

    # -- messages -----------------------------------------------------------------------------
    def decode(self, msg, recv_s: float) -> list[Event]:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            self.dropped["bad frame"] += 1
            return []
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        if mtype == "HEARTBEAT" and self.target_system is None:
            if msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type != MAV_TYPE_GCS:
                self.target_system, self.target_component = src_sys, src_comp
        if self.target_system is None:
            self.dropped["before autopilot heartbeat"] += 1
            return []
        if src_sys != self.target_system or (src_comp != self.target_component and mtype not in self.from_system):
            self.dropped[f"other system {src_sys}/{src_comp}"] += 1
            return []
        handler = self.handlers.get(mtype)
        if handler is None:
            return []
        out: list[Event] = []
        try:
            handler(self, msg, recv_s, out)
        except (TypeError, ValueError, OverflowError) as err:  # malformed field values
            self.dropped[f"{mtype} malformed ({err.__class__.__name__})"] += 1
            return []
        return out

    def _heartbeat(self, msg, recv_s: float, out: list[Event]) -> None:
        t_s = self._stamp(None, recv_s, out)
        if t_s is None:
            return
        out.append(
            Heartbeat(
                t_s=t_s,
                system_id=msg.get_srcSystem(),
                component_id=msg.get_srcComponent(),
                vehicle_type=msg.type,
                autopilot=msg.autopilot,
                armed=bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
                custom_mode=msg.custom_mode,
            )
        )

    def _gps(self, msg, recv_s: float, out: list[Event]) -> None:
        instance = 1 if msg.get_type() == "GPS2_RAW" else 0
        boot_s = None
        # ArduPilot stamps GPS_RAW_INT with the time of the last fix: during an outage a no-fix message keeps the
        # time the fix was lost. Such a message is news of the outage now, not a late sample: it takes the stream's
        # time (the newest boot time plus the receive delta), like a message without a time stamp
        if 0 < msg.time_usec < _EPOCH_US and (int(msg.fix_type) >= FixType.FIX_2D or self._last_boot_s is None):
            boot_s = units.s_from_us(msg.time_usec)
        t_s = self._stamp(boot_s, recv_s, out)
        if t_s is None:
            if self._last_boot_s is None:
                self.dropped["GPS before any boot time"] += 1
            return
        fix = int(msg.fix_type)
        has_pos = fix >= FixType.FIX_2D and not (msg.lat == 0 and msg.lon == 0)
        lat = units.deg_from_degE7(msg.lat) if has_pos else None
        lon = units.deg_from_degE7(msg.lon) if has_pos else None
        if has_pos and not (-90.0 < lat < 90.0 and -180.0 < lon < 180.0 and MIN_ALT_M <= units.m_from_mm(msg.alt) <= MAX_ALT_M):
            # out of range, or saturated at the limits of its integer (a pole, the antimeridian, +-2147 km)
            self.dropped["GPS position out of range"] += 1
            has_pos, lat, lon = False, None, None
        if fix >= FixType.FIX_2D and not has_pos:
            fix = int(FixType.NO_FIX)  # a "fix" at 0,0 is no fix
        speed = units.m_from_cm(msg.vel) if msg.vel != UINT16_MAX else None
        course = units.deg_from_cdeg(msg.cog) if msg.cog != UINT16_MAX else None
        vn = ve = None
        if has_pos and speed is not None and course is not None:
            vn = speed * math.cos(math.radians(course))
            ve = speed * math.sin(math.radians(course))
        h_acc = getattr(msg, "h_acc", 0)
        v_acc = getattr(msg, "v_acc", 0)
        vel_acc = getattr(msg, "vel_acc", 0)
        out.append(
            GnssFix(
                t_s=t_s,
                fix_type=fix,
                lat_deg=lat,
                lon_deg=lon,
                alt_msl_m=units.m_from_mm(msg.alt) if has_pos else None,
                vel_n_mps=vn,
                vel_e_mps=ve,
                vel_d_mps=None,
                ground_speed_mps=speed if has_pos else None,
                course_deg=course if has_pos else None,
                satellites=msg.satellites_visible if msg.satellites_visible != 255 else None,
                hdop=msg.eph / 100.0 if msg.eph != UINT16_MAX else None,
                vdop=msg.epv / 100.0 if msg.epv != UINT16_MAX else None,
                h_acc_m=units.m_from_mm(h_acc) if h_acc else None,
                v_acc_m=units.m_from_mm(v_acc) if v_acc else None,
                speed_acc_mps=units.m_from_mm(vel_acc) if vel_acc else None,
                gps_week=None,
                gps_tow_s=None,
                instance=instance,
            )
        )

    def _imu(self, msg, recv_s: float, out: list[Event]) -> None:
        mtype = msg.get_type()
        if mtype == "RAW_IMU":
            boot_s = units.s_from_us(msg.time_usec) if 0 < msg.time_usec < _EPOCH_US else None
            index = 0  # ArduPilot sends IMU 0 as RAW_IMU (its `id` extension is not reliable in old firmware)
        else:
            boot_s = units.s_from_ms(msg.time_boot_ms)
            index = _IMU_INDEX[mtype]
        raw = (msg.xacc, msg.yacc, msg.zacc, msg.xgyro, msg.ygyro, msg.zgyro)
        if INT16_MIN in raw or INT16_MAX in raw:  # tuple membership: no generator per IMU message
            self.dropped[f"{mtype} clamped (a field at its int16 limit)"] += 1
            return
        t_s = self._stamp(boot_s, recv_s, out)
        if t_s is None:
            return
        acc = tuple(units.mps2_from_mG(v) for v in (msg.xacc, msg.yacc, msg.zacc))
        gyr = tuple(units.radps_from_mradps(v) for v in (msg.xgyro, msg.ygyro, msg.zgyro))
        out.append(ImuSample(t_s=t_s, accel_frd_mps2=acc, gyro_frd_radps=gyr, imu_index=index))
        if mtype == "RAW_IMU" and (msg.xmag or msg.ymag or msg.zmag) and not t_s - self._mag_t_s < MAG_PERIOD_S:
            self._mag_t_s = t_s  # ArduPilot's first compass (mGauss), at most every MAG_PERIOD_S (heading enough)
            out.append(MagField(t_s=t_s, field_frd_gauss=(msg.xmag * 1e-3, msg.ymag * 1e-3, msg.zmag * 1e-3)))

    def _highres_imu(self, msg, recv_s: float, out: list[Event]) -> None:
        vals = (msg.xacc, msg.yacc, msg.zacc, msg.xgyro, msg.ygyro, msg.zgyro)
        if not _finite(*vals):
            self.dropped["HIGHRES_IMU non-finite"] += 1
            return
        boot_s = units.s_from_us(msg.time_usec) if 0 < msg.time_usec < _EPOCH_US else None
        t_s = self._stamp(boot_s, recv_s, out)
        if t_s is not None:
            out.append(ImuSample(t_s=t_s, accel_frd_mps2=tuple(float(v) for v in vals[:3]),
                                 gyro_frd_radps=tuple(float(v) for v in vals[3:]), imu_index=HIGHRES_IMU_INDEX))

    def _attitude(self, msg, recv_s: float, out: list[Event]) -> None:
        if not _finite(msg.roll, msg.pitch, msg.yaw):
            self.dropped["ATTITUDE non-finite"] += 1
            return
        # roll in [-pi, pi], pitch in [-pi/2, pi/2]; yaw in [-pi, pi] (ArduPilot) or [0, 2 pi] (float32 rounding aside)
        if abs(msg.roll) > math.pi + 1e-3 or abs(msg.pitch) > math.pi / 2 + 1e-3 or abs(msg.yaw) > 2 * math.pi + 1e-3:
            self.dropped["ATTITUDE out of range"] += 1
            return
        t_s = self._stamp(units.s_from_ms(msg.time_boot_ms), recv_s, out)
        if t_s is None:
            return
        out.append(Attitude(t_s=t_s, roll_rad=msg.roll, pitch_rad=msg.pitch, yaw_rad=msg.yaw))

    def _vfr_hud(self, msg, recv_s: float, out: list[Event]) -> None:
        """VFR_HUD's airspeed (no time field: stamped on arrival); negative or beyond 300 m/s is corrupt."""
        if not (_finite(msg.airspeed) and 0.0 <= msg.airspeed <= 300.0):
            self.dropped["VFR_HUD airspeed out of range"] += 1
            return
        t_s = self._stamp(None, recv_s, out)
        if t_s is not None:
            out.append(AirData(t_s=t_s, airspeed_mps=float(msg.airspeed)))

    def _system_time(self, msg, recv_s: float, out: list[Event]) -> None:
        t_s = self._stamp(units.s_from_ms(msg.time_boot_ms), recv_s, out)
        if t_s is not None and msg.time_unix_usec > 0:
            out.append(SystemTime(t_s=t_s, unix_time_s=units.s_from_us(msg.time_unix_usec)))

    def _statustext(self, msg, recv_s: float, out: list[Event]) -> None:
        t_s = self._stamp(None, recv_s, out)
        if t_s is None:
            return
        text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
        out.append(StatusText(t_s=t_s, severity=int(msg.severity), text=text.rstrip("\x00")))

    def _global_position(self, msg, recv_s: float, out: list[Event]) -> None:
        t_s = self._stamp(units.s_from_ms(msg.time_boot_ms), recv_s, out)
        if t_s is None:
            return
        alt = units.m_from_mm(msg.alt)
        out.append(AutopilotAltitude(t_s=t_s, alt_msl_m=alt))
        if msg.lat == 0 and msg.lon == 0:  # no position yet (the EKF has no origin)
            return
        lat, lon = units.deg_from_degE7(msg.lat), units.deg_from_degE7(msg.lon)
        if -90.0 < lat < 90.0 and -180.0 < lon < 180.0 and MIN_ALT_M <= alt <= MAX_ALT_M:
            out.append(AutopilotPosition(t_s=t_s, lat_deg=lat, lon_deg=lon, alt_msl_m=alt, source="GLOBAL_POSITION_INT"))
        else:
            self.dropped["GLOBAL_POSITION_INT position out of range"] += 1

    def _named_value(self, msg, recv_s: float, out: list[Event]) -> None:
        """A gravimeter's or a speed log's NAMED_VALUE_FLOAT -> GravityReading / WaterSpeed on the vehicle clock
        (time_boot_ms; 0: receive time)."""
        for sensor in (self.gravity, self.speed_log):
            v = None if sensor is None else sensor.value(msg)
            if v is None:
                continue
            t_s = self._stamp(units.s_from_ms(msg.time_boot_ms) if msg.time_boot_ms else None, recv_s, out)
            if t_s is not None:
                out.append(sensor.reading(t_s, v))
            return


#: Handlers of the messages every decoder takes from the autopilot component (more per decoder: `handlers`).
_HANDLERS = {
    "HEARTBEAT": MavlinkDecoder._heartbeat,
    "GPS_RAW_INT": MavlinkDecoder._gps,
    "GPS2_RAW": MavlinkDecoder._gps,
    "RAW_IMU": MavlinkDecoder._imu,
    "SCALED_IMU": MavlinkDecoder._imu,
    "SCALED_IMU2": MavlinkDecoder._imu,
    "SCALED_IMU3": MavlinkDecoder._imu,
    "HIGHRES_IMU": MavlinkDecoder._highres_imu,
    "ATTITUDE": MavlinkDecoder._attitude,
    "SYSTEM_TIME": MavlinkDecoder._system_time,
    "STATUSTEXT": MavlinkDecoder._statustext,
    "GLOBAL_POSITION_INT": MavlinkDecoder._global_position,
    "VFR_HUD": MavlinkDecoder._vfr_hud,
}
