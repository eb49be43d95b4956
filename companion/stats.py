"""What a stream held: counts per event type, sensor rates and gaps — the replay/run summary."""

from __future__ import annotations

from collections import Counter, defaultdict, deque
from itertools import islice
from dataclasses import dataclass, field

import numpy as np

from companion.events import Event, GnssFix, ImuSample, Reboot

#: A stream gap: no event at all for longer than max(STREAM_GAP_S, 2 GNSS intervals) (telemetry links
#: at ~1 Hz pause for a second routinely).
STREAM_GAP_S = 1.0
#: A GNSS gap: no usable fix for longer than max(GNSS_GAP_MIN_S, GNSS_GAP_FACTOR x the stream's local interval), the
#: local interval being the larger median of the GNSS_GAP_LOCAL intervals before and after it: a telemetry stream
#: whose rate the ground station changes (0.4 Hz before it sets stream rates, 1.25 Hz after) has no gap at its slow
#: rate, and a fix missing at either rate is still one.
GNSS_GAP_MIN_S = 1.0
GNSS_GAP_FACTOR = 3.0
GNSS_GAP_LOCAL = 10


@dataclass(frozen=True)
class Gap:
    kind: str  # "gnss" or "stream"
    start_s: float
    end_s: float
    note: str

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


#: Rates come from the median of the most recent intervals (bounded memory for a live service).
RATE_WINDOW = 20_000


class _Candidate:
    """An interval longer than ``keep_over_s``, with the stream's intervals around it."""

    __slots__ = ("start_s", "end_s", "before", "after", "rows_without_fix")

    def __init__(self, start_s: float, end_s: float, before: list[float]) -> None:
        self.start_s, self.end_s, self.before, self.after = start_s, end_s, before, []
        self.rows_without_fix = 0  # GNSS messages in it that had no position (a receiver without a fix)

    def local_interval_s(self) -> float | None:
        """The larger of the median intervals before and after (what there is of them)."""
        meds = [float(np.median(x)) for x in (self.before, self.after) if x]
        return max(meds) if meds else None


class _Intervals:
    """Arrival statistics of one stream in bounded memory: count, first/last time, recent intervals,
    and every interval longer than ``keep_over_s`` (the gap candidates) with the ``local`` intervals on each side."""

    def __init__(self, keep_over_s: float, local: int = GNSS_GAP_LOCAL) -> None:
        self.count = 0
        self.first_s: float | None = None
        self.last_s: float | None = None
        self.recent: deque[float] = deque(maxlen=RATE_WINDOW)
        self.keep_over_s = keep_over_s
        self.local = local
        self.long: list[_Candidate] = []
        self._open: list[_Candidate] = []  # candidates still collecting the intervals after them

    def add(self, t_s: float) -> _Candidate | None:
        """Count one arrival; returns the gap candidate it closes, if any."""
        new = None
        if self.last_s is not None:
            dt = t_s - self.last_s
            if dt > 0:
                for c in self._open:
                    c.after.append(dt)
                self._open = [c for c in self._open if len(c.after) < self.local]
            if dt > self.keep_over_s:
                before = list(islice(reversed(self.recent), self.local))
                c = new = _Candidate(self.last_s, t_s, before)
                self.long.append(c)
                if self.local:
                    self._open.append(c)
            if dt > 0:
                self.recent.append(dt)
        else:
            self.first_s = t_s
        self.count += 1
        self.last_s = t_s if self.last_s is None else max(self.last_s, t_s)
        return new

    def rate_hz(self) -> float | None:
        return float(1.0 / np.median(np.fromiter(self.recent, float))) if self.recent else None


