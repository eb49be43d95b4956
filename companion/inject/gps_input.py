"""The GPS_INPUT injector stage: FusedState -> MAVLink GPS_INPUT (common.xml, id 232), with integrity checks.

Field by field (what ArduPilot's AP_GPS_MAV driver and EKF3 do with each field, and how the injector fills it:
accuracies from the covariance never better than the real receiver's, the fix type from ``max_h_acc_3d_m`` /
``max_v_acc_3d_m`` / ``max_h_acc_2d_m``, the vertical flagged ignored beyond ``max_v_acc_alt_m`` and ``vd`` while worse
than the speed accuracy, GPS time and boot time of the solution): the table in docs/ardupilot.md, "GPS_INPUT, field
by field".

Integrity: a state with a non-finite or out-of-range field, lat = lon = 0, an implausible speed, a
non-positive or non-finite sigma, a field that does not fit its wire type, or a time not after the previous
one (or ahead of every input) is never sent; nor a *stale* state (more than ``max_lag_s`` behind the newest sensor event: a navigator
catching up after a gap would otherwise emit a burst of old positions), nor one that disagrees with the real
receiver, nor one older than ``autopilot_lag_s`` + ``max_lag_s`` on the autopilot's clock as the link shows it
(:mod:`companion.inject.link_clock`: after a silent link the backlog arrives at once, new bytes of old states). Every state is checked against the receiver's 3D fix nearest to it in time (newer or older, within
``consistency_window_s``), carried to the state's epoch at the fix's velocity (the state's when the fix has
none): horizontal distance d with d^2 > ``consistency_chi2`` (sigma_state^2 + sigma_receiver^2) +
(``receiver_lag_s`` |v|)^2 is a disagreement (chi-square 2 dof 99.9 % = 13.816); so is a horizontal velocity
difference w with w^2 > ``consistency_chi2`` (sigma_v,state^2 + sigma_v,receiver^2) + (``consistency_accel_mps2``
(|dt| + ``receiver_lag_s``))^2 when the fix has a velocity (|v| is the fix's speed then). After one nothing is sent
until a check passes again. The fraction of states checked is in the metadata (``cross_check.*``). Each
refusal is counted and recorded on ``/inject/dropped`` with the reason. Every GPS_INPUT built (sent in
``inject`` mode, or what would be sent in ``shadow`` mode) is recorded on ``/inject/gps_input``.

Activation: ``activate = "always"`` sends every valid solution (the set-up where the companion is the
GPS instance the EKF follows); ``"gnss_loss"`` sends only while the real receiver (``receiver_instance``)
has no 3D fix or has been silent for ``gnss_timeout_s``, and stops ``recover_s`` after it is healthy again;
``"backup"`` keeps this instance ready beside the receiver but sends no fix in an outage unless aided by what the
autopilot lacks; ``"takeover"`` is ``backup`` that also carries the vehicle through an outage on its own solution when
the trust monitor (companion.nav.trust) judged that solution fit at the moment of the loss.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

from companion import units
from companion.constants import CHI2_2DOF_999, GPS_EPOCH_UNIX_S, UERE_M, WEEK_S, receiver_sigma
from companion.gpstime import split_gps_s
from companion.nav.outputs import FusedState
from companion.events import Attitude, Event, FixType, GnssFix, Heartbeat, ImuSample, Reboot, SystemTime
from companion.mavlink.gps_input import (  # noqa: F401 - the wire encoding, re-exported for the injector's users
    IGNORE_ALT,
    IGNORE_HDOP,
    IGNORE_HORIZONTAL_ACCURACY,
    IGNORE_SPEED_ACCURACY,
    IGNORE_VDOP,
    IGNORE_VEL_HORIZ,
    IGNORE_VEL_VERT,
    IGNORE_VERTICAL_ACCURACY,
    decode_gps_input,
    encode_gps_input,
    gps_week_from_unix,
)
from companion.inject.carry import AccelerationTracker, carry
from companion.inject.carry import fast_replace as _replace
from companion.inject.checks import encoded, invalid
from companion.inject.link_clock import LinkClock
from companion.inject.receiver_check import ReceiverCrossCheck
from companion.nav.outputs import MeasurementUpdate, ModeChange, NavigatorReset
from companion.nav.trust import TrustConfig, TrustMonitor, TrustVerdict
from companion.pipeline.stage import Stage

MAX_UNIX_S = 4102444800  # 2100-01-01: a later "UTC" is a corrupt clock (and its GPS week overflows uint16)
MAX_GPS_WEEK = 65535  # GPS_INPUT.time_week is a uint16

MODES = ("off", "shadow", "inject")
ACTIVATIONS = ("backup", "takeover", "always", "gnss_loss")


#: the rate limit lets through a state at least this fraction of 1 / rate_hz after the last one sent: the epochs
#: jitter by an input period (20 ms at 50 Hz IMU), and a strict 1 / rate_hz dropped every state that came early
RATE_GAP_FRACTION = 0.75

@dataclass(frozen=True)
class InjectConfig:
    mode: str = "shadow"  # off | shadow (compute and record only) | inject (send)
    gps_id: int = 1  # GPS instance fed: 0 with GPS1_TYPE = 14, 1 with GPS2_TYPE = 14
    # backup: beside a real receiver that stays in charge while healthy (ArduPilot GPS_AUTO_SWITCH = 4, the receiver
    # primary): every state is sent, so this GPS instance is ready and passes arming; while the receiver has no 3D fix
    # a state keeps its fix type only if it was aided within ``aid_valid_s`` by information the autopilot lacks
    # (``outage_aids``), else it goes out as no fix and ArduPilot dead-reckons exactly as it would alone.
    # always: every valid state with its covariance's fix type (the companion as the GPS the EKF follows).
    # takeover: backup, and in an outage the navigator's own solution with its covariance's fix type, provided the trust
    # monitor (companion.nav.trust, settings [trust]) judged it fit when the receiver was lost; decided once per outage
    # (an unfit solution cannot become fit without GNSS), after which the fix type follows the growing covariance.
    # gnss_loss: while the receiver has no 3D fix (until it is healthy again for ``recover_s``), and while the autopilot
    # says it is disarmed (its arming check needs a 3D fix on every configured GPS); nothing while armed beside a
    # healthy receiver. With no HEARTBEAT (a dataflash log) the armed state is unknown: only the outage counts.
    activate: str = "backup"
    # '+'-separated FusedState.measurement names that count as aid in an outage: a gravity fix, the air-data gravity
    # state, a boat's dead reckoning on its water-speed log (companion.gravity.air_data_stage)
    outage_aids: str = "position_fix+gravity_airdata+speed_log"
    aid_valid_s: float = 300.0  # an aid keeps the fix type this long (the covariance grows and degrades it meanwhile)
    # backup, vehicle armed, receiver healthy: send the state with its fix type (True) or as no fix (False). ArduPilot
    # checks every GPS for a 3D fix at arming only; in flight, GPS_AUTO_SWITCH = 4 switches to this instance the moment
    # the receiver loses its fix if this one still reports 3D (SITL's GPS1 reports no fix 0.1-0.3 s after a denial,
    # before the companion hears of it), and EKF3 takes its position. False removes that switch.
    backup_fix_when_armed: bool = True
    rate_hz: float = 10.0  # at most this many GPS_INPUT per second of vehicle time (>= 5 when injecting)
    max_h_acc_3d_m: float = 10.0  # 3D fix only while sigma_h is within this ...
    max_v_acc_3d_m: float = 20.0  # ... and sigma_v within this
    max_h_acc_2d_m: float = 50.0  # 2D fix up to this sigma_h; no fix beyond
    # sigma_v beyond this: altitude, vertical velocity and its accuracy are flagged ignored (ArduPilot then keeps its
    # barometric height; the navigator has no vertical aid of its own once the receiver is gone), `alt` repeats
    # the last altitude sent with a smaller sigma_v, and the fix type follows the horizontal alone. Set it equal to
    # max_v_acc_3d_m where the autopilot takes its height from its barometer (EK3_SRC1_POSZ = 1): a free vertical
    # channel then never degrades a good horizontal fix to 2D (docs/decisions/0001)
    max_v_acc_alt_m: float = 200.0
    satellites: int = 10  # satellites_visible reported with a fix (ArduPilot needs >= 6)
    uere_m: float = UERE_M  # HDOP = sigma_h / uere_m, VDOP = sigma_v / uere_m
    max_speed_mps: float = 80.0  # a faster state is not plausible for the vehicle: not sent
    receiver_instance: int = 0  # the real receiver's GnssFix.instance (for activate = gnss_loss)
    gnss_timeout_s: float = 0.6  # receiver silent this long (vehicle time) counts as lost
    recover_s: float = 3.0  # receiver healthy this long before injection stops (gnss_loss)
    send_yaw: bool = False  # send the state's heading in ``yaw`` (only with a real heading source)
    floor_to_receiver: bool = True  # accuracies >= the receiver's last reported h_acc/v_acc (or DOP x uere_m)
    max_lag_s: float = 0.5  # a state this far behind the newest sensor event is stale: not sent
    # the measurement lag the autopilot assumes for this GPS instance: ArduPilot's EKF fuses a GPS message as the
    # vehicle ``GPSn_DELAY_MS`` before its arrival (0 there: the driver's default, 0.2 s for a MAVLink GPS), but never
    # further back than its delay buffer, which EKF3 sizes by the *primary* GPS's lag (0.12 s for a u-blox M8 or
    # newer): set GPSn_DELAY_MS to this value and at most the primary's lag (the recommended set-up: 100 ms, 0.1 s).
    # Each GPS_INPUT describes the vehicle at (newest sensor time - autopilot_lag_s): the navigator's state, final
    # once the reorder window has passed, is carried to that epoch (companion.inject.carry)
    autopilot_lag_s: float = 0.2
    consistency_chi2: float = CHI2_2DOF_999  # gate of the receiver cross-check (chi-square, 2 dof, 99.9 %)
    consistency_window_s: float = 0.5  # cross-check against receiver fixes at most this old
    receiver_lag_s: float = 0.2  # receiver fixes may lag the state by this much (allowance |v| x lag)
    # the velocity cross-check allows the vehicle this horizontal acceleration between the fix and the state (and over
    # receiver_lag_s); receiver_speed_sigma_mps when the fix gives no speed accuracy
    consistency_accel_mps2: float = 10.0
    receiver_speed_sigma_mps: float = 0.5

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, not {self.mode!r}")
        if self.activate not in ACTIVATIONS:
            raise ValueError(f"activate must be one of {', '.join(ACTIVATIONS)}, not {self.activate!r}")
        if not 0 <= self.gps_id <= 1:
            raise ValueError(f"gps_id must be 0 (GPS1_TYPE = 14) or 1 (GPS2_TYPE = 14), not {self.gps_id}")
        if self.mode == "inject" and self.rate_hz < 5.0:
            raise ValueError(f"rate_hz must be >= 5 while injecting (ArduPilot drops a slower GPS), not {self.rate_hz:g}")
        if not 0 < self.rate_hz <= 50:
            raise ValueError(f"rate_hz must be in (0, 50], not {self.rate_hz:g}")
        if not 0 < self.max_h_acc_3d_m <= self.max_h_acc_2d_m:
            raise ValueError("need 0 < max_h_acc_3d_m <= max_h_acc_2d_m")
        if not self.max_v_acc_alt_m >= self.max_v_acc_3d_m:
            raise ValueError("need max_v_acc_alt_m >= max_v_acc_3d_m")
        if not self.max_v_acc_3d_m > 0:
            raise ValueError("max_v_acc_3d_m must be > 0")
        if not 6 <= self.satellites <= 254:
            raise ValueError(f"satellites must be in 6..254 (ArduPilot needs >= 6 for a usable fix), not {self.satellites}")
        for k in ("uere_m", "max_speed_mps", "gnss_timeout_s", "recover_s", "max_lag_s", "consistency_chi2", "consistency_window_s",
                  "consistency_accel_mps2", "receiver_speed_sigma_mps"):
            if not getattr(self, k) > 0:
                raise ValueError(f"{k} must be > 0")
        if not 0.0 <= self.autopilot_lag_s < self.max_lag_s:
            raise ValueError(f"autopilot_lag_s must be in [0, max_lag_s = {self.max_lag_s:g}), not {self.autopilot_lag_s:g}")


@dataclass(frozen=True, slots=True)
class GpsInputRecord(Event):
    """One GPS_INPUT built from a fused state, in SI (``sent``: it left on the link)."""

    mode: str
    sent: bool
    gps_id: int
    fix_type: int
    fix_reason: str
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    vel_n_mps: float
    vel_e_mps: float
    vel_d_mps: float
    h_acc_m: float
    v_acc_m: float
    speed_acc_mps: float
    h_floor_m: float  # the receiver accuracy floor applied (0: none)
    hdop: float
    vdop: float
    satellites: int
    ignore_flags: int
    time_boot_us: int
    time_week: int
    time_week_ms: int
    yaw_cdeg: int
    extrapolated_s: float = 0.0  # how far the navigator's state was carried (companion.inject.carry) to the epoch t_s
    topic: ClassVar[str] = "/inject/gps_input"


@dataclass(frozen=True, slots=True)
class InjectorDrop(Event):
    """A fused state that was not turned into GPS_INPUT, and why."""

    reason: str
    topic: ClassVar[str] = "/inject/dropped"


@dataclass(frozen=True, slots=True)
class InjectorState(Event):
    """Injection switched on or off (activate = gnss_loss), or the autopilot rebooted."""

    active: bool
    reason: str
    topic: ClassVar[str] = "/inject/state"


def _finite(*vals) -> bool:
    for v in vals:  # (a loop, not all() over a generator: called for every input event)
        if not (isinstance(v, (int, float)) and math.isfinite(v)):
            return False
    return True


class Injector(Stage):
    """Pipeline stage: consumes FusedState (and GnssFix, SystemTime, Reboot), emits GpsInputRecord.

    ``sender`` (set by the live runtime) takes the pymavlink message and returns True when it was
    written to the link; without one (replay) nothing leaves the process and records say ``sent=False``.
    ``on_sent(record)`` is called right after a message left (the runtime measures latency there).
    Pure apart from the sender callback: vehicle time only.
    """

    def __init__(self, config: InjectConfig | None = None, sender: Callable[[Any], bool] | None = None,
                 trust: TrustConfig | None = None) -> None:
        self.config = config or InjectConfig()
        #: judges the navigator's solution for a takeover (activate = "takeover"; its verdicts are recorded)
        self.trust = TrustMonitor(trust) if self.config.activate == "takeover" else None
        self._outage_t: float | None = None  # start of the receiver outage in progress (takeover)
        self._takeover = False  # the navigator carries the vehicle through this outage
        self.sender = sender
        self.on_sent: Callable[[GpsInputRecord], None] | None = None
        #: live: the clock of the link's receive times, and the arrival time of the input being processed (the
        #: runtime sets both); a state built from input that arrived more than max_lag_s ago is never sent
        self.arrival_clock: Callable[[], float] | None = None
        self.arrival_s: float | None = None
        #: live: the vehicle's time now, from the arrivals (a burst of old messages is old, however new its bytes)
        self.link_clock = LinkClock()
        #: live: how many autopilot reboots the link has seen (the runtime sets it); a message built before one the
        #: link has seen but this stage has not yet been told of is on the previous boot's clock: never sent
        self.link_reboots: Callable[[], int] | None = None
        self.reboots = 0
        self._boot_start_t = -math.inf  # vehicle time the autopilot's current boot began (its last reboot)
        self.dropped: Counter[str] = Counter()
        self.sent = 0
        self.built = 0
        self.fix_types: Counter[int] = Counter()
        self._boot_offset_s = 0.0  # vehicle time minus autopilot boot time (grows at each reboot)
        self._utc: SystemTime | None = None
        self._gnss_time: tuple[float, int, float] | None = None  # (t_s, week, tow_s) of the receiver
        self._last_state_t: float | None = None
        self._last_out_t: float | None = None
        self._last_good_gnss_t: float | None = None  # the receiver's last 3D fix, and its last message without one
        self._last_bad_gnss_t: float | None = None
        self._last_gnss_t: float | None = None
        self._healthy_since: float | None = None
        self._active = self.config.activate != "gnss_loss"
        self._aids = frozenset(a for a in self.config.outage_aids.split("+") if a)
        self._last_aid_t: float | None = None
        self._floor_h_m = 0.0
        self._floor_v_m = 0.0
        self._last_alt_m: float | None = None  # last altitude sent with sigma_v within max_v_acc_alt_m
        self._newest_input_t = -math.inf
        # the receiver's recent 3D fixes: (t_s, lat_deg, lon_deg, sigma_h_m, vel_n_mps, vel_e_mps, speed_sigma_mps),
        # velocities None when not given
        self.cross_check = ReceiverCrossCheck(self.config)
        self.accel = AccelerationTracker()  # the output's acceleration, to carry a state to its epoch
        self._armed: bool | None = None  # the autopilot's HEARTBEAT armed flag (None: never heard)

    # -- stage interface ----------------------------------------------------------------------
    def process(self, item: Any) -> list[Event]:
        if self.config.mode == "off":
            return []
        if isinstance(item, (ImuSample, GnssFix, Attitude)) and _finite(item.t_s):
            self._newest_input_t = max(self._newest_input_t, item.t_s)
            if self.arrival_s is not None and not isinstance(item, GnssFix):  # (a fix is stamped when it was solved)
                self.link_clock.observe(item.t_s, self.arrival_s)
        if isinstance(item, NavigatorReset):
            self.accel.reset()  # (the velocity jumps: no motion to carry a state with)
        verdicts: list[Event] = []
        if self.trust is not None and isinstance(item, _TRUST_INPUTS):
            verdicts = self.trust.observe(item)
        if isinstance(item, FusedState):
            return verdicts + self._on_state(item) if verdicts else self._on_state(item)
        if isinstance(item, GnssFix):
            return self._on_gnss(item)
        if isinstance(item, Heartbeat):
            self._armed = item.armed
            return []
        if isinstance(item, SystemTime):
            if _finite(item.unix_time_s) and GPS_EPOCH_UNIX_S < item.unix_time_s < MAX_UNIX_S:
                self._utc = item
            else:
                self.dropped["SYSTEM_TIME without a valid UTC"] += 1
            return []
        if isinstance(item, Reboot):
            # boot time restarts: keep the offset so time_usec is the autopilot's new boot time; forget
            # UTC (SYSTEM_TIME is re-sent) and the time order of states (the navigator restarts its clock)
            self._boot_offset_s = item.t_s - item.new_boot_s
            self._boot_start_t = item.t_s - item.new_boot_s
            self._utc = None
            self._gnss_time = None
            self._last_out_t = None
            self.link_clock.reset()
            self.accel.reset()
            self.reboots += 1
            return [InjectorState(item.t_s, self._active, "autopilot rebooted")]
        return []

    def metadata(self) -> dict[str, str]:
        c = self.config
        meta = {"mode": c.mode, "gps_id": str(c.gps_id), "activate": c.activate, "rate_hz": f"{c.rate_hz:g}"}
        meta["built"], meta["sent"] = str(self.built), str(self.sent)
        for k, v in sorted(self.fix_types.items()):
            meta[f"fix_type.{k}"] = str(v)
        for why, n in sorted(self.dropped.items()):
            meta[f"dropped.{why}"] = str(n)
        meta.update(self.cross_check.metadata())
        return meta

    def summary_lines(self) -> list[str]:
        c = self.config
        fix = ", ".join(f"{FixType(k).name} {v}" for k, v in sorted(self.fix_types.items())) or "none"
        lines = [f"gps_input    mode {c.mode}, gps_id {c.gps_id}: {self.built} built, {self.sent} sent ({fix})"]
        lines += [f"gps_input    not sent {n}: {why}" for why, n in sorted(self.dropped.items())]
        lines += self.cross_check.summary_lines()
        return lines

    # -- activation ---------------------------------------------------------------------------
    def _on_gnss(self, fix: GnssFix) -> list[Event]:
        c = self.config
        if fix.instance != c.receiver_instance:
            return []
        if not _finite(fix.t_s):
            self.dropped["receiver fix with a non-finite time (not used)"] += 1
            return []
        self._last_gnss_t = fix.t_s
        good = fix.fix_type >= FixType.FIX_3D and fix.has_position
        if good and c.floor_to_receiver:
            h, v = receiver_sigma(fix, c.uere_m)
            if h is not None and _finite(h):
                self._floor_h_m = h
            if v is not None and _finite(v):
                self._floor_v_m = v
        if fix.gps_week is not None and fix.gps_tow_s is not None:
            if _finite(fix.gps_tow_s) and 0 < fix.gps_week <= MAX_GPS_WEEK and 0.0 <= fix.gps_tow_s < WEEK_S:
                self._gnss_time = (fix.t_s, int(fix.gps_week), float(fix.gps_tow_s))
            else:
                self.dropped["receiver GPS time out of range (not used)"] += 1
        if good and not _finite(fix.t_s, fix.lat_deg, fix.lon_deg):
            good = False
        if good:
            h = receiver_sigma(fix, c.uere_m)[0]
            vn, ve = (fix.vel_n_mps, fix.vel_e_mps) if _finite(fix.vel_n_mps, fix.vel_e_mps) else (None, None)
            s_v = fix.speed_acc_mps if _finite(fix.speed_acc_mps) and fix.speed_acc_mps > 0 else c.receiver_speed_sigma_mps
            self.cross_check.add_fix(fix.t_s, fix.lat_deg, fix.lon_deg, h if h is not None and _finite(h) else c.uere_m,
                                     vn, ve, s_v)
            self._last_good_gnss_t = fix.t_s
        else:
            self._last_bad_gnss_t = fix.t_s
        if not good:
            self._healthy_since = None
            return self._set_active(fix.t_s, True, f"receiver fix_type {fix.fix_type}")
        if self._healthy_since is None:
            self._healthy_since = fix.t_s
        if fix.t_s - self._healthy_since >= c.recover_s:
            return self._set_active(fix.t_s, False, f"receiver 3D fix for {c.recover_s:g} s")
        return []

    def _set_active(self, t_s: float, active: bool, reason: str) -> list[Event]:
        if self.config.activate != "gnss_loss" or active == self._active:
            return []
        self._active = active
        return [InjectorState(t_s, active, reason)]

    # -- states -> GPS_INPUT -----------------------------------------------------------------
    def _drop(self, t_s: float, reason: str) -> list[Event]:
        self.dropped[reason] += 1
        return [InjectorDrop(t_s, reason)]

    def _receiver_out(self, t_s: float) -> bool:
        """The real receiver has no 3D fix now: its last one is older than gnss_timeout_s, or a no-fix came after it."""
        good, bad = self._last_good_gnss_t, self._last_bad_gnss_t
        return good is None or t_s - good > self.config.gnss_timeout_s or (bad is not None and bad > good)

    def _on_state(self, s: FusedState) -> list[Event]:
        c = self.config
        out: list[Event] = []
        accel = self.accel.observe(s)
        if self._aids and _finite(s.t_s) and not self._aids.isdisjoint(s.measurement.split("+")):
            self._last_aid_t = s.t_s
        if (
            c.activate == "gnss_loss"
            and not self._active
            and (self._last_gnss_t is None or s.t_s - self._last_gnss_t > c.gnss_timeout_s)
        ):
            self._healthy_since = None
            out += self._set_active(s.t_s, True, f"receiver silent for more than {c.gnss_timeout_s:g} s")
        if c.activate == "takeover" and _finite(s.t_s):
            out += self._decide_takeover(s.t_s)
        if not (self._active or (c.activate == "gnss_loss" and self._armed is False)):
            return out
        if not _finite(s.t_s):
            return out + self._drop(0.0, "non-finite time")
        if -math.inf < self._newest_input_t < s.t_s - c.max_lag_s:  # a state is built from inputs: ahead is corrupt
            return out + self._drop(s.t_s, "time ahead of every input")
        if self._last_state_t is not None and s.t_s <= self._last_state_t:
            return out + self._drop(s.t_s, "time not after the previous state")
        self._last_state_t = s.t_s
        if s.t_s < self._newest_input_t - c.max_lag_s:
            return out + self._drop(s.t_s, f"stale: more than {c.max_lag_s:g} s behind the sensors")
        tgt = s.t_s if self._newest_input_t == -math.inf else self._newest_input_t - c.autopilot_lag_s
        # rate limit (or an older state finalised beside a newer one): not a fault, not recorded. The epoch moves with
        # the newest input, which jitters by an IMU period: a gap of a quarter period less still counts as one period
        if self._last_out_t is not None and tgt - self._last_out_t < RATE_GAP_FRACTION / c.rate_hz:
            return out
        alt_ignored = self._alt_ignored(s)
        why = invalid(s, c, check_alt=not alt_ignored)
        if why:
            return out + self._drop(s.t_s, why)
        carried_s = tgt - s.t_s
        s = carry(s, tgt, accel)
        why = self.cross_check.disagreement(s)
        if why:
            return out + self._drop(s.t_s, why)
        if self.arrival_clock is not None and self.arrival_s is not None:
            now_s = self.arrival_clock()
            if now_s - self.arrival_s > c.max_lag_s:
                return out + self._drop(s.t_s, f"stale: its input arrived more than {c.max_lag_s:g} s ago")
            vehicle_now = self.link_clock.vehicle_now(now_s)
            if vehicle_now is not None and vehicle_now - s.t_s - c.autopilot_lag_s > c.max_lag_s:
                return out + self._drop(s.t_s, f"stale: older than its stated lag by more than {c.max_lag_s:g} s "
                                               "on the autopilot's clock (old messages delivered late)")
        if s.t_s <= self._boot_start_t:
            return out + self._drop(s.t_s, "from before the autopilot's last reboot")
        rec = self._record(s, alt_ignored, carried_s)
        if rec.time_boot_us <= 0:
            return out + self._drop(s.t_s, "no boot time (before the autopilot's boot)")
        msg, why = encoded(rec)  # every field against its wire type, in every mode: a record is what would be sent
        if why:
            return out + self._drop(s.t_s, f"not encodable ({why})")
        self._last_out_t = s.t_s
        self.built += 1
        self.fix_types[rec.fix_type] += 1
        if c.mode == "inject" and self.sender is not None:
            if self.link_reboots is not None and self.link_reboots() != self.reboots:
                self.dropped["built on the autopilot's previous boot (it rebooted meanwhile)"] += 1
            elif self.sender(msg):
                self.sent += 1
                rec = _replace_sent(rec)
                if self.on_sent is not None:
                    self.on_sent(rec)
            else:
                self.dropped["link not ready"] += 1
        out.append(rec)
        return out

    def _decide_takeover(self, t_s: float) -> list[Event]:
        """At the start of a receiver outage, take over for its whole length if the trust monitor's latest verdict
        says fit (a verdict cannot turn fit without GNSS, so it is not revisited); at its end, hand back."""
        out_now = self._last_good_gnss_t is not None and self._receiver_out(t_s)
        if out_now and self._outage_t is None:
            self._outage_t = t_s
            v = self.trust.verdict if self.trust is not None else None
            self._takeover = v is not None and v.fit
            why = ("takeover: the navigator's solution was fit at the loss" if self._takeover
                   else f"no takeover: {v.reason if v is not None else 'not judged yet'}")
            return [InjectorState(t_s, self._takeover, why)]
        if not out_now and self._outage_t is not None:
            self._outage_t = None
            if self._takeover:
                self._takeover = False
                return [InjectorState(t_s, False, "receiver back: takeover ends")]
        return []

    def _backup_fix(self, t_s: float, fix: int, why: str) -> tuple[int, str]:
        """The fix type a backup (or takeover) instance sends for a state whose covariance gives ``fix`` (2D or 3D):
        in a receiver outage no fix unless aided within aid_valid_s by what the autopilot lacks, or taking over; armed
        beside a healthy receiver no fix unless backup_fix_when_armed."""
        c = self.config
        aided = self._last_aid_t is not None and t_s - self._last_aid_t <= c.aid_valid_s
        if self._receiver_out(t_s):
            if aided:
                return fix, why
            if self._takeover:
                return fix, f"takeover, {why}"
            return int(FixType.NO_FIX), "receiver outage, no aid the autopilot lacks: it dead-reckons alone"
        if self._armed and not c.backup_fix_when_armed:
            return int(FixType.NO_FIX), "armed beside a healthy receiver: no fix, so no switch when it is lost"
        return fix, why

    def _alt_ignored(self, s: FusedState) -> bool:
        return not (_finite(s.sigma_v_m) and max(s.sigma_v_m, self._floor_v_m) <= self.config.max_v_acc_alt_m)

    def _record(self, s: FusedState, alt_ignored: bool, carried_s: float = 0.0) -> GpsInputRecord:
        c = self.config
        sh, sv = max(s.sigma_h_m, self._floor_h_m), max(s.sigma_v_m, self._floor_v_m)
        alt, vd = s.alt_msl_m, s.vel_d_mps
        flags = 0
        if alt_ignored:
            flags |= IGNORE_ALT | IGNORE_VEL_VERT | IGNORE_VERTICAL_ACCURACY
            alt, vd = (self._last_alt_m if self._last_alt_m is not None else 0.0), 0.0
        else:
            self._last_alt_m = alt
        if sh <= c.max_h_acc_3d_m and (sv <= c.max_v_acc_3d_m or alt_ignored):
            fix, why = int(FixType.FIX_3D), "within 3D bounds"
        elif sh <= c.max_h_acc_2d_m:
            fix = int(FixType.FIX_2D)
            why = f"sigma_h {sh:.1f} m > {c.max_h_acc_3d_m:g}" if sh > c.max_h_acc_3d_m else f"sigma_v {sv:.1f} m > {c.max_v_acc_3d_m:g}"
        else:
            fix, why = int(FixType.NO_FIX), f"sigma_h {sh:.1f} m > {c.max_h_acc_2d_m:g}"
        if c.activate in ("backup", "takeover") and fix >= FixType.FIX_2D:
            fix, why = self._backup_fix(s.t_s, fix, why)
        cov = s.cov_diag
        if len(cov) >= 6 and _finite(cov[3], cov[4]) and min(cov[3], cov[4]) >= 0:
            speed_acc = math.sqrt(max(cov[3], cov[4]))
            if not flags & IGNORE_VEL_VERT and not (_finite(cov[5]) and 0 <= cov[5] <= speed_acc**2):
                flags |= IGNORE_VEL_VERT
                vd = 0.0
        else:
            speed_acc, flags = 0.0, flags | IGNORE_SPEED_ACCURACY
        week = week_ms = 0
        if self._gnss_time is not None:
            t0, wk, tow = self._gnss_time
            week, week_ms = split_gps_s(wk * WEEK_S + tow + (s.t_s - t0))  # the receiver's own GPS time
        elif self._utc is not None:
            week, week_ms = gps_week_from_unix(self._utc.unix_time_s + (s.t_s - self._utc.t_s))
        if not 0 <= week <= MAX_GPS_WEEK:
            self.dropped["GPS week beyond uint16: time sent as unknown (0/0)"] += 1
            week = week_ms = 0
        if week == 0 and fix >= FixType.FIX_2D:  # a fix is never sent without its time (ArduPilot would take arrival)
            fix, why = int(FixType.NO_FIX), "GPS time not known yet: no fix without a time"
        boot_s = max(0.0, s.t_s - self._boot_offset_s)
        yaw = 0
        if c.send_yaw and _finite(s.yaw_rad):
            yaw = units.cdeg_from_deg(math.degrees(s.yaw_rad) % 360.0) % 36000 or 36000
        return GpsInputRecord(
            t_s=s.t_s, mode=c.mode, sent=False, gps_id=c.gps_id, fix_type=fix, fix_reason=why,
            lat_deg=s.lat_deg, lon_deg=s.lon_deg, alt_msl_m=alt,
            vel_n_mps=s.vel_n_mps, vel_e_mps=s.vel_e_mps, vel_d_mps=vd,
            h_acc_m=sh, v_acc_m=sv, speed_acc_mps=speed_acc, h_floor_m=self._floor_h_m, hdop=sh / c.uere_m, vdop=sv / c.uere_m,
            satellites=c.satellites if fix >= FixType.FIX_2D else 0, ignore_flags=flags,
            time_boot_us=units.us_from_s(boot_s), time_week=week, time_week_ms=week_ms, yaw_cdeg=yaw,
            extrapolated_s=carried_s,
        )


_TRUST_INPUTS = (FusedState, GnssFix, MeasurementUpdate, NavigatorReset, ModeChange)


def _replace_sent(rec: GpsInputRecord) -> GpsInputRecord:
    return _replace(rec, sent=True)
