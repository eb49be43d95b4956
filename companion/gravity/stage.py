"""Gravity-aided navigation as pipeline stages (issue 6 items 3-4).

    source events --> GnssDeniedNavigator (stage 0; GNSS after the cut withheld) --> FusedState, FrameInfo
      --> GravitySimStage (replay/sim only: a SimulatedGravimeter at the withheld GNSS truth) --> GravityReading
      --> GravityMatchStage (Matcher.feed on navigator positions + readings) --> PositionFix, MatchRecord
      --> (PositionFix goes back to the Navigator: companion.pipeline.core FEEDBACK_TYPES)
      --> GnssDeniedInjector (shadow GPS_INPUT) --> GpsInputRecord
      --> DenialErrorStage (horizontal error of fused / injected positions vs the withheld GNSS) --> NavError

A live gravimeter (companion.mavlink.gravimeter, companion.sources.gravity) delivers GravityReading as input events instead of GravitySimStage.
Positions are laid on the map with a `Placement` (flight NE metres from the navigator's frame origin -> map NE).
Pure: vehicle time only.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from companion.nav.navigator import Navigator, NavigatorConfig
from companion.nav.outputs import FrameInfo, FusedState
from companion.events import Event, GnssFix, PositionFix
from companion.nav.frame import LocalFrame
from companion.inject import Injector
from companion.inject.gps_input import GpsInputRecord
from companion.gravity.matchers.base import Matcher, MatchResult
from companion.gravity.maps import LocalGravityMap
from companion.events import GravityReading
from companion.gravity.placement import Placement
from companion.sim.gravimeter import SimulatedGravimeter


def gravity_nav_config(**overrides) -> NavigatorConfig:
    """Navigator settings for gravity-aided runs: GNSS weighted by the receiver's own accuracy, no KNN
    predictor, and the autopilot's (barometric) altitude as the vertical aid once GNSS is gone (a free INS height
    diverges exponentially: 775 km after 72 min in a 3 h live run without it).

    Measured on the synthetic chain (tests/gravity/test_gravity_e2e.py flight, Viterbi n=9): with the default
    'short_term' GNSS model (0.3 m) the filter leaves the cut overconfident, the matcher fixes then drag the INS
    and the matcher follows the dragged track (fix error 12 -> 360 m in 85 s) instead of 13 m mean error."""
    return NavigatorConfig(**{"gnss_sigma_model": "accuracy", "fuse_predictor": False, "fuse_autopilot_alt": True,
                              **overrides})


class GnssDenial:
    """Shared cut time: GNSS fixes at or after (first event time + after_s) are withheld (kept as truth only)."""

    def __init__(self, after_s: float | None):
        self.after_s = None if after_s is None else float(after_s)
        self.t_cut_s: float | None = None

    def observe(self, ev: Any) -> None:
        if self.t_cut_s is None and self.after_s is not None and isinstance(ev, Event) and math.isfinite(ev.t_s):
            self.t_cut_s = ev.t_s + self.after_s

    def withheld(self, ev: Any) -> bool:
        self.observe(ev)
        return isinstance(ev, GnssFix) and self.t_cut_s is not None and ev.t_s >= self.t_cut_s


class GnssDeniedNavigator(Navigator):
    """The Navigator with GNSS withheld after the cut (a test/replay set-up: the real fixes stay truth)."""

    def __init__(self, config: NavigatorConfig | None, denial: GnssDenial) -> None:
        super().__init__(config)
        self.denial = denial
        self.gnss_withheld = 0

    def process(self, event: Event) -> list[Event]:
        if self.denial.withheld(event):
            self.gnss_withheld += 1
            return []
        return super().process(event)

    def metadata(self) -> dict[str, str]:
        return {"gnss_withheld_after_s": f"{self.denial.after_s:g}", "gnss_withheld": str(self.gnss_withheld)}


class GnssDeniedInjector(Injector):
    """The GPS_INPUT injector blind to the withheld fixes (its receiver cross-check would otherwise use truth)."""

    def __init__(self, config, denial: GnssDenial, sender=None) -> None:
        super().__init__(config, sender)
        self.denial = denial

    def process(self, item: Any) -> list[Event]:
        if self.denial.withheld(item):
            return []
        return super().process(item)


def _frame_of(item: FrameInfo) -> LocalFrame:
    return LocalFrame(item.ref_lat_deg, item.ref_lon_deg, item.ref_alt_msl_m)


class GravitySimStage:
    """Simulated gravimeter along the withheld GNSS fixes (truth), one reading per `period_s`."""

    def __init__(self, gravimeter: SimulatedGravimeter, denial: GnssDenial, period_s: float = 1.0) -> None:
        self.g, self.denial, self.period_s = gravimeter, denial, float(period_s)
        self._frame: LocalFrame | None = None
        self._next_t = -math.inf
        self.readings = 0

    def process(self, item: Any) -> list[Event]:
        if isinstance(item, FrameInfo):
            self._frame = _frame_of(item)
        elif (self._frame is not None and self.denial.withheld(item) and item.has_position
              and item.instance == 0 and item.t_s + 1e-9 >= self._next_t):
            ne = self._frame.to_ned_m(item.lat_deg, item.lon_deg, item.alt_msl_m or 0.0)[:2]
            r = self.g.read(item.t_s, ne)
            if r is not None:
                self._next_t = item.t_s + self.period_s
                self.readings += 1
                return [r]
        return []

    def finish(self) -> list[Event]:
        return []

    def metadata(self) -> dict[str, str]:
        return {"readings": str(self.readings), "period_s": f"{self.period_s:g}", "sigma_mgal": f"{self.g.sigma_mgal:g}"}


@dataclass(frozen=True, slots=True)
class MatchRecord(Event):
    """One online gravity match (ok or not). north_m/east_m: flight frame (the navigator's), NaN if not ok.
    accepted: the fix passed the acceptance test and went to the navigator (reason says why not)."""

    ok: bool
    method: str
    north_m: float
    east_m: float
    lat_deg: float
    lon_deg: float
    sigma_m: float
    quality: float
    reason: str
    compute_time_s: float
    accepted: bool = False
    track_m: float = math.nan
    signal_mgal: float = math.nan
    topic: ClassVar[str] = "/gravity/match"


@dataclass(frozen=True)
class FixAcceptance:
    """Whether a matcher fix carries information, judged from the matcher's window before the fix is fused.

    A fix is only as good as the map signal the window saw. A slow vehicle (a drone over a few hundred metres of a
    1-4 km altimetry grid) sees a flat field: every position in the search area fits, the matcher returns a confident
    but arbitrary fix, and fusing it drags the navigator away (measured: 4.87 km error aided vs 1.16 km unaided on the
    ac313 log, replay/results/gravity_part2.md). Two tests, both on the window the matcher used:

    * track: the INS track over the window is at least ``min_track_cells`` map cells long (fewer cells: the window
      holds fewer independent map values than unknowns);
    * signal: the gravity variation along the window stands out of the noise: sqrt(max(var(g) - sigma^2, 0)) >=
      ``min_signal_ratio`` x sigma, with sigma the noise of the values the matcher was fed (mGal): the gravimeter's
      sigma, divided by sqrt(n) where n readings were averaged into one sample.
    """

    min_track_cells: float = 2.0
    min_signal_ratio: float = 1.0

    def check(self, track_m: float, cell_m: float, signal_mgal: float, sigma_mgal: float) -> str:
        """'' if accepted, else the reason."""
        if not track_m >= self.min_track_cells * cell_m:
            return f"track {track_m:.0f} m < {self.min_track_cells:g} cells of {cell_m:.0f} m"
        if not signal_mgal >= self.min_signal_ratio * sigma_mgal:
            return f"signal {signal_mgal:.2f} mGal < {self.min_signal_ratio:g} x sigma {sigma_mgal:g} mGal"
        return ""


def window_signal_mgal(g_mgal: np.ndarray, sigma_mgal: float) -> float:
    """Map signal along a window: the spread of the readings with the noise variance removed (mGal)."""
    g = np.asarray(g_mgal, float)
    if g.size < 2:
        return 0.0
    return float(math.sqrt(max(float(np.var(g, ddof=1)) - sigma_mgal**2, 0.0)))


class GravityMatchStage:
    """Online map matching: FusedState (navigator positions, velocities) + GravityReading -> Matcher.feed
    -> PositionFix (sigma = max(matcher sigma, sigma_floor_m)) + MatchRecord.

    A reading is matched once a FusedState at or after its time is seen: the navigator position and velocity
    are interpolated to the reading time between the two bracketing states (readings older than every state
    are dropped). sigma_floor_m: a matcher's own spread can be overconfident (cell quantisation, ambiguity);
    default one map cell of the matcher if it has one, else the map's cell.

    Positions reach the map either through a `Placement` of the navigator's local frame (replay: a drone log laid on
    a chosen map area) or, with ``geographic=True`` (a live vehicle flying over the map's own area), through
    latitude/longitude: exact over hundreds of kilometres, where two tangent planes differ by kilometres.

    feed_spacing_m: None feeds every reading; a distance averages the readings along each stretch of that length of
    the navigator track (airborne gravimetry is low-pass filtered; the matchers' designs take one sample per cell)
    and feeds the mean reading at the mean time and position. acceptance: see `FixAcceptance` (None: every fix).
    navigator_prior: a Viterbi matcher's first state gets a Gaussian prior of the navigator's own horizontal sigma
    (ours, not the paper's uniform B_1: without it a smooth map lets the path jump to a look-alike tens of km away).
    """

    def __init__(self, lmap: LocalGravityMap, matcher: Matcher, placement: Placement | None = None,
                 sigma_floor_m: float | None = None, source: str | None = None, *, geographic: bool = False,
                 feed_spacing_m: float | None = None, acceptance: FixAcceptance | None = None,
                 sigma_mgal: float | None = None, navigator_prior: bool = True) -> None:
        if geographic and lmap.frame is None:
            raise ValueError("geographic matching needs a geographic map")
        if feed_spacing_m is not None and not feed_spacing_m > 0:
            raise ValueError("feed_spacing_m must be > 0")
        self.lmap, self.matcher = lmap, matcher
        self.placement = placement or Placement()
        self.geographic = bool(geographic)
        cells = getattr(matcher, "cells", None)
        self.cell_m = float(cells.cell_m) if cells is not None else float(min(lmap.cell_size_m()))
        self.sigma_floor_m = float(sigma_floor_m if sigma_floor_m is not None else self.cell_m)
        self.source = source or f"gravity:{matcher.name}"
        self.feed_spacing_m = feed_spacing_m
        self.acceptance = acceptance
        cfg = getattr(matcher, "cfg", None) or getattr(matcher, "config", None)
        self.navigator_prior = bool(navigator_prior) and hasattr(getattr(matcher, "cfg", None), "prior_sigma_m")
        self.sigma_mgal = float(sigma_mgal if sigma_mgal is not None else getattr(cfg, "sigma_z_mgal", 1.0))
        self._frame: LocalFrame | None = None
        self._prev: FusedState | None = None
        self._pending: deque[GravityReading] = deque()
        self._acc: list[np.ndarray] = []  # readings of the current stretch: (t, n, e, vn, ve, g, sigma_g, sigma_h) map NE
        self._acc_dist_m = 0.0  # track length of the stretch, from the last reading of the previous one
        self._acc_last: np.ndarray | None = None
        self._fed: deque[np.ndarray] = deque(maxlen=max(2, int(getattr(matcher, "window_len", 2))))
        self.results: list[MatchResult] = []  # ok matches, in map NE
        self.n_fed = self.n_fixes = self.n_failed = self.n_rejected = 0

    def process(self, item: Any) -> list[Event]:
        if isinstance(item, FrameInfo):
            self._frame = _frame_of(item)
        elif isinstance(item, GravityReading):
            if math.isfinite(item.gravity_mgal):
                self._pending.append(item)
        elif isinstance(item, FusedState) and self._frame is not None:
            out: list[Event] = []
            prev, self._prev = self._prev, item
            while self._pending and self._pending[0].t_s <= item.t_s:
                r = self._pending.popleft()
                if prev is None or r.t_s < prev.t_s:
                    continue
                out += self._reading(r, prev, item)
            return out
        return []

    def _map_sample(self, s: FusedState) -> np.ndarray:
        """(north, east, v_north, v_east) of a navigator state in map metres (velocity: map metres per second)."""
        if self.geographic:
            ne = np.array(self.lmap.xy_to_ne(s.lon_deg, s.lat_deg), float)
            n1, e1, _ = self._frame.to_ned_m(s.lat_deg, s.lon_deg, s.alt_msl_m)
            lat2, lon2, _ = self._frame.to_geodetic(np.array([n1 + s.vel_n_mps, e1 + s.vel_e_mps, 0.0]))
            vel = np.array(self.lmap.xy_to_ne(float(lon2), float(lat2)), float) - ne  # 1 s of motion on the map
            return np.concatenate([ne, vel])
        n, e, _ = self._frame.to_ned_m(s.lat_deg, s.lon_deg, s.alt_msl_m)
        pl = self.placement
        return np.concatenate([pl.to_map(np.array([n, e])), pl.to_map(np.array([s.vel_n_mps, s.vel_e_mps])) - pl.to_map(np.zeros(2))])

    def _to_geodetic(self, map_ne: np.ndarray) -> tuple[float, float, np.ndarray]:
        """lat, lon and the navigator-frame NE of a map position."""
        if self.geographic:
            lon, lat = self.lmap.ne_to_xy(map_ne[0], map_ne[1])
            ne = self._frame.to_ned_m(float(lat), float(lon), 0.0)[:2]
            return float(lat), float(lon), ne
        ne = self.placement.to_flight(map_ne)
        lat, lon, _ = self._frame.to_geodetic(np.array([ne[0], ne[1], 0.0]))
        return float(lat), float(lon), ne

    def _reading(self, r: GravityReading, a: FusedState, b: FusedState) -> list[Event]:
        xa, xb = self._map_sample(a), self._map_sample(b)
        w = (r.t_s - a.t_s) / (b.t_s - a.t_s) if b.t_s > a.t_s else 1.0
        x = xa + w * (xb - xa)
        sig_h = a.sigma_h_m + w * (b.sigma_h_m - a.sigma_h_m)
        sample = np.array([r.t_s, x[0], x[1], x[2], x[3], r.gravity_mgal, self.sigma_mgal, sig_h])
        if self.feed_spacing_m is None:
            return self._feed(sample)
        if self._acc_last is not None:
            self._acc_dist_m += float(np.hypot(*(sample[1:3] - self._acc_last[1:3])))
        self._acc_last = sample
        self._acc.append(sample)
        if self._acc_dist_m < self.feed_spacing_m:
            return []
        mean = np.mean(np.asarray(self._acc), axis=0)
        mean[6] = self.sigma_mgal / math.sqrt(len(self._acc))  # noise of a mean of n readings
        self._acc, self._acc_dist_m = [], 0.0
        return self._feed(mean)

    def _feed(self, x: np.ndarray) -> list[Event]:
        self.n_fed += 1
        self._fed.append(x)
        if self.navigator_prior and len(self._fed) == self._fed.maxlen:
            # the navigator's own uncertainty at the window's first sample is the prior of the first state
            # (RVBMP-2i+prior in BENCHMARKS.md; floored at half a cell so the lattice can still move)
            cfg = self.matcher.cfg
            self.matcher.cfg = replace(cfg, prior_sigma_m=float(max(self._fed[0][7], 0.5 * self.cell_m)))
            self.matcher.name = self.matcher.cfg.name
        m = self.matcher.feed(float(x[0]), x[1:3], x[3:5], float(x[5]))
        if m is None:
            return []
        nan = math.nan
        if not m.ok:
            self.n_failed += 1
            return [MatchRecord(float(x[0]), False, m.method, nan, nan, nan, nan, nan, float(m.quality), m.reason,
                                float(m.compute_time_s))]
        self.results.append(m)
        lat, lon, ne = self._to_geodetic(m.position_ne_m)
        sig = float(max(m.sigma_m, self.sigma_floor_m)) if math.isfinite(m.sigma_m) else self.sigma_floor_m
        win = np.asarray(self._fed)
        track_m = float(np.sum(np.hypot(*np.diff(win[:, 1:3], axis=0).T))) if len(win) > 1 else 0.0
        sigma_fed = float(np.sqrt(np.mean(win[:, 6] ** 2)))
        signal = window_signal_mgal(win[:, 5], sigma_fed)
        why = self.acceptance.check(track_m, self.cell_m, signal, sigma_fed) if self.acceptance else ""
        t = float(m.t_s)
        rec = MatchRecord(t, True, m.method, float(ne[0]), float(ne[1]), lat, lon, float(m.sigma_m),
                          float(m.quality), why, float(m.compute_time_s), not why, track_m, signal)
        if why:
            self.n_rejected += 1
            return [rec]
        self.n_fixes += 1
        return [rec, PositionFix(t, lat, lon, sig, sig, self.source)]

    def finish(self) -> list[Event]:
        return []

    def metadata(self) -> dict[str, str]:
        where = ("geographic (lat/lon on the map's own area)" if self.geographic else
                 f"origin_ne_m={tuple(round(v, 1) for v in self.placement.origin_ne_m)} rot={self.placement.rotation_deg:g}")
        acc = self.acceptance
        return {"matcher": self.matcher.name, "readings_fed": str(self.n_fed), "fixes": str(self.n_fixes),
                "failed": str(self.n_failed), "rejected": str(self.n_rejected), "sigma_floor_m": f"{self.sigma_floor_m:g}",
                "cell_m": f"{self.cell_m:g}", "feed_spacing_m": str(self.feed_spacing_m), "placement": where,
                "navigator_prior": str(self.navigator_prior),
                "acceptance": (f"min_track_cells={acc.min_track_cells:g} min_signal_ratio={acc.min_signal_ratio:g}"
                               if acc else "none")}


@dataclass(frozen=True, slots=True)
class NavError(Event):
    """Horizontal error vs a withheld GNSS fix (truth), for the fused state and the last GPS_INPUT built."""

    since_cut_s: float
    fused_error_m: float
    injected_error_m: float
    topic: ClassVar[str] = "/gravity/error"


class DenialErrorStage:
    """Error of the fused and injected positions against the withheld GNSS fixes after the cut.

    Each truth fix is compared with the fused state / GPS_INPUT interpolated to its time (computed at the end
    of the run; the records are emitted from finish())."""

    def __init__(self, denial: GnssDenial) -> None:
        self.denial = denial
        self._frame: LocalFrame | None = None
        self._truth: list[tuple[float, float, float]] = []
        self._fused: list[tuple[float, float, float]] = []
        self._inj: list[tuple[float, float, float]] = []
        self.errors: list[NavError] = []

    def process(self, item: Any) -> list[Event]:
        if isinstance(item, FrameInfo):
            self._frame = _frame_of(item)
        elif self._frame is None:
            return []
        elif isinstance(item, FusedState):
            if self.denial.t_cut_s is not None and item.t_s >= self.denial.t_cut_s - 1.0:
                self._fused.append((item.t_s, *self._frame.to_ned_m(item.lat_deg, item.lon_deg, item.alt_msl_m)[:2]))
        elif isinstance(item, GpsInputRecord):
            if self.denial.t_cut_s is not None and item.t_s >= self.denial.t_cut_s - 1.0:
                self._inj.append((item.t_s, *self._frame.to_ned_m(item.lat_deg, item.lon_deg, item.alt_msl_m)[:2]))
        elif self.denial.withheld(item) and item.has_position and item.instance == 0:
            self._truth.append((item.t_s, *self._frame.to_ned_m(item.lat_deg, item.lon_deg, item.alt_msl_m or 0.0)[:2]))
        return []

    def finish(self) -> list[Event]:
        if not self._truth:
            return []
        tr = np.asarray(self._truth)
        errs = [_interp_error(np.asarray(x).reshape(-1, 3), tr) for x in (self._fused, self._inj)]
        t0 = self.denial.t_cut_s
        self.errors = [NavError(float(t), float(t - t0), float(ef), float(ei)) for t, ef, ei in zip(tr[:, 0], *errs)]
        return list(self.errors)

    def table(self, every_s: float = 60.0) -> list[tuple[float, float, float]]:
        """(minutes since the cut, fused error m, injected error m): the truth fix nearest each mark."""
        if not self.errors:
            return []
        ts = np.array([e.since_cut_s for e in self.errors])
        rows = []
        for mark in np.arange(0.0, ts[-1] + 1e-9, every_s):
            i = int(np.argmin(np.abs(ts - mark)))
            rows.append((float(ts[i] / 60.0), self.errors[i].fused_error_m, self.errors[i].injected_error_m))
        if rows and rows[-1][0] * 60.0 < ts[-1] - 1.0:
            rows.append((float(ts[-1] / 60.0), self.errors[-1].fused_error_m, self.errors[-1].injected_error_m))
        return rows

    def summary_lines(self, every_s: float = 60.0) -> list[str]:
        if not self.errors:
            return ["gravity      no withheld GNSS fix to compare with"]
        fe = np.array([e.fused_error_m for e in self.errors])
        ie = np.array([e.injected_error_m for e in self.errors])
        lines = [f"gravity      horizontal error vs withheld GNSS after the cut ({len(self.errors)} fixes): "
                 f"fused mean {np.nanmean(fe):.1f} m, max {np.nanmax(fe):.1f} m; injected mean "
                 f"{_nanmean(ie):.1f} m",
                 "gravity        min after cut   fused err m   injected err m"]
        lines += [f"gravity        {m:13.2f}   {a:11.1f}   {b:14.1f}" for m, a, b in self.table(every_s)]
        return lines


def _nanmean(x: np.ndarray) -> float:
    return float(np.nanmean(x)) if np.any(np.isfinite(x)) else math.nan


def _interp_error(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|est(t) - truth(t)| at the truth times, est linearly interpolated (NaN outside its span or gaps > 1 s)."""
    out = np.full(truth.shape[0], np.nan)
    if est.shape[0] < 2:
        return out
    t = truth[:, 0]
    inside = (t >= est[0, 0]) & (t <= est[-1, 0])
    j = np.clip(np.searchsorted(est[:, 0], t), 1, est.shape[0] - 1)
    gap_ok = est[j, 0] - est[j - 1, 0] <= 1.0
    n = np.interp(t, est[:, 0], est[:, 1])
    e = np.interp(t, est[:, 0], est[:, 2])
    err = np.hypot(n - truth[:, 1], e - truth[:, 2])
    keep = inside & gap_ok
    out[keep] = err[keep]
    return out


#: Matchers the CLI offers (online, through Matcher.feed).
MATCHERS = ("viterbi", "knn", "iccp")


def make_matcher(name: str, lmap: LocalGravityMap, sigma_mgal: float = 1.0, cell_m: float | None = None) -> Matcher:
    """A matcher with the settings of the gravity benchmarks (Viterbi: RVBMP-2, o = 5, T = 6)."""
    if name == "viterbi":
        from companion.gravity.matchers.li_viterbi import ViterbiConfig, ViterbiMatcher

        return ViterbiMatcher(lmap, ViterbiConfig(o=5, T=6, sigma_z_mgal=max(sigma_mgal, 0.1), subcell_values="interp"),
                              cell_m=cell_m)
    if name == "knn":
        from companion.gravity.matchers.gao_knn import KnnMatcher

        return KnnMatcher(lmap)
    if name == "iccp":
        from companion.gravity.matchers.gao_iccp import IccpMatcher

        return IccpMatcher(lmap)
    raise ValueError(f"unknown matcher {name!r} (choose from {', '.join(MATCHERS)})")


def gravity_stages(lmap: LocalGravityMap, denial: GnssDenial, *, matcher: str = "viterbi",
                   place_lat_lon: tuple[float, float] | None = None, sigma_mgal: float = 1.0, seed: int = 0,
                   period_s: float = 1.0, inject_config=None, nav_config: NavigatorConfig | None = None,
                   acceptance: FixAcceptance | None = FixAcceptance()) -> list:
    """The replay stages of a gravity-aided run with GNSS denied (see the module docstring), stage 0 first.

    The flight starts at place_lat_lon on a geographic map (default: the map's centre / local origin)."""
    from companion.inject import InjectConfig

    if place_lat_lon is not None and lmap.frame is not None:
        placement = Placement.at_lat_lon(lmap, *place_lat_lon)
    else:
        placement = Placement()
    n0, e0 = placement.origin_ne_m
    if not math.isfinite(float(lmap.interp_ne(n0, e0))):
        raise ValueError("the flight's start point is off the gravity map (or on a masked cell)")
    grav = SimulatedGravimeter(lmap, placement, np.random.default_rng(seed), sigma_mgal=sigma_mgal)
    return [
        GnssDeniedNavigator(nav_config or gravity_nav_config(), denial),
        GravitySimStage(grav, denial, period_s),
        GravityMatchStage(lmap, make_matcher(matcher, lmap, sigma_mgal), placement, acceptance=acceptance),
        GnssDeniedInjector(inject_config or InjectConfig(mode="shadow"), denial),
        DenialErrorStage(denial),
    ]


def live_gravity_stage(config) -> GravityMatchStage:
    """The match stage of a live vehicle (``[gravity]`` of companion.config.GravityConfig): a geographic map,
    positions through latitude/longitude, readings averaged over one map cell of track unless set otherwise, and the
    fix acceptance test. Raises ValueError / MapFormatError with the reason on a bad map."""
    from companion.gravity.maps import load_grid

    gmap = load_grid(config.map)
    if gmap.axes != "geographic_deg":
        raise ValueError("a live vehicle needs a geographic (longitude/latitude) gravity map")
    lmap = LocalGravityMap.around(gmap)
    matcher = make_matcher(config.matcher, lmap, config.sigma_mgal)
    acc = FixAcceptance(config.accept_min_track_cells, config.accept_min_signal_ratio)
    stage = GravityMatchStage(lmap, matcher, geographic=True, acceptance=acc, sigma_mgal=config.sigma_mgal,
                              source=f"gravity:{config.named_value}:{matcher.name}")
    stage.feed_spacing_m = config.feed_spacing_m or stage.cell_m
    return stage
