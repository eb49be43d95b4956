"""Whether the navigator's own solution deserves to carry the vehicle through a GNSS outage: the trust monitor.

An INS aided by GNSS learns its heading and its accelerometer biases only from manoeuvres: in a hover or on a straight
line the specific force has no horizontal part that a heading error would rotate, and a horizontal accelerometer bias
cannot be told from a tilt (Groves 2013, sec. 14.2 and 16.3.2). Taken over after a hover, such an INS runs away as soon
as the vehicle turns (far worse than the autopilot dead-reckoning alone); after a manoeuvring lap it holds metres. So
the companion takes over in an outage only while every measure below passes, judged on what was seen *before* the loss
(docs/decisions/0001-takeover-trust.md: the SITL flights behind each bound):

* ``mode``: the navigator runs its INS (a constant-velocity filter cannot carry a manoeuvring vehicle);
* ``aided_s``: GNSS has aided that INS for this long since its last (re)initialisation or reset;
* ``yaw_sigma_rad``: the filter's own heading uncertainty, sqrt(P_psi_d) of the error state;
* ``manoeuvre_mps``: the manoeuvres seen since the last reset, from the receiver's velocity alone (independent of the
  filter): velocity changes over ``manoeuvre_interval_s`` accumulate into M = sum dv dv^T (north/east, forgotten over
  ``manoeuvre_tau_s``); sqrt(lambda_min(M)) is large only after accelerations in two horizontal directions, which is
  what makes heading and both horizontal biases observable;
* ``accel_bias_sigma_mps2``: the filter's horizontal accelerometer-bias uncertainty, sqrt(P_bax + P_bay);
* ``nis_ratio``: the receiver's position innovations consistent with their covariance (forgotten mean NIS / dof over
  ``nis_tau_s``, companion.nav.consistency), and none refused by the gate within ``clean_s``.

Pure: vehicle time from the events only. ``observe(item)`` takes the pipeline's items (the receiver's GnssFix, the
navigator's FusedState, MeasurementUpdate, NavigatorReset and ModeChange); ``verdict`` is the latest judgement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from companion.events import Event, GnssFix
from companion.nav.consistency import NisMonitor
from companion.nav.outputs import FusedState, MeasurementUpdate, ModeChange, NavigatorReset


@dataclass(frozen=True)
class TrustConfig:
    """Bounds of the trust decision (each measured on SITL: docs/decisions/0001-takeover-trust.md)."""

    min_aided_s: float = 30.0
    max_yaw_sigma_rad: float = 0.05
    min_manoeuvre_mps: float = 3.0
    max_accel_bias_sigma_mps2: float = 0.2
    max_nis_ratio: float = 3.0
    clean_s: float = 10.0  # no gate refusal and no reset for this long before the verdict
    manoeuvre_interval_s: float = 1.0
    manoeuvre_tau_s: float = 600.0
    nis_tau_s: float = 20.0
    receiver_instance: int = 0
    report_interval_s: float = 1.0  # a TrustVerdict is recorded this often (and whenever the verdict changes)

    def __post_init__(self) -> None:
        for k in ("max_yaw_sigma_rad", "max_accel_bias_sigma_mps2", "max_nis_ratio", "manoeuvre_interval_s",
                  "manoeuvre_tau_s", "nis_tau_s", "report_interval_s"):
            if not getattr(self, k) > 0:
                raise ValueError(f"{k} must be > 0")
        for k in ("min_aided_s", "min_manoeuvre_mps", "clean_s"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"{k} must be >= 0")


@dataclass(frozen=True, slots=True)
class TrustVerdict(Event):
    """The trust monitor's judgement of the navigator's solution and the measures behind it (NaN: not known yet)."""

    fit: bool
    reason: str  # "fit", or the first measure that failed
    aided_s: float
    yaw_sigma_rad: float
    manoeuvre_mps: float
    accel_bias_sigma_mps2: float
    nis_ratio: float
    since_refusal_s: float  # since the last gate refusal or reset (inf: none since the INS started)
    topic: ClassVar[str] = "/estimation/trust"


class TrustMonitor:
    """Judges the navigator's solution from the pipeline's items (see the module docstring)."""

    def __init__(self, config: TrustConfig | None = None) -> None:
        self.config = config or TrustConfig()
        self._nis = NisMonitor(self.config.nis_tau_s)
        self.verdict: TrustVerdict | None = None
        self._reset(None)

    def _reset(self, t_s: float | None) -> None:
        """Forget everything learnt about the INS: a new filter starts unaligned."""
        self._ins_since: float | None = None  # first INS state after the last (re)initialisation
        self._m = [0.0, 0.0, 0.0]  # forgotten sum of dv dv^T: (nn, ne, ee)
        self._m_t: float | None = None
        self._anchor: tuple[float, float, float] | None = None  # (t, vn, ve) of the receiver
        self._nis.reset()
        self._last_bad_t = t_s  # last gate refusal or reset
        self._last_report_t = -math.inf

    def observe(self, item: Any) -> list[TrustVerdict]:
        """Take one pipeline item; returns a TrustVerdict to record when one is due (at ``report_interval_s`` and
        whenever ``fit`` changes), else []."""
        if isinstance(item, FusedState):
            return self._on_state(item)
        if isinstance(item, GnssFix):
            self._on_fix(item)
        elif isinstance(item, MeasurementUpdate):
            if item.filter == "ins" and item.kind == "gnss_pos":
                self._nis.add(item.t_s, item.nis, len(item.innovation))
                if not item.accepted:
                    self._last_bad_t = item.t_s
        elif isinstance(item, NavigatorReset):
            if item.kind == "reinit":
                self._reset(item.t_s)
            else:
                self._last_bad_t = item.t_s
        elif isinstance(item, ModeChange):
            self._reset(item.t_s)
        return []

    def _on_fix(self, fix: GnssFix) -> None:
        c = self.config
        if fix.instance != c.receiver_instance or fix.fix_type < 3 or fix.vel_n_mps is None or fix.vel_e_mps is None:
            return
        if not all(math.isfinite(v) for v in (fix.t_s, fix.vel_n_mps, fix.vel_e_mps)):
            return
        a = self._anchor
        if a is None or fix.t_s - a[0] > 3.0 * c.manoeuvre_interval_s or fix.t_s < a[0]:
            self._anchor = (fix.t_s, fix.vel_n_mps, fix.vel_e_mps)  # start, or after a gap: a new anchor
            return
        if fix.t_s - a[0] < c.manoeuvre_interval_s:
            return
        dn, de = fix.vel_n_mps - a[1], fix.vel_e_mps - a[2]
        self._anchor = (fix.t_s, fix.vel_n_mps, fix.vel_e_mps)
        w = 1.0 if self._m_t is None else math.exp(-(fix.t_s - self._m_t) / c.manoeuvre_tau_s)
        self._m_t = fix.t_s
        m = self._m
        m[0], m[1], m[2] = m[0] * w + dn * dn, m[1] * w + dn * de, m[2] * w + de * de

    def manoeuvre_mps(self) -> float:
        """sqrt of the smaller eigenvalue of the forgotten velocity-change scatter (m/s)."""
        nn, ne, ee = self._m
        half_tr = 0.5 * (nn + ee)
        lam = half_tr - math.sqrt(max(0.25 * (nn - ee) ** 2 + ne * ne, 0.0))
        return math.sqrt(max(lam, 0.0))

    def _on_state(self, s: FusedState) -> list[TrustVerdict]:
        c = self.config
        t = s.t_s
        if s.mode != "ins" or len(s.cov_diag) < 15:
            if self._ins_since is not None:
                self._reset(t)
            v = self._judge(t, math.nan, math.nan, math.nan, f"navigator in {s.mode} mode, not INS")
        else:
            if self._ins_since is None:
                self._ins_since = t
            cov = s.cov_diag
            yaw = math.sqrt(max(cov[8], 0.0))
            ba = math.sqrt(max(cov[9], 0.0) + max(cov[10], 0.0))
            v = self._judge(t, t - self._ins_since, yaw, ba, "")
        prev = self.verdict
        self.verdict = v
        if prev is None or prev.fit != v.fit or t - self._last_report_t >= c.report_interval_s:
            self._last_report_t = t
            return [v]
        return []

    def _judge(self, t: float, aided_s: float, yaw: float, ba: float, why: str) -> TrustVerdict:
        c = self.config
        man = self.manoeuvre_mps()
        nis = self._nis.ratio()
        since = math.inf if self._last_bad_t is None else t - self._last_bad_t
        if not why:
            if not aided_s >= c.min_aided_s:
                why = f"INS aided for {aided_s:.0f} s < {c.min_aided_s:g} s"
            elif not yaw <= c.max_yaw_sigma_rad:
                why = f"heading sigma {math.degrees(yaw):.1f} deg > {math.degrees(c.max_yaw_sigma_rad):.1f}"
            elif not man >= c.min_manoeuvre_mps:
                why = f"manoeuvres {man:.1f} m/s < {c.min_manoeuvre_mps:g} (heading and biases not observed)"
            elif not ba <= c.max_accel_bias_sigma_mps2:
                why = f"accelerometer bias sigma {ba:.3f} m/s^2 > {c.max_accel_bias_sigma_mps2:g}"
            elif not nis <= c.max_nis_ratio:
                why = f"GNSS innovations {nis:.1f}x their covariance > {c.max_nis_ratio:g}"
            elif not since >= c.clean_s:
                why = f"gate refusal or reset {since:.0f} s ago < {c.clean_s:g} s"
        return TrustVerdict(t, not why, why or "fit", aided_s, yaw, man, ba, nis, since)
