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

    hover_s: hover after the climb before the square (or the whole hover when ``laps`` is 0).
    laps: laps of the square (0: no square). deny_in: "hover", "square" or "" (no denial).
    deny_at_s: denial start, after the start of the phase it is in (for "square" with ``deny_lap`` > 0: after
    the start of that lap). deny_s: denial length. recover_s: flight after re-enabling GPS1 (the scenario
    ends then, or when the laps are done, whichever is later).
    """

    name: str
    hover_s: float = 20.0
    laps: int = 1
    deny_in: str = ""
    deny_at_s: float = 0.0
    deny_s: float = 0.0
    deny_lap: int = 0
    recover_s: float = 30.0
    side_m: float = 100.0
    speed_mps: float = 8.0
    alt_m: float = 20.0

    @property
    def denies(self) -> bool:
        return bool(self.deny_in) and self.deny_s > 0


def _scenarios() -> dict[str, Scenario]:
    out = {"healthy": Scenario("healthy", hover_s=20.0, laps=1)}
    for d in (10, 30, 60):
        out[f"hover-deny-{d}"] = Scenario(f"hover-deny-{d}", hover_s=15.0, laps=0, deny_in="hover", deny_at_s=15.0,
                                          deny_s=d, recover_s=30.0)
        out[f"square-deny-{d}"] = Scenario(f"square-deny-{d}", hover_s=10.0, laps=99, deny_in="square", deny_at_s=10.0,
                                           deny_s=d, recover_s=30.0)
    out["survey-deny-45"] = Scenario("survey-deny-45", hover_s=10.0, laps=4, deny_in="square", deny_lap=3,
                                     deny_at_s=5.0, deny_s=45.0, recover_s=30.0)
    out["recovery"] = Scenario("recovery", hover_s=10.0, laps=99, deny_in="square", deny_at_s=10.0, deny_s=20.0,
                               recover_s=90.0)
    out["hover-short"] = Scenario("hover-short", hover_s=30.0, laps=0)
    return out


SCENARIOS = _scenarios()
DEFAULT_SCENARIOS = ["healthy", "hover-deny-30", "square-deny-30"]


def square_corners(side_m: float) -> list[tuple[float, float]]:
    """North/east offsets of the square's corners from its start, flown in order and closed."""
    return [(side_m, 0.0), (side_m, side_m), (0.0, side_m), (0.0, 0.0)]


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
                "events": self.events}

    @classmethod
    def from_dict(cls, d: dict) -> "FlightLog":
        log = cls()
        log.ekf = [tuple(x) for x in d["ekf"]]
        log.truth = [tuple(x) for x in d["truth"]]
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
PHASES = ("hover", "square", "denial", "recovery")


def phase_intervals(marks: dict[str, float]) -> dict[str, tuple[float, float]]:
    """Non-overlapping [t0, t1) of each phase from the driver's marks.

    Marks: hover (climb done), square (square started), deny_on, deny_off, end. Hover and square stop at the
    denial; everything after the re-enable is recovery.
    """
    end = marks.get("end")
    if end is None:
        return {}
    deny_on, deny_off = marks.get("deny_on"), marks.get("deny_off")
    out: dict[str, tuple[float, float]] = {}
    cut = deny_on if deny_on is not None else end
    if "hover" in marks:
        h1 = min(marks.get("square", end), cut)
        if h1 > marks["hover"]:
            out["hover"] = (marks["hover"], h1)
    if "square" in marks and cut > marks["square"]:
        out["square"] = (marks["square"], cut)
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


