"""What a GPS_INPUT must pass before it is built: every field fits its wire type, and the fused state is one the
injector can stand behind (finite, in range, a plausible speed, a valid covariance)."""

from __future__ import annotations

import math
import struct
from typing import Any

from companion import units
from companion.mavlink.gps_input import encode_gps_input
from companion.nav.outputs import FusedState


def _finite(*vals) -> bool:
    for v in vals:  # (a loop, not all() over a generator: called for every input event)
        if not (isinstance(v, (int, float)) and math.isfinite(v)):
            return False
    return True


def encoded(rec) -> tuple[Any, str]:
    """(pymavlink message, "") for a record whose every field fits its wire type, else (None, the first that does not)."""
    try:
        msg = encode_gps_input(rec)
    except (ValueError, TypeError, OverflowError) as err:
        return None, str(err)
    fmt = msg.unpacker.format.lstrip("<")
    for code, name in zip(fmt, msg.ordered_fieldnames, strict=True):
        try:
            struct.pack("<" + code, getattr(msg, name))
        except (struct.error, OverflowError, TypeError):
            return None, f"{name} does not fit its wire type"
    return msg, ""


def invalid(s: FusedState, c, check_alt: bool = True) -> str:
    """Why a fused state cannot be stood behind ("" when it can); check_alt False: its altitude and vertical
    velocity are not sent, so neither is judged."""
    if not _finite(s.lat_deg, s.lon_deg, s.alt_msl_m):
        return "non-finite position"
    if not (-90.0 <= s.lat_deg <= 90.0 and -180.0 <= s.lon_deg <= 180.0):
        return "lat/lon out of range"
    if units.degE7_from_deg(s.lat_deg) == 0 and units.degE7_from_deg(s.lon_deg) == 0:
        return "lat = lon = 0"
    if check_alt and not -1000.0 <= s.alt_msl_m <= 20000.0:
        return "altitude out of range"
    if not _finite(s.vel_n_mps, s.vel_e_mps, s.vel_d_mps):
        return "non-finite velocity"
    vd = s.vel_d_mps if check_alt else 0.0  # an ignored vertical channel is not judged
    if math.hypot(s.vel_n_mps, s.vel_e_mps, vd) > c.max_speed_mps:
        return f"speed above {c.max_speed_mps:g} m/s"
    if not (_finite(s.sigma_h_m, s.sigma_v_m) and s.sigma_h_m > 0 and s.sigma_v_m > 0):
        return "no valid covariance"
    return ""
