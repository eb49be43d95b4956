"""Typed events: what every source emits and every pipeline stage consumes.

All values are SI with the unit (and frame, where one applies) in the field name. MAVLink's scaled
integers never appear here; they are converted in :mod:`companion.units` at ingest.

Time: ``t_s`` is seconds on one monotonic *vehicle* clock per source. It is the autopilot's boot time
(dataflash ``TimeMS``/``TimeUS``, MAVLink ``time_boot_ms``), continued across autopilot reboots: when
boot time jumps back, the clock adds the time reached before the reboot so ``t_s`` never runs
backwards by a reboot (see :mod:`companion.timebase`). Wall-clock time never enters an event.

Frames: body axes are FRD (forward-right-down, ArduPilot's body frame); local navigation axes NED.
Altitude datum: ``alt_msl_m`` is metres above mean sea level, as ArduPilot reports GNSS altitude
(GPS_RAW_INT.alt and dataflash GPS.Alt are MSL; the receiver's geoid model is not re-applied).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import ClassVar

from companion.mavlink.dialect import mavlink


class FixType(IntEnum):
    """MAVLink GPS_FIX_TYPE (common.xml); dataflash GPS.Status uses the same numbers."""

    NO_GPS = mavlink.GPS_FIX_TYPE_NO_GPS
    NO_FIX = mavlink.GPS_FIX_TYPE_NO_FIX
    FIX_2D = mavlink.GPS_FIX_TYPE_2D_FIX
    FIX_3D = mavlink.GPS_FIX_TYPE_3D_FIX
    DGPS = 4
    RTK_FLOAT = 5
    RTK_FIXED = 6
    STATIC = 7
    PPP = 8


@dataclass(frozen=True, slots=True)
class Event:
    """Base of all events. ``topic`` names the MCAP topic the event is recorded on."""

    t_s: float
    topic: ClassVar[str] = "/events"
    #: a stage's output of this type goes back to the pipeline's first stage as an input (companion.pipeline.core)
    feedback: ClassVar[bool] = False
    #: False for what passes between stages only and is not recorded (e.g. the truth of a GNSS denial)
    recorded: ClassVar[bool] = True

    def to_dict(self) -> dict:
        """Plain dict for JSON; NaN/inf become None (JSON has no NaN), tuples become lists."""
        out = {}
        for f in fields(self):
            out[f.name] = _jsonable(getattr(self, f.name))
        return out


def _jsonable(v):
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, (tuple, list)):
        return [_jsonable(x) for x in v]
    if isinstance(v, IntEnum):
        return int(v)
    return v


Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class ImuSample(Event):
    """One IMU sample. ``accel_frd_mps2`` is specific force (at rest, level: about (0, 0, -9.8)).

    ``imu_index`` is 0 for the first IMU (dataflash IMU / MAVLink RAW_IMU or SCALED_IMU),
    1 for IMU2 / SCALED_IMU2, 2 for IMU3 / SCALED_IMU3, 3 for MAVLink HIGHRES_IMU (the autopilot's primary IMU in
    floats).
    """

    accel_frd_mps2: Vec3
    gyro_frd_radps: Vec3
    imu_index: int
    topic: ClassVar[str] = "/input/imu"


@dataclass(frozen=True, slots=True)
class GnssFix(Event):
    """One GNSS receiver solution (or a report of no solution).

    Position fields are None unless ``has_position``: rows with fix_type < 2 or lat = lon = 0 carry
    no position (ArduPilot logs such rows while the fix is lost). ``alt_msl_m``: metres above mean sea
    level. Velocity components are None when the source does not give them (GPS_RAW_INT has ground
    speed and course but no vertical speed). Accuracy fields are None when not reported; ``hdop`` and
    ``vdop`` are unitless. ``gps_week`` / ``gps_tow_s`` are GPS time when the receiver gave it.
    ``instance`` is 0 for GPS1, 1 for GPS2.
    """

    fix_type: int
    lat_deg: float | None
    lon_deg: float | None
    alt_msl_m: float | None
    vel_n_mps: float | None
    vel_e_mps: float | None
    vel_d_mps: float | None
    ground_speed_mps: float | None
    course_deg: float | None
    satellites: int | None
    hdop: float | None
    vdop: float | None
    h_acc_m: float | None
    v_acc_m: float | None
    speed_acc_mps: float | None
    gps_week: int | None
    gps_tow_s: float | None
    instance: int = 0
    topic: ClassVar[str] = "/input/gnss"

    @property
    def has_position(self) -> bool:
        return self.lat_deg is not None and self.lon_deg is not None and self.fix_type >= FixType.FIX_2D

    @property
    def vel_ned_mps(self) -> Vec3 | None:
        """NED velocity when all three components are known."""
        if None in (self.vel_n_mps, self.vel_e_mps, self.vel_d_mps):
            return None
        return (self.vel_n_mps, self.vel_e_mps, self.vel_d_mps)  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class Attitude(Event):
    """Autopilot attitude estimate: Euler angles of body FRD relative to NED (ZYX: yaw, pitch, roll)."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    topic: ClassVar[str] = "/input/attitude"


