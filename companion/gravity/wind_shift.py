"""A shift of the wind an air-data reference holds, seen in the gravity filter's innovations.

The air-data reference (companion.gravity.air_data) holds the wind it learnt while GNSS was good. When the wind turns,
the held wind's error steps by metres per second. The part of that step along the Eotvos sensitivity (mostly east:
2 Omega cos(lat), some 8 mGal per m/s at 56 deg) reaches every reading at once: the innovations' mean NIS over the
last ``window_s`` rises far above what it has been in the outage so far. The filter then adds the step's variance
to the held wind's error along that direction, so that the linear part of the filter, not the particles' positions,
takes the step (docs/decisions/0017-wind-shift.md). The other component (along the lines, north on north-south
lines) does not show at once; a variance added there without evidence walks the position along the track, measured
to cost more than it gains, so it is left to the random walk and the map.

Pure: vehicle time only, bounded memory (the filter's NIS window).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class WindShiftSpec:
    """``step_mps`` 0 turns the detector off."""

    step_mps: float = 0.0  # 1-sigma of a wind shift's step in the held wind's error (m/s)
    nis_ratio: float = 5.0  # a shift: the mean NIS over window_s above this many times the mean before it
    window_s: float = 60.0
    min_history_s: float = 240.0  # ... with at least this much of the outage before the window to compare with
    holdoff_s: float = 300.0  # no second shift within this long of one


class WindShiftDetector:
    """Mean NIS over the last ``window_s`` against the mean over the rest of a history of ``history_s``."""

    def __init__(self, spec: WindShiftSpec, history_s: float):
        if not (spec.step_mps >= 0 and spec.nis_ratio > 1 and spec.window_s > 0 and spec.holdoff_s >= 0
                and history_s > spec.window_s + spec.min_history_s):
            raise ValueError(f"inconsistent wind-shift settings: {spec}, history {history_s} s")
        self.spec = spec
        self.history_s = float(history_s)
        self._nis: deque[tuple[float, float]] = deque()
        self._hold_until = float("-inf")
        self.shifts_t_s: deque[float] = deque(maxlen=100)
        self.last_ratio = float("nan")

    @property
    def enabled(self) -> bool:
        return self.spec.step_mps > 0

    def reset(self) -> None:
        """A new outage or a re-initialised filter: nothing before it is comparable."""
        self._nis.clear()

    def add(self, t_s: float, nis: float) -> bool:
        """One reading's NIS; True when it completes a shift (then held off for ``holdoff_s``)."""
        s = self.spec
        self.last_ratio = float("nan")
        if not self.enabled:
            return False
        self._nis.append((float(t_s), float(nis)))
        while self._nis and self._nis[0][0] < t_s - self.history_s:
            self._nis.popleft()
        if t_s < self._hold_until or self._nis[0][0] > t_s - s.window_s - s.min_history_s:
            return False
        recent = [v for t, v in self._nis if t > t_s - s.window_s]
        before = [v for t, v in self._nis if t <= t_s - s.window_s]
        ref = sum(before) / len(before)
        self.last_ratio = (sum(recent) / len(recent)) / ref if ref > 0 else float("inf")
        if self.last_ratio <= s.nis_ratio:
            return False
        self._hold_until = t_s + s.holdoff_s
        self.shifts_t_s.append(float(t_s))
        return True
