"""Pure logic of the SITL A/B harness (replay/live/sitl.py): scenarios, the flight log built from a MAVLink
message stream, EKF error against SITL truth, failsafe/mode parsing and the report. No processes, no sockets:
everything here is driven by message objects (anything with ``get_type()`` and the MAVLink fields), so the
unit tests feed it scripted streams.

Time base: the autopilot's boot time (``time_boot_ms``) in seconds. SIMSTATE (the simulator's truth) has no
time field; each one is stamped with the newest ``time_boot_ms`` seen on the stream before it. The harness
requests SIMSTATE and ATTITUDE at the same 50 Hz, so a stamp is at most one ATTITUDE period (20 ms) old and
usually from the same scheduler tick; see ``FlightLog.on_message``.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from pymavlink import mavutil

from companion.constants import WGS84_A_M
from companion.mavlink.dialect import mavlink

#: ArduCopter's custom modes, from pymavlink's table (HEARTBEAT.custom_mode -> name)
COPTER_MODES: dict[int, str] = dict(mavutil.mode_mapping_acm)
MODE_GUIDED = next(n for n, name in COPTER_MODES.items() if name == "GUIDED")
MODE_LAND = next(n for n, name in COPTER_MODES.items() if name == "LAND")
MAV_MODE_FLAG_SAFETY_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
EARTH_R_M = WGS84_A_M
#: a truth sample pair further apart than this is a gap: no interpolated truth inside it
MAX_TRUTH_GAP_S = 0.5
MARK_STEP_S = 5.0


# -- scenarios ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Scenario:
    """One scripted flight. Times in seconds of vehicle time.

    hover_s: hover after the climb, before the route (or the whole hover when ``laps`` is 0). route: "square" or
    "survey" (a lawnmower of ``side_m`` lines ``side_m / 4`` apart), flown ``laps`` times (99: until the scripted end).
    deny_in: "hover", "route" or "" (no denial). deny_at_s: denial start after the start of that phase (for "route"
    with ``deny_lap`` > 0: after the start of that lap; a denial in the hover at ``hover_s`` - 0.5 s has the vehicle
    leave its hover half a second into the outage). deny_s: denial length. recover_s: flight after GPS1 is back (the
    scenario ends then, or when the laps are done, whichever is later). wind_mps, turb_mps: SITL's wind
    (SIM_WIND_SPD from ``wind_dir_deg``, SIM_WIND_TURB); 0 is calm.
    """

    name: str
    hover_s: float = 20.0
    route: str = "square"
    laps: int = 1
    deny_in: str = ""
    deny_at_s: float = 0.0
    deny_s: float = 0.0
    deny_lap: int = 0
    recover_s: float = 30.0
    side_m: float = 100.0
    speed_mps: float = 8.0
    alt_m: float = 20.0
    wind_mps: float = 0.0
    turb_mps: float = 0.0
    wind_dir_deg: float = 200.0

    @property
    def denies(self) -> bool:
        return bool(self.deny_in) and self.deny_s > 0

    def sim_params(self) -> dict[str, float]:
        """SITL's wind for this scenario (set in both arms)."""
        return {"SIM_WIND_SPD": self.wind_mps, "SIM_WIND_DIR": self.wind_dir_deg, "SIM_WIND_TURB": self.turb_mps}


