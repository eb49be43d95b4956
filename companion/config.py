"""Settings of the live companion (``companion run``): a TOML file with command-line overrides.

Every setting is checked when the process starts (:func:`load_config`): an unknown key, a wrong type, a
value out of range or a missing file is a :class:`ConfigError` naming the key, raised before any link is
opened. ``systemd/companion.toml`` is the annotated example; the defaults below are what an empty file gives.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.inject.gps_input import InjectConfig
from companion.nav.trust import TrustConfig
from companion.mavlink.dialect import mavlink


class ConfigError(Exception):
    """A setting is missing, unknown or invalid; ``str(err)`` names it."""


#: link settings' bounds: a floor keeps the process calm (a back-off of 1e-9 s logged 43,779 lines in 5 s), a ceiling
#: keeps the link watched
LINK_BOUNDS = (("heartbeat_hz", 0.1, 10.0), ("link_timeout_s", 0.5, 600.0), ("reconnect_min_s", 0.1, 600.0),
               ("reconnect_max_s", 0.1, 3600.0))
MIN_FLUSH_S = 0.1


#: Messages the runtime asks the autopilot for, with the rate (Hz) it asks for by default.
DEFAULT_STREAMS_HZ: dict[str, float] = {
    "GPS_RAW_INT": 10.0,
    "RAW_IMU": 50.0,
    "ATTITUDE": 10.0,
    "SYSTEM_TIME": 1.0,
    # the autopilot's own position: the Map track /map/autopilot beside ours (and, with gravity aiding, the
    # navigator's vertical aid)
    "GLOBAL_POSITION_INT": 5.0,
}
#: Messages SET_MESSAGE_INTERVAL may be asked for (what the decoder understands).
STREAMABLE = ("GPS_RAW_INT", "GPS2_RAW", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU", "ATTITUDE",
              "SYSTEM_TIME",
              "GLOBAL_POSITION_INT", "VFR_HUD")
#: requested as well when gravity aiding is on: the autopilot's barometric altitude, the navigator's vertical aid
GRAVITY_STREAMS_HZ = {"GLOBAL_POSITION_INT": 5.0}
#: ... and with gravity.reference = "air_data": the airspeed (VFR_HUD) and the heading (ATTITUDE)
AIR_DATA_STREAMS_HZ = {"VFR_HUD": 5.0, "ATTITUDE": 10.0, "RAW_IMU": 25.0}


@dataclass(frozen=True)
class LinkConfig:
    """The MAVLink link to the autopilot and how the companion presents itself on it."""

    connect: str = ""  # pymavlink's strings: udpin:/udpout:/udpbcast:/tcp:/tcpin:HOST:PORT, HOST:PORT, a serial device
    baud: int = 115200
    system_id: int = 1  # our system id (ArduPilot convention: the vehicle's own id for onboard components)
    component_id: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = 0  # 0: the first autopilot heard
    target_component: int = 0  # 0: the component of that first autopilot heartbeat
    heartbeat_hz: float = 1.0
    link_timeout_s: float = 3.0  # no message from the autopilot for this long: link lost
    reconnect_min_s: float = 0.5  # back-off of reconnection attempts: doubles from min to max
    reconnect_max_s: float = 8.0
    signing_key_file: str = ""  # MAVLink2 signing: 32-byte key (raw, or 64 hex characters); "" = unsigned
    allow_unsigned: bool = False  # with signing: also accept unsigned messages from the autopilot


@dataclass(frozen=True)
class StreamConfig:
    """Rates requested with MAV_CMD_SET_MESSAGE_INTERVAL and the watch on what actually arrives."""

    rates_hz: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_STREAMS_HZ))
    check_period_s: float = 5.0  # measure arrival rates over this window
    min_fraction: float = 0.5  # a rate below this fraction of the request is re-requested


@dataclass(frozen=True)
class RecordConfig:
    out: str = "out/live.mcap"  # MCAP file; a directory: a new companion-<UTC time>.mcap in it per run
    flush_interval_s: float = 1.0
    fsync: bool = False
    # start a new file (NAME-000.mcap, NAME-001.mcap, ...) every this many seconds of vehicle time so a
    # service that runs for hours keeps flat memory (an MCAP writer indexes every chunk until it closes);
    # 0 writes one file (the default for interactive runs; the service's example config sets 900)
    segment_s: float = 0.0
    # disk budget (0: none): segments are cut at a quarter of it and the oldest deleted (companion.record.rotating);
    # with segment_s = 0 files are cut by size only. With `out` a directory it bounds the directory: earlier runs'
    # companion-<UTC>.mcap records there count and are deleted first, oldest first (the service's example sets 2000)
    max_total_mb: float = 0.0


@dataclass(frozen=True)
class GravityConfig:
    """Gravity-aided navigation on a live vehicle (companion.gravity.stage): gravimeter readings arrive as MAVLink
    NAMED_VALUE_FLOAT(name, value in mGal, time_boot_ms) from the autopilot's system -- an autopilot Lua script's
    gcs:send_named_float or a gravimeter component -- and are matched against ``map``; the fixes go into the
    navigator as position measurements. Off while ``map`` is empty."""

    map: str = ""  # gravity anomaly grid (netCDF, mGal) covering the area flown
    matcher: str = "viterbi"  # viterbi | knn | iccp (window matchers) | sequential (every reading, slow vehicles)
    named_value: str = "GRAV"  # NAMED_VALUE_FLOAT.name of the readings (1-10 characters)
    # false: the readings still hold the Eotvos term (a gravimeter that does not know the vehicle's velocity); the
    # gravity stage corrects them with the navigator's velocity (as flown on ArduPlane SITL: docs/decisions/0012)
    eotvos_corrected: bool = True
    sigma_mgal: float = 1.0  # gravimeter noise per reading (matcher likelihood, acceptance test)
    feed_spacing_m: float = 0.0  # average readings over this much track per matcher sample; 0: one map cell
    accept_min_track_cells: float = 2.0  # fix acceptance: matcher window >= this many map cells of track
    accept_min_signal_ratio: float = 1.0  # ... and map signal along it >= this x sigma_mgal; 0 and 0: accept all
    # matcher = "sequential" (companion.gravity.sequential_stage): the filter's particles and the error sources of
    # the vehicle's INS as the filter assumes them (1 sigma; defaults: marine grade, Liu 2019 sec. 4.1)
    seq_particles: int = 1000
    seq_gyro_bias_degph: float = 0.01
    seq_accel_bias_ug: float = 100.0
    seq_gyro_arw_deg_rthr: float = 0.001
    seq_accel_vrw_ug_rthz: float = 10.0
    seq_init_vel_sigma_mps: float = 0.05
    # > 0: the navigator's attitude is held by the autopilot's AHRS (fused attitude): its error's time constant and
    # sigmas replace the gyro terms in the filter's INS model (companion.gravity.sequential.InsErrorSpec)
    seq_attitude_tau_s: float = 0.0
    seq_attitude_tilt_sigma_rad: float = 0.0
    seq_attitude_heading_sigma_rad: float = 0.0
    seq_noise_corr_s: float = 1.0  # the gravimeter's noise correlation time (its output filter; 1 s: white at 1 Hz)
    seq_min_gain: float = 0.1  # a fix goes out when the filter is this fraction more certain than the navigator
    # the fix also carries the filter's estimate of the navigator's horizontal velocity (its velocity-error states,
    # the navigator's own velocity variance divided out); the navigator fuses it as a measurement of its own
    seq_velocity_fixes: bool = False
    # the sequential filter's reference motion: "navigator" (the navigator's state; its fixes go back into it) or
    # "air_data" (a fixed wing: airspeed along the heading plus the wind learnt with GNSS, companion.gravity.air_data;
    # in a GNSS outage the stage's own state replaces the navigator's towards the injector, nothing goes back)
    reference: str = "navigator"
    air_wind_window_s: float = 300.0  # the wind held at a GNSS loss: the mean over this long before it
    # a boat: the reference's speed is its water-speed log, NAMED_VALUE_FLOAT of this name (m/s, companion.mavlink
    # .speed_log), not VFR_HUD's airspeed (on ArduRover the GPS's ground speed: the companion's own fixes in an
    # outage); the current takes the wind's place; "": the airspeed
    air_speed_log: str = ""
    # the correction an outage state carries moves towards the filter's at most this fast (m/s) beyond the reckoning,
    # the rest added to its stated covariance: an autopilot that fuses the states (ArduRover's EKF3) fails their
    # velocity check when the position jumps; 0: no limit (docs/decisions/0020-gravity-aiding-on-a-boat.md)
    air_correction_rate_mps: float = 0.0
    # the velocity its states carry is low-passed over this long (s; 0: raw): the air velocity's pitot noise and gusts
    # step it several m/s between states otherwise (docs/decisions/0016-air-data-velocity.md)
    air_output_tau_s: float = 1.0
    # the reference's heading: "attitude" (ATTITUDE yaw: EKF3's, which the fixes sent can turn), "magnetometer" (the
    # compass in RAW_IMU levelled by ATTITUDE roll/pitch, plus its offset to ATTITUDE yaw learnt while GNSS is good) or
    # "gyro" (RAW_IMU's gyro integrated, levelled by ATTITUDE roll/pitch, its bias learnt while GNSS is good)
    air_heading: str = "attitude"
    # air_heading = "gyro" (companion.gravity.gyro_heading): the z-gyro bias and alignment are fitted over this much of
    # the latest GNSS period; the bias's in-run drift (deg/h per sqrt(h)) and the integration's angle random walk
    # (deg/sqrt(h)) the heading's stated error grows by in an outage
    air_gyro_window_s: float = 1200.0
    # the gyro's message: "RAW_IMU" (int16 mrad/s, truncated towards zero by ArduPilot) or "HIGHRES_IMU" (floats;
    # requested at RAW_IMU's air-data rate)
    air_gyro_source: str = "RAW_IMU"
    air_gyro_bias_walk_degph_rth: float = 5.0
    air_gyro_arw_deg_rth: float = 0.5
    # air data: the held wind's error, a random walk (1 sigma per sqrt(s)); its prior is seq_init_vel_sigma_mps
    seq_wind_walk_mps_rts: float = 0.1
    # air data: a wind shift the readings show (their NIS over a minute above seq_wind_shift_nis_ratio x the outage's so
    # far) adds a step of this 1-sigma to the held wind's error along the readings' Eotvos direction; 0: off
    # (companion.gravity.wind_shift, docs/decisions/0017-wind-shift.md)
    seq_wind_shift_mps: float = 5.0
    seq_wind_shift_nis_ratio: float = 5.0
    # air data: a shift of the filter's estimate beyond this chi-square (2 dof) under what its covariance allowed, at
    # one reading or over the last 10 min, is added to every accuracy stated for the rest of the outage; 0: off
    # (companion.gravity.jump_guard, docs/decisions/0018-jump-guard.md)
    seq_jump_chi2: float = 9.21
    # air data: the speed accuracy its states state is never below this (the autopilot fuses their velocity by it, and
    # their velocity is made of the autopilot's own heading: a large value keeps that heading from following it)
    air_speed_sigma_floor_mps: float = 0.0
    # a reading describes the vehicle this long before its stamp (a gravimeter averaging over a window: half of it)
    reading_delay_s: float = 0.0


@dataclass(frozen=True)
class Config:
    link: LinkConfig = field(default_factory=LinkConfig)
    streams: StreamConfig = field(default_factory=StreamConfig)
    inject: InjectConfig = field(default_factory=InjectConfig)
    #: when the navigator's solution may carry the vehicle through an outage (inject.activate = "takeover")
    trust: TrustConfig = field(default_factory=TrustConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    gravity: GravityConfig = field(default_factory=GravityConfig)
    #: NavigatorConfig settings (companion.nav.navigator) to change, e.g. the noise of the vehicle's sensors;
    #: empty: the defaults (with [gravity]: companion.gravity.stage.gravity_nav_config)
    navigator: dict[str, Any] = field(default_factory=dict)
    duration_s: float = 0.0  # stop after this long (0: run until SIGTERM/SIGINT)

    def as_flat_dict(self) -> dict[str, str]:
        """section.key -> value text, for the MCAP ``config`` metadata."""
        out: dict[str, str] = {"duration_s": str(self.duration_s)}
        for sec in ("link", "streams", "inject", "trust", "record", "gravity"):
            for k, v in dataclasses.asdict(getattr(self, sec)).items():
                out[f"{sec}.{k}"] = str(v)
        for k, v in sorted(self.navigator.items()):
            out[f"navigator.{k}"] = str(v)
        return out

    def nav_config(self):
        """The NavigatorConfig of the run: defaults (gravity-aided: gravity_nav_config; the sequential filter's fixes
        correct the position only) with [navigator] applied."""
        if self.gravity.map:
            from companion.gravity.stage import gravity_nav_config

            return gravity_nav_config(**{"position_fix_position_only": self.gravity.matcher == "sequential",
                                         **self.navigator})
        if not self.navigator:
            return None
        from companion.nav.navigator import NavigatorConfig

        return NavigatorConfig(**self.navigator)


_SECTIONS = {"link": LinkConfig, "inject": InjectConfig, "trust": TrustConfig, "record": RecordConfig,
             "gravity": GravityConfig}

#: The range every numeric setting must lie in, from the unit in its name (longest suffix first); a value outside
#: its range is a start-up error, so no setting can make the process spin, fill the disk or claim nonsense.
_UNIT_RANGES: tuple[tuple[str, tuple[float, float]], ...] = (
    ("_mps2_rthz", (0.0, 100.0)), ("_radps_rthz", (0.0, 10.0)), ("_mps2", (0.0, 1000.0)), ("_radps", (0.0, 10.0)),
    ("_mps", (0.0, 1000.0)), ("_hz", (1e-3, 1000.0)), ("_rad", (0.0, 2.0 * math.pi)), ("_deg", (0.0, 360.0)),
    ("_mgal", (0.0, 1e4)), ("_chi2", (0.1, 1e4)), ("_s", (0.0, 86400.0)), ("_m", (0.0, 1e6)),
)
#: Settings whose sane range is narrower than their unit's, or that have no unit (counts, ratios, indices).
_RANGES: dict[str, tuple[float, float]] = {
    "duration_s": (0.0, 1e8),
    "link.baud": (1200, 20_000_000), "link.system_id": (1, 255), "link.component_id": (1, 255),
    "link.target_system": (0, 255), "link.target_component": (0, 255),
    "streams.check_period_s": (0.5, 600.0), "streams.min_fraction": (1e-3, 1.0),
    "inject.gps_id": (0, 1), "inject.receiver_instance": (0, 1), "inject.satellites": (6, 254),
    "inject.max_lag_s": (0.01, 5.0), "inject.autopilot_lag_s": (0.0, 0.25), "inject.receiver_lag_s": (0.0, 2.0),
    "inject.consistency_window_s": (0.05, 10.0), "inject.gnss_timeout_s": (0.05, 60.0),
    "trust.max_nis_ratio": (0.1, 1e4), "trust.receiver_instance": (0, 1), "trust.report_interval_s": (0.1, 3600.0),
    "record.flush_interval_s": (0.05, 3600.0), "record.segment_s": (0.0, 86400.0), "record.max_total_mb": (0.0, 1e7),
    "gravity.accept_min_track_cells": (0.0, 1e4), "gravity.accept_min_signal_ratio": (0.0, 1e9),
    "gravity.sigma_mgal": (1e-3, 1e4),
    "gravity.seq_particles": (50, 20_000), "gravity.seq_gyro_bias_degph": (0.0, 1e4), "gravity.seq_accel_bias_ug": (0.0, 1e6),
    "gravity.seq_gyro_arw_deg_rthr": (0.0, 100.0), "gravity.seq_accel_vrw_ug_rthz": (0.0, 1e6),
    "gravity.seq_init_vel_sigma_mps": (1e-4, 100.0), "gravity.seq_noise_corr_s": (0.0, 3600.0),
    "gravity.seq_min_gain": (0.0, 0.99), "gravity.seq_wind_walk_mps_rts": (0.0, 10.0),
    "gravity.seq_wind_shift_mps": (0.0, 50.0), "gravity.seq_wind_shift_nis_ratio": (1.01, 1e6),
    "gravity.seq_jump_chi2": (0.0, 1e6),
    "gravity.air_gyro_window_s": (120.0, 7200.0), "gravity.air_gyro_bias_walk_degph_rth": (0.0, 1000.0),
    "gravity.air_gyro_arw_deg_rth": (0.0, 100.0), "gravity.air_output_tau_s": (0.0, 60.0),
    "gravity.air_correction_rate_mps": (0.0, 1e3),
    "gravity.reading_delay_s": (0.0, 600.0),
    "navigator.imu_index": (0, 3), "navigator.gnss_instance": (0, 1), "navigator.gnss_delay_s": (0.0, 1.0),
    "navigator.gnss_vel_delay_s": (0.0, 1.0),
    "navigator.reorder_window_s": (0.0, 2.0), "navigator.max_imu_step_s": (1e-3, 1.0),
    "navigator.rate_window_s": (0.1, 60.0), "navigator.imu_timeout_s": (0.1, 60.0),
    "navigator.reset_after_n_rejected": (1, 10000),
    "navigator.att_reset_after_n_rejected": (1, 10000), "navigator.reset_cov_scale": (1.0, 1000.0),
    "navigator.future_confirm_n": (1, 1000), "navigator.predictor_sigma_scale": (0.1, 100.0),
    "navigator.ahrs_check_min_coherence": (0.0, 1.0), "navigator.output_rate_hz": (0.1, 50.0),
}
#: record.segment_s between 0 (one file) and this is refused: a new file every few seconds is a runaway
MIN_SEGMENT_S = 10.0
#: record.max_total_mb between 0 (no budget) and this is refused: segments of a quarter of it would be a few chunks
MIN_BUDGET_MB = 1.0


def setting_range(where: str) -> tuple[float, float] | None:
    """The (min, max) a numeric setting ``section.key`` must lie in, or None when nothing bounds it."""
    if where in _RANGES:
        return _RANGES[where]
    key = where.rpartition(".")[2]
    for suffix, rng in _UNIT_RANGES:
        if key.endswith(suffix):
            return rng
    return None


def _in_range(where: str, value: float) -> float:
    rng = setting_range(where)
    if rng is None:
        raise ConfigError(f"{where}: no range is known for this setting")  # every numeric setting has one (tested)
    lo, hi = rng
    if not lo <= value <= hi:
        raise ConfigError(f"{where}: {value!r} is out of range {lo:g}..{hi:g}")
    return value


def _coerce(where: str, value: Any, default: Any, check_range: bool = True) -> Any:
    """Check ``value`` against the type of the default (ints are accepted for floats) and numbers against their range."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return _in_range(where, value) if check_range else value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: must be finite, got {value!r}")
        return _in_range(where, float(value)) if check_range else float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    raise ConfigError(f"{where}: unsupported setting")  # pragma: no cover