@dataclass
class StreamStats:
    counts: Counter = field(default_factory=Counter)
    first_s: float | None = None
    last_s: float | None = None
    reboots: int = 0
    _fixes: _Intervals = field(default_factory=lambda: _Intervals(GNSS_GAP_MIN_S))
    _gnss_rows: int = 0
    _rows_without_fix: int = 0  # primary GNSS messages without a position since the last fix
    _imu: dict[int, _Intervals] = field(default_factory=lambda: defaultdict(lambda: _Intervals(float("inf"))))
    _stream_gaps: list[Gap] = field(default_factory=list)

    def add(self, ev: Event) -> None:
        name = type(ev).__name__
        if isinstance(ev, ImuSample):
            self.counts[f"{name}[{ev.imu_index}]"] += 1
            self._imu[ev.imu_index].add(ev.t_s)
        elif isinstance(ev, GnssFix):
            self.counts[f"{name}[{ev.instance}]"] += 1
            if ev.instance == 0:
                self._gnss_rows += 1
                if ev.has_position:
                    gap = self._fixes.add(ev.t_s)
                    if gap is not None:
                        gap.rows_without_fix = self._rows_without_fix
                    self._rows_without_fix = 0
                else:
                    self._rows_without_fix += 1
        else:
            self.counts[name] += 1
            if isinstance(ev, Reboot):
                self.reboots += 1
        if self.last_s is not None and ev.t_s - self.last_s > STREAM_GAP_S:
            self._stream_gaps.append(Gap("stream", self.last_s, ev.t_s, "no messages at all"))
        if self.first_s is None:
            self.first_s = ev.t_s
        if self.last_s is None or ev.t_s > self.last_s:
            self.last_s = ev.t_s

    @property
    def duration_s(self) -> float:
        return 0.0 if self.first_s is None else self.last_s - self.first_s

    @property
    def gnss_rate_hz(self) -> float | None:
        return self._fixes.rate_hz()

    def imu_rates_hz(self) -> dict[int, float | None]:
        return {i: iv.rate_hz() for i, iv in sorted(self._imu.items())}

    @property
    def gnss_fixes(self) -> int:
        return self._fixes.count

    def gnss_gaps(self) -> list[Gap]:
        """Spans without a usable primary GNSS fix, including before the first and after the last."""
        if self.first_s is None:
            return []
        fx = self._fixes
        if not fx.count:
            return [Gap("gnss", self.first_s, self.last_s, "no GNSS fix in the whole stream")]
        rate = self.gnss_rate_hz
        limit = max(GNSS_GAP_MIN_S, GNSS_GAP_FACTOR / rate) if rate else GNSS_GAP_MIN_S
        gaps = []
        if fx.first_s - self.first_s > limit:
            gaps.append(Gap("gnss", self.first_s, fx.first_s, "no fix yet at the start"))
        for c in fx.long:
            local = c.local_interval_s()
            here = max(GNSS_GAP_MIN_S, GNSS_GAP_FACTOR * local) if local else limit
            if c.end_s - c.start_s > here:
                note = (f"no fix ({c.rows_without_fix} rows without position)" if c.rows_without_fix
                        else "no GNSS message (valid fixes around)")
                gaps.append(Gap("gnss", c.start_s, c.end_s, note))
        if self.last_s - fx.last_s > limit:
            gaps.append(Gap("gnss", fx.last_s, self.last_s, "fix lost until the end of the stream"))
        return gaps

    def stream_gaps(self) -> list[Gap]:
        rate = self.gnss_rate_hz
        limit = max(STREAM_GAP_S, 2.0 / rate) if rate else STREAM_GAP_S
        return [g for g in self._stream_gaps if g.duration_s > limit]

    def gaps(self) -> list[Gap]:
        return sorted(self.gnss_gaps() + self.stream_gaps(), key=lambda g: (g.start_s, g.kind))

    def warnings(self) -> list[str]:
        out = []
        if not self._imu:
            out.append("no IMU data in this stream: inertial navigation is not possible")
        if self._gnss_rows == 0:
            out.append("no GNSS messages in this stream")
        elif not self._fixes.count:
            out.append("GNSS messages present but never a usable fix")
        return out

    def as_dict(self) -> dict:
        return {
            "duration_s": round(self.duration_s, 3),
            "first_s": self.first_s,
            "last_s": self.last_s,
            "counts": dict(sorted(self.counts.items())),
            "gnss_fixes": self.gnss_fixes,
            "gnss_rate_hz": self.gnss_rate_hz,
            "imu_rates_hz": {str(k): v for k, v in self.imu_rates_hz().items()},
            "reboots": self.reboots,
            "gaps": [
                {"kind": g.kind, "start_s": g.start_s, "end_s": g.end_s, "duration_s": g.duration_s, "note": g.note}
                for g in self.gaps()
            ],
        }

    def format(self) -> str:
        def hz(v: float | None) -> str:
            return "-" if v is None else f"{v:.2f} Hz"

        lines = []
        if self.first_s is None:
            return "no events"
        lines.append(f"duration     {self.duration_s:.1f} s (vehicle time {self.first_s:.3f} .. {self.last_s:.3f} s)")
        lines.append("events")
        for name, n in sorted(self.counts.items()):
            lines.append(f"  {name:<18} {n:>9}")
        lines.append(f"GNSS rate    {hz(self.gnss_rate_hz)} ({self.gnss_fixes} fixes with position)")
        for i, r in self.imu_rates_hz().items():
            lines.append(f"IMU{i} rate    {hz(r)}")
        if self.reboots:
            lines.append(f"reboots      {self.reboots}")
        gaps = self.gaps()
        lines.append(f"gaps         {len(gaps)}")
        for g in gaps:
            lines.append(f"  {g.kind:<6}{g.start_s:9.3f} ..{g.end_s:9.3f} s ({g.duration_s:5.1f} s) {g.note}")
        for w in self.warnings():
            lines.append(f"warning: {w}")
        return "\n".join(lines)