def _scenarios() -> dict[str, Scenario]:
    S = Scenario
    out = {
        "healthy": S("healthy", hover_s=20.0, laps=1),
        "hover-short": S("hover-short", hover_s=30.0, laps=0),
    }
    for d in (30, 60):
        # (a) after one manoeuvring lap: GPS1 lost 1 s into the second lap, the laps go on
        out[f"lap-deny-{d}"] = S(f"lap-deny-{d}", hover_s=10.0, laps=99, deny_in="route", deny_lap=2, deny_at_s=1.0,
                                 deny_s=d)
        # (d) on the third line of a lawnmower survey
        out[f"survey-deny-{d}"] = S(f"survey-deny-{d}", hover_s=10.0, route="survey", side_m=160.0, laps=99,
                                    deny_in="route", deny_at_s=50.0, deny_s=d)
    # the suite's short SITL test: a smaller lap, a 20 s denial
    out["lap-deny-20-short"] = S("lap-deny-20-short", hover_s=5.0, laps=99, deny_in="route", deny_lap=2, deny_at_s=1.0,
                                 deny_s=20, recover_s=10.0, side_m=60.0)
    out["lap-deny-30-10mps"] = S("lap-deny-30-10mps", hover_s=10.0, laps=99, deny_in="route", deny_lap=2,
                                 deny_at_s=1.0, deny_s=30, speed_mps=10.0)
    out["lap-deny-30-wind"] = S("lap-deny-30-wind", hover_s=10.0, laps=99, deny_in="route", deny_lap=2, deny_at_s=1.0,
                                deny_s=30, wind_mps=6.0, turb_mps=2.0)
    # (b) only a short hover after take-off, (c) a long hover: GPS1 lost just before the vehicle sets off on its laps
    out["short-hover-deny-30"] = S("short-hover-deny-30", hover_s=10.0, laps=99, deny_in="hover", deny_at_s=9.5,
                                   deny_s=30)
    out["short-hover-deny-30-wind"] = S("short-hover-deny-30-wind", hover_s=10.0, laps=99, deny_in="hover",
                                        deny_at_s=9.5, deny_s=30, wind_mps=6.0, turb_mps=2.0)
    out["long-hover-deny-30"] = S("long-hover-deny-30", hover_s=90.0, laps=99, deny_in="hover", deny_at_s=89.5,
                                  deny_s=30)
    out["short-hover-deny-30-10mps"] = S("short-hover-deny-30-10mps", hover_s=10.0, laps=99, deny_in="hover",
                                         deny_at_s=9.5, deny_s=30, speed_mps=10.0)
    return out


SCENARIOS = _scenarios()
DEFAULT_SCENARIOS = ["lap-deny-30", "short-hover-deny-30"]


def route_corners(sc: Scenario) -> list[tuple[float, float]]:
    """North/east offsets of the route's corners from its start, flown in order and closed."""
    s = sc.side_m
    if sc.route == "survey":
        w = s / 4.0
        return [(s, 0.0), (s, w), (0.0, w), (0.0, 2 * w), (s, 2 * w), (s, 3 * w), (0.0, 3 * w), (0.0, 0.0)]
    return [(s, 0.0), (s, s), (0.0, s), (0.0, 0.0)]


