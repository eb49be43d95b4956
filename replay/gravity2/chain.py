"""Gravity-aided flight end to end, on a replayed (or simulated) event stream (issue 6 item 4).

    GNSS withheld after `deny_gnss_after_s`  ->  Navigator (INS + KF, companion.estimation) keeps running on IMU
    -> its positions, laid on the map by a `Placement`, and a gravity reading go to a matcher (`Matcher.feed`)
    -> each fix becomes a GnssFix (h_acc_m = matcher sigma; companion.matching.fusion.match_to_gnss_fix) fed back
    to the Navigator  ->  the Navigator's FusedState stream is what the GPS_INPUT injector sends (shadow mode).

Gravity readings come from a `SimulatedGravimeter` at the true position (the withheld GNSS fixes are the
truth), or from any list of GravityReading events (a live or logged gravimeter). Pure: no asyncio, no clock.

`gravity_replay(log, map, deny_gnss_after_s, ...)` is the function for the CLI
(`companion replay LOG --gravity-map FILE --deny-gnss-after S`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.estimation.integrator import Navigator, NavigatorConfig
from companion.estimation.outputs import FusedState
from companion.events import Event, GnssFix
from companion.geodesy import LocalFrame
from companion.matching.base import Matcher, MatchResult
from companion.matching.maps import LocalGravityMap, load_grid
from companion.sources.gravity import GravityReading, Placement, SimulatedGravimeter


@dataclass
class ChainResult:
    t_s: np.ndarray  # FusedState times after the denial
    nav_ne_m: np.ndarray  # navigator positions (flight frame NE)
    truth_ne_m: np.ndarray  # withheld GNSS interpolated to t_s (NaN where none)
    fixes: list[MatchResult] = field(default_factory=list)
    n_fixes_sent: int = 0
    outputs: list[Event] = field(default_factory=list)  # everything the navigator emitted (FusedState etc.)

    @property
    def error_m(self) -> np.ndarray:
        return np.hypot(*(self.nav_ne_m - self.truth_ne_m).T)

    def table(self, every_s: float = 60.0) -> list[tuple[float, float]]:
        """(minutes since denial start, horizontal error m) every `every_s`."""
        if not self.t_s.size:
            return []
        t0 = self.t_s[0]
        marks = np.arange(t0, self.t_s[-1] + 1e-9, every_s)
        idx = np.minimum(np.searchsorted(self.t_s, marks), self.t_s.size - 1)
        return [(float((self.t_s[i] - t0) / 60.0), float(self.error_m[i])) for i in idx]


def run_gravity_chain(events: list[Event], lmap: LocalGravityMap, placement: Placement, deny_gnss_after_s: float,
                      matcher: Matcher | None, gravimeter: SimulatedGravimeter | None = None,
                      readings: list[GravityReading] | None = None, gravity_period_s: float = 1.0,
                      nav_config: NavigatorConfig | None = None, sigma_floor_m: float = 1.0) -> ChainResult:
    """Run the chain over time-ordered events. matcher=None gives the unaided (INS-only) reference.

    Each fix goes to the Navigator with h_acc_m = max(matcher sigma, sigma_floor_m): a matcher's own spread
    can be overconfident (cell quantisation, map ambiguity); the floor keeps one bad fix from dragging the
    INS velocity."""
    if gravimeter is None and readings is None and matcher is not None:
        raise ValueError("need a gravimeter (simulated) or a list of gravity readings")
    events = sorted(events, key=lambda e: e.t_s)
    fixes_in = [e for e in events if isinstance(e, GnssFix) and e.lat_deg is not None and e.lon_deg is not None]
    if not fixes_in:
        raise ValueError("the log has no GNSS positions (needed for the frame and as truth)")
    t_start = events[0].t_s
    t_deny = t_start + float(deny_gnss_after_s)
    f0 = fixes_in[0]
    frame = LocalFrame(f0.lat_deg, f0.lon_deg, f0.alt_msl_m or 0.0)
    truth = [(e.t_s, *frame.to_ned_m(e.lat_deg, e.lon_deg, e.alt_msl_m or 0.0)[:2]) for e in fixes_in if e.t_s >= t_deny]
    truth_a = np.asarray(truth, float).reshape(-1, 3)
    read_q = sorted(readings, key=lambda r: r.t_s) if readings is not None else None
    ri = 0
    # Matcher fixes must be weighted by their own sigma (the 'short_term' GNSS model would use 0.3 m) and must not
    # seed the KNN GNSS predictor (it would extrapolate fix-to-fix jumps as velocity).
    nav = Navigator(nav_config or NavigatorConfig(gnss_sigma_model="accuracy", fuse_predictor=False))
    res = ChainResult(np.empty(0), np.empty((0, 2)), np.empty((0, 2)))
    ts, pos = [], []
    next_g = t_deny
    pending: list[GnssFix] = []

    def truth_at(t):
        if truth_a.shape[0] < 2 or t < truth_a[0, 0] or t > truth_a[-1, 0]:
            return np.array([np.nan, np.nan])
        return np.array([np.interp(t, truth_a[:, 0], truth_a[:, 1]), np.interp(t, truth_a[:, 0], truth_a[:, 2])])

    def on_outputs(outs):
        nonlocal next_g, ri
        for o in outs:
            res.outputs.append(o)
            if not isinstance(o, FusedState) or o.t_s < t_deny:
                continue
            p_ne = frame.to_ned_m(o.lat_deg, o.lon_deg, o.alt_msl_m)[:2]
            ts.append(o.t_s)
            pos.append(p_ne)
            if matcher is None or o.t_s + 1e-9 < next_g:
                continue
            next_g = o.t_s + gravity_period_s
            if read_q is not None:
                while ri < len(read_q) and read_q[ri].t_s < o.t_s - gravity_period_s / 2:
                    ri += 1
                if ri >= len(read_q) or abs(read_q[ri].t_s - o.t_s) > gravity_period_s / 2:
                    continue
                g = read_q[ri].gravity_mgal
            else:
                tr = truth_at(o.t_s)
                if not np.all(np.isfinite(tr)):
                    continue
                r = gravimeter.read(o.t_s, tr)
                if r is None:
                    continue
                g = r.gravity_mgal
            vel_map = placement.to_map(np.array([o.vel_n_mps, o.vel_e_mps])) - placement.to_map(np.zeros(2))
            m = matcher.feed(o.t_s, placement.to_map(p_ne), vel_map, g)
            if m is None or not m.ok:
                continue
            res.fixes.append(m)
            fix_ne = placement.to_flight(m.position_ne_m)
            lat, lon, _ = frame.to_geodetic(np.array([fix_ne[0], fix_ne[1], 0.0]))
            pending.append(GnssFix(t_s=float(m.t_s), fix_type=3, lat_deg=float(lat), lon_deg=float(lon),
                                   alt_msl_m=float(o.alt_msl_m), vel_n_mps=None, vel_e_mps=None, vel_d_mps=None,
                                   ground_speed_mps=None, course_deg=None, satellites=None, hdop=None, vdop=None,
                                   h_acc_m=float(max(m.sigma_m, sigma_floor_m)), v_acc_m=None, speed_acc_mps=None,
                                   gps_week=None, gps_tow_s=None))

    for ev in events:
        if isinstance(ev, GnssFix) and ev.t_s >= t_deny:
            continue  # withheld: truth only
        on_outputs(nav.process(ev))
        while pending:
            fx = pending.pop(0)
            res.n_fixes_sent += 1
            on_outputs(nav.process(fx))
    on_outputs(nav.finish())
    res.t_s = np.asarray(ts, float)
    res.nav_ne_m = np.asarray(pos, float).reshape(-1, 2)
    res.truth_ne_m = np.array([truth_at(t) for t in res.t_s]).reshape(-1, 2)
    return res


def gravity_replay(log_path: str | Path, map_path: str | Path, deny_gnss_after_s: float, *, matcher: str = "viterbi",
                   place_lat_lon: tuple[float, float] | None = None, rotation_deg: float = 0.0, sigma_mgal: float = 1.0,
                   cell_m: float | None = None, seed: int = 0, gravity_period_s: float = 1.0) -> ChainResult:
    """CLI entry: read a dataflash/tlog log, withhold GNSS after `deny_gnss_after_s`, aid with a simulated
    gravimeter over `map_path` (flight placed at place_lat_lon, default the map centre) and a matcher."""
    from companion.sources.files import read_events

    from companion.matching.viterbi import ViterbiConfig, ViterbiMatcher

    events = read_events(log_path)
    gmap = load_grid(map_path)
    lmap = LocalGravityMap.around(gmap)
    placement = Placement.at_lat_lon(lmap, *place_lat_lon, rotation_deg) if place_lat_lon and lmap.frame else Placement((0.0, 0.0), rotation_deg)
    rng = np.random.default_rng(seed)
    grav = SimulatedGravimeter(lmap, placement, rng, sigma_mgal=sigma_mgal)
    if matcher == "viterbi":
        m = ViterbiMatcher(lmap, ViterbiConfig(o=5, T=6, sigma_z_mgal=max(sigma_mgal, 0.1), subcell_values="interp"), cell_m=cell_m)
    elif matcher == "none":
        m = None
    else:
        raise ValueError(f"unknown matcher {matcher!r} (viterbi, none)")
    floor = m.cells.cell_m if m is not None else 1.0  # a fix is not trusted below one map cell
    return run_gravity_chain(events, lmap, placement, deny_gnss_after_s, m, grav, gravity_period_s=gravity_period_s,
                             sigma_floor_m=floor)


def main(argv=None):  # python -m replay.gravity2.chain LOG MAP --deny-gnss-after S
    import argparse

    ap = argparse.ArgumentParser(description="gravity-aided replay with GNSS withheld")
    ap.add_argument("log")
    ap.add_argument("map")
    ap.add_argument("--deny-gnss-after", type=float, required=True)
    ap.add_argument("--matcher", default="viterbi", choices=["viterbi", "none"])
    ap.add_argument("--place", type=float, nargs=2, metavar=("LAT", "LON"))
    ap.add_argument("--sigma-mgal", type=float, default=1.0)
    ap.add_argument("--cell-m", type=float, default=None)
    a = ap.parse_args(argv)
    r = gravity_replay(a.log, a.map, a.deny_gnss_after, matcher=a.matcher, place_lat_lon=tuple(a.place) if a.place else None,
                       sigma_mgal=a.sigma_mgal, cell_m=a.cell_m)
    print(f"fixes sent {r.n_fixes_sent}; error after denial (min, m):")
    for t, e in r.table(30.0):
        print(f"  {t:6.2f}  {e:8.1f}")
    return 0 if math.isfinite(float(np.nanmean(r.error_m))) else 1


if __name__ == "__main__":
    raise SystemExit(main())
