"""A final navigator state carried forward to the epoch the autopilot will assume for it.

The navigator's state is final a reorder window behind the newest sensor sample; ArduPilot's EKF3 fuses a GPS_INPUT
as the vehicle ``GPSn_DELAY_MS`` before it arrived. The state is carried across that gap (a few tens of ms) at its own
velocity *and acceleration*: carried at constant velocity, the velocity sent lags the vehicle's by the whole gap, and
EKF3, which fuses that velocity beside the position, is pulled along track whenever the vehicle accelerates
(docs/decisions/0001-takeover-trust.md, "Where the 3 m target is missed").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import fields, replace
from typing import Any

from companion.nav.frame import LocalFrame
from companion.nav.outputs import FusedState

#: the acceleration is the change of the navigator's velocity over at least this span (s): long enough that the
#: velocity's own noise (cm/s) stays below 0.1 m/s^2, short enough to follow a vehicle starting a turn
ACCEL_SPAN_S = 0.1
#: a larger change of velocity than this is a navigator reset, not a motion (m/s^2): no acceleration is applied
MAX_ACCEL_MPS2 = 30.0


class AccelerationTracker:
    """The NED acceleration of the navigator's output, from its velocity over the last ``ACCEL_SPAN_S``."""

    def __init__(self, span_s: float = ACCEL_SPAN_S, max_accel_mps2: float = MAX_ACCEL_MPS2) -> None:
        self.span_s = span_s
        self.max_accel_mps2 = max_accel_mps2
        self._hist: deque[tuple[float, float, float, float]] = deque()
        self.accel_ned_mps2 = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        self._hist.clear()
        self.accel_ned_mps2 = (0.0, 0.0, 0.0)

    def observe(self, s: FusedState) -> tuple[float, float, float]:
        v = (s.t_s, s.vel_n_mps, s.vel_e_mps, s.vel_d_mps)
        if not all(math.isfinite(x) for x in v) or (self._hist and s.t_s <= self._hist[-1][0]):
            return self.accel_ned_mps2
        self._hist.append(v)
        while len(self._hist) > 2 and self._hist[1][0] <= s.t_s - self.span_s:
            self._hist.popleft()  # keep the newest sample at least span_s old, and what came after it
        t0, *v0 = self._hist[0]
        dt = s.t_s - t0
        if dt < self.span_s:
            return self.accel_ned_mps2
        a = tuple((v[i + 1] - v0[i]) / dt for i in range(3))
        self.accel_ned_mps2 = a if math.hypot(*a) <= self.max_accel_mps2 else (0.0, 0.0, 0.0)
        return self.accel_ned_mps2


def carry(s: FusedState, t_s: float, accel_ned_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> FusedState:
    """``s`` carried to epoch ``t_s`` at its velocity and the given acceleration (constant over the gap)."""
    dt = t_s - s.t_s
    if dt == 0.0:
        return s
    an, ae, ad = accel_ned_mps2
    vn, ve, vd = s.vel_n_mps + an * dt, s.vel_e_mps + ae * dt, s.vel_d_mps + ad * dt
    dn, de, dd = ((s.vel_n_mps + vn) / 2 * dt, (s.vel_e_mps + ve) / 2 * dt, (s.vel_d_mps + vd) / 2 * dt)
    lat, lon, alt = LocalFrame(s.lat_deg, s.lon_deg, s.alt_msl_m).to_geodetic((dn, de, dd))
    return fast_replace(s, t_s=t_s, lat_deg=float(lat), lon_deg=float(lon), alt_msl_m=float(alt),
                        north_m=s.north_m + dn, east_m=s.east_m + de, down_m=s.down_m + dd,
                        vel_n_mps=vn, vel_e_mps=ve, vel_d_mps=vd, age_since_fix_s=s.age_since_fix_s + dt)


_INIT_FIELDS: dict[type, tuple[str, ...] | None] = {}  # None: a class with keyword-only or non-init fields
_NAME_SETS: dict[type, frozenset[str]] = {}
_UNSEEN = object()


def fast_replace(obj: Any, **changes: Any) -> Any:
    """``dataclasses.replace(obj, **changes)``, the same object built positionally from cached field names
    (``replace`` walks the fields and builds keywords each time: a fifth of the injector's work a state)."""
    cls = type(obj)
    names = _INIT_FIELDS.get(cls, _UNSEEN)
    if names is _UNSEEN:
        fs = fields(cls)
        names = _INIT_FIELDS[cls] = tuple(f.name for f in fs) if all(f.init and not f.kw_only for f in fs) else None
        _NAME_SETS[cls] = frozenset(names or ())
    if names is None or not changes.keys() <= _NAME_SETS[cls]:  # (what replace itself refuses, it says why)
        return replace(obj, **changes)
    return cls(*[changes[n] if n in changes else getattr(obj, n) for n in names])