def _section(name: str, cls, table: Any):
    if not isinstance(table, dict):
        raise ConfigError(f"[{name}] must be a table")
    defaults = cls()
    known = {f.name for f in dataclasses.fields(cls)}
    kw = {}
    for k, v in table.items():
        if k not in known:
            raise ConfigError(f"[{name}] unknown setting {k!r} (known: {', '.join(sorted(known))})")
        kw[k] = _coerce(f"{name}.{k}", v, getattr(defaults, k))
    try:
        return cls(**kw)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"[{name}] {err}") from None


def _streams(table: Any) -> StreamConfig:
    if not isinstance(table, dict):
        raise ConfigError("[streams] must be a table")
    d = StreamConfig()
    rates = dict(d.rates_hz)
    kw: dict[str, Any] = {}
    for k, v in table.items():
        if k in ("check_period_s", "min_fraction"):
            kw[k] = _coerce(f"streams.{k}", v, getattr(d, k))
        elif k in STREAMABLE:
            r = _coerce(f"streams.{k}", v, 1.0, check_range=False)
            if not (r == 0 or 0.01 <= r <= 400):
                raise ConfigError(f"streams.{k}: rate {r:g} Hz out of range 0.01..400 (0 = do not request)")
            if r == 0:
                rates.pop(k, None)
            else:
                rates[k] = r
        else:
            raise ConfigError(
                f"[streams] unknown setting {k!r}: give a rate in Hz for one of {', '.join(STREAMABLE)}, "
                f"or check_period_s / min_fraction"
            )
    kw["rates_hz"] = rates
    cfg = StreamConfig(**kw)
    if not 1.0 <= cfg.check_period_s <= 3600:
        raise ConfigError(f"streams.check_period_s must be in [1, 3600], got {cfg.check_period_s}")
    if not 0 < cfg.min_fraction <= 1:
        raise ConfigError("streams.min_fraction must be in (0, 1]")
    if "GPS_RAW_INT" not in rates:
        raise ConfigError("streams.GPS_RAW_INT must be requested (> 0 Hz): the navigator needs the receiver")
    return cfg


