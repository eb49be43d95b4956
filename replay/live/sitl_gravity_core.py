"""Pure logic of the gravity-aided ArduPilot SITL A/B (replay.live.sitl_gravity): the survey mission over a gravity
grid, the flight's schedule (GNSS, denial, return; the wind turning during the denial), and the figures of one arm
against SITL's truth in the schema of ``DIR/summary.json``. No processes, no sockets; driven by a
replay.live.sitl_core.FlightLog and the companion's GPS_INPUT records, so the unit tests feed it scripted data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink import mavutil

from companion.gravity.maps import LocalGravityMap
from companion.nav.frame import LocalFrame
from companion.sim.cruise import survey_waypoints
from replay.live import sitl_core as core

PLANE_MODES: dict[int, str] = dict(mavutil.mode_mapping_apm)
ROVER_MODES: dict[int, str] = dict(mavutil.mode_mapping_rover)
MARK_MIN = tuple(range(5, 61, 5))


# -- the mission ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Survey:
    """Lawn-mower lines from ``origin`` (lat, lon): ``lines`` lines of ``line_km`` along ``heading_deg``, ``spacing_km``
    apart (the next to the right), flown at ``alt_m`` above home; the vehicle flies them over and over."""

    origin: tuple[float, float]
    line_km: float = 30.0
    spacing_km: float = 4.0
    lines: int = 4
    heading_deg: float = 0.0
    alt_m: float = 150.0

    def corners_ne_m(self) -> np.ndarray:
        """The corners from the origin (first line start) in NE metres, closed back to the start."""
        per_loop = self.lines * (self.line_km + self.spacing_km) * 1e3
        pts = survey_waypoints(per_loop, self.line_km * 1e3, self.spacing_km * 1e3, self.heading_deg,
                               max_lines=self.lines)
        pts = np.array([(0.0, 0.0)] + [tuple(p) for p in pts])
        keep = [0] + [i for i in range(1, len(pts)) if np.hypot(*(pts[i] - pts[i - 1])) > 1.0]
        pts = pts[keep]
        # the pattern comes back across: stop at the last line's end and close the loop to the start
        out = [pts[0]]
        for p in pts[1:]:
            out.append(p)
            if len(out) >= 2 * self.lines:
                break
        return np.array(out + [pts[0]])

    def corners_lat_lon(self) -> list[tuple[float, float]]:
        fr = LocalFrame(self.origin[0], self.origin[1], 0.0)
        ne = self.corners_ne_m()
        lat, lon, _ = fr.to_geodetic(np.column_stack([ne, np.zeros(len(ne))]))
        return list(zip(np.atleast_1d(lat).tolist(), np.atleast_1d(lon).tolist()))

    def loop_length_m(self) -> float:
        ne = self.corners_ne_m()
        return float(np.sum(np.hypot(*np.diff(ne, axis=0).T)))


def map_signal(survey: Survey, lmap: LocalGravityMap, step_m: float = 500.0,
               origin_lat_lon: tuple[float, float] | None = None) -> dict[str, float]:
    """The map along the planned lines: its STD (mGal), the share of the path on valid map, and the mean gradient
    (mGal/km) -- whether the lines lie over signal a matcher can use. ``origin_lat_lon`` lays a local metric grid's
    (0, 0) at that point."""
    ne = survey.corners_ne_m()
    pts = []
    for a, b in zip(ne[:-1], ne[1:]):
        k = max(1, int(np.hypot(*(b - a)) / step_m))
        pts += [a + (b - a) * i / k for i in range(k)]
    p = np.array(pts)
    fr = LocalFrame(survey.origin[0], survey.origin[1], 0.0)
    lat, lon, _ = fr.to_geodetic(np.column_stack([p, np.zeros(len(p))]))
    if lmap.frame is not None:
        n, e = lmap.xy_to_ne(lon, lat)
    else:
        o = LocalFrame(*(origin_lat_lon or survey.origin), 0.0).to_ned_m(lat, lon, 0.0)
        n, e = o[..., 0], o[..., 1]
    g = lmap.interp_ne(n, e)
    ok = np.isfinite(g)
    grad = np.abs(np.diff(g)) / (step_m / 1e3)
    return {"std_mgal": float(np.std(g[ok])) if ok.any() else math.nan, "on_map": float(ok.mean()),
            "grad_mgal_per_km": float(np.nanmean(grad)) if np.isfinite(grad).any() else math.nan}


def cross_track_m(lat, lon, survey: Survey) -> np.ndarray:
    """Distance of each true position from the nearest planned line (m)."""
    fr = LocalFrame(survey.origin[0], survey.origin[1], 0.0)
    q = fr.to_ned_m(np.asarray(lat, float), np.asarray(lon, float), 0.0)[..., :2].reshape(-1, 2)
    c = survey.corners_ne_m()
    best = np.full(len(q), np.inf)
    for a, b in zip(c[:-1], c[1:]):
        d = b - a
        L2 = float(d @ d)
        s = np.clip(((q - a) @ d) / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(q))
        best = np.minimum(best, np.hypot(*(q - (a + s[:, None] * d)).T))
    return best


# -- the flight's schedule -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Schedule:
    """Minutes after the survey start: GNSS for ``healthy_min``, denied for ``denial_min``, back for ``back_min``.
    The wind (``wind_mps`` from ``wind_dir_deg``, turbulence ``turb_mps``) turns by ``wind_turn_deg`` every
    ``wind_turn_min`` of the denial; on a boat the water's current (SITL's tide, ``current_mps`` from
    ``current_dir_deg``; 0: still) turns by ``current_turn_deg`` every ``wind_turn_min`` too."""

    healthy_min: float = 20.0
    denial_min: float = 60.0
    back_min: float = 5.0
    wind_mps: float = 7.0
    wind_dir_deg: float = 240.0
    turb_mps: float = 2.0
    wind_turn_deg: float = 40.0
    wind_turn_min: float = 15.0
    current_mps: float = 0.0
    current_dir_deg: float = 200.0
    current_turn_deg: float = 7.5

    def events(self, t0_s: float) -> list[tuple[float, str, dict[str, float]]]:
        """(vehicle time, label, parameters to set) in time order, from survey start ``t0_s``."""
        on = t0_s + 60.0 * self.healthy_min
        off = on + 60.0 * self.denial_min
        ev = [(on, "deny_on", {"SIM_GPS1_ENABLE": 0.0})]
        k = 1
        while self.wind_turn_min > 0 and k * self.wind_turn_min < self.denial_min:
            d = (self.wind_dir_deg + k * self.wind_turn_deg) % 360.0
            ev.append((on + 60.0 * k * self.wind_turn_min, f"wind {d:.0f} deg", {"SIM_WIND_DIR": d}))
            if self.current_mps > 0:
                c = (self.current_dir_deg + k * self.current_turn_deg) % 360.0
                ev.append((on + 60.0 * k * self.wind_turn_min, f"current {c:.1f} deg", {"SIM_TIDE_DIR": c}))
            k += 1
        ev.append((off, "deny_off", {"SIM_GPS1_ENABLE": 1.0}))
        ev.append((off + 60.0 * self.back_min, "end", {}))
        return sorted(ev, key=lambda x: x[0])

    def sim_params(self) -> dict[str, float]:
        p = {"SIM_WIND_SPD": self.wind_mps, "SIM_WIND_DIR": self.wind_dir_deg, "SIM_WIND_TURB": self.turb_mps}
        if self.current_mps > 0:  # SITL's boats only (SIM_Sailboat, which the motorboat is): a tide moving the hull
            p.update(SIM_TIDE_SPEED=self.current_mps, SIM_TIDE_DIR=self.current_dir_deg)
        return p


# -- one arm's figures ---------------------------------------------------------------------------------------------
FAILSAFE_TEXT = ("failsafe", "dead reckoning", "emergency", "mission abort", "rtl", "land")


def failsafes(log: core.FlightLog, deny_on: float, modes: dict[int, str]) -> list[list]:
    """Every mode change and failsafe-like message after the survey started (``marks['route']``), as [minute after
    the denial began, text] (negative: before it)."""
    t0 = log.marks.get("route", deny_on)
    out = []
    for t, m, _armed in log.modes:
        if math.isfinite(t) and t > t0:
            out.append([round((t - deny_on) / 60.0, 2), f"mode {modes.get(m, m)}"])
    for t, _sev, txt in log.texts:
        if math.isfinite(t) and t > t0 and any(w in txt.lower() for w in FAILSAFE_TEXT):
            out.append([round((t - deny_on) / 60.0, 2), txt])
    return sorted(out)


def ahrs_messages(log: core.FlightLog, deny_on: float) -> list[list]:
    """The AHRS's messages after the survey started ("AHRS: DCM active": ArduPilot's fixed wing left EKF3 for its
    DCM fallback, AP_AHRS), as [minute after the denial began, text]: not a failsafe, but what flies the vehicle."""
    t0 = log.marks.get("route", deny_on)
    return [[round((t - deny_on) / 60.0, 2), txt] for t, _sev, txt in log.texts
            if math.isfinite(t) and t > t0 and txt.lower().startswith("ahrs:")]


def _settled(t: np.ndarray, err: np.ndarray, level_m: float, hold_s: float) -> np.ndarray:
    """Per sample: it is within ``level_m``, and so is the median error of every ``hold_s`` window starting in the next
    ``hold_s`` (each window covered by samples, not cut by the series' end)."""
    end = np.searchsorted(t, t + hold_s, side="right")
    whole = t[end - 1] >= t + hold_s - 1.0
    med_ok = np.array([bool(whole[k]) and float(np.median(err[k:end[k]])) <= level_m for k in range(len(t))], bool)
    bad = np.concatenate([[0], np.cumsum(~med_ok)])
    return (err <= level_m) & whole & (bad[end] == bad[np.arange(len(t))])


def reconverge_s(t: np.ndarray, err: np.ndarray, t_back: float, level_m: float, hold_s: float = 10.0) -> float:
    """Seconds after ``t_back`` until the error is back within ``level_m``: the first sample within it from which the
    median error of every ``hold_s`` window starting in the next ``hold_s`` is within it too; NaN never. A median, not
    every sample: a healthy error is above its own 95th percentile 5 % of the time, so asking every sample of 10 s
    to stay under it read healthy flight as not converged for minutes (docs/decisions/0021)."""
    sel = t >= t_back
    idx = np.nonzero(_settled(t[sel], err[sel], level_m, hold_s))[0]
    return float(t[sel][idx[0]] - t_back) if len(idx) else math.nan


def healthy_wait_max_s(t: np.ndarray, err: np.ndarray, t0: float, t1: float, level_m: float,
                       step_s: float = 20.0, hold_s: float = 10.0) -> float:
    """The measure's own check: :func:`reconverge_s` started every ``step_s`` within [t0, t1 - 60 s) of a phase with
    GNSS, the longest it waits (NaN when it never settles from some start). Near 0 when the measure reads healthy
    flight as converged."""
    sel = (t >= t0) & (t < t1)
    tt = t[sel]
    ok = _settled(tt, err[sel], level_m, hold_s)
    waits = []
    for start in np.arange(t0, t1 - 60.0, step_s):
        idx = np.nonzero(ok & (tt >= start))[0]
        waits.append(float(tt[idx[0]] - start) if len(idx) else math.nan)
    return float(max(waits)) if waits and not any(math.isnan(w) for w in waits) else math.nan


def _nearest(t, v, at, tol):
    if len(t) == 0:
        return math.nan
    i = int(np.argmin(np.abs(t - at)))
    return float(v[i]) if abs(t[i] - at) <= tol else math.nan


def _f(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 2)


def arm_summary(log: core.FlightLog, survey: Survey, modes: dict[int, str], kept_up: bool,
                records: list[dict] | None = None, healthy_level_m: float | None = None) -> dict:
    """One ARM of summary.json (module doc): the EKF's horizontal error against the truth at every 5 min of the denial,
    its mean and max over the denial, failsafes and mode changes, whether the run kept up; with ``records`` (the
    companion's GPS_INPUT) the share of its 3D fixes in the denial within 2x their h_acc, the EKF's jump when GNSS came
    back, and the time until its error is back within ``healthy_level_m`` (arm A's healthy error)."""
    t, err = core.ekf_error(log)
    on, off = log.marks.get("deny_on", math.nan), log.marks.get("deny_off", math.nan)
    route = log.marks.get("route", on)
    den = (t >= on) & (t < off)
    healthy = (t >= route + 120.0) & (t < on)
    tr = np.asarray(log.truth, float).reshape(-1, 3)
    xt = cross_track_m(tr[:, 1], tr[:, 2], survey) if len(tr) else np.zeros(0)
    xt_t = tr[:, 0] if len(tr) else np.zeros(0)
    xden = (xt_t >= on) & (xt_t < off)
    out = {
        "error_m_at_min": {str(m): _f(_nearest(t, err, on + 60.0 * m, 2.0)) for m in MARK_MIN
                           if m * 60.0 <= (off - on) + 1.0},
        "mean_m": _f(float(err[den].mean())) if den.any() else None,
        "max_m": _f(float(err[den].max())) if den.any() else None,
        "healthy_mean_m": _f(float(err[healthy].mean())) if healthy.any() else None,
        "healthy_p95_m": _f(float(np.percentile(err[healthy], 95))) if healthy.any() else None,
        "cross_track_mean_m": _f(float(xt[xden].mean())) if xden.any() else None,
        "cross_track_max_m": _f(float(xt[xden].max())) if xden.any() else None,
        "failsafes": failsafes(log, on, modes),
        "ahrs": ahrs_messages(log, on),
        "kept_up": bool(kept_up),
        "return_jump_m": _f(core.return_jump(log, off)) if math.isfinite(off) else None,
    }
    out["yaw_err_deg"] = yaw_error_deg(log, on, off)
    level = healthy_level_m if healthy_level_m is not None else out["healthy_p95_m"]
    out["reconverge_s"] = _f(reconverge_s(t, err, off, level)) if level is not None and math.isfinite(off) else None
    out["healthy_wait_max_s"] = _f(healthy_wait_max_s(t, err, route + 120.0, on, level)) if level is not None else None
    if records is not None:
        own_t, own_err, own_fx, own_hacc = core.companion_error(records, log.truth)
        sel = (own_t >= on) & (own_t < off) & (own_fx >= 3) & np.isfinite(own_hacc) & (own_hacc > 0)
        out["within_2hacc_frac"] = _f(float(np.mean(own_err[sel] <= 2.0 * own_hacc[sel]))) if sel.any() else None
        out["fixes_in_denial"] = int(sel.sum())
        # the claim standing when GNSS came back: the companion's last fix in the denial, if it was 3D
        last = np.nonzero((own_t >= on) & (own_t < off))[0]
        out["last_hacc_m"] = _f(float(own_hacc[last[-1]])) if last.size and own_fx[last[-1]] >= 3 else None
        # ... and its velocity, which EKF3 carries past the position reset at the return (docs/decisions/0021)
        out["last_vel_err_mps"], out["last_speed_acc_mps"] = _last_velocity(records, log.truth, on, off)
        out["own_mean_m"] = _f(float(own_err[sel].mean())) if sel.any() else None
    return out


def _last_velocity(records: list[dict], truth, on: float, off: float) -> tuple[float | None, float | None]:
    """The error of the velocity in the companion's last 3D fix of the denial against SITL's, and its stated speed
    accuracy (m/s); None without one."""
    rs = [r for r in records if r.get("sent") and r.get("fix_type", 0) >= 3 and on <= r["time_boot_us"] / 1e6 < off]
    if not rs or rs[-1].get("vel_n_mps") is None:
        return None, None
    r = rs[-1]
    vt = core.truth_velocity_ne(truth, np.array([r["time_boot_us"] / 1e6]))[0]
    err = math.hypot(r["vel_n_mps"] - vt[0], r["vel_e_mps"] - vt[1])
    return _f(err), _f(r.get("speed_acc_mps", math.nan))


def yaw_error_deg(log: core.FlightLog, on: float, off: float) -> dict | None:
    """EKF3's yaw (ATTITUDE) against SITL's (SIMSTATE) in the denial: mean and RMS of the wrapped difference, deg
    (what the companion's air-data reference takes as heading; compared across arms, it shows whether the fixes sent
    moved it)."""
    if not (log.yaw and log.truth_yaw) or not math.isfinite(on):
        return None
    a, b = np.asarray(log.yaw, float), np.asarray(log.truth_yaw, float)
    sel = (a[:, 0] >= on) & (a[:, 0] < off)
    if not sel.any() or b.shape[0] < 2:
        return None
    tb = b[:, 0]
    tru = np.unwrap(b[:, 1])
    d = np.angle(np.exp(1j * (a[sel, 1] - np.interp(a[sel, 0], tb, tru))))
    return {"mean": _f(float(np.degrees(d.mean()))), "rms": _f(float(np.degrees(np.sqrt(np.mean(d * d)))))}


def validate_summary(s: dict) -> list[str]:
    """What is missing or mistyped in a summary.json against the schema (empty: valid)."""
    bad = []
    arms = s.get("arms")
    if not isinstance(arms, dict) or set(arms) != {"alone", "companion"} and not set(arms) <= {"alone", "companion"}:
        return ["arms must be a dict with alone and/or companion"]
    for name, a in arms.items():
        for k, typ in (("error_m_at_min", dict), ("failsafes", list), ("kept_up", bool)):
            if not isinstance(a.get(k), typ):
                bad.append(f"{name}.{k} missing or not {typ.__name__}")
        for k in ("mean_m", "max_m"):
            if k not in a or not (a[k] is None or isinstance(a[k], (int, float))):
                bad.append(f"{name}.{k} missing or not a number")
        if isinstance(a.get("error_m_at_min"), dict):
            for m, v in a["error_m_at_min"].items():
                if not (m.isdigit() and int(m) % 5 == 0 and (v is None or isinstance(v, (int, float)))):
                    bad.append(f"{name}.error_m_at_min[{m!r}] not minute -> metres")
        for f in a.get("failsafes") or []:
            if not (isinstance(f, list) and len(f) == 2 and isinstance(f[0], (int, float)) and isinstance(f[1], str)):
                bad.append(f"{name}.failsafes entry {f!r} not [minute, text]")
        if name == "companion":
            for k in ("within_2hacc_frac", "return_jump_m", "reconverge_s"):
                if k not in a:
                    bad.append(f"companion.{k} missing")
    return bad
