"""The injector's cross-check of each fused state against the real receiver's recent 3D fixes (see the integrity
paragraph of companion.inject.gps_input): a state that disagrees with the receiver is never sent, and after one
disagreement nothing is sent until a check passes again. Pure: vehicle time only."""

from __future__ import annotations

import math
from collections import deque

from companion.nav.frame import LocalFrame
from companion.nav.outputs import FusedState

RX_FIXES_KEPT = 32  # recent receiver 3D fixes kept for the cross-check (>= 0.6 s of a 50 Hz receiver)


def _finite(*vals) -> bool:
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals)


class ReceiverCrossCheck:
    """Checks fused states against the receiver fix nearest in time (``config``: the injector's InjectConfig)."""

    def __init__(self, config) -> None:
        self.config = config
        # (t_s, lat_deg, lon_deg, sigma_h_m, vel_n_mps, vel_e_mps, speed_sigma_mps), velocities None when not given
        self._fixes: deque[tuple[float, float, float, float, float | None, float | None, float]] = deque(
            maxlen=RX_FIXES_KEPT)
        self._inconsistent = False
        self.checked = 0  # states compared with a receiver fix, of ``states`` that reached the check
        self.states = 0

    def add_fix(self, t_s: float, lat_deg: float, lon_deg: float, sigma_h_m: float, vel_n_mps: float | None,
                vel_e_mps: float | None, speed_sigma_mps: float) -> None:
        """One of the receiver's 3D fixes (finite time and position)."""
        self._fixes.append((t_s, lat_deg, lon_deg, sigma_h_m, vel_n_mps, vel_e_mps, speed_sigma_mps))

    def disagreement(self, s: FusedState) -> str:
        """Why the state disagrees with the real receiver ("" when it agrees or cannot be checked): against the 3D
        fix nearest to it in time within consistency_window_s, carried to the state's epoch."""
        c = self.config
        self.states += 1
        fx = min(self._fixes, key=lambda f: abs(s.t_s - f[0]), default=None)
        if fx is None or abs(s.t_s - fx[0]) > c.consistency_window_s:
            return "inconsistent with the receiver (not yet re-checked)" if self._inconsistent else ""
        self.checked += 1
        dt = s.t_s - fx[0]
        has_v = fx[4] is not None
        vn, ve = (fx[4], fx[5]) if has_v else (s.vel_n_mps, s.vel_e_mps)
        n, e, _ = LocalFrame(fx[1], fx[2], 0.0).to_ned_m(s.lat_deg, s.lon_deg, 0.0)
        dn, de = float(n) - vn * dt, float(e) - ve * dt
        # hypot: no square of a huge (finite) sigma or velocity overflows. The lag allowance takes the receiver's
        # speed when it has one: a wrong state velocity must not widen its own allowance
        lag_m = math.hypot(vn, ve) * c.receiver_lag_s
        k = math.sqrt(c.consistency_chi2)
        allowed_m = math.hypot(k * math.hypot(s.sigma_h_m, fx[3]), lag_m)
        ok = math.hypot(dn, de) <= allowed_m
        if ok and has_v:
            # velocity: a state moving 15 m/s off the receiver is metres off it 0.1 s later, whatever sigma_h says
            cov = s.cov_diag
            known = len(cov) >= 6 and _finite(cov[3], cov[4]) and min(cov[3], cov[4]) >= 0
            sv_state = math.sqrt(max(cov[3], cov[4])) if known else math.inf
            allowed_v = math.hypot(k * math.hypot(sv_state, fx[6]), c.consistency_accel_mps2 * (abs(dt) + c.receiver_lag_s))
            ok = math.hypot(s.vel_n_mps - vn, s.vel_e_mps - ve) <= allowed_v
        self._inconsistent = not ok
        return "inconsistent with the receiver" if self._inconsistent else ""

    def metadata(self) -> dict[str, str]:
        return {"cross_check.states": str(self.states), "cross_check.checked": str(self.checked),
                "cross_check.fraction": f"{self.checked / self.states:.4f}" if self.states else "0"}

    def summary_lines(self) -> list[str]:
        if not self.states:
            return []
        return [f"gps_input    receiver cross-check on {self.checked} of {self.states} states "
                f"({100.0 * self.checked / self.states:.1f} %)"]