@dataclass(frozen=True, slots=True)
class AirData(Event):
    """The autopilot's airspeed (MAVLink VFR_HUD.airspeed: on ArduPilot the airspeed sensor's equivalent airspeed
    when one is fitted and used, else its own estimate), m/s."""

    airspeed_mps: float
    topic: ClassVar[str] = "/input/air_data"


@dataclass(frozen=True, slots=True)
class WaterSpeed(Event):
    """A vessel's speed log: its speed through the water along the keel, m/s (on MAVLink a NAMED_VALUE_FLOAT of a
    configured name: companion.mavlink.speed_log). A boat's counterpart of AirData."""

    speed_mps: float
    topic: ClassVar[str] = "/input/water_speed"


@dataclass(frozen=True, slots=True)
class MagField(Event):
    """The autopilot's first compass, its calibrated field in the body frame (MAVLink RAW_IMU x/y/zmag), gauss."""

    field_frd_gauss: tuple[float, float, float]
    topic: ClassVar[str] = "/input/mag"


@dataclass(frozen=True, slots=True)
class SystemTime(Event):
    """Relation of the vehicle clock to UTC: at vehicle time ``t_s`` the UTC time was ``unix_time_s``."""

    unix_time_s: float
    topic: ClassVar[str] = "/input/system_time"


@dataclass(frozen=True, slots=True)
class Reboot(Event):
    """The autopilot rebooted: its boot time went from ``previous_boot_s`` back to ``new_boot_s``."""

    previous_boot_s: float
    new_boot_s: float
    topic: ClassVar[str] = "/input/reboot"


@dataclass(frozen=True, slots=True)
class StatusText(Event):
    """A text message from the autopilot (MAVLink STATUSTEXT, dataflash MSG). severity: MAV_SEVERITY."""

    severity: int
    text: str
    topic: ClassVar[str] = "/input/statustext"


@dataclass(frozen=True, slots=True)
class Heartbeat(Event):
    """Autopilot HEARTBEAT (live links and tlogs). ``armed`` from base_mode's safety-armed bit."""

    system_id: int
    component_id: int
    vehicle_type: int
    autopilot: int
    armed: bool
    custom_mode: int
    topic: ClassVar[str] = "/input/heartbeat"


@dataclass(frozen=True, slots=True)
class GravityReading(Event):
    """One gravimeter reading (anomaly in mGal, Eotvos-corrected unless the sender says otherwise). ``sigma_mgal``
    is None when the sender gives none. Sources: companion.sources.gravity (line protocol), the link's
    NAMED_VALUE_FLOAT (companion.mavlink.gravimeter), the simulated gravimeter (companion.sim.gravimeter)."""

    gravity_mgal: float
    sigma_mgal: float | None = None
    eotvos_corrected: bool = True
    sensor: str = ""
    topic: ClassVar[str] = "/input/gravity"


@dataclass(frozen=True, slots=True)
class PositionFix(Event):
    """A horizontal position measurement that is not GNSS (e.g. a gravity-matching fix), with its own
    1-sigma north/east uncertainty. The Navigator fuses it with its own gate; it never feeds the GNSS
    predictor. ``source`` names the producer ("gravity:viterbi", ...). A stage's PositionFix is fed back to the
    pipeline's first stages (``feedback``), so the navigator sees it like an input event. A producer that also
    estimates the vehicle's horizontal velocity (the sequential gravity filter) may send it with its 1-sigma; NaN:
    none (the navigator fuses a finite velocity as a measurement of its own, companion.nav.aids)."""

    lat_deg: float
    lon_deg: float
    sigma_n_m: float
    sigma_e_m: float
    source: str = ""
    vel_n_mps: float = math.nan
    vel_e_mps: float = math.nan
    sigma_vn_mps: float = math.nan
    sigma_ve_mps: float = math.nan
    topic: ClassVar[str] = "/input/position_fix"
    feedback: ClassVar[bool] = True  # a measurement for the navigator, which is the pipeline's first stage


@dataclass(frozen=True, slots=True)
class AutopilotAltitude(Event):
    """The autopilot's own altitude estimate (MAVLink GLOBAL_POSITION_INT.alt, metres MSL). On ArduPilot it is the
    EKF height, barometric by default (EK3_SRC1_POSZ = 1), so it survives a GNSS loss: the Navigator's vertical aid
    when the receiver is gone (an INS alone is unstable in height)."""

    alt_msl_m: float
    topic: ClassVar[str] = "/input/altitude"


@dataclass(frozen=True, slots=True)
class AutopilotPosition(Event):
    """The autopilot's own position estimate (its EKF's output): MAVLink GLOBAL_POSITION_INT, dataflash POS.
    Recorded for comparison (the Map track ``/map/autopilot`` beside ours); the navigator does not use it.
    ``source`` names the message it came from."""

    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    source: str
    topic: ClassVar[str] = "/input/autopilot_position"


#: Every event type, for schema registration and tests.
EVENT_TYPES: tuple[type[Event], ...] = (
    ImuSample,
    GnssFix,
    Attitude,
    AirData,
    WaterSpeed,
    MagField,
    SystemTime,
    Reboot,
    StatusText,
    Heartbeat,
    GravityReading,
    PositionFix,
    AutopilotAltitude,
    AutopilotPosition,
)
