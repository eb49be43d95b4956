"""When the navigator resets, as a flight computer's filter does it (ArduPilot EKF3 resets to GNSS after a GPS-glitch
timeout): re-initialisation from the next fix after a stream gap, reset of position/velocity after a GNSS gap or
persistent rejection of a good fix, reset of the tilt after persistent rejection of the autopilot attitude.

:class:`Recovery` decides and counts; the filters carry the resets out (companion.nav.ins_filter, kinematic). Every
reset is a :class:`companion.nav.outputs.NavigatorReset` output and counted in ``resets``."""

from __future__ import annotations

from collections.abc import Callable

from companion.events import Event, FixType, GnssFix
from companion.nav.config import NavigatorConfig
from companion.nav.outputs import NavigatorReset


class Recovery:
    """Gap detection and the rejection runs that call for a reset. ``emit`` receives the NavigatorReset records."""

    def __init__(self, config: NavigatorConfig, emit: Callable[[Event], None]) -> None:
        self.config, self._emit = config, emit
        self._last_t: float | None = None  # newest event time handled
        self.pending: tuple[float, float] | None = None  # (gap start, gap end) of a stream gap not yet re-initialised
        self._reject_since: float | None = None
        self._n_reject_run = 0  # consecutive rejected GNSS positions of a good 3D fix
        self._fix_good = False  # the fix being processed is a good 3D fix
        self.fix_vel: tuple[float, float, float] | None = None  # ... and its velocity
        self._fix_seen_t: float | None = None  # newest GNSS position seen, accepted or not
        self._att_reject_since: float | None = None
        self._n_att_reject_run = 0
        self.attitude_stale = False  # the INS was re-initialised with an attitude from before the gap
        self.resets: dict[str, int] = {}

    def record(self, t: float, kind: str, reason: str, filt: str, dp: float, dv: float) -> None:
        """Count a reset and emit its record."""
        self.resets[kind] = self.resets.get(kind, 0) + 1
        self._emit(NavigatorReset(t, kind, reason, filt, float(dp), float(dv)))

    # ------------------------------------------------------------------ stream gap
    def stream_gap(self, t: float, started: bool) -> bool:
        """An event at t: True if no event at all came for > ``reinit_gap_s`` before it (no output is ticked across
        it); a started navigator then re-initialises at the next fix (``pending``)."""
        last = self._last_t
        if last is None or t > last:
            self._last_t = t
        if last is None or t - last <= self.config.reinit_gap_s:
            return False
        if started:
            self.pending = (last, t)
        return True

    def take_gap(self) -> tuple[float, str]:
        """The pending stream gap is being re-initialised from: forget it and every rejection run. Returns the gap's
        end and its description."""
        gap0, gap1 = self.pending
        self.pending = None
        self._reject_since, self._n_reject_run = None, 0
        self._att_reject_since, self._n_att_reject_run = None, 0
        return gap1, f"stream gap {gap0:.3f} .. {gap1:.3f} s ({gap1 - gap0:.1f} s)"

    # ------------------------------------------------------------------ GNSS
    def note_fix(self, ev: GnssFix, vel) -> bool:
        """Remember the fix's quality and velocity; True if it ends a GNSS gap > reinit_gap_s (no fix at all)."""
        self._fix_good = ev.fix_type >= FixType.FIX_3D
        self.fix_vel = vel
        prev, self._fix_seen_t = self._fix_seen_t, ev.t_s
        return prev is not None and ev.t_s - prev > self.config.reinit_gap_s and self.config.reset_after_rejection

    def gnss_reset(self, t: float, accepted: bool, after_gap: bool = False) -> tuple[str, str] | None:
        """The gate's verdict on a GNSS position; (kind, reason) when the filter must reset to the fix. Persisting
        rejection of a good 3D fix (``reset_after_n_rejected`` consecutive or ``gate_reset_s``) is a real step, not a
        glitch; ``after_gap``: the first fix after a GNSS gap > reinit_gap_s, rejected, resets at once."""
        c = self.config
        if accepted:
            self._reject_since, self._n_reject_run = None, 0
            return None
        if not self._fix_good:
            return None
        if self._reject_since is None:
            self._reject_since = t
        self._n_reject_run += 1
        if (not after_gap and self._n_reject_run < c.reset_after_n_rejected
                and t - self._reject_since < c.gate_reset_s):
            return None
        kind = "gnss_gap" if after_gap else "gnss_rejected"
        reason = (f"first fix after a GNSS gap > {c.reinit_gap_s:g} s outside the gate" if after_gap else
                  f"{self._n_reject_run} GNSS positions rejected over {t - self._reject_since:.1f} s")
        self._reject_since, self._n_reject_run = None, 0
        return kind, reason

    # ------------------------------------------------------------------ autopilot attitude
    def attitude_reset(self, t: float, accepted: bool) -> str | None:
        """The gate's verdict on an autopilot attitude; the reason when the INS tilt must reset to it
        (``att_reset_after_n_rejected`` consecutive or ``gate_reset_s`` of rejections)."""
        c = self.config
        if accepted:
            self._att_reject_since, self._n_att_reject_run = None, 0
            return None
        if self._att_reject_since is None:
            self._att_reject_since = t
        self._n_att_reject_run += 1
        if self._n_att_reject_run < c.att_reset_after_n_rejected and t - self._att_reject_since < c.gate_reset_s:
            return None
        n = self._n_att_reject_run
        self._att_reject_since, self._n_att_reject_run = None, 0
        return f"{n} autopilot attitudes rejected"
