"""The navigator's vertical aid: the autopilot's (barometric) altitude, fused once GNSS is gone (see
``fuse_autopilot_alt`` in companion.nav.config.NavigatorConfig). A mixin of companion.nav.navigator.Navigator."""

from __future__ import annotations

import math

from companion.events import AutopilotAltitude
from companion.nav.measurements import AltitudeMeasurement


class BaroAid:
    """Mixin: learn the offset of the autopilot's altitude from ours while GNSS aids; fuse it when GNSS is gone."""

    def _on_altitude(self, ev: AutopilotAltitude) -> None:
        """The autopilot's altitude: learn its offset from ours while GNSS aids, fuse it (1-dof gate) once GNSS is gone."""
        if self.mode != "ins" or self.frame is None or not math.isfinite(ev.alt_msl_m):
            return
        c, t = self.config, ev.t_s
        self._ins_predict(max(t, self._kf_t))
        down = float(self._ins_state_at(t, delay_s=0.0)[0][2])
        alt_ins = self._ref[2] - down
        if self._last_fix_t is not None and t - self._last_fix_t <= c.alt_gnss_gap_s:
            off = ev.alt_msl_m - alt_ins
            if self._alt_off is None:
                self._alt_off = off
            else:
                self._alt_off += (off - self._alt_off) * min(1.0, max(0.0, t - self._alt_off_t) / c.alt_offset_tau_s)
            self._alt_off_t = t
            return
        if self._alt_off is None:
            return  # never seen beside GNSS: its datum is unknown
        m = AltitudeMeasurement(t, "altitude", z_down_m=self._ref[2] - (ev.alt_msl_m - self._alt_off), sigma_m=c.alt_sigma_m)
        if self._ins_apply(m)[0]:
            self._used.add("altitude")
