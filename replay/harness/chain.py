"""Gravity-aided flight end to end on a replayed (or simulated) event stream, for benchmarks and studies.

A thin wrapper over the product's replay pipeline (companion.gravity.stage.gravity_replay_pipeline: GNSS denial in
front of the navigator, simulated gravimeter at the withheld truth, match stage whose fixes go back to the
navigator, shadow GPS_INPUT, error against the withheld fixes), with the results in memory. Pure: no asyncio,
no clock.

    python -m replay.harness.chain LOG MAP --deny-gnss-after S [--matcher viterbi|none] [--accept-all]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.events import Event, GnssFix, GravityReading, PositionFix
from companion.gravity.maps import LocalGravityMap, load_grid
from companion.gravity.matchers.base import Matcher, MatchResult
from companion.gravity.placement import Placement
from companion.gravity.stage import FixAcceptance, GravityMatchStage, gravity_replay_pipeline
from companion.nav.navigator import NavigatorConfig
from companion.nav.outputs import FrameInfo, FusedState, MeasurementUpdate, ModeChange, NavigatorReset, PredictorPoint
from companion.pipeline.denial import DenialErrorStage, GnssDenial
from companion.sim.gravimeter import SimulatedGravimeter

#: What the navigator emits (kept in ChainResult.outputs).
_NAV_OUTPUTS = (FusedState, FrameInfo, MeasurementUpdate, ModeChange, PredictorPoint, NavigatorReset)


@dataclass
class ChainResult:
    t_s: np.ndarray  # times of the withheld GNSS fixes (truth) after the denial
    error_m: np.ndarray  # horizontal error of the navigator there (NaN where it has no state around)
    injected_error_m: np.ndarray  # and of the GPS_INPUT built
    fixes: list[MatchResult] = field(default_factory=list)
    n_fixes_sent: int = 0
    outputs: list[Event] = field(default_factory=list)  # everything the navigator emitted (FusedState etc.)

    def table(self, every_s: float = 60.0) -> list[tuple[float, float]]:
        """(minutes since denial start, horizontal error m) every `every_s`."""
        if not self.t_s.size:
            return []
        t0 = self.t_s[0]
        marks = np.arange(t0, self.t_s[-1] + 1e-9, every_s)
        idx = np.minimum(np.searchsorted(self.t_s, marks), self.t_s.size - 1)
        return [(float((self.t_s[i] - t0) / 60.0), float(self.error_m[i])) for i in idx]


class _Collect:
    """Pipeline sink keeping everything in memory."""

    def __init__(self):
        self.items: list = []

    def write(self, item, topic=None):
        self.items.append(item)

    def write_location(self, *a, **k):
        pass

    def write_log(self, *a, **k):
        pass


def run_gravity_chain(events: list[Event], lmap: LocalGravityMap, placement: Placement, deny_gnss_after_s: float,
                      matcher: Matcher | None, gravimeter: SimulatedGravimeter | None = None,
                      readings: list[GravityReading] | None = None, gravity_period_s: float = 1.0,
                      nav_config: NavigatorConfig | None = None, sigma_floor_m: float = 1.0,
                      acceptance="default") -> ChainResult:
    """Run the chain over time-ordered events. matcher=None gives the unaided (INS-only) reference.

    Each matcher fix reaches the Navigator as a PositionFix with sigma = max(matcher sigma, sigma_floor_m):
    a matcher's own spread can be overconfident (cell quantisation, map ambiguity); the floor keeps one bad fix
    from dragging the INS velocity. acceptance: a companion.gravity.stage.FixAcceptance ("default": FixAcceptance();
    None: every fix is fused). The error is the product's (companion.pipeline.denial.DenialErrorStage)."""
    if gravimeter is None and readings is None and matcher is not None:
        raise ValueError("need a gravimeter (simulated) or a list of gravity readings")
    events = sorted(list(events) + list(readings or []), key=lambda e: e.t_s)
    if not any(isinstance(e, GnssFix) and e.lat_deg is not None and e.lon_deg is not None for e in events):
        raise ValueError("the log has no GNSS positions (needed for the frame and as truth)")
    sink = _Collect()
    pipe = gravity_replay_pipeline(sink, lmap, GnssDenial(deny_gnss_after_s), matcher=matcher, placement=placement,
                                   gravimeter=gravimeter, simulate_gravimeter=readings is None,
                                   period_s=gravity_period_s, sigma_floor_m=sigma_floor_m, nav_config=nav_config,
                                   acceptance=FixAcceptance() if acceptance == "default" else acceptance)
    for ev in events:
        pipe.process(ev)
    pipe.finish()
    err = next(s for s in pipe.stages if isinstance(s, DenialErrorStage)).errors
    mstage = next((s for s in pipe.stages if isinstance(s, GravityMatchStage)), None)
    return ChainResult(np.array([e.t_s for e in err], float), np.array([e.fused_error_m for e in err], float),
                       np.array([e.injected_error_m for e in err], float),
                       fixes=list(mstage.results) if mstage is not None else [],
                       n_fixes_sent=sum(isinstance(o, PositionFix) for o in sink.items),
                       outputs=[o for o in sink.items if isinstance(o, _NAV_OUTPUTS)])


def gravity_replay(log_path: str | Path, map_path: str | Path, deny_gnss_after_s: float, *, matcher: str = "viterbi",
                   place_lat_lon: tuple[float, float] | None = None, rotation_deg: float = 0.0, sigma_mgal: float = 1.0,
                   cell_m: float | None = None, seed: int = 0, gravity_period_s: float = 1.0,
                   acceptance="default") -> ChainResult:
    """CLI entry: read a dataflash/tlog log, withhold GNSS after `deny_gnss_after_s`, aid with a simulated
    gravimeter over `map_path` (flight placed at place_lat_lon, default the map centre) and a matcher."""
    from companion.gravity.matchers.li_viterbi import ViterbiConfig, ViterbiMatcher
    from companion.sources.files import read_events

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