def _validate(cfg: Config) -> Config:
    from companion.sources.base import SourceError
    from companion.mavlink.address import parse_url

    L = cfg.link
    if not L.connect:
        raise ConfigError("link.connect is not set: give --connect URL or connect = \"...\" in [link]")
    try:
        parse_url(L.connect, L.baud)
    except SourceError as err:
        raise ConfigError(f"link.connect: {err}") from None
    for k in ("system_id", "target_system"):
        lo = 1 if k == "system_id" else 0
        if not lo <= getattr(L, k) <= 255:
            raise ConfigError(f"link.{k} must be in {lo}..255, got {getattr(L, k)}")
    for k in ("component_id", "target_component"):
        lo = 1 if k == "component_id" else 0
        if not lo <= getattr(L, k) <= 255:
            raise ConfigError(f"link.{k} must be in {lo}..255, got {getattr(L, k)}")
    if L.baud <= 0:
        raise ConfigError(f"link.baud must be > 0, got {L.baud}")
    for k, lo, hi in LINK_BOUNDS:
        v = getattr(L, k)
        if not (math.isfinite(v) and lo <= v <= hi):
            raise ConfigError(f"link.{k} must be in [{lo:g}, {hi:g}] (a calm process, a link still watched), got {v}")
    if L.reconnect_max_s < L.reconnect_min_s:
        raise ConfigError("link.reconnect_max_s must be >= link.reconnect_min_s")
    for k, v in (("link.connect", L.connect), ("link.signing_key_file", L.signing_key_file),
                 ("record.out", cfg.record.out), ("gravity.map", cfg.gravity.map)):
        if "\0" in v:
            raise ConfigError(f"{k} contains a NUL byte")
    if L.signing_key_file:
        load_signing_key(L.signing_key_file)  # fails now, not at the first message
    if not (math.isfinite(cfg.duration_s) and cfg.duration_s >= 0):
        raise ConfigError(f"duration_s must be a finite number >= 0, got {cfg.duration_s}")
    if not cfg.record.out:
        raise ConfigError("record.out must name a file or directory")
    if not MIN_FLUSH_S <= cfg.record.flush_interval_s <= 3600:
        raise ConfigError(f"record.flush_interval_s must be in [{MIN_FLUSH_S:g}, 3600], got {cfg.record.flush_interval_s}")
    if 0 < cfg.record.segment_s < MIN_SEGMENT_S:
        raise ConfigError(f"record.segment_s must be 0 (one file) or >= {MIN_SEGMENT_S:g} s, got {cfg.record.segment_s:g}")
    if 0 < cfg.record.max_total_mb < MIN_BUDGET_MB:
        raise ConfigError(f"record.max_total_mb must be 0 (no budget) or >= {MIN_BUDGET_MB:g} MB, got {cfg.record.max_total_mb:g}")
    _validate_gravity(cfg.gravity)
    wanted = {**GRAVITY_STREAMS_HZ, **(AIR_DATA_STREAMS_HZ if cfg.gravity.reference == "air_data" else {})}
    if cfg.gravity.reference == "air_data" and cfg.gravity.air_heading == "gyro" and cfg.gravity.air_gyro_source != "RAW_IMU":
        wanted[cfg.gravity.air_gyro_source] = AIR_DATA_STREAMS_HZ["RAW_IMU"]
    if cfg.gravity.map and any(n not in cfg.streams.rates_hz for n in wanted):
        cfg = dataclasses.replace(cfg, streams=dataclasses.replace(
            cfg.streams, rates_hz={**wanted, **cfg.streams.rates_hz}))
    return cfg


