"""What a stream held: counts per event type, sensor rates and gaps — the replay/run summary."""

from __future__ import annotations

from collections import Counter, defaultdict, deque
from dataclasses import dataclass, field

import numpy as np

from companion.events import Event, GnssFix, ImuSample, Reboot

#: A stream gap: no event at all for longer than max(STREAM_GAP_S, 2 GNSS intervals) (telemetry links
#: at ~1 Hz pause for a second routinely).
STREAM_GAP_S = 1.0
#: A GNSS gap: no usable fix for longer than max(GNSS_GAP_MIN_S, GNSS_GAP_FACTOR x median interval).
GNSS_GAP_MIN_S = 1.0
GNSS_GAP_FACTOR = 3.0


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


class _Intervals:
    """Arrival statistics of one stream in bounded memory: count, first/last time, recent intervals,
    and every interval longer than ``keep_over_s`` (the gap candidates)."""

    def __init__(self, keep_over_s: float) -> None:
        self.count = 0
        self.first_s: float | None = None
        self.last_s: float | None = None
        self.recent: deque[float] = deque(maxlen=RATE_WINDOW)
        self.keep_over_s = keep_over_s
        self.long: list[tuple[float, float]] = []

    def add(self, t_s: float) -> None:
        if self.last_s is not None:
            dt = t_s - self.last_s
            if dt > 0:
                self.recent.append(dt)
            if dt > self.keep_over_s:
                self.long.append((self.last_s, t_s))
        else:
            self.first_s = t_s
        self.count += 1
        self.last_s = t_s if self.last_s is None else max(self.last_s, t_s)

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
                    self._fixes.add(ev.t_s)
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
        for a, b in fx.long:
            if b - a > limit:
                gaps.append(Gap("gnss", a, b, "no usable fix received"))
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
            lines.append(f"  {g.kind:<6} {g.start_s:9.3f} .. {g.end_s:9.3f} s  ({g.duration_s:6.1f} s)  {g.note}")
        for w in self.warnings():
            lines.append(f"warning: {w}")
        return "\n".join(lines)