# -- the flight log ------------------------------------------------------------------------------------------------
@dataclass
class FlightLog:
    """What the harness keeps from the autopilot's stream, all stamped in boot seconds."""

    t_boot: float | None = None
    ekf: list[tuple[float, float, float, float]] = field(default_factory=list)  # t, lat, lon, rel_alt_m
    truth: list[tuple[float, float, float]] = field(default_factory=list)  # t, lat, lon
    local: tuple[float, float, float] | None = None  # newest LOCAL_POSITION_NED x, y, z
    texts: list[tuple[float, int, str]] = field(default_factory=list)
    modes: list[tuple[float, int, bool]] = field(default_factory=list)  # changes only: t, custom_mode, armed
    gps: dict[int, list[tuple[float, int, int]]] = field(default_factory=lambda: {1: [], 2: []})  # t, fix, sats
    ekf_flags: list[tuple[float, int]] = field(default_factory=list)
    marks: dict[str, float] = field(default_factory=dict)
    events: list[tuple[float, str]] = field(default_factory=list)
    yaw: list[tuple[float, float]] = field(default_factory=list)  # t, ATTITUDE yaw (rad): the EKF's
    truth_yaw: list[tuple[float, float]] = field(default_factory=list)  # t, SIMSTATE yaw (rad)

    def on_message(self, m) -> None:
        kind = m.get_type()
        if kind == "BAD_DATA":
            return
        tb = getattr(m, "time_boot_ms", None)
        if tb is not None and kind != "SIMSTATE":
            t = tb / 1000.0
            # a boot time going back is a reboot: not expected in one scripted flight; keep the newest
            self.t_boot = t if self.t_boot is None else max(self.t_boot, t)
        t = self.t_boot
        if kind == "GLOBAL_POSITION_INT":
            self.ekf.append((m.time_boot_ms / 1000.0, m.lat * 1e-7, m.lon * 1e-7, m.relative_alt / 1000.0))
        elif kind == "SIMSTATE":
            if t is not None:
                self.truth.append((t, m.lat * 1e-7, m.lng * 1e-7))
                if hasattr(m, "yaw"):
                    self.truth_yaw.append((t, float(m.yaw)))
        elif kind == "ATTITUDE" and hasattr(m, "yaw"):
            self.yaw.append((m.time_boot_ms / 1000.0, float(m.yaw)))
        elif kind == "LOCAL_POSITION_NED":
            self.local = (m.x, m.y, m.z)
        elif kind == "STATUSTEXT":
            self.texts.append((t if t is not None else math.nan, int(m.severity), _text(m.text)))
        elif kind == "HEARTBEAT":
            comp = m.get_srcComponent() if hasattr(m, "get_srcComponent") else 1
            if comp != 1 or getattr(m, "autopilot", 3) == 8 or getattr(m, "type", 2) in (6, 18, 26, 27):
                return  # not the autopilot: GCS / companion heartbeats relayed on the link
            armed = bool(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
            state = (int(m.custom_mode), armed)
            if not self.modes or self.modes[-1][1:] != state:
                self.modes.append((t if t is not None else math.nan, *state))
        elif kind in ("GPS_RAW_INT", "GPS2_RAW"):
            if t is not None:
                self.gps[1 if kind == "GPS_RAW_INT" else 2].append((t, int(m.fix_type), int(m.satellites_visible)))
        elif kind == "EKF_STATUS_REPORT":
            if t is not None:
                self.ekf_flags.append((t, int(m.flags)))

    def to_dict(self) -> dict:
        return {"ekf": self.ekf, "truth": self.truth, "texts": self.texts, "modes": self.modes,
                "gps": {str(k): v for k, v in self.gps.items()}, "ekf_flags": self.ekf_flags, "marks": self.marks,
                "events": self.events, "yaw": self.yaw, "truth_yaw": self.truth_yaw}

    @classmethod
    def from_dict(cls, d: dict) -> "FlightLog":
        log = cls()
        log.ekf = [tuple(x) for x in d["ekf"]]
        log.truth = [tuple(x) for x in d["truth"]]
        log.yaw = [tuple(x) for x in d.get("yaw", [])]
        log.truth_yaw = [tuple(x) for x in d.get("truth_yaw", [])]
        log.texts = [(math.nan if t is None else t, s, x) for t, s, x in d["texts"]]
        log.modes = [(math.nan if t is None else t, m, a) for t, m, a in d["modes"]]
        log.gps = {int(k): [tuple(x) for x in v] for k, v in d["gps"].items()}
        log.ekf_flags = [tuple(x) for x in d["ekf_flags"]]
        log.marks = dict(d["marks"])
        log.events = [tuple(x) for x in d["events"]]
        return log

    def mark(self, name: str, t: float | None = None) -> None:
        self.marks[name] = self.t_boot if t is None else t

    def note(self, text: str) -> None:
        self.events.append((self.t_boot if self.t_boot is not None else math.nan, text))

    @property
    def mode(self) -> int | None:
        return self.modes[-1][1] if self.modes else None

    @property
    def armed(self) -> bool:
        return bool(self.modes and self.modes[-1][2])

    def gps_fix(self, instance: int) -> int:
        g = self.gps[instance]
        return g[-1][1] if g else 0


def _text(v) -> str:
    if isinstance(v, (bytes, bytearray)):
        v = v.decode(errors="replace")
    return str(v).rstrip("\x00").strip()


# -- geometry and error vs truth ------------------------------------------------------------------------------------
def to_ne(lat, lon, lat0: float, lon0: float) -> tuple[np.ndarray, np.ndarray]:
    """Local north/east metres around (lat0, lon0); equirectangular, exact to mm over a few hundred metres."""
    lat = np.asarray(lat, float)
    lon = np.asarray(lon, float)
    n = np.radians(lat - lat0) * EARTH_R_M
    e = np.radians(lon - lon0) * EARTH_R_M * math.cos(math.radians(lat0))
    return n, e


def truth_at(truth: list[tuple[float, float, float]], t) -> tuple[np.ndarray, np.ndarray]:
    """Truth (lat, lon) interpolated to times ``t``; NaN outside the truth's span or inside a gap."""
    t = np.asarray(t, float)
    if len(truth) < 2:
        return np.full(t.shape, np.nan), np.full(t.shape, np.nan)
    tr = np.asarray(truth, float)
    order = np.argsort(tr[:, 0], kind="stable")
    tr = tr[order]
    # duplicated stamps (two SIMSTATE on one time_boot_ms): keep the last of each
    keep = np.append(np.diff(tr[:, 0]) > 0, True)
    tr = tr[keep]
    tt = tr[:, 0]
    if len(tt) < 2:
        return np.full(t.shape, np.nan), np.full(t.shape, np.nan)
    lat = np.interp(t, tt, tr[:, 1])
    lon = np.interp(t, tt, tr[:, 2])
    i = np.clip(np.searchsorted(tt, t), 1, len(tt) - 1)
    bad = (t < tt[0]) | (t > tt[-1]) | ((tt[i] - tt[i - 1]) > MAX_TRUTH_GAP_S)
    lat[bad] = np.nan
    lon[bad] = np.nan
    return lat, lon


def truth_velocity_ne(truth: list[tuple[float, float, float]], t, half_s: float = 0.5) -> np.ndarray:
    """The truth's horizontal velocity (N, E m/s) at times ``t``: its displacement from t - half_s to t + half_s over
    2 half_s (SIMSTATE has positions only); NaN where the truth is."""
    t = np.asarray(t, float)
    la, lo = truth_at(truth, t - half_s)
    lat0 = float(np.nanmean(la)) if np.isfinite(la).any() else 0.0
    na, ea = to_ne(la, lo, lat0, 0.0)
    nb, eb = to_ne(*truth_at(truth, t + half_s), lat0, 0.0)
    return np.stack([nb - na, eb - ea], axis=-1) / (2.0 * half_s)


def velocity_steps_mps2(t, vel_ne) -> np.ndarray:
    """|v(k+1) - v(k)| / (t(k+1) - t(k)) of a velocity series (m/s^2): what a stated velocity changes between two
    messages, to be set beside what the vehicle's own velocity does at the same times. Repeated stamps are skipped."""
    t = np.asarray(t, float)
    v = np.asarray(vel_ne, float).reshape(-1, 2)
    dt = np.diff(t)
    ok = dt > 0
    return np.hypot(*np.diff(v, axis=0)[ok].T) / dt[ok]


def horizontal_error(samples_t, samples_lat, samples_lon, truth) -> np.ndarray:
    """Horizontal distance (m) of each sample from the truth at its time."""
    tl, tn = truth_at(truth, samples_t)
    lat = np.asarray(samples_lat, float)
    lon = np.asarray(samples_lon, float)
    ok = np.isfinite(tl)
    lat0 = float(np.nanmean(tl)) if ok.any() else 0.0
    dn = np.radians(lat - tl) * EARTH_R_M
    de = np.radians(lon - tn) * EARTH_R_M * math.cos(math.radians(lat0))
    return np.hypot(dn, de)


def ekf_error(log: FlightLog) -> tuple[np.ndarray, np.ndarray]:
    """(t, horizontal EKF error) at every GLOBAL_POSITION_INT with truth around it."""
    if not log.ekf:
        return np.zeros(0), np.zeros(0)
    a = np.asarray(log.ekf, float)
    err = horizontal_error(a[:, 0], a[:, 1], a[:, 2], log.truth)
    ok = np.isfinite(err)
    return a[ok, 0], err[ok]


def best_lag(t, lat, lon, truth, taus=None) -> tuple[float, float]:
    """(tau, mean error at tau): the delay tau for which the samples best match the truth at t - tau.

    A position source that reports the state of tau seconds ago shows as tau > 0; on a vehicle moving at v the
    error it costs is about v * tau. NaN when there are too few samples."""
    t = np.asarray(t, float)
    if len(t) < 20:
        return math.nan, math.nan
    taus = np.arange(-0.3, 1.0001, 0.01) if taus is None else np.asarray(taus, float)
    means = np.array([np.nanmean(horizontal_error(t - tau, lat, lon, truth)) for tau in taus])
    if not np.isfinite(means).any():
        return math.nan, math.nan
    i = int(np.nanargmin(means))
    return float(taus[i]), float(means[i])


def _window(rows, t0: float, t1: float):
    a = np.asarray(rows, float)
    if a.size == 0:
        return a.reshape(0, 3)
    sel = (a[:, 0] >= t0) & (a[:, 0] < t1)
    return a[sel]


# -- phases -----------------------------------------------------------------------------------------------------------
PHASES = ("hover", "route", "denial", "recovery")


def phase_intervals(marks: dict[str, float]) -> dict[str, tuple[float, float]]:
    """Non-overlapping [t0, t1) of each phase from the driver's marks.

    Marks: hover (climb done), route (route started), deny_on, deny_off, end. Hover and route stop at the denial;
    everything after the re-enable is recovery.
    """
    end = marks.get("end")
    if end is None:
        return {}
    deny_on, deny_off = marks.get("deny_on"), marks.get("deny_off")
    out: dict[str, tuple[float, float]] = {}
    cut = deny_on if deny_on is not None else end
    if "hover" in marks:
        h1 = min(marks.get("route", end), cut)
        if h1 > marks["hover"]:
            out["hover"] = (marks["hover"], h1)
    if "route" in marks and cut > marks["route"]:
        out["route"] = (marks["route"], cut)
    if deny_on is not None:
        off = deny_off if deny_off is not None else end
        out["denial"] = (deny_on, off)
        if deny_off is not None and end > deny_off:
            out["recovery"] = (deny_off, end)
    return out


def phase_stats(t: np.ndarray, err: np.ndarray, intervals: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float, int]]:
    """Per phase: (mean, max, samples) of the error; NaN when the phase has no sample."""
    out = {}
    for name, (a, b) in intervals.items():
        sel = (t >= a) & (t < b)
        out[name] = (float(err[sel].mean()), float(err[sel].max()), int(sel.sum())) if sel.any() else (math.nan, math.nan, 0)
    return out