def _validate_gravity(g: GravityConfig) -> None:
    if not g.map:
        return
    from companion.gravity.stage import MATCHERS  # (scipy.signal and .stats: 0.5 s of start-up, only with gravity)

    if not Path(g.map).is_file():
        raise ConfigError(f"gravity.map: {g.map} is not a file")
    if g.matcher not in MATCHERS:
        raise ConfigError(f"gravity.matcher must be one of {', '.join(MATCHERS)}, got {g.matcher!r}")
    if g.reference not in ("navigator", "air_data"):
        raise ConfigError(f"gravity.reference must be navigator or air_data, got {g.reference!r}")
    if g.air_heading not in ("attitude", "magnetometer", "gyro"):
        raise ConfigError(f"gravity.air_heading must be attitude, magnetometer or gyro, got {g.air_heading!r}")
    from companion.gravity.gyro_heading import GYRO_SOURCES

    if g.air_gyro_source not in GYRO_SOURCES:
        raise ConfigError(f"gravity.air_gyro_source must be one of {', '.join(GYRO_SOURCES)}, got {g.air_gyro_source!r}")
    if g.reference == "air_data" and g.matcher != "sequential":
        raise ConfigError("gravity.reference = \"air_data\" needs gravity.matcher = \"sequential\"")
    if not g.eotvos_corrected and g.matcher != "sequential":
        raise ConfigError("gravity.eotvos_corrected = false needs gravity.matcher = \"sequential\" (the stage that "
                          "corrects a reading with the navigator's velocity)")
    if not 1 <= len(g.named_value) <= 10:
        raise ConfigError("gravity.named_value must be 1-10 characters (NAMED_VALUE_FLOAT.name)")
    if len(g.air_speed_log) > 10 or g.air_speed_log == g.named_value:
        raise ConfigError("gravity.air_speed_log must be a NAMED_VALUE_FLOAT name of 0-10 characters other than "
                          "gravity.named_value")
    if not g.sigma_mgal > 0:
        raise ConfigError(f"gravity.sigma_mgal must be > 0, got {g.sigma_mgal:g}")
    if g.seq_attitude_tau_s > 0 and not (g.seq_attitude_tilt_sigma_rad > 0 and g.seq_attitude_heading_sigma_rad > 0):
        raise ConfigError("gravity.seq_attitude_tau_s > 0 needs seq_attitude_tilt_sigma_rad and "
                          "seq_attitude_heading_sigma_rad > 0 (the attitude reference's errors)")
    for k in ("feed_spacing_m", "accept_min_track_cells", "accept_min_signal_ratio"):
        if not getattr(g, k) >= 0:
            raise ConfigError(f"gravity.{k} must be >= 0, got {getattr(g, k):g}")


