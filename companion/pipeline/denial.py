"""A GNSS denial as an ordinary filter stage, and the error of the navigator's and the injector's positions against
the receiver fixes it withheld (the truth of the run).

    source events --> GnssDenialStage (GNSS fixes at or after the cut: withheld; each becomes a WithheldFix)
      --> Navigator --> ... --> Injector --> DenialErrorStage (error vs the withheld fixes) --> NavError

The stages after the denial never see a withheld GnssFix: the navigator runs without it and the injector's
receiver cross-check is blind to it. The truth travels on as `WithheldFix`, which is not recorded (the fix itself
is already on /input/gnss) and which only truth consumers read (the simulated gravimeter of a replay,
companion.sim.gravimeter.GravitySimStage, and `DenialErrorStage`). Pure: vehicle time only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from companion.events import Event, GnssFix
from companion.inject.gps_input import GpsInputRecord
from companion.nav.frame import LocalFrame
from companion.nav.outputs import FrameInfo, FusedState
from companion.pipeline.stage import Stage


class GnssDenial:
    """The cut time: GNSS fixes at or after (first event time + after_s) are withheld (kept as truth only)."""

    def __init__(self, after_s: float | None):
        self.after_s = None if after_s is None else float(after_s)
        self.t_cut_s: float | None = None

    def observe(self, ev: Any) -> None:
        if self.t_cut_s is None and self.after_s is not None and isinstance(ev, Event) and math.isfinite(ev.t_s):
            self.t_cut_s = ev.t_s + self.after_s

    def withheld(self, ev: Any) -> bool:
        self.observe(ev)
        return isinstance(ev, GnssFix) and self.t_cut_s is not None and ev.t_s >= self.t_cut_s


@dataclass(frozen=True, slots=True)
class WithheldFix(Event):
    """A receiver fix the denial kept from the stages after it: the truth of the run (not recorded)."""

    fix: GnssFix
    topic: ClassVar[str] = "/denial/withheld"
    recorded: ClassVar[bool] = False


class GnssDenialStage(Stage):
    """Filter stage: withholds GNSS after the cut from every later stage; passes each withheld fix on as a
    `WithheldFix` (the truth). Placed in front of the navigator (companion.pipeline.build_pipeline ``filters``)."""

    filters = True

    def __init__(self, denial: GnssDenial) -> None:
        self.denial = denial
        self.gnss_withheld = 0

    def process(self, item: Any) -> list[Event]:
        if self.denial.withheld(item):
            self.gnss_withheld += 1
            return [WithheldFix(item.t_s, item)]
        return []

    def passes(self, item: Any) -> bool:
        return not self.denial.withheld(item)

    def metadata(self) -> dict[str, str]:
        return {"gnss_withheld_after_s": f"{self.denial.after_s:g}", "gnss_withheld": str(self.gnss_withheld)}


@dataclass(frozen=True, slots=True)
class NavError(Event):
    """Horizontal error vs a withheld GNSS fix (truth), for the fused state and the last GPS_INPUT built."""

    since_cut_s: float
    fused_error_m: float
    injected_error_m: float
    topic: ClassVar[str] = "/gravity/error"


def frame_of(item: FrameInfo) -> LocalFrame:
    """The navigator's local frame, from its FrameInfo output."""
    return LocalFrame(item.ref_lat_deg, item.ref_lon_deg, item.ref_alt_msl_m)


class DenialErrorStage(Stage):
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
            self._frame = frame_of(item)
        elif self._frame is None:
            return []
        elif isinstance(item, FusedState):
            if self.denial.t_cut_s is not None and item.t_s >= self.denial.t_cut_s - 1.0:
                self._fused.append((item.t_s, *self._frame.to_ned_m(item.lat_deg, item.lon_deg, item.alt_msl_m)[:2]))
        elif isinstance(item, GpsInputRecord):
            if self.denial.t_cut_s is not None and item.t_s >= self.denial.t_cut_s - 1.0:
                self._inj.append((item.t_s, *self._frame.to_ned_m(item.lat_deg, item.lon_deg, item.alt_msl_m)[:2]))
        elif isinstance(item, WithheldFix) and item.fix.has_position and item.fix.instance == 0:
            f = item.fix
            self._truth.append((f.t_s, *self._frame.to_ned_m(f.lat_deg, f.lon_deg, f.alt_msl_m or 0.0)[:2]))
        return []

    def finish(self) -> list[Event]:
        if not self._truth:
            return []
        tr = np.asarray(self._truth)
        errs = [interp_error(np.asarray(x).reshape(-1, 3), tr) for x in (self._fused, self._inj)]
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


def interp_error(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|est(t) - truth(t)| at the truth times, est (t, north, east) linearly interpolated (NaN outside its span or
    across gaps > 1 s); truth rows (t, north, east)."""
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