# -- status text, modes, failsafes -------------------------------------------------------------------------------------
FAILSAFE_RE = re.compile(r"^EKF Failsafe(?!.*Cleared)", re.I)
VARIANCE_RE = re.compile(r"^EKF variance", re.I)
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
def companion_error(records: list[dict], truth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(boot time, error, fix_type) of every GPS_INPUT the companion sent, against the truth at the time it claims
    (``time_boot_us``: the autopilot boot time of the state the message describes)."""
    recs = [r for r in records if r.get("sent") and r.get("lat_deg") is not None and r.get("time_boot_us") is not None]
    if not recs:
        return np.zeros(0), np.zeros(0), np.zeros(0, int)
    t = np.array([r["time_boot_us"] / 1e6 for r in recs])
    err = horizontal_error(t, [r["lat_deg"] for r in recs], [r["lon_deg"] for r in recs], truth)
    fx = np.array([int(r["fix_type"]) for r in recs])
    ok = np.isfinite(err)
    return t[ok], err[ok], fx[ok]


# -- one arm's result -------------------------------------------------------------------------------------------------
@dataclass
class ArmResult:
    scenario: str
    arm: str  # "A" (ArduPilot alone) or "B" (+ companion)
    armed: bool
    arm_time_s: float  # boot seconds at arming (nan: never)
    refusals: list[str]
    phases: dict[str, tuple[float, float, int]]
    marks_err: list[tuple[float, float]]
    failsafe_s: float  # after deny_on; nan: none
    variance_s: float
    land_s: float
    gps2_fix: dict[int, int]
    gps2_fix_denial: dict[int, int]
    sent_fix: dict[int, int]
    own_err_at: dict[float, float]
    own_healthy_mean: float
    t_err: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    err: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    own_t: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    own_err: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    deny_on: float = math.nan
    ekf_lag_s: float = math.nan  # best_lag of the EKF over the square before any denial
    ekf_lag_err: float = math.nan
    own_lag_s: float = math.nan  # best_lag of the companion's GPS_INPUT (vs the time it claims) over the same window
    own_lag_err: float = math.nan
    notes: list[str] = field(default_factory=list)


OWN_MARKS = (10.0, 30.0, 60.0)


def analyse(scenario: Scenario, arm: str, log: FlightLog, records: list[dict] | None = None) -> ArmResult:
    t, err = ekf_error(log)
    iv = phase_intervals(log.marks)
    deny_on = log.marks.get("deny_on", math.nan)
    have_deny = math.isfinite(deny_on)
    until = (log.marks.get("end", deny_on) - deny_on) if have_deny else 0.0
    fs = first_text(log, FAILSAFE_RE, deny_on) if have_deny else None
    var = first_text(log, VARIANCE_RE, deny_on) if have_deny else None
    land = first_mode(log, MODE_LAND, deny_on) if have_deny else None
    arm_t = next((tt for tt, _m, a in log.modes if a), math.nan)
    own_t, own_err, own_fx = companion_error(records or [], log.truth)
    own_at = {}
    if have_deny:
        for off in OWN_MARKS:
            own_at[off] = _nearest(own_t, own_err, deny_on + off, 0.5)
    healthy_end = deny_on if have_deny else log.marks.get("end", math.inf)
    sel = (own_t >= log.marks.get("hover", math.inf)) & (own_t < healthy_end)
    off = log.marks.get("deny_off", math.inf)
    lag = (math.nan, math.nan)
    own_lag = (math.nan, math.nan)
    if "square" in iv:
        w = _window(log.ekf, *iv["square"])
        if len(w):
            lag = best_lag(w[:, 0], w[:, 1], w[:, 2], log.truth)
        recs = [r for r in (records or []) if r.get("sent") and r.get("time_boot_us") is not None
                and iv["square"][0] <= r["time_boot_us"] / 1e6 < iv["square"][1]]
        if recs:
            own_lag = best_lag([r["time_boot_us"] / 1e6 for r in recs], [r["lat_deg"] for r in recs],
                               [r["lon_deg"] for r in recs], log.truth)
    return ArmResult(
        scenario=scenario.name, arm=arm, armed=math.isfinite(arm_t), arm_time_s=arm_t, refusals=arm_refusals(log),
        phases=phase_stats(t, err, iv),
        marks_err=error_at_marks(t, err, deny_on, until) if have_deny else [],
        failsafe_s=(fs[0] - deny_on) if fs else math.nan, variance_s=(var[0] - deny_on) if var else math.nan,
        land_s=(land - deny_on) if land is not None else math.nan,
        gps2_fix=fix_counts(log, 2), gps2_fix_denial=fix_counts(log, 2, deny_on, off) if have_deny else {},
        sent_fix=dict(sorted(Counter(int(f) for f in own_fx).items())), own_err_at=own_at,
        own_healthy_mean=float(own_err[sel].mean()) if sel.any() else math.nan,
        t_err=t, err=err, own_t=own_t, own_err=own_err, deny_on=deny_on,
        ekf_lag_s=lag[0], ekf_lag_err=lag[1], own_lag_s=own_lag[0], own_lag_err=own_lag[1],
    )


# -- report -----------------------------------------------------------------------------------------------------------
ARM_NAMES = {"A": "ArduPilot alone", "B": "+ companion (GPS2)"}


def _f(v: float, nd: int = 2) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.{nd}f}"


def _fixes(d: dict[int, int]) -> str:
    return " ".join(f"{k}:{v}" for k, v in d.items()) if d else "—"


def md(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def phase_table(results: list[ArmResult]) -> str:
    rows = []
    for r in results:
        cells = [r.scenario, ARM_NAMES.get(r.arm, r.arm), "yes" if r.armed else "NO"]
        for p in PHASES:
            s = r.phases.get(p)
            cells.append(f"{_f(s[0])} / {_f(s[1])}" if s else "")
        cells += [_f(r.variance_s, 1), _f(r.failsafe_s, 1), _f(r.land_s, 1)]
        rows.append(cells)
    return md(["scenario", "arm", "armed", "hover mean / max (m)", "square mean / max (m)", "denial mean / max (m)",
               "recovery mean / max (m)", "EKF variance (+s)", "EKF failsafe (+s)", "LAND (+s)"], rows)


def marks_table(results: list[ArmResult]) -> str:
    denied = [r for r in results if r.marks_err]
    if not denied:
        return ""
    n = max(len(r.marks_err) for r in denied)
    header = ["scenario", "arm"] + [f"+{int(k * MARK_STEP_S)}" for k in range(n)]
    rows = []
    for r in denied:
        vals = [_f(e, 1) for _o, e in r.marks_err]
        rows.append([r.scenario, r.arm] + vals + [""] * (n - len(vals)))
    return md(header, rows)


def companion_table(results: list[ArmResult]) -> str:
    rows = []
    for r in results:
        if r.arm != "B":
            continue
        rows.append([r.scenario, _fixes(r.sent_fix), _fixes(r.gps2_fix), _fixes(r.gps2_fix_denial), _f(r.own_healthy_mean)]
                    + [_f(r.own_err_at.get(o, math.nan), 1) for o in OWN_MARKS])
    if not rows:
        return ""
    return md(["scenario", "fix types sent (type:count)", "GPS2_RAW fix types (whole flight)",
               "GPS2_RAW during denial", "own error before denial, mean (m)"]
              + [f"own error +{int(o)} s (m)" for o in OWN_MARKS], rows)


def lag_table(results: list[ArmResult]) -> str:
    rows = [[r.scenario, ARM_NAMES.get(r.arm, r.arm), _f(r.ekf_lag_s), _f(r.ekf_lag_err),
             _f(r.own_lag_s) if r.arm == "B" else "", _f(r.own_lag_err) if r.arm == "B" else ""]
            for r in results if math.isfinite(r.ekf_lag_s)]
    if not rows:
        return ""
    return md(["scenario", "arm", "EKF delay vs truth (s)", "EKF error at that delay (m)",
               "GPS_INPUT delay vs its time_usec (s)", "GPS_INPUT error at that delay (m)"], rows)


def arming_lines(results: list[ArmResult]) -> str:
    lines = []
    for r in results:
        ref = "; ".join(r.refusals[:4]) if r.refusals else "none"
        lines.append(f"- {r.scenario} {r.arm}: armed {'yes' if r.armed else 'NO'} "
                     f"(boot +{_f(r.arm_time_s, 1)} s); refusals seen: {ref}" + (f"; {'; '.join(r.notes)}" if r.notes else ""))
    return "\n".join(lines)


LATLON_STEP_M = 0.011  # GLOBAL_POSITION_INT's lat/lon step (1e-7 deg) in metres
FAILSAFE_CHECK_S = 0.1  # ArduCopter's EKF failsafe check period


def ab_verdicts(results: list[ArmResult]) -> list[str]:
    """The issue's targets, checked per scenario where both arms ran."""
    by = {(r.scenario, r.arm): r for r in results}
    out = []
    pooled: dict[str, list[tuple[float, float]]] = {}
    for (sc, arm), a in by.items():
        if arm != "A" or (sc, "B") not in by:
            continue
        b = by[(sc, "B")]
        for p in ("hover", "square"):
            if p in a.phases and p in b.phases and math.isfinite(a.phases[p][0]) and math.isfinite(b.phases[p][0]):
                ma, mb = a.phases[p][0], b.phases[p][0]
                pooled.setdefault(p, []).append((ma, mb))
                ratio = mb / max(ma, 1e-6)
                # a hover's mean error is ~1-2 cm: a ratio of such means is the resolution of GLOBAL_POSITION_INT
                # (1e-7 deg, 1.1 cm), not a difference between the arms
                verdict = "met" if ratio <= 1.1 else ("met (difference below one 1e-7 deg step, 1.1 cm)"
                                                      if mb - ma < LATLON_STEP_M else "NOT met")
                out.append(f"- {sc}, {p}: mean EKF error B/A = {ratio:.1f}x ({mb:.3f} vs {ma:.3f} m; target <= 1.1x): "
                           f"{verdict}")
        if a.marks_err and b.marks_err:
            worse = [(o, eb - ea) for (o, ea), (_o, eb) in zip(a.marks_err, b.marks_err)
                     if math.isfinite(ea) and math.isfinite(eb) and eb > ea + 0.5]
            out.append(f"- {sc}, denial: 5 s marks where B > A + 0.5 m: {len(worse)} of {len(a.marks_err)}"
                       + (f" (worst +{int(max(worse, key=lambda w: w[1])[0])} s: +{max(w[1] for w in worse):.1f} m)" if worse else ""))
            fa, fb = a.failsafe_s, b.failsafe_s
            # ArduCopter checks the EKF failsafe at 10 Hz: times within one check period are the same failsafe
            if math.isfinite(fb) and (not math.isfinite(fa) or fb < fa - FAILSAFE_CHECK_S):
                out.append(f"- {sc}: failsafe with the companion earlier than alone (+{fb:.2f} s vs +{_f(fa, 2)} s)")
            elif math.isfinite(fa) and not math.isfinite(fb):
                out.append(f"- {sc}: no EKF failsafe with the companion (alone: +{fa:.1f} s)")
            if not math.isfinite(fb):
                within = max((eb for _o, eb in b.marks_err if math.isfinite(eb)), default=math.nan)
                out.append(f"- {sc}: kept flying (no failsafe), EKF error <= {within:.1f} m at every 5 s mark "
                           f"(target <= 3 m: {'met' if within <= 3.0 else 'NOT met'})")
    for p, pairs in pooled.items():
        if len(pairs) > 1:  # one scenario's ratio carries the run-to-run spread of a 0.15 m mean; the pool less so
            ma, mb = (float(np.mean(x)) for x in zip(*pairs))
            out.append(f"- all {len(pairs)} scenarios pooled, {p}: mean EKF error B/A = {mb / max(ma, 1e-6):.2f}x "
                       f"({mb:.3f} vs {ma:.3f} m; A's scenario means span {min(x[0] for x in pairs):.3f}-"
                       f"{max(x[0] for x in pairs):.3f} m)")
    return out