def error_at_marks(t: np.ndarray, err: np.ndarray, t0: float, until_s: float, step_s: float = MARK_STEP_S,
                   tol_s: float = 0.5) -> list[tuple[float, float]]:
    """(offset, error) at t0 + 0, step, 2 step ... <= until_s: the sample nearest each mark within ``tol_s``."""
    out = []
    k = 0
    while k * step_s <= until_s + 1e-9:
        off = k * step_s
        out.append((off, _nearest(t, err, t0 + off, tol_s)))
        k += 1
    return out


def _nearest(t: np.ndarray, v: np.ndarray, at: float, tol_s: float) -> float:
    if len(t) == 0:
        return math.nan
    i = int(np.argmin(np.abs(t - at)))
    return float(v[i]) if abs(t[i] - at) <= tol_s else math.nan


def error_vectors(log: FlightLog) -> tuple[np.ndarray, np.ndarray]:
    """(t, north/east EKF error vectors (m)) at every GLOBAL_POSITION_INT with truth around it."""
    if not log.ekf:
        return np.zeros(0), np.zeros((0, 2))
    a = np.asarray(log.ekf, float)
    tl, tn = truth_at(log.truth, a[:, 0])
    ok = np.isfinite(tl)
    lat0 = float(np.nanmean(tl)) if ok.any() else 0.0
    dn = np.radians(a[:, 1] - tl) * EARTH_R_M
    de = np.radians(a[:, 2] - tn) * EARTH_R_M * math.cos(math.radians(lat0))
    return a[ok, 0], np.stack([dn[ok], de[ok]], axis=1)


