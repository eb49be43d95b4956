"""GNSS blockages on a shared flight log: the log's fixes and airborne stretches, blockage windows and stream cuts,
the fixes withheld from the navigator, and each method's error at the withheld fixes (the truth). The scenarios of
the gap-filling benchmark (replay/gap_filling.py) and its plots (replay/gap_filling_plots.py)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.events import Event, GnssFix, ImuSample
from companion.nav.frame import LocalFrame
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState, ModeChange, NavigatorReset, PredictorPoint
from companion.shared_data import shared_logs_dir
from replay.harness.baselines import constant_velocity, hold_last_fix, series_at, withhold_aiding

SHARED_LOGS = shared_logs_dir()
LENGTHS_S = (1.0, 4.0, 8.0, 15.0, 30.0)
METHODS = ("hold", "cv", "knn", "ins_alone", "ins_att", "knn_ins_kf")
METHOD_LABEL = {
    "hold": "GNSS hold last fix (no predictor)",
    "cv": "constant-velocity extrapolation",
    "knn": "KNN predictor alone",
    "ins_alone": "INS alone (free inertial)",
    "ins_att": "INS + KF + AHRS attitude, no predictor",
    "knn_ins_kf": "**KNN + INS + Kalman**",
}


@dataclass
class LogData:
    name: str
    events: list[Event]
    frame: LocalFrame
    fix_t: np.ndarray
    fix_ned: np.ndarray
    fix_vel: np.ndarray  # NaN where the receiver gives none
    airborne: np.ndarray  # per fix
    imu_rate_hz: float
    duration_s: float


def load_log(path: Path) -> LogData:
    from companion.sources import read_events  # I/O edge

    events = read_events(path)
    fixes = [e for e in events if isinstance(e, GnssFix) and e.has_position and e.instance == 0
             and e.alt_msl_m is not None]
    if len(fixes) < 10:
        raise ValueError(f"{path.name}: fewer than 10 GNSS fixes")
    t = np.array([f.t_s for f in fixes])
    f0 = fixes[0]
    frame = LocalFrame(f0.lat_deg, f0.lon_deg, f0.alt_msl_m)
    ned = frame.to_ned_m([f.lat_deg for f in fixes], [f.lon_deg for f in fixes], [f.alt_msl_m for f in fixes])
    vel = np.array([[math.nan if v is None else v for v in (f.vel_n_mps, f.vel_e_mps, f.vel_d_mps)] for f in fixes])
    imu_t = [e.t_s for e in events if isinstance(e, ImuSample) and e.imu_index == 0]
    rate = (len(imu_t) - 1) / (imu_t[-1] - imu_t[0]) if len(imu_t) > 1 else 0.0
    if len(imu_t) > 10:
        rate = 1.0 / float(np.median(np.diff(imu_t)))
    return LogData(path.name, events, frame, t, ned, vel, airborne_mask(t, ned), rate,
                   events[-1].t_s - events[0].t_s)


def airborne_mask(t: np.ndarray, ned: np.ndarray, climb_m: float = 2.5, speed_mps: float = 1.5) -> np.ndarray:
    """Fixes where the vehicle is flying: above the ground level (5th percentile of altitude) by climb_m
    or moving faster than speed_mps horizontally, smoothed over 5 s so touch-and-go moments break it."""
    alt = -ned[:, 2]
    ground = np.percentile(alt, 5)
    sp = np.zeros(len(t))
    sp[1:] = np.hypot(*np.diff(ned[:, :2], axis=0).T) / np.maximum(np.diff(t), 1e-3)
    raw = (alt > ground + climb_m) | (sp > speed_mps)
    out = raw.copy()
    for i in range(len(t)):  # airborne only if the whole +-2.5 s neighbourhood is
        m = np.abs(t - t[i]) <= 2.5
        out[i] = raw[m].all()
    return out


def decimate_mask(t: np.ndarray, hz: float | None) -> np.ndarray:
    """Keep the first fix in each 1/hz interval (the paper's 1 Hz receiver); all when hz is None."""
    if not hz:
        return np.ones(len(t), dtype=bool)
    slot = np.floor(t * hz + 1e-9)
    keep = np.ones(len(t), dtype=bool)
    keep[1:] = slot[1:] != slot[:-1]
    return keep


def choose_windows(log: LogData, length_s: float, offset_frac: float, pre_s: float = 10.0,
                   post_s: float = 3.0, settle_s: float = 15.0) -> list[tuple[float, float]]:
    """Blockage windows [start, start + L) fully airborne, with pre_s airborne before and post_s after,
    no natural fix gap > 1 s inside, spaced by L + settle_s, first one shifted by offset_frac of a spacing."""
    t, air = log.fix_t, log.airborne
    spacing = length_s + settle_s
    wins: list[tuple[float, float]] = []
    tb = t[0] + pre_s + offset_frac * spacing
    while tb + length_s + post_s < t[-1]:
        m = (t >= tb - pre_s) & (t <= tb + length_s + post_s)
        tm = t[m]
        ok = m.any() and air[m].all() and tm[0] - (tb - pre_s) < 1.0 and (tb + length_s + post_s) - tm[-1] < 1.0
        ok = ok and (np.diff(tm).max() < 1.0 if len(tm) > 1 else False)
        if ok:
            wins.append((round(tb, 3), round(tb + length_s, 3)))
            tb += spacing
        else:
            tb += 1.0
    return wins


def distinct_windows(wins, used: list[tuple[float, float]], length_s: float) -> list[tuple[float, float]]:
    """The windows not overlapping one already used by more than half a length (several start-time phases
    converge on the same airborne stretch); ``used`` is extended."""
    out = []
    for a, b in wins:
        if all(min(b, d) - max(a, c) <= 0.5 * length_s for c, d in used):
            out.append((a, b))
            used.append((a, b))
    return out


def stream_gap_events(log: LogData, cut: tuple[float, float], first: str, decimate_hz: float | None):
    """Every message removed in [cut); at resume the IMU/attitude ("imu") or the first fix ("gnss") arrives first
    (the other 9 ms later), GNSS decimated to decimate_hz. Returns the events and the kept fix times."""
    a, b = cut
    keep = decimate_mask(log.fix_t, decimate_hz) & ~((log.fix_t >= a) & (log.fix_t < b))
    drop = set(log.fix_t[~keep].tolist())
    kept_t = log.fix_t[keep]
    t_fix = float(kept_t[kept_t >= b][0])
    lo, hi = (b, t_fix + 0.009) if first == "gnss" else (b, t_fix - 0.009)
    ev = [e for e in drop_fixes(log.events, drop) if not a <= e.t_s < b
          and (isinstance(e, GnssFix) or not lo <= e.t_s < hi)]
    return ev, kept_t, t_fix


def stream_gap_case(log: LogData, cut, first: str, decimate_hz: float | None, cfg: NavigatorConfig,
                    radius_m: float = 3.0, hold_s: float = 10.0) -> dict[str, float]:
    """How many fixes after the resume until the output stays within radius_m of GNSS (every native fix of the
    next hold_s), the largest error from the 2nd fix on, and the resets the navigator reported."""
    ev, kept_t, t_fix = stream_gap_events(log, cut, first, decimate_hz)
    out = run_navigator(ev, cfg)
    ft, fned = series(out, log.frame, FusedState)
    resets = [o.kind for o in out if isinstance(o, NavigatorReset)]
    after = kept_t[kept_t >= t_fix]
    m = (log.fix_t >= t_fix) & (log.fix_t <= after[min(len(after) - 1, 40)] + hold_s)
    tq, truth = log.fix_t[m], log.fix_ned[m]
    h = np.hypot(*(series_at(ft, fned, tq - cfg.gnss_delay_s) - truth)[:, :2].T)
    h = np.where(np.isfinite(h), h, np.inf)
    n_needed = math.inf
    for k, tk in enumerate(after[:40]):
        w = (tq >= tk) & (tq <= tk + hold_s)
        if w.any() and h[w].max() < radius_m:
            n_needed = k + 1
            break
    t2 = after[min(1, len(after) - 1)]
    w2 = (tq >= t2) & (tq <= t2 + hold_s)
    return {"fixes": n_needed, "max_after_2nd_m": float(h[w2].max()) if w2.any() else math.nan,
            "first_err_m": float(h[0]) if len(h) else math.nan, "resets": ",".join(resets) or "none"}


def choose_cut(log: LogData, length_s: float, pre_s: float = 5.0, post_s: float = 20.0) -> tuple[float, float] | None:
    """The first stream cut [tb, tb + L) that starts airborne (pre_s of airborne fixes before it) with post_s of
    fixes after it (resume may be on the ground)."""
    t, air = log.fix_t, log.airborne
    for tb in np.arange(t[0] + pre_s, t[-1] - length_s - post_s, 1.0):
        m = (t >= tb - pre_s) & (t < tb)
        if m.sum() >= 3 and air[m].all() and np.diff(t[m]).max() < 1.0 and t[-1] > tb + length_s + post_s:
            post = t[(t >= tb + length_s) & (t <= tb + length_s + post_s)]
            if len(post) >= post_s * 0.8 and np.diff(post).max() < 1.5:
                return round(float(tb), 3), round(float(tb + length_s), 3)
    return None


def in_windows(t: np.ndarray, windows) -> np.ndarray:
    m = np.zeros(len(t), dtype=bool)
    for a, b in windows:
        m |= (t >= a) & (t < b)
    return m


def window_info(log: LogData, w: tuple[float, float]) -> np.ndarray:
    """[start, end, GNSS horizontal speed at the last fix before and at the first fix after] of a blockage."""
    i0 = max(int(np.searchsorted(log.fix_t, w[0], side="left")) - 1, 0)
    i1 = min(int(np.searchsorted(log.fix_t, w[1], side="left")), len(log.fix_t) - 1)  # windows are [start, end)
    return np.array([w[0], w[1], math.hypot(*log.fix_vel[i0, :2]), math.hypot(*log.fix_vel[i1, :2])])


def drop_fixes(events: list[Event], drop_t: set[float]) -> list[Event]:
    return [e for e in events if not (isinstance(e, GnssFix) and e.instance == 0 and e.t_s in drop_t)]


def series(out, frame: LocalFrame, cls):
    rows = [o for o in out if isinstance(o, cls)]
    if not rows:
        return np.zeros(0), np.zeros((0, 3))
    t = np.array([o.t_s for o in rows])
    ned = frame.to_ned_m([o.lat_deg for o in rows], [o.lon_deg for o in rows], [o.alt_msl_m for o in rows])
    return t, ned


def free_ins(cfg: NavigatorConfig) -> NavigatorConfig:
    """The navigator as the INS-alone baseline: no predictor and none of the aids that are not inertial (motion prior,
    rotor drag, zero velocity); with GNSS and attitude withheld it coasts on the IMU from the filter's state."""
    return dataclasses.replace(cfg, fuse_predictor=False, motion_prior=False, rotor_drag=False, zero_velocity=False)


def run_case(log: LogData, windows, decimate_hz: float | None, cfg: NavigatorConfig,
             truth_mask: np.ndarray) -> tuple[dict[str, np.ndarray], str]:
    """Errors (n, 3) NED at the truth fixes for every method; truth = fixes in truth_mask (withheld)."""
    keep = decimate_mask(log.fix_t, decimate_hz) & ~in_windows(log.fix_t, windows)
    drop = set(log.fix_t[~keep].tolist())
    events = drop_fixes(log.events, drop)
    tq = log.fix_t[truth_mask]
    truth = log.fix_ned[truth_mask]
    avail_t, avail_ned, avail_vel = log.fix_t[keep], log.fix_ned[keep], log.fix_vel[keep]
    err: dict[str, np.ndarray] = {}
    err["hold"] = hold_last_fix(avail_t, avail_ned, tq) - truth
    err["cv"] = constant_velocity(avail_t, avail_ned, avail_vel, tq) - truth
    full = run_navigator(events, cfg)
    mode = [o for o in full if isinstance(o, ModeChange)][-1].mode
    pt, pned = series(full, log.frame, PredictorPoint)
    kt = np.concatenate([avail_t, pt])
    kn = np.concatenate([avail_ned, pned])
    o = np.argsort(kt, kind="stable")
    err["knn"] = series_at(kt[o], kn[o], tq) - truth
    ft, fned = series(full, log.frame, FusedState)
    err["knn_ins_kf"] = series_at(ft, fned, tq - cfg.gnss_delay_s) - truth
    # 1-sigma horizontal the methods claim at the truth times (predictor: 0 at a real fix)
    ps = np.array([p.sigma_h_m for p in full if isinstance(p, PredictorPoint)])
    ks = np.concatenate([np.zeros(len(avail_t)), ps])[o]
    err["_sigma_knn"] = series_at(kt[o], ks[:, None], tq)
    fs = np.array([f.sigma_h_m for f in full if isinstance(f, FusedState)])
    err["_sigma_knn_ins_kf"] = series_at(ft, fs[:, None], tq - cfg.gnss_delay_s)
    no_pred = dataclasses.replace(cfg, fuse_predictor=False)
    if mode == "ins":
        ft, fned = series(run_navigator(events, no_pred), log.frame, FusedState)
        err["ins_att"] = series_at(ft, fned, tq - cfg.gnss_delay_s) - truth
        if windows:
            ft, fned = series(run_navigator(withhold_aiding(events, windows), free_ins(cfg)), log.frame, FusedState)
            err["ins_alone"] = series_at(ft, fned, tq - cfg.gnss_delay_s) - truth
    else:  # kinematic: the CV Kalman filter without predictor is the comparable row
        ft, fned = series(run_navigator(events, no_pred), log.frame, FusedState)
        err["ins_att"] = series_at(ft, fned, tq - cfg.gnss_delay_s) - truth
    return err, mode


def stats(err: np.ndarray) -> dict[str, float]:
    h = np.hypot(err[:, 0], err[:, 1])
    v = np.abs(err[:, 2])
    return {
        "n": len(h),
        "h_rmse": float(np.sqrt(np.mean(h**2))), "h_p95": float(np.percentile(h, 95)), "h_max": float(h.max()),
        "v_rmse": float(np.sqrt(np.mean(v**2))), "v_p95": float(np.percentile(v, 95)), "v_max": float(v.max()),
    }
