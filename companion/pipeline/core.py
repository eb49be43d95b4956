"""The pipeline: source -> stages -> MCAP record, the same objects for replay and for a live link.

A stage is a :class:`companion.pipeline.stage.Stage`: ``process(item) -> list[outputs]``, ``finish()`` and the
optional hooks. Outputs are frozen dataclasses (companion.events.Event) with ``t_s`` and a ``topic``, recorded as
they come (unless their type says ``recorded = False``). Later stages see earlier stages' outputs as well as the
input events, so a predictor's points can feed the integrator; a filter stage (``filters = True``) decides with
``passes(item)`` which items the stages after it see (a GNSS denial withholds the receiver from the navigator).

Feedback: an output of a stage whose type says ``feedback = True`` (companion.events.PositionFix, e.g. a
gravity-matching fix) is recorded when produced, is *not* passed to the stages after its producer in that pass,
and is queued; once the current input event has gone through every stage, the queue is drained in order, each
item running through all stages from the first (the filters, then the Navigator) like an input event (not
recorded a second time, not counted in the input stats). Deterministic: the order depends only on the event
stream. Feedback produced in ``finish()`` is recorded only (the Navigator has already finished); so is feedback
from the first stage, which would only loop back to itself.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from companion.constants import UERE_M, receiver_sigma
from companion.events import Event, GnssFix, ImuSample, StatusText
from companion.mavlink.dialect import mavlink
from companion.pipeline.stage import Stage
from companion.sources.base import Source
from companion.stats import StreamStats

#: Map-panel track of the raw receiver fixes.
GNSS_MAP_TOPIC = "/map/gnss"
#: the autopilot's STATUSTEXT (dataflash MSG) as foxglove.Log, for Foxglove's Log panel
AUTOPILOT_LOG_TOPIC = "/log/autopilot"
#: MAV_SEVERITY -> foxglove.LogLevel (DEBUG 1, INFO 2, WARNING 3, ERROR 4, FATAL 5)
_LOG_LEVEL = {
    mavlink.MAV_SEVERITY_EMERGENCY: 5, mavlink.MAV_SEVERITY_ALERT: 5, mavlink.MAV_SEVERITY_CRITICAL: 5,
    mavlink.MAV_SEVERITY_ERROR: 4, mavlink.MAV_SEVERITY_WARNING: 3, mavlink.MAV_SEVERITY_NOTICE: 2,
    mavlink.MAV_SEVERITY_INFO: 2, mavlink.MAV_SEVERITY_DEBUG: 1,
}


class Sink(Protocol):
    """Where everything goes: the MCAP recorder in practice (companion.record.Recorder)."""

    def write(self, item: Any, topic: str | None = None) -> None: ...

    def write_location(
        self, topic: str, t_s: float, lat_deg: float, lon_deg: float, alt_m: float, cov_enu_m2=None
    ) -> None: ...

    def write_log(self, topic: str, t_s: float, level: int, message: str, name: str = "") -> None: ...


@dataclass
class Pipeline:
    stages: list[Stage] = field(default_factory=list)
    sink: Sink | None = None
    stats: StreamStats = field(default_factory=StreamStats)
    outputs: int = 0
    _feedback: deque = field(default_factory=deque, repr=False)
    _finishing: bool = field(default=False, repr=False)

    def process(self, ev: Event) -> None:
        self.stats.add(ev)
        self._emit(ev)
        if isinstance(ev, GnssFix) and ev.has_position and self.sink is not None:
            self.sink.write_location(
                f"{GNSS_MAP_TOPIC}{ev.instance if ev.instance else ''}",
                ev.t_s,
                ev.lat_deg,
                ev.lon_deg,
                ev.alt_msl_m if ev.alt_msl_m is not None else 0.0,
                cov_enu_m2=_gnss_cov_enu_m2(ev),
            )
        self._run_stages([ev], 0)
        while self._feedback:
            self._run_stages([self._feedback.popleft()], 0)

    def _run_stages(self, items: Iterable[Any], first: int) -> None:
        for i in range(first, len(self.stages)):
            stage = self.stages[i]
            produced = []
            for item in items:
                produced += stage.process(item)
            for out in produced:
                self._emit(out)
            self.outputs += len(produced)
            if produced and i > 0:
                fb = [o for o in produced if o.feedback]
                if fb:
                    if not self._finishing:
                        self._feedback.extend(fb)
                    produced = [o for o in produced if not o.feedback]
            if stage.filters:
                items = [item for item in items if stage.passes(item)]
            items = list(items) + produced if produced else items

    def _emit(self, item: Any) -> None:
        if self.sink is not None and item.recorded:
            self.sink.write(item, _instance_topic(item))
            track = _MAP_TRACKS.get(type(item).__name__)
            if track is not None and _finite(item.lat_deg, item.lon_deg, item.alt_msl_m):
                self.sink.write_location(track, item.t_s, item.lat_deg, item.lon_deg, item.alt_msl_m, cov_enu_m2=_cov_enu(item))
            elif type(item) is StatusText:
                self.sink.write_log(AUTOPILOT_LOG_TOPIC, item.t_s, _LOG_LEVEL.get(item.severity, 0), item.text,
                                    "autopilot")

    def finish(self) -> None:
        self._finishing = True
        for i, stage in enumerate(self.stages):
            outs = stage.finish()
            for out in outs:
                self._emit(out)
            self.outputs += len(outs)
            if i > 0:
                outs = [o for o in outs if not o.feedback]  # recorded only
            if outs:
                self._run_stages(outs, i + 1)


#: Outputs that also go to Foxglove's Map panel, one LocationFix track each (GPS_INPUT: what went, or in shadow mode
#: would go, to the autopilot).
_MAP_TRACKS = {"FusedState": "/map/fused", "PredictorPoint": "/map/predictor", "GpsInputRecord": "/map/gps_input",
               "AutopilotPosition": "/map/autopilot"}


def _finite(*vals: float) -> bool:
    return all(v is not None and math.isfinite(v) for v in vals)


def _cov_enu(item: Any) -> list[list[float]] | None:
    """Diagonal ENU covariance from an output's horizontal/vertical sigmas (NED position variances)."""
    h, v = getattr(item, "sigma_h_m", None), getattr(item, "sigma_v_m", None)
    if h is None:  # a GPS_INPUT: the accuracies it reports
        h, v = getattr(item, "h_acc_m", None), getattr(item, "v_acc_m", None)
    if not _finite(h, v):
        return None
    return [[h * h, 0.0, 0.0], [0.0, h * h, 0.0], [0.0, 0.0, v * v]]