def return_jump(log: FlightLog, t_back: float, window_s: float = 10.0) -> float:
    """The largest step of the EKF's position relative to the truth between two consecutive GLOBAL_POSITION_INT in the
    ``window_s`` after GNSS came back (``t_back``): the jump a vehicle makes when its estimate snaps to the receiver
    (the truth's own motion between the samples is taken out). NaN without samples."""
    t, ev = error_vectors(log)
    sel = (t >= t_back - 0.5) & (t <= t_back + window_s)
    if sel.sum() < 2:
        return math.nan
    return float(np.max(np.hypot(*np.diff(ev[sel], axis=0).T)))


# -- status text, modes, failsafes -------------------------------------------------------------------------------------
FAILSAFE_RE = re.compile(r"^EKF Failsafe(?!.*Cleared)", re.I)
VARIANCE_RE = re.compile(r"^EKF variance", re.I)
DEAD_RECKONING_RE = re.compile(r"^Dead Reckoning started", re.I)
ARM_REFUSAL_RE = re.compile(r"^(PreArm|Arm):", re.I)


def first_text(log: FlightLog, pattern: re.Pattern, after: float) -> tuple[float, str] | None:
    for t, _sev, text in log.texts:
        if math.isfinite(t) and t >= after and pattern.search(text):
            return t, text
    return None


