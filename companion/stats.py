"""What a stream held: counts per event type, sensor rates and gaps — the replay/run summary."""

from __future__ import annotations

from collections import Counter, defaultdict
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


def _median_rate_hz(times: list[float]) -> float | None:
    if len(times) < 2:
        return None
    dt = np.diff(np.asarray(times))
    dt = dt[dt > 0]
    return float(1.0 / np.median(dt)) if dt.size else None


@dataclass
class StreamStats:
    counts: Counter = field(default_factory=Counter)
    first_s: float | None = None
    last_s: float | None = None
    reboots: int = 0
    _fix_times: list[float] = field(default_factory=list)
    _gnss_rows: int = 0
    _imu_times: dict[int, list[float]] = field(default_factory=lambda: defaultdict(list))
    _stream_gaps: list[Gap] = field(default_factory=list)

    def add(self, ev: Event) -> None:
        name = type(ev).__name__
        if isinstance(ev, ImuSample):
            self.counts[f"{name}[{ev.imu_index}]"] += 1
            self._imu_times[ev.imu_index].append(ev.t_s)
        elif isinstance(ev, GnssFix):
            self.counts[f"{name}[{ev.instance}]"] += 1
            if ev.instance == 0:
                self._gnss_rows += 1
                if ev.has_position:
                    self._fix_times.append(ev.t_s)
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
        return _median_rate_hz(self._fix_times)

    def imu_rates_hz(self) -> dict[int, float | None]:
        return {i: _median_rate_hz(t) for i, t in sorted(self._imu_times.items())}

    @property
    def gnss_fixes(self) -> int:
        return len(self._fix_times)

    def gnss_gaps(self) -> list[Gap]:
        """Spans without a usable primary GNSS fix, including before the first and after the last."""
        if self.first_s is None:
            return []
        t = self._fix_times
        if not t:
            return [Gap("gnss", self.first_s, self.last_s, "no GNSS fix in the whole stream")]
        rate = self.gnss_rate_hz
        limit = max(GNSS_GAP_MIN_S, GNSS_GAP_FACTOR / rate) if rate else GNSS_GAP_MIN_S
        gaps = []
        if t[0] - self.first_s > limit:
            gaps.append(Gap("gnss", self.first_s, t[0], "no fix yet at the start"))
        arr = np.asarray(t)
        for i in np.nonzero(np.diff(arr) > limit)[0]:
            gaps.append(Gap("gnss", float(arr[i]), float(arr[i + 1]), "no usable fix received"))
        if self.last_s - t[-1] > limit:
            gaps.append(Gap("gnss", t[-1], self.last_s, "fix lost until the end of the stream"))
        return gaps

    def stream_gaps(self) -> list[Gap]:
        rate = self.gnss_rate_hz
        limit = max(STREAM_GAP_S, 2.0 / rate) if rate else STREAM_GAP_S
        return [g for g in self._stream_gaps if g.duration_s > limit]

    def gaps(self) -> list[Gap]:
        return sorted(self.gnss_gaps() + self.stream_gaps(), key=lambda g: (g.start_s, g.kind))

    def warnings(self) -> list[str]:
        out = []
        if not self._imu_times:
            out.append("no IMU data in this stream: inertial navigation is not possible")
        if self._gnss_rows == 0:
            out.append("no GNSS messages in this stream")
        elif not self._fix_times:
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
