"""Simulated samples -> MAVLink 2 messages as an ArduCopter sends them over telemetry.

Encoders take SI values and return pymavlink message objects (``pymavlink.dialects.v20.ardupilotmega``);
every scaled integer goes through :mod:`companion.units`. ``telemetry_messages`` turns a whole
:class:`~companion.sim.flight.SimulatedFlight` into time-ordered messages; ``pack_stream`` frames them
(MAVLink 2, sequence numbers counting up) and stamps each with a receive time.

Streams (rates as an ArduCopter with SR_* set for a companion computer link):

* HEARTBEAT 1 Hz (MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode as ArduCopter builds it,
  armed bit while armed, custom_mode = ArduCopter mode number), plus a ground station's HEARTBEAT
  (system 255, component 190) 1 Hz as a GCS tlog contains;
* SYSTEM_TIME 1 Hz (time_unix_usec = boot epoch + boot time);
* GPS_RAW_INT at the GNSS rate (time_usec = boot time in us, as ArduPilot 3.x/4.x sends it);
* RAW_IMU at the IMU rate (time_usec boot time; acc mG, gyro mrad/s, mag mGauss, id 0, temperature cdegC);
* SCALED_IMU2 at the IMU rate (time_boot_ms; same units) when the flight has a second IMU;
* ATTITUDE at the attitude rate (autopilot estimate, rad and rad/s);
* STATUSTEXT at the flight's text times;
* NAMED_VALUE_FLOAT (name "GRAV" by default, value mGal, time_boot_ms) at the gravimeter's times when
  readings are given: what an ArduPilot Lua script ``gcs:send_named_float("GRAV", v)`` sends, from (1, 1).

``telemetry_messages(..., t_range=(t0, t1))`` builds only the messages sent in [t0, t1): a long flight is
framed a chunk at a time instead of holding every message object at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion import units

MAV_TYPE_QUADROTOR = mavlink2.MAV_TYPE_QUADROTOR
MAV_TYPE_GCS = mavlink2.MAV_TYPE_GCS
MAV_AUTOPILOT_ARDUPILOTMEGA = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
MAV_AUTOPILOT_INVALID = mavlink2.MAV_AUTOPILOT_INVALID
MAV_STATE_STANDBY = mavlink2.MAV_STATE_STANDBY
MAV_STATE_ACTIVE = mavlink2.MAV_STATE_ACTIVE
UINT16_MAX = 65535

#: ArduCopter modes in which it sets MAV_MODE_FLAG_GUIDED_ENABLED (AUTO, GUIDED, RTL, CIRCLE, LAND, ...).
_GUIDED_MODES = {3, 4, 6, 7, 9, 11, 21}

#: sort order of messages with the same boot time (ArduPilot's stream order is not specified; ours is fixed)
_ORDER = {"HEARTBEAT": 0, "SYSTEM_TIME": 1, "STATUSTEXT": 2, "RAW_IMU": 3, "SCALED_IMU2": 4, "ATTITUDE": 5, "GPS_RAW_INT": 6,
          "NAMED_VALUE_FLOAT": 7, "GLOBAL_POSITION_INT": 8}
#: the autopilot's barometric height error (Gauss-Markov): what GLOBAL_POSITION_INT.alt carries beside the truth
BARO_SIGMA_M = 1.0
BARO_TAU_S = 300.0


# ---------------------------------------------------------------------------------------------
# encoders
def heartbeat(armed: bool, custom_mode: int) -> mavlink2.MAVLink_heartbeat_message:
    """ArduCopter's HEARTBEAT: base_mode = custom | stabilize | manual input [| guided] [| armed]."""
    base = (
        mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        | mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    )
    if custom_mode in _GUIDED_MODES:
        base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
    if armed:
        base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    status = MAV_STATE_ACTIVE if armed else MAV_STATE_STANDBY
    return mavlink2.MAVLink_heartbeat_message(
        MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, base, int(custom_mode), status, 3
    )