def load_signing_key(path: str) -> bytes:
    """A MAVLink2 signing key: a file holding 32 raw bytes or 64 hexadecimal characters."""
    from companion.inputs import MAX_KEY_BYTES, input_problem

    why = input_problem(path, "signing key file", MAX_KEY_BYTES)
    if why:
        raise ConfigError(f"link.signing_key_file: {why}")
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as err:
        raise ConfigError(f"link.signing_key_file: cannot read {p}: {err.strerror or err}") from None
    text = data.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == 32:
        return data
    raise ConfigError(f"link.signing_key_file: {p} must hold a 32-byte key (raw, or as 64 hex characters)")


def load_config(path: str | os.PathLike | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Read a TOML file (None: defaults only), apply ``overrides`` ("section.key" -> value), validate.

    Override values are given as TOML values would be (int/float/bool/str); strings from the command
    line are converted with :func:`parse_override`.
    """
    data: dict[str, Any] = {}
    if path is not None:
        from companion.inputs import MAX_CONFIG_BYTES, input_problem

        why = input_problem(path, "config file", MAX_CONFIG_BYTES)
        if why:
            raise ConfigError(why)
        p = Path(path)
        try:
            with p.open("rb") as f:
                data = tomllib.load(f)
        except FileNotFoundError:
            raise ConfigError(f"config file {p} not found") from None
        except OSError as err:
            raise ConfigError(f"config file {p}: {err.strerror or err}") from None
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file {p}: not valid TOML ({err})") from None
        except UnicodeDecodeError as err:
            raise ConfigError(f"config file {p}: not UTF-8 text (byte {err.start})") from None
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        sec, _, k = key.rpartition(".")
        target = data.setdefault(sec, {}) if sec else data
        if not isinstance(target, dict):
            raise ConfigError(f"[{sec}] must be a table")
        target[k] = value
    unknown = set(data) - {*_SECTIONS, "streams", "navigator", "duration_s"}
    if unknown:
        raise ConfigError(f"unknown setting(s) {', '.join(sorted(unknown))} (sections: link, streams, inject, trust, "
                          "record, gravity, navigator)")
    kw: dict[str, Any] = {}
    for name, cls in _SECTIONS.items():
        if name in data:
            kw[name] = _section(name, cls, data[name])
    if "streams" in data:
        kw["streams"] = _streams(data["streams"])
    if "duration_s" in data:
        kw["duration_s"] = _coerce("duration_s", data["duration_s"], 0.0)
    if "navigator" in data:
        kw["navigator"] = _navigator(data["navigator"])
    return _validate(Config(**kw))


def _navigator(table: Any) -> dict[str, Any]:
    """[navigator]: scalar NavigatorConfig settings, type-checked against their defaults and then by NavigatorConfig."""
    from companion.nav.navigator import NavigatorConfig

    if not isinstance(table, dict):
        raise ConfigError("[navigator] must be a table")
    defaults = NavigatorConfig()
    known = {f.name for f in dataclasses.fields(NavigatorConfig)
             if isinstance(getattr(defaults, f.name), (bool, int, float, str))}
    out: dict[str, Any] = {}
    for k, v in table.items():
        if k not in known:
            raise ConfigError(f"[navigator] unknown setting {k!r} (scalar fields of "
                              "companion.nav.navigator.NavigatorConfig)")
        out[k] = _coerce(f"navigator.{k}", v, getattr(defaults, k))
    try:
        NavigatorConfig(**out)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"[navigator] {err}") from None
    return out


def parse_override(text: str) -> tuple[str, Any]:
    """``section.key=value`` from the command line; the value is read as a TOML value, else as a string."""
    key, eq, raw = text.partition("=")
    key = key.strip()
    if not eq or not key:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return key, value