def _instance_topic(item: Any) -> str | None:
    """Second and third sensors get their own topics (/input/imu1, /input/gnss1) so rates read right."""
    if isinstance(item, ImuSample) and item.imu_index:
        return f"{item.topic}{item.imu_index}"
    if isinstance(item, GnssFix) and item.instance:
        return f"{item.topic}{item.instance}"
    return None


def build_pipeline(
    sink: Sink | None,
    *,
    nav_config: Any = None,
    filters: Iterable[Stage] = (),
    extra_stages: Iterable[Stage] = (),
    navigator: bool = True,
) -> Pipeline:
    """The one pipeline wiring used by replay, the live runtime and the benchmarks.

    source events -> filters (e.g. a GNSS denial, companion.pipeline.denial) -> navigator (KNN predictor + INS +
    Kalman integrator, companion.nav) -> extra stages (gravity matching, the GPS_INPUT injector, which consumes
    the navigator's FusedState, ...) -> sink. ``navigator=False``: no navigator (an ingest-only replay).
    """
    from companion.nav import Navigator

    stages: list[Stage] = [*filters, *([Navigator(nav_config)] if navigator else []), *extra_stages]
    return Pipeline(stages=stages, sink=sink)


def _gnss_cov_enu_m2(fix: GnssFix) -> list[list[float]] | None:
    """Diagonal ENU covariance from the receiver's accuracy fields, else from DOP x UERE; None if unknown."""
    h, v = receiver_sigma(fix, UERE_M)
    if h is None:
        return None
    v = v if v is not None else 2.0 * h
    return [[h * h, 0.0, 0.0], [0.0, h * h, 0.0], [0.0, 0.0, v * v]]


#: a replay hands the event loop a turn at least this often (wall s): SIGINT/SIGTERM stop it within it
YIELD_S = 0.05


async def run_source(
    source: Source,
    pipeline: Pipeline,
    *,
    realtime_factor: float | None = None,
    on_progress: Callable[[Source, int], None] | None = None,
    progress_interval_s: float = 0.25,
) -> None:
    """Drive a source through the pipeline until it ends (or the task is cancelled).

    ``realtime_factor``: None replays as fast as possible; 1.0 paces events at the vehicle's own rate
    (2.0 twice as fast). Pacing uses the loop clock only to wait; event times stay the log's.
    ``on_progress(source, events so far)`` is called every ``progress_interval_s`` of wall time (a display: a paced
    replay's few events a second refresh it as often as a fast one's thousands); the clock is looked at after every
    paced event, else every 64 events; the loop gets a turn every ``YIELD_S`` (a signal stops the replay there).
    """
    loop = asyncio.get_running_loop()
    t0_wall = t0_ev = None
    n = 0
    next_progress = loop.time() + progress_interval_s if on_progress is not None else math.inf
    next_yield = loop.time() + YIELD_S
    async for ev in source:
        if realtime_factor:
            if t0_ev is None:
                t0_wall, t0_ev = loop.time(), ev.t_s
            delay = t0_wall + (ev.t_s - t0_ev) / realtime_factor - loop.time()
            if delay > 0.001:
                await asyncio.sleep(delay)
        pipeline.process(ev)
        n += 1
        if realtime_factor or not n & 63:
            now = loop.time()
            if now >= next_progress:
                on_progress(source, n)
                next_progress = now + progress_interval_s
            if now >= next_yield:  # a signal's handler runs at the loop's next turn, not after a whole batch
                await asyncio.sleep(0)
                next_yield = loop.time() + YIELD_S
    pipeline.finish()


def wall_time_s() -> float:
    """For throughput figures only; never enters an event or a record."""
    return time.perf_counter()