def first_mode(log: FlightLog, mode: int, after: float) -> float | None:
    for t, m, _armed in log.modes:
        if math.isfinite(t) and t >= after and m == mode:
            return t
    return None


def first_mode_change(log: FlightLog, after: float, mode: int = MODE_GUIDED) -> tuple[float, int] | None:
    """The first time after ``after`` the vehicle left ``mode`` (a failsafe's LAND or RTL), and the mode it took."""
    for t, m, _armed in log.modes:
        if math.isfinite(t) and t >= after and m != mode:
            return t, m
    return None


def mode_events(log: FlightLog, after: float) -> list[tuple[float, str]]:
    """Every mode change and failsafe or dead-reckoning message after ``after``: (time, text), in time order."""
    out = [(t, f"mode {COPTER_MODES.get(m, m)}") for t, m, _a in log.modes if math.isfinite(t) and t >= after]
    pats = (FAILSAFE_RE, DEAD_RECKONING_RE, re.compile(r"^Dead Reckoning timeout", re.I))
    out += [(t, txt) for t, _s, txt in log.texts if math.isfinite(t) and t >= after and any(p.search(txt) for p in pats)]
    return sorted(out)


def arm_refusals(log: FlightLog) -> list[str]:
    """Distinct PreArm/Arm refusal texts, in order of first appearance."""
    seen: list[str] = []
    for _t, _s, text in log.texts:
        if ARM_REFUSAL_RE.search(text) and text not in seen:
            seen.append(text)
    return seen


def fix_counts(log: FlightLog, instance: int, t0: float = -math.inf, t1: float = math.inf) -> dict[int, int]:
    return dict(sorted(Counter(f for t, f, _ in log.gps[instance] if t0 <= t < t1).items()))