def gcs_heartbeat() -> mavlink2.MAVLink_heartbeat_message:
    return mavlink2.MAVLink_heartbeat_message(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def system_time(boot_s: float, boot_epoch_us: int) -> mavlink2.MAVLink_system_time_message:
    return mavlink2.MAVLink_system_time_message(boot_epoch_us + units.us_from_s(boot_s), units.ms_from_s(boot_s))


def _dop_x100(dop: float) -> int:
    """eph/epv carry DOP x 100 (unitless); UINT16_MAX when unknown."""
    return UINT16_MAX if not math.isfinite(dop) else min(int(round(dop * 100.0)), UINT16_MAX - 1)


def gps_raw_int(
    boot_s: float,
    fix_type: int,
    lat_deg: float,
    lon_deg: float,
    alt_msl_m: float,
    vel_n_mps: float,
    vel_e_mps: float,
    hdop: float,
    vdop: float,
    satellites: int,
    *,
    alt_ellipsoid_m: float = 0.0,
    h_acc_m: float = math.nan,
    v_acc_m: float = math.nan,
    speed_acc_mps: float = math.nan,
) -> mavlink2.MAVLink_gps_raw_int_message:
    """GPS_RAW_INT as ArduPilot fills it; with fix_type < 2 lat/lon/alt are 0 and accuracies unknown."""
    has_fix = fix_type >= 2
    speed = math.hypot(vel_n_mps, vel_e_mps)
    if has_fix:
        course = math.degrees(math.atan2(vel_e_mps, vel_n_mps)) % 360.0
        cog = units.cdeg_from_deg(course) % 36000
    else:
        cog = UINT16_MAX

    def acc_mm(v: float) -> int:
        return units.mm_from_m(v) if (has_fix and math.isfinite(v)) else 0

    return mavlink2.MAVLink_gps_raw_int_message(
        units.us_from_s(boot_s),
        int(fix_type),
        units.degE7_from_deg(lat_deg) if has_fix else 0,
        units.degE7_from_deg(lon_deg) if has_fix else 0,
        units.mm_from_m(alt_msl_m) if has_fix else 0,
        _dop_x100(hdop),
        _dop_x100(vdop),
        min(units.cm_from_m(speed), UINT16_MAX - 1) if has_fix else 0,
        cog,
        int(satellites),
        units.mm_from_m(alt_ellipsoid_m) if has_fix else 0,
        acc_mm(h_acc_m),
        acc_mm(v_acc_m),
        acc_mm(speed_acc_mps),  # mm/s
        0,
        0,
    )


def _i16(v: int) -> int:
    return max(-32768, min(32767, v))


def raw_imu(boot_s: float, accel_frd_mps2, gyro_frd_radps, mag_frd_mgauss, temperature_c: float):
    """RAW_IMU in ArduPilot's scaling: acceleration mG, rotation mrad/s, field mGauss, temperature cdegC."""
    a = [_i16(units.mG_from_mps2(float(v))) for v in accel_frd_mps2]
    g = [_i16(units.mradps_from_radps(float(v))) for v in gyro_frd_radps]
    m = [_i16(int(round(float(v)))) for v in mag_frd_mgauss]
    return mavlink2.MAVLink_raw_imu_message(
        units.us_from_s(boot_s), *a, *g, *m, 0, _i16(int(round(temperature_c * 100.0)))
    )


def scaled_imu2(boot_s: float, accel_frd_mps2, gyro_frd_radps, mag_frd_mgauss, temperature_c: float):
    a = [_i16(units.mG_from_mps2(float(v))) for v in accel_frd_mps2]
    g = [_i16(units.mradps_from_radps(float(v))) for v in gyro_frd_radps]
    m = [_i16(int(round(float(v)))) for v in mag_frd_mgauss]
    return mavlink2.MAVLink_scaled_imu2_message(
        units.ms_from_s(boot_s), *a, *g, *m, _i16(int(round(temperature_c * 100.0)))
    )


def attitude(boot_s: float, euler_rad, rates_frd_radps):
    r, p, y = (float(v) for v in euler_rad)
    wr, wp, wy = (float(v) for v in rates_frd_radps)
    return mavlink2.MAVLink_attitude_message(units.ms_from_s(boot_s), r, p, y, wr, wp, wy)


def global_position_int(boot_s: float, lat_deg: float, lon_deg: float, alt_msl_m: float, home_alt_m: float,
                        vel_ned_mps, yaw_rad: float):
    """The autopilot's fused position (ArduPilot: EKF; its height barometric)."""
    vn, ve, vd = (units.cm_from_m(float(v)) for v in vel_ned_mps)
    hdg = units.cdeg_from_deg(math.degrees(yaw_rad) % 360.0) % 36000
    return mavlink2.MAVLink_global_position_int_message(
        units.ms_from_s(boot_s), units.degE7_from_deg(lat_deg), units.degE7_from_deg(lon_deg),
        units.mm_from_m(alt_msl_m), units.mm_from_m(alt_msl_m - home_alt_m), vn, ve, vd, hdg)


def baro_error_m(flight) -> np.ndarray:
    """Barometric height error at the ATTITUDE times (seeded by the flight's seed; the same for every time window)."""
    from companion.sim.sensors import gauss_markov

    ta = flight.truth_attitude.t_s
    dt = float(ta[1] - ta[0]) if len(ta) > 1 else 1.0
    rng = np.random.default_rng([int(flight.seed), 0xBA20])
    return gauss_markov(len(ta), dt, BARO_SIGMA_M, BARO_TAU_S, rng).reshape(-1)


def statustext(severity: int, text: str):
    raw = text.encode("ascii")
    if len(raw) > 50:
        raise ValueError(f"STATUSTEXT carries at most 50 characters, got {len(raw)}: {text!r}")
    return mavlink2.MAVLink_statustext_message(int(severity), raw, 0, 0)


def named_value_float(boot_s: float, name: str, value: float):
    """NAMED_VALUE_FLOAT as ``gcs:send_named_float(name, value)`` sends it (name at most 10 characters)."""
    raw = name.encode("ascii")
    if not 1 <= len(raw) <= 10:
        raise ValueError(f"NAMED_VALUE_FLOAT names are 1-10 characters, got {name!r}")
    return mavlink2.MAVLink_named_value_float_message(units.ms_from_s(boot_s), raw, float(value))


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Outgoing:
    """One message to send: the boot time it is sent at and who sends it."""

    boot_us: int
    msg: object
    src_system: int = 1
    src_component: int = 1


def _window(t_s, t_range) -> range:
    """Indices of the (sorted) send times ``t_s`` whose microsecond time lies in ``t_range`` = [t0, t1)."""
    t = np.asarray(t_s, dtype=float)
    if t_range is None:
        return range(len(t))
    us = np.round(t * 1e6)
    lo, hi = (np.round(v * 1e6) if math.isfinite(v) else v for v in t_range)
    return range(int(np.searchsorted(us, lo, "left")), int(np.searchsorted(us, hi, "left")))


def telemetry_messages(
    flight,
    *,
    heartbeat_hz: float = 1.0,
    system_time_hz: float = 1.0,
    gcs: bool = True,
    gravity: tuple[np.ndarray, np.ndarray] | None = None,
    gravity_name: str = "GRAV",
    t_range: tuple[float, float] | None = None,
    global_position: bool = False,
    baro_err_m: np.ndarray | None = None,
) -> list[Outgoing]:
    """Every message of a simulated flight sent in ``t_range`` (default: all), ordered by send time (boot time).

    ``gravity``: (boot times s, values mGal) of gravimeter readings, sent as NAMED_VALUE_FLOAT ``gravity_name``.
    ``global_position``: also GLOBAL_POSITION_INT at the ATTITUDE times (truth position, barometric height error
    ``baro_err_m`` from :func:`baro_error_m`, computed here when not given).
    """
    out: list[Outgoing] = []
    end_s = flight.duration_s
    # 1 Hz streams; SYSTEM_TIME a few ms after the heartbeat as a scheduler would send it
    n_hb = int(math.floor(end_s * heartbeat_hz)) + 1
    t_hb = np.arange(n_hb) / heartbeat_hz
    sel = _window(t_hb, t_range)
    if len(sel):
        armed = flight.armed_at(t_hb[sel.start:sel.stop])
        modes = flight.custom_mode_at(t_hb[sel.start:sel.stop])
        for t, arm, mode in zip(t_hb[sel.start:sel.stop], armed, modes):
            out.append(Outgoing(units.us_from_s(t), heartbeat(bool(arm), mode)))
    if gcs:
        for k in _window(t_hb + 0.5, t_range):
            out.append(Outgoing(units.us_from_s(t_hb[k] + 0.5), gcs_heartbeat(), 255, 190))
    n_st = int(math.floor(end_s * system_time_hz)) + 1
    t_st = np.arange(n_st) / system_time_hz + 0.005
    for k in _window(t_st, t_range):
        out.append(Outgoing(units.us_from_s(t_st[k]), system_time(t_st[k], flight.config.boot_epoch_us)))
    texts = sorted(flight.statustexts, key=lambda x: x[0])
    for k in _window([x[0] for x in texts], t_range):
        t, sev, text = texts[k]
        out.append(Outgoing(units.us_from_s(t), statustext(sev, text)))
    imu = flight.imu
    for k in _window(imu.t_s, t_range):
        t = imu.t_s[k]
        out.append(Outgoing(units.us_from_s(t), raw_imu(t, imu.accel_frd_mps2[k], imu.gyro_frd_radps[k], imu.mag_frd_mgauss[k], imu.temperature_c)))
    if flight.imu2 is not None:
        i2 = flight.imu2
        for k in _window(i2.t_s, t_range):
            t = i2.t_s[k]
            out.append(Outgoing(units.us_from_s(t), scaled_imu2(t, i2.accel_frd_mps2[k], i2.gyro_frd_radps[k], i2.mag_frd_mgauss[k], i2.temperature_c)))
    ta = flight.truth_attitude.t_s
    for k in _window(ta, t_range):
        out.append(Outgoing(units.us_from_s(ta[k]), attitude(ta[k], flight.attitude_euler_rad[k], flight.attitude_rates_radps[k])))
    g = flight.gnss
    for k in _window(g.t_s, t_range):
        t = g.t_s[k]
        out.append(
            Outgoing(
                units.us_from_s(t),
                gps_raw_int(
                    t, int(g.fix_type[k]), float(g.lat_deg[k]), float(g.lon_deg[k]), float(g.alt_msl_m[k]),
                    float(g.vel_ned_mps[k, 0]), float(g.vel_ned_mps[k, 1]), float(g.hdop[k]), float(g.vdop[k]),
                    int(g.satellites[k]), alt_ellipsoid_m=float(g.alt_ellipsoid_m[k]), h_acc_m=float(g.h_acc_m[k]),
                    v_acc_m=float(g.v_acc_m[k]), speed_acc_mps=float(g.speed_acc_mps[k]),
                ),
            )
        )
    if global_position:
        tr = flight.truth_attitude
        berr = baro_error_m(flight) if baro_err_m is None else baro_err_m
        home = float(tr.alt_msl_m[0])
        for k in _window(ta, t_range):
            out.append(Outgoing(units.us_from_s(ta[k]), global_position_int(
                ta[k], float(tr.lat_deg[k]), float(tr.lon_deg[k]), float(tr.alt_msl_m[k] + berr[k]), home,
                tr.vel_ned_mps[k], float(flight.attitude_euler_rad[k, 2]))))
    if gravity is not None:
        tg, vg = gravity
        for k in _window(tg, t_range):
            out.append(Outgoing(units.us_from_s(tg[k]), named_value_float(float(tg[k]), gravity_name, float(vg[k]))))
    out.sort(key=lambda o: (o.boot_us, _ORDER.get(o.msg.get_type(), 9)))  # stable: ties keep insertion order
    return out


@dataclass(frozen=True)
class LinkModel:
    """Serial link to the receiver: fixed processing delay plus transmission time at ``baud`` (10 bits/byte)."""

    latency_us: int = 500
    baud: int = 921_600


def pack_stream(
    messages: Sequence[Outgoing], boot_epoch_us: int, link: LinkModel = LinkModel()
) -> Iterable[tuple[int, bytes]]:
    """(receive time us since the Unix epoch, MAVLink 2 frame) for each message, in order.

    Each sender (system, component) has its own sequence counter. A message is received when the link
    has finished sending it: after its send time + latency and after the previous frame, plus its own
    transmission time; receive times therefore never decrease.
    """
    senders: dict[tuple[int, int], mavlink2.MAVLink] = {}
    link_free_us = 0
    for o in messages:
        key = (o.src_system, o.src_component)
        mav = senders.get(key)
        if mav is None:
            mav = senders[key] = mavlink2.MAVLink(None, srcSystem=o.src_system, srcComponent=o.src_component)
        frame = o.msg.pack(mav)
        mav.seq = (mav.seq + 1) % 256  # what MAVLink.send() does after packing
        ready = boot_epoch_us + o.boot_us + link.latency_us
        tx_us = (len(frame) * 10 * 1_000_000 + link.baud - 1) // link.baud
        link_free_us = max(link_free_us, ready) + tx_us
        yield link_free_us, bytes(frame)
