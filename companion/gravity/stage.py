"""The product's gravity match stage: navigator positions + gravimeter readings -> matcher fixes for the navigator.

    ... --> Navigator --> FusedState, FrameInfo
      --> GravityMatchStage (Matcher.feed on navigator positions + readings) --> PositionFix, MatchRecord
      --> (PositionFix goes back to the Navigator: a feedback event, companion.pipeline.core)

In a replay with GNSS denied (`gravity_replay_pipeline`) a companion.pipeline.denial.GnssDenialStage stands in
front of the navigator, a companion.sim.gravimeter.GravitySimStage reads the map at the withheld GNSS truth, the
injector builds shadow GPS_INPUT and a DenialErrorStage measures the error against the withheld fixes.

A live gravimeter (companion.mavlink.gravimeter, companion.sources.gravity) delivers GravityReading as input events instead of GravitySimStage.
Positions are laid on the map with a `Placement` (flight NE metres from the navigator's frame origin -> map NE).
Pure: vehicle time only.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from companion.events import Event, GravityReading, PositionFix
from companion.gravity.maps import LocalGravityMap
from companion.gravity.matchers.base import Matcher, MatchResult
from companion.gravity.placement import MapView, Placement
from companion.gravity.reading_stage import GravityReadingStage
from companion.inject import InjectConfig, Injector
from companion.nav.navigator import NavigatorConfig
from companion.nav.outputs import FusedState
from companion.pipeline.core import Pipeline, build_pipeline
from companion.pipeline.denial import DenialErrorStage, GnssDenial, GnssDenialStage
from companion.pipeline.stage import Stage
from companion.sim.gravimeter import GravitySimStage, SimulatedGravimeter


def gravity_nav_config(**overrides) -> NavigatorConfig:
    """Navigator settings for gravity-aided runs: GNSS weighted by the receiver's own accuracy (the navigator must
    leave the GNSS period with an honest covariance, or the matcher's fixes drag it), no KNN predictor, and the
    autopilot's (barometric) altitude as the vertical aid once GNSS is gone (a free INS height diverges
    exponentially). Measured: docs/decisions/0010-gravity-fixes-into-the-navigator.md."""
    return NavigatorConfig(**{"gnss_sigma_model": "accuracy", "fuse_predictor": False, "fuse_autopilot_alt": True,
                              **_NOT_A_MULTICOPTER, **overrides})


#: the multicopter blockage aids of the navigator's defaults (rotor drag, the loiter/hold motion prior, the u-blox
#: velocity latency, the autopilot's heading) were chosen on the shared multicopter logs; gravity-aided cruises
#: (aircraft, ship; simulated receivers without latency) keep the navigator they were measured with
_NOT_A_MULTICOPTER = {"rotor_drag": False, "motion_prior": False, "gnss_vel_delay_s": 0.0, "fuse_attitude_yaw": False,
                      "fuse_flagged_tilt_in_gap": True}


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
    but arbitrary fix, and fusing it drags the navigator away (docs/decisions/0010-gravity-fixes-into-the-navigator.md).
    Two tests, both on the window the matcher used:

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


@dataclass(frozen=True, slots=True)
class MatchSample:
    """One matcher input, in map metres: the navigator's position and velocity at the reading's time, the reading,
    the noise of the value fed (mGal; sigma / sqrt(n) for a mean of n readings) and the navigator's horizontal
    1-sigma at that time (m)."""

    t_s: float
    north_m: float
    east_m: float
    vel_n_mps: float
    vel_e_mps: float
    gravity_mgal: float
    sigma_mgal: float
    sigma_h_m: float

    def as_row(self) -> tuple[float, ...]:
        return (self.t_s, self.north_m, self.east_m, self.vel_n_mps, self.vel_e_mps, self.gravity_mgal,
                self.sigma_mgal, self.sigma_h_m)

    @classmethod
    def of_row(cls, row) -> "MatchSample":
        return cls(*(float(v) for v in row))


class GravityMatchStage(GravityReadingStage):
    """Online map matching: FusedState (navigator positions, velocities) + GravityReading -> Matcher.feed
    -> PositionFix (sigma = max(matcher sigma, sigma_floor_m)) + MatchRecord.

    A reading is matched once a FusedState at or after its time is seen: the navigator position and velocity
    are interpolated to the reading time between the two bracketing states (readings older than every state
    are dropped); each state is laid on the map once. sigma_floor_m: a matcher's own spread can be
    overconfident (cell quantisation, ambiguity); default one map cell of the matcher if it has one, else the
    map's cell.

    Positions reach the map either through a `Placement` of the navigator's local frame (replay: a drone log laid on
    a chosen map area) or, with ``geographic=True`` (a live vehicle flying over the map's own area), through
    latitude/longitude: exact over hundreds of kilometres, where two tangent planes differ by kilometres.

    feed_spacing_m: None feeds every reading; a distance averages the readings along each stretch of that length of
    the navigator track (airborne gravimetry is low-pass filtered; the matchers' designs take one sample per cell)
    and feeds the mean reading at the mean time and position. acceptance: see `FixAcceptance` (None: every fix).
    navigator_prior: a matcher that takes a prior (Viterbi) gets the navigator's own horizontal sigma at the
    window's first sample as the Gaussian prior of its first state (ours, not the paper's uniform B_1: without it a
    smooth map lets the path jump to a look-alike tens of km away), floored at half a cell so the lattice can
    still move (RVBMP-2i+prior in BENCHMARKS.md).
    """

    def __init__(self, lmap: LocalGravityMap, matcher: Matcher, placement: Placement | None = None,
                 sigma_floor_m: float | None = None, source: str | None = None, *, geographic: bool = False,
                 feed_spacing_m: float | None = None, acceptance: FixAcceptance | None = None,
                 sigma_mgal: float | None = None, navigator_prior: bool = True) -> None:
        if feed_spacing_m is not None and not feed_spacing_m > 0:
            raise ValueError("feed_spacing_m must be > 0")
        self.lmap, self.matcher = lmap, matcher
        self.matcher_name = matcher.name  # as run: with the navigator prior once the first window is full
        self.placement = placement or Placement()
        self.geographic = bool(geographic)
        self.view = MapView(lmap, self.placement, self.geographic)
        self.cell_m = float(matcher.cell_m) if matcher.cell_m is not None else float(min(lmap.cell_size_m()))
        self.sigma_floor_m = float(sigma_floor_m if sigma_floor_m is not None else self.cell_m)
        self.source = source or f"gravity:{matcher.name}"
        self.feed_spacing_m = feed_spacing_m
        self.acceptance = acceptance
        self.navigator_prior = bool(navigator_prior) and matcher.supports_prior
        self.sigma_mgal = float(sigma_mgal if sigma_mgal is not None else
                                (matcher.sigma_z_mgal if matcher.sigma_z_mgal is not None else 1.0))
        super().__init__()
        self._prev: FusedState | None = None
        self._prev_x: np.ndarray | None = None  # the previous state laid on the map, once needed
        self._acc: list[MatchSample] = []  # readings of the current stretch (map NE)
        self._acc_dist_m = 0.0  # track length of the stretch, from the last reading of the previous one
        self._acc_last: MatchSample | None = None
        self._fed: deque[MatchSample] = deque(maxlen=max(2, int(matcher.window_len)))
        self.results: list[MatchResult] = []  # ok matches, in map NE
        self.n_fed = self.n_fixes = self.n_failed = self.n_rejected = 0

    def _state(self, item: FusedState) -> list[Event]:
        out: list[Event] = []
        prev, self._prev = self._prev, item
        xa, xb = self._prev_x, None
        while self._pending and self._pending[0].t_s <= item.t_s:
            r = self._pending.popleft()
            if prev is None or r.t_s < prev.t_s:
                continue
            if xa is None:
                xa = self._map_sample(prev)
            if xb is None:
                xb = self._map_sample(item)
            out += self._reading(r, prev, item, xa, xb)
        self._prev_x = xb
        return out

    def _map_sample(self, s: FusedState) -> np.ndarray:
        """(north, east, v_north, v_east) of a navigator state in map metres (velocity: map metres per second)."""
        return self.view.state(s, self._frame)

    def _to_geodetic(self, map_ne: np.ndarray) -> tuple[float, float, np.ndarray]:
        """lat, lon and the navigator-frame NE of a map position."""
        return self.view.to_geodetic(map_ne, self._frame)

    def _reading(self, r: GravityReading, a: FusedState, b: FusedState, xa: np.ndarray, xb: np.ndarray) -> list[Event]:
        w = (r.t_s - a.t_s) / (b.t_s - a.t_s) if b.t_s > a.t_s else 1.0
        x = xa + w * (xb - xa)
        sig_h = a.sigma_h_m + w * (b.sigma_h_m - a.sigma_h_m)
        sample = MatchSample(float(r.t_s), float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(r.gravity_mgal),
                             self.sigma_mgal, float(sig_h))
        if self.feed_spacing_m is None:
            return self._feed(sample)
        if self._acc_last is not None:
            self._acc_dist_m += float(np.hypot(sample.north_m - self._acc_last.north_m,
                                               sample.east_m - self._acc_last.east_m))
        self._acc_last = sample
        self._acc.append(sample)
        if self._acc_dist_m < self.feed_spacing_m:
            return []
        mean = np.mean(np.array([s.as_row() for s in self._acc]), axis=0)
        mean[6] = self.sigma_mgal / math.sqrt(len(self._acc))  # noise of a mean of n readings
        self._acc, self._acc_dist_m = [], 0.0
        return self._feed(MatchSample.of_row(mean))

    def _feed(self, s: MatchSample) -> list[Event]:
        self.n_fed += 1
        self._fed.append(s)
        prior = None
        if self.navigator_prior and len(self._fed) == self._fed.maxlen:
            prior = float(max(self._fed[0].sigma_h_m, 0.5 * self.cell_m))
            self.matcher_name = self.matcher.method_name(prior)
        m = self.matcher.feed(s.t_s, (s.north_m, s.east_m), (s.vel_n_mps, s.vel_e_mps), s.gravity_mgal,
                              prior_sigma_m=prior)
        if m is None:
            return []
        nan = math.nan
        if not m.ok:
            self.n_failed += 1
            return [MatchRecord(s.t_s, False, m.method, nan, nan, nan, nan, nan, float(m.quality), m.reason,
                                float(m.compute_time_s))]
        self.results.append(m)
        lat, lon, ne = self._to_geodetic(m.position_ne_m)
        sig = float(max(m.sigma_m, self.sigma_floor_m)) if math.isfinite(m.sigma_m) else self.sigma_floor_m
        win = np.array([x.as_row() for x in self._fed])
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

    def metadata(self) -> dict[str, str]:
        where = self.view.describe()
        acc = self.acceptance
        return {"matcher": self.matcher_name, "readings_fed": str(self.n_fed), "fixes": str(self.n_fixes),
                "failed": str(self.n_failed), "rejected": str(self.n_rejected), "sigma_floor_m": f"{self.sigma_floor_m:g}",
                "cell_m": f"{self.cell_m:g}", "feed_spacing_m": "every reading" if self.feed_spacing_m is None else f"{self.feed_spacing_m:g}", "placement": where,
                "navigator_prior": str(self.navigator_prior),
                "acceptance": (f"min_track_cells={acc.min_track_cells:g} min_signal_ratio={acc.min_signal_ratio:g}"
                               if acc else "none")}

    def summary_lines(self) -> list[str]:
        return [f"gravity      {self.n_fed} matcher samples ({self.matcher_name}), {self.n_fixes} fixes fused, "
                f"{self.n_rejected} rejected by the acceptance test, {self.n_failed} failed"]


#: Matchers the CLI offers: window matchers (online, through Matcher.feed) and the sequential filter
#: (companion.gravity.sequential_stage: every reading, for slow vehicles).
MATCHERS = ("viterbi", "knn", "iccp", "sequential")


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
    if name == "sequential":
        raise ValueError("the sequential filter is a stage of its own (companion.gravity.sequential_stage), not a Matcher")
    raise ValueError(f"unknown matcher {name!r} (choose from {', '.join(MATCHERS)})")


def gravity_replay_pipeline(sink, lmap: LocalGravityMap, denial: GnssDenial, *,
                            matcher: str | Matcher | None = "viterbi", placement: Placement | None = None,
                            place_lat_lon: tuple[float, float] | None = None,
                            gravimeter: SimulatedGravimeter | None = None, simulate_gravimeter: bool = True,
                            sigma_mgal: float = 1.0, seed: int = 0, period_s: float = 1.0,
                            sigma_floor_m: float | None = None, inject_config=None,
                            nav_config: NavigatorConfig | None = None,
                            acceptance: FixAcceptance | None = FixAcceptance(), seq_config=None) -> Pipeline:
    """The pipeline of a gravity-aided replay with GNSS denied (see the module docstring): the denial in front of
    the navigator, then the simulated gravimeter, the match stage, the shadow injector and the error stage.

    matcher: a name of `MATCHERS` ("sequential": the sequential filter, settings ``seq_config``, a
    companion.gravity.sequential.SeqGravConfig), a Matcher, or None for the unaided (INS-only) reference. The flight lies on the
    map by `placement`, else it starts at place_lat_lon on a geographic map (default: the map's centre / local
    origin). gravimeter: the simulated gravimeter (default: seeded Gaussian noise of sigma_mgal);
    simulate_gravimeter=False when the event stream brings its own GravityReading events."""
    if placement is None:
        placement = Placement.at_lat_lon(lmap, *place_lat_lon) if place_lat_lon is not None and lmap.frame is not None \
            else Placement()
    n0, e0 = placement.origin_ne_m
    if not math.isfinite(float(lmap.interp_ne(n0, e0))):
        raise ValueError("the flight's start point is off the gravity map (or on a masked cell)")
    stages: list[Stage] = []
    if matcher is not None:
        if simulate_gravimeter:
            grav = gravimeter or SimulatedGravimeter(lmap, placement, np.random.default_rng(seed), sigma_mgal=sigma_mgal)
            stages.append(GravitySimStage(grav, period_s))
        if matcher == "sequential":
            from companion.gravity.sequential_stage import SequentialGravityStage

            stages.append(SequentialGravityStage(lmap, seq_config, placement, sigma_mgal=sigma_mgal, seed=seed))
        else:
            m = make_matcher(matcher, lmap, sigma_mgal) if isinstance(matcher, str) else matcher
            stages.append(GravityMatchStage(lmap, m, placement, sigma_floor_m=sigma_floor_m, acceptance=acceptance))
    stages += [Injector(inject_config or InjectConfig(mode="shadow")), DenialErrorStage(denial)]
    nav_config = nav_config or gravity_nav_config(position_fix_position_only=matcher == "sequential")
    return build_pipeline(sink, nav_config=nav_config, filters=[GnssDenialStage(denial)],
                          extra_stages=stages)


def live_gravity_stage(config) -> Stage:
    """The match stage of a live vehicle (``[gravity]`` of companion.config.GravityConfig): a geographic map,
    positions through latitude/longitude, readings averaged over one map cell of track unless set otherwise, and the
    fix acceptance test. Raises ValueError / MapFormatError with the reason on a bad map."""
    from companion.gravity.maps import load_grid

    gmap = load_grid(config.map)
    if gmap.axes != "geographic_deg":
        raise ValueError("a live vehicle needs a geographic (longitude/latitude) gravity map")
    lmap = LocalGravityMap.around(gmap)
    if config.matcher == "sequential" and config.reference == "air_data":
        from companion.gravity.air_data import AirDataConfig
        from companion.gravity.air_data_stage import AirDataGravityStage
        from companion.gravity.gyro_heading import GYRO_SOURCES, GyroHeadingConfig
        from companion.gravity.sequential_stage import seq_config_of

        # a log reads ~0 at rest where a pitot reads noise: a boat's reference moves from a walking pace
        air = AirDataConfig(wind_window_s=config.air_wind_window_s, output_tau_s=config.air_output_tau_s,
                            min_airspeed_mps=0.3 if config.air_speed_log else AirDataConfig.min_airspeed_mps)
        return AirDataGravityStage(lmap, seq_config_of(config), air,
                                   sigma_mgal=config.sigma_mgal, reading_delay_s=config.reading_delay_s,
                                   source=f"gravity:{config.named_value}:air_data",
                                   speed_sigma_floor_mps=config.air_speed_sigma_floor_mps,
                                   heading=config.air_heading,
                                   gyro=GyroHeadingConfig(window_s=config.air_gyro_window_s,
                                                          bias_walk_degph_rth=config.air_gyro_bias_walk_degph_rth,
                                                          arw_deg_rth=config.air_gyro_arw_deg_rth),
                                   gyro_imu_index=GYRO_SOURCES[config.air_gyro_source],
                                   jump_chi2=config.seq_jump_chi2, speed_log=bool(config.air_speed_log),
                                   correction_rate_mps=config.air_correction_rate_mps)
    if config.matcher == "sequential":
        from companion.gravity.sequential_stage import SequentialGravityStage, seq_config_of

        return SequentialGravityStage(lmap, seq_config_of(config), geographic=True, sigma_mgal=config.sigma_mgal,
                                      source=f"gravity:{config.named_value}:sequential", min_gain=config.seq_min_gain,
                                      velocity_fixes=config.seq_velocity_fixes)
    matcher = make_matcher(config.matcher, lmap, config.sigma_mgal)
    acc = FixAcceptance(config.accept_min_track_cells, config.accept_min_signal_ratio)
    stage = GravityMatchStage(lmap, matcher, geographic=True, acceptance=acc, sigma_mgal=config.sigma_mgal,
                              source=f"gravity:{config.named_value}:{matcher.name}")
    stage.feed_spacing_m = config.feed_spacing_m or stage.cell_m
    return stage