# -- the companion's own solution ----------------------------------------------------------------------------------------
def companion_error(records: list[dict], truth) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(boot time, error, fix_type, stated h_acc) of every GPS_INPUT the companion sent, against the truth at the time
    it claims (``time_boot_us``: the autopilot boot time of the state the message describes)."""
    recs = [r for r in records if r.get("sent") and r.get("lat_deg") is not None and r.get("time_boot_us") is not None]
    if not recs:
        return np.zeros(0), np.zeros(0), np.zeros(0, int), np.zeros(0)
    t = np.array([r["time_boot_us"] / 1e6 for r in recs])
    err = horizontal_error(t, [r["lat_deg"] for r in recs], [r["lon_deg"] for r in recs], truth)
    fx = np.array([int(r["fix_type"]) for r in recs])
    hacc = np.array([float(r.get("h_acc_m") or math.nan) for r in recs])
    ok = np.isfinite(err)
    return t[ok], err[ok], fx[ok], hacc[ok]


# -- one arm's result -------------------------------------------------------------------------------------------------
@dataclass
class ArmResult:
    scenario: str
    arm: str  # "A" (ArduPilot alone), "AD" (alone with drag fusion and the dead-reckoning failsafe), "B" (+ companion)
    armed: bool
    arm_time_s: float  # boot seconds at arming (nan: never)
    refusals: list[str]
    phases: dict[str, tuple[float, float, int]]
    marks_err: list[tuple[float, float]]
    failsafe_s: float  # EKF failsafe after deny_on; nan: none
    variance_s: float
    land_s: float
    left_guided_s: float  # the vehicle left GUIDED (a failsafe's LAND or RTL) after deny_on; nan: kept flying
    dead_reckoning_s: float  # ArduPilot said "Dead Reckoning started" after deny_on
    events: list[tuple[float, str]]  # mode changes and failsafe messages, time after deny_on
    gps2_fix: dict[int, int]
    gps2_fix_denial: dict[int, int]
    sent_fix: dict[int, int]
    own_err_at: dict[float, float]
    own_healthy_mean: float
    within_2hacc: float  # share of the 3D fixes sent whose error is within 2x their h_acc
    fixes_with_hacc: int  # how many that share is of
    return_jump_m: float  # the EKF's largest step when GPS1 came back
    last_hacc_m: float  # h_acc of the companion's last fix before GPS1 came back if it was 3D (nan: no claim standing)
    t_err: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    err: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    own_t: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    own_err: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    own_hacc: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    own_fix: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, int))
    deny_on: float = math.nan
    ekf_lag_s: float = math.nan  # best_lag of the EKF over the route before any denial
    ekf_lag_err: float = math.nan
    own_lag_s: float = math.nan  # best_lag of the companion's GPS_INPUT (vs the time it claims) over the same window
    own_lag_err: float = math.nan
    takeover: str = ""  # the companion's decision at the loss (its /inject/state reason), "" when none was recorded
    trust: dict = field(default_factory=dict)  # its trust verdict at the loss (companion.nav.trust.TrustVerdict)
    run: int = 1  # which repetition of the scenario
    imu_coalesced: tuple[int, int] = (0, 0)  # the companion's IMU samples coalesced / taken in while behind its link
    notes: list[str] = field(default_factory=list)


OWN_MARKS = (5.0, 10.0, 30.0, 60.0)


def _since(t: float | None, t0: float) -> float:
    return (t - t0) if t is not None else math.nan


def analyse(scenario: Scenario, arm: str, log: FlightLog, records: list[dict] | None = None) -> ArmResult:
    t, err = ekf_error(log)
    iv = phase_intervals(log.marks)
    deny_on = log.marks.get("deny_on", math.nan)
    deny_off = log.marks.get("deny_off", math.nan)
    have_deny = math.isfinite(deny_on)
    until = (log.marks.get("end", deny_on) - deny_on) if have_deny else 0.0
    fs = first_text(log, FAILSAFE_RE, deny_on) if have_deny else None
    var = first_text(log, VARIANCE_RE, deny_on) if have_deny else None
    dr = first_text(log, DEAD_RECKONING_RE, deny_on) if have_deny else None
    land = first_mode(log, MODE_LAND, deny_on) if have_deny else None
    left = first_mode_change(log, deny_on) if have_deny else None
    arm_t = next((tt for tt, _m, a in log.modes if a), math.nan)
    own_t, own_err, own_fx, own_hacc = companion_error(records or [], log.truth)
    own_at = {}
    if have_deny:
        for off in OWN_MARKS:
            own_at[off] = _nearest(own_t, own_err, deny_on + off, 0.5)
    healthy_end = deny_on if have_deny else log.marks.get("end", math.inf)
    sel = (own_t >= log.marks.get("hover", math.inf)) & (own_t < healthy_end)
    used = own_fx >= 3  # what EKF3 fuses (a 2D fix is no position to it) and GPS_AUTO_SWITCH selects
    ok_h = used & np.isfinite(own_hacc) & (own_hacc > 0)
    # the claim standing when GPS1 came back: the last fix sent before, if it was a 3D fix EKF3 was fusing
    sent_before = own_t < deny_off if math.isfinite(deny_off) else np.zeros(len(own_t), bool)
    last_claim = (float(own_hacc[sent_before][-1]) if sent_before.any() and own_fx[sent_before][-1] >= 3
                  else math.nan)
    lag = (math.nan, math.nan)
    own_lag = (math.nan, math.nan)
    if "route" in iv:
        w = _window(log.ekf, *iv["route"])
        if len(w):
            lag = best_lag(w[:, 0], w[:, 1], w[:, 2], log.truth)
        recs = [r for r in (records or []) if r.get("sent") and r.get("time_boot_us") is not None
                and iv["route"][0] <= r["time_boot_us"] / 1e6 < iv["route"][1]]
        if recs:
            own_lag = best_lag([r["time_boot_us"] / 1e6 for r in recs], [r["lat_deg"] for r in recs],
                               [r["lon_deg"] for r in recs], log.truth)
    return ArmResult(
        scenario=scenario.name, arm=arm, armed=math.isfinite(arm_t), arm_time_s=arm_t, refusals=arm_refusals(log),
        phases=phase_stats(t, err, iv),
        marks_err=error_at_marks(t, err, deny_on, until) if have_deny else [],
        failsafe_s=_since(fs[0] if fs else None, deny_on), variance_s=_since(var[0] if var else None, deny_on),
        land_s=_since(land, deny_on), left_guided_s=_since(left[0] if left else None, deny_on),
        dead_reckoning_s=_since(dr[0] if dr else None, deny_on),
        events=[(tt - deny_on, txt) for tt, txt in mode_events(log, deny_on)] if have_deny else [],
        gps2_fix=fix_counts(log, 2), gps2_fix_denial=fix_counts(log, 2, deny_on, deny_off) if have_deny else {},
        sent_fix=dict(sorted(Counter(int(f) for f in own_fx).items())), own_err_at=own_at,
        own_healthy_mean=float(own_err[sel].mean()) if sel.any() else math.nan,
        within_2hacc=float(np.mean(own_err[ok_h] <= 2.0 * own_hacc[ok_h])) if ok_h.any() else math.nan,
        fixes_with_hacc=int(ok_h.sum()),
        return_jump_m=return_jump(log, deny_off) if math.isfinite(deny_off) else math.nan,
        last_hacc_m=last_claim,
        t_err=t, err=err, own_t=own_t, own_err=own_err, own_hacc=own_hacc, own_fix=own_fx, deny_on=deny_on,
        ekf_lag_s=lag[0], ekf_lag_err=lag[1], own_lag_s=own_lag[0], own_lag_err=own_lag[1],
    )
