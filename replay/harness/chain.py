"""Gravity-aided flight end to end, on a replayed (or simulated) event stream (issue 6 item 4).

    GNSS withheld after `deny_gnss_after_s`  ->  Navigator (INS + KF, companion.nav) keeps running on IMU
    -> its positions, laid on the map by a `Placement`, and a gravity reading go to a matcher (`Matcher.feed`)
    -> each fix becomes a PositionFix (sigma = matcher sigma, floored) fed back to the Navigator through the
    pipeline's feedback path (companion.pipeline.core FEEDBACK_TYPES)  ->  the Navigator's FusedState stream is what the GPS_INPUT injector sends (shadow mode).

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

from companion.nav.navigator import NavigatorConfig
from companion.nav.outputs import FrameInfo, FusedState, MeasurementUpdate, ModeChange, PredictorPoint
from companion.events import Event, GnssFix, PositionFix
from companion.nav.frame import LocalFrame
from companion.gravity.matchers.base import Matcher, MatchResult
from companion.gravity.maps import LocalGravityMap, load_grid
from companion.events import GravityReading
from companion.gravity.placement import Placement
from companion.sim.gravimeter import SimulatedGravimeter


#: What the navigator emits (kept in ChainResult.outputs).
_NAV_OUTPUTS = (FusedState, FrameInfo, MeasurementUpdate, ModeChange, PredictorPoint)


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
                      nav_config: NavigatorConfig | None = None, sigma_floor_m: float = 1.0,
                      acceptance="default") -> ChainResult:
    """Run the chain over time-ordered events: a thin wrapper over the streaming stages of
    companion.gravity.stage in a companion.pipeline.core.Pipeline (one implementation for CLI and benchmarks).
    matcher=None gives the unaided (INS-only) reference.

    Each matcher fix reaches the Navigator as a PositionFix with sigma = max(matcher sigma, sigma_floor_m):
    a matcher's own spread can be overconfident (cell quantisation, map ambiguity); the floor keeps one bad fix
    from dragging the INS velocity. acceptance: a companion.gravity.stage.FixAcceptance ("default": FixAcceptance();
    None: every fix is fused)."""
    from companion.gravity.stage import (FixAcceptance, GnssDenial, GnssDeniedNavigator, GravityMatchStage,
                                       GravitySimStage, gravity_nav_config)
    from companion.pipeline.core import Pipeline

    if gravimeter is None and readings is None and matcher is not None:
        raise ValueError("need a gravimeter (simulated) or a list of gravity readings")
    events = sorted(list(events) + list(readings or []), key=lambda e: e.t_s)
    fixes_in = [e for e in events if isinstance(e, GnssFix) and e.lat_deg is not None and e.lon_deg is not None]
    if not fixes_in:
        raise ValueError("the log has no GNSS positions (needed for the frame and as truth)")
    t_deny = events[0].t_s + float(deny_gnss_after_s)
    denial = GnssDenial(deny_gnss_after_s)
    stages: list = [GnssDeniedNavigator(nav_config or gravity_nav_config(), denial)]
    mstage = None
    if matcher is not None:
        if readings is None:
            stages.append(GravitySimStage(gravimeter, denial, gravity_period_s))
        acc = FixAcceptance() if acceptance == "default" else acceptance
        mstage = GravityMatchStage(lmap, matcher, placement, sigma_floor_m=sigma_floor_m, acceptance=acc)
        stages.append(mstage)
    sink = _Collect()
    pipe = Pipeline(stages=stages, sink=sink)
    for ev in events:
        pipe.process(ev)
    pipe.finish()

    frame = None
    res = ChainResult(np.empty(0), np.empty((0, 2)), np.empty((0, 2)))
    ts, pos, truth = [], [], []
    for o in sink.items:
        if isinstance(o, FrameInfo):
            frame = LocalFrame(o.ref_lat_deg, o.ref_lon_deg, o.ref_alt_msl_m)
        elif isinstance(o, GnssFix) and frame is not None and o.t_s >= t_deny and o.instance == 0 and o.has_position:
            truth.append((o.t_s, *frame.to_ned_m(o.lat_deg, o.lon_deg, o.alt_msl_m or 0.0)[:2]))
        elif isinstance(o, PositionFix):
            res.n_fixes_sent += 1
        if isinstance(o, _NAV_OUTPUTS):
            res.outputs.append(o)
            if isinstance(o, FusedState) and o.t_s >= t_deny and frame is not None:
                ts.append(o.t_s)
                pos.append(frame.to_ned_m(o.lat_deg, o.lon_deg, o.alt_msl_m)[:2])
    truth_a = np.asarray(truth, float).reshape(-1, 3)

    def truth_at(t):
        if truth_a.shape[0] < 2 or t < truth_a[0, 0] or t > truth_a[-1, 0]:
            return np.array([np.nan, np.nan])
        return np.array([np.interp(t, truth_a[:, 0], truth_a[:, 1]), np.interp(t, truth_a[:, 0], truth_a[:, 2])])

    res.fixes = list(mstage.results) if mstage is not None else []
    res.t_s = np.asarray(ts, float)
    res.nav_ne_m = np.asarray(pos, float).reshape(-1, 2)
    res.truth_ne_m = np.array([truth_at(t) for t in res.t_s]).reshape(-1, 2)
    return res


class _Collect:
    """Pipeline sink keeping everything in memory."""

    def __init__(self):
        self.items: list = []

    def write(self, item, topic=None):
        self.items.append(item)

    def write_location(self, *a, **k):
        pass


def gravity_replay(log_path: str | Path, map_path: str | Path, deny_gnss_after_s: float, *, matcher: str = "viterbi",
                   place_lat_lon: tuple[float, float] | None = None, rotation_deg: float = 0.0, sigma_mgal: float = 1.0,
                   cell_m: float | None = None, seed: int = 0, gravity_period_s: float = 1.0,
                   acceptance="default") -> ChainResult:
    """CLI entry: read a dataflash/tlog log, withhold GNSS after `deny_gnss_after_s`, aid with a simulated
    gravimeter over `map_path` (flight placed at place_lat_lon, default the map centre) and a matcher."""
    from companion.sources.files import read_events

    from companion.gravity.matchers.li_viterbi import ViterbiConfig, ViterbiMatcher

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
                             sigma_floor_m=floor, acceptance=acceptance)


def main(argv=None):  # python -m replay.harness.chain LOG MAP --deny-gnss-after S
    import argparse

    ap = argparse.ArgumentParser(description="gravity-aided replay with GNSS withheld")
    ap.add_argument("log")
    ap.add_argument("map")
    ap.add_argument("--deny-gnss-after", type=float, required=True)
    ap.add_argument("--matcher", default="viterbi", choices=["viterbi", "none"])
    ap.add_argument("--place", type=float, nargs=2, metavar=("LAT", "LON"))
    ap.add_argument("--sigma-mgal", type=float, default=1.0)
    ap.add_argument("--cell-m", type=float, default=None)
    ap.add_argument("--accept-all", action="store_true", help="fuse every matcher fix (no companion.gravity.stage.FixAcceptance)")
    a = ap.parse_args(argv)
    r = gravity_replay(a.log, a.map, a.deny_gnss_after, matcher=a.matcher, place_lat_lon=tuple(a.place) if a.place else None,
                       sigma_mgal=a.sigma_mgal, cell_m=a.cell_m, acceptance=None if a.accept_all else "default")
    print(f"fixes {len(r.fixes)}, sent to the navigator {r.n_fixes_sent}; error after denial (min, m):")
    for t, e in r.table(30.0):
        print(f"  {t:6.2f}  {e:8.1f}")
    return 0 if math.isfinite(float(np.nanmean(r.error_m))) else 1


if __name__ == "__main__":
    raise SystemExit(main())
