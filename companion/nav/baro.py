"""The navigator's vertical aid: the autopilot's (barometric) altitude, fused once GNSS is gone (see
``fuse_autopilot_alt`` in companion.nav.config.NavigatorConfig)."""

from __future__ import annotations

from companion.nav.config import NavigatorConfig
from companion.nav.measurements import AltitudeMeasurement


class BaroAid:
    """Learns the offset of the autopilot's altitude from ours while GNSS aids (datum, baro bias; time constant
    ``alt_offset_tau_s``); once no GNSS position has come for ``alt_gnss_gap_s``, the offset-corrected altitude is a
    measurement (1-dof gate)."""

    def __init__(self, config: NavigatorConfig) -> None:
        self.config = config
        self.offset_m: float | None = None  # autopilot altitude minus ours
        self._offset_t = -float("inf")

    def measurement(self, t: float, alt_msl_m: float, own_alt_msl_m: float, ref_alt_msl_m: float,
                    last_fix_t: float | None) -> AltitudeMeasurement | None:
        """The autopilot's altitude at t, ours at t; a measurement of our down coordinate (frame at
        ``ref_alt_msl_m``), or None while GNSS aids (the offset is learnt) or before any offset was learnt."""
        c = self.config
        if last_fix_t is not None and t - last_fix_t <= c.alt_gnss_gap_s:
            off = alt_msl_m - own_alt_msl_m
            if self.offset_m is None:
                self.offset_m = off
            else:
                self.offset_m += (off - self.offset_m) * min(1.0, max(0.0, t - self._offset_t) / c.alt_offset_tau_s)
            self._offset_t = t
            return None
        if self.offset_m is None:
            return None  # never seen beside GNSS: its datum is unknown
        return AltitudeMeasurement(t, "altitude", z_down_m=ref_alt_msl_m - (alt_msl_m - self.offset_m),
                                   sigma_m=c.alt_sigma_m)
