"""Consistency of an aiding source by covariance matching: a forgotten mean of normalised squared residuals.

A source whose noise model is right gives residuals whose normalised square has expectation 1 per degree of freedom
(for a KF innovation, NIS / dof with NIS = y' S^-1 y; for the autopilot's tilt, the excess residual of
companion.nav.monitors.AhrsHeadingCheck._tilt_residual). The monitor keeps an exponentially forgotten mean of it over
``tau_s`` (time-weighted, so the source's rate does not set the window) and returns ``max(1, ratio)``: the factor by
which R must grow for the observed residuals to match their model (the adaptive-R / covariance-matching idea of
Mehra 1970 and Mohamed & Schwarz 1999, J. Geodesy 73, with R scaled instead of re-estimated). A consistent source
stays near 1 and is fused as configured; a biased one is de-weighted by what it has shown. The residual fed in must be
normalised with the nominal R, not the inflated one, else the de-weighting would hide itself.

Pure: no I/O, no clock."""

from __future__ import annotations

import math


class NisMonitor:
    """Exponentially forgotten mean of NIS / dof with time constant ``tau_s``; ``inflation()`` >= 1."""

    def __init__(self, tau_s: float, min_weight_s: float = 0.0) -> None:
        if tau_s <= 0:
            raise ValueError("tau_s must be positive")
        self.tau_s = tau_s
        self.min_weight_s = min_weight_s  # no inflation before this much (time-weighted) evidence
        self._sum = 0.0  # forgotten sum of (NIS / dof) x dt
        self._w = 0.0  # forgotten sum of dt
        self._t: float | None = None

    def reset(self) -> None:
        self._sum, self._w, self._t = 0.0, 0.0, None

    def add(self, t_s: float, nis: float, dof: int) -> None:
        """One innovation's NIS (nominal R) at ``t_s``; weighted by the time since the previous one (capped at tau)."""
        if not math.isfinite(nis) or dof <= 0:
            return
        dt = 0.0 if self._t is None else min(t_s - self._t, self.tau_s)
        self._t = t_s if self._t is None else max(self._t, t_s)
        dt = max(dt, 1e-3)  # the first or a same-epoch sample: a small weight rather than none
        f = math.exp(-dt / self.tau_s)
        self._sum = self._sum * f + (nis / dof) * dt
        self._w = self._w * f + dt

    def ratio(self) -> float:
        """Mean NIS / dof over the window (1 when nothing has been seen)."""
        return self._sum / self._w if self._w > 0.0 else 1.0

    def inflation(self) -> float:
        """The factor for R: max(1, ratio) once the window holds ``min_weight_s`` of evidence, else 1."""
        if self._w < self.min_weight_s:
            return 1.0
        return max(1.0, self.ratio())
