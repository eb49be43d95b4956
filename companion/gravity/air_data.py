"""Air-data dead reckoning: the reference motion of the gravity filter on a fixed wing without GNSS.

A MEMS INS on an aircraft's IMU does not hold for an hour; the autopilot's pitot and heading do, up to the wind. The
reference velocity is the true airspeed along the heading plus a wind held from the GNSS period:

    v_ref = TAS (cos yaw, sin yaw) + w_held,    w_held = mean over ``wind_window_s`` of (v_GNSS - TAS (cos, sin) yaw)

so its error is the held wind's error (the wind turns and changes in the denial), which the gravity filter estimates
as a random walk (companion.gravity.sequential.InsErrorSpec.air_data). While GNSS is good the position is the
receiver's; after the loss it is integrated on the ellipsoid (WGS84 radii of curvature) from the last fix. Inputs are
the autopilot's raw air data (VFR_HUD airspeed, its equivalent airspeed turned into true airspeed at the altitude by
the ISA atmosphere) and heading (ATTITUDE yaw): never the companion's own output. Pure: vehicle time only.

The velocity it states (``output_velocity``) is that velocity through a first-order low-pass of ``output_tau_s``: the
air velocity carries the pitot's noise and the gusts sample by sample, so unfiltered it steps several m/s between
states where the vehicle's own velocity does not (docs/decisions/0016); the position is integrated from the unfiltered
velocity (the noise averages out there, a lag would not).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.constants import WGS84_A_M

WGS84_E2 = 6.69437999014e-3
#: ISA troposphere: sea-level temperature (K), lapse rate (K/m), exponent of the density ratio (g / (R L) - 1)
ISA_T0_K, ISA_LAPSE_KPM, ISA_RHO_EXP = 288.15, 0.0065, 4.2559


def tas_from_eas_mps(eas_mps: float, alt_msl_m: float) -> float:
    """True airspeed from equivalent airspeed at an ISA altitude (below 11 km): TAS = EAS / sqrt(rho / rho0)."""
    h = min(max(float(alt_msl_m), -500.0), 11_000.0)
    rho_ratio = (1.0 - ISA_LAPSE_KPM * h / ISA_T0_K) ** ISA_RHO_EXP
    return float(eas_mps) / math.sqrt(rho_ratio)


def radii_m(lat_deg: float) -> tuple[float, float]:
    """(meridian, prime-vertical) radii of curvature of the WGS84 ellipsoid."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w


def mag_heading_rad(field_frd, roll_rad: float, pitch_rad: float) -> float:
    """Magnetic heading of a body-frame (FRD) field levelled by roll and pitch (tilt compensation)."""
    mx, my, mz = (float(v) for v in field_frd)
    cr, sr, cp, sp = math.cos(roll_rad), math.sin(roll_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    xh = mx * cp + my * sr * sp + mz * cr * sp
    yh = my * cr - mz * sr
    return math.atan2(-yh, xh)


class HeadingOffset:
    """The angle from a magnetic heading to the true heading (declination plus what the compass's calibration leaves),
    learnt as the circular mean of (reference yaw - magnetic heading) over ``window_s`` while the reference is good
    (the autopilot's yaw with GNSS) and held otherwise."""

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self._d: deque[tuple[float, float, float]] = deque()  # t, cos, sin
        self._sum = np.zeros(2)

    def add(self, t_s: float, yaw_rad: float, mag_heading: float) -> None:
        c, s_ = math.cos(yaw_rad - mag_heading), math.sin(yaw_rad - mag_heading)
        self._d.append((t_s, c, s_))
        self._sum += (c, s_)
        while self._d and self._d[0][0] < t_s - self.window_s:
            _, a, b = self._d.popleft()
            self._sum -= (a, b)

    @property
    def offset_rad(self) -> float | None:
        return math.atan2(self._sum[1], self._sum[0]) if len(self._d) >= 10 else None


class LowPass:
    """First-order low-pass dy/dt = (x - y) / tau on irregular samples, exact for x held over each step:
    y += (1 - exp(-dt / tau)) (x - y). tau = 0 passes x through; a step back in time restarts it at x."""

    def __init__(self, tau_s: float) -> None:
        if not tau_s >= 0:
            raise ValueError("a low-pass time constant must be >= 0")
        self.tau_s = float(tau_s)
        self.t: float | None = None
        self.y: np.ndarray | None = None

    def update(self, t_s: float, x) -> np.ndarray:
        x = np.asarray(x, float)
        if self.y is None or self.t is None or self.tau_s == 0 or t_s < self.t:
            self.y = x.copy()
        else:
            self.y = self.y + (1.0 - math.exp(-(t_s - self.t) / self.tau_s)) * (x - self.y)
        self.t = float(t_s)
        return self.y.copy()


@dataclass(frozen=True)
class AirDataConfig:
    wind_window_s: float = 300.0  # the wind held at the loss: the mean of GNSS minus air velocity over this long
    air_max_age_s: float = 1.0  # an airspeed or heading older than this is not used (the last velocity is kept)
    min_airspeed_mps: float = 5.0  # below: not flying on the wing, no air velocity (nor wind sample)
    history_s: float = 120.0  # the reference is kept this far back (a reading describes a past position)
    output_tau_s: float = 1.0  # the stated velocity's low-pass (module doc; docs/decisions/0016)

    def __post_init__(self) -> None:
        if not (self.wind_window_s > 0 and self.air_max_age_s > 0 and self.history_s > 0 and self.min_airspeed_mps >= 0):
            raise ValueError("air-data windows and ages must be > 0")
        if not self.output_tau_s >= 0:
            raise ValueError("output_tau_s must be >= 0")


class AirDataReckoner:
    """GNSS fixes, airspeed and heading in (vehicle time, any order of kinds, each kind in time order) -> the
    reference (lat, lon, v_n, v_e) at any time of the last ``history_s``: the receiver's while it has a fix, air-data
    dead reckoning after. ``wind_ne_mps``: the wind learnt (and held without GNSS)."""

    def __init__(self, cfg: AirDataConfig | None = None) -> None:
        self.cfg = cfg or AirDataConfig()
        self._air: tuple[float, float, float] | None = None  # t, air velocity N, E (TAS along the heading)
        self._tas: tuple[float, float] | None = None  # t, TAS
        self._yaw: tuple[float, float] | None = None  # t, yaw
        self._wind: deque[tuple[float, float, float]] = deque()  # t, wind N, E samples
        self._wind_sum = np.zeros(2)
        self.wind_held: np.ndarray | None = None  # the wind used for dead reckoning (the window's mean at the loss)
        self.t: float | None = None
        self.lat = self.lon = math.nan
        self.vel = np.zeros(2)
        self._out = LowPass(self.cfg.output_tau_s)
        self.hist: deque[tuple[float, ...]] = deque()  # t, lat, lon, v_n, v_e, low-passed v_n, v_e
        self.stale_steps = 0  # dead-reckoning steps without a recent air velocity (the last velocity kept)

    # -- inputs ------------------------------------------------------------------------------------
    def airspeed(self, t_s: float, tas_mps: float) -> None:
        if math.isfinite(tas_mps):
            self._tas = (t_s, float(tas_mps))
            self._air_now()

    def heading(self, t_s: float, yaw_rad: float) -> None:
        if math.isfinite(yaw_rad):
            self._yaw = (t_s, float(yaw_rad))
            self._air_now()

    def _air_now(self) -> None:
        if self._tas is None or self._yaw is None or abs(self._tas[0] - self._yaw[0]) > self.cfg.air_max_age_s:
            return
        t = max(self._tas[0], self._yaw[0])
        v = self._tas[1] if self._tas[1] >= self.cfg.min_airspeed_mps else 0.0
        self._air = (t, v * math.cos(self._yaw[1]), v * math.sin(self._yaw[1]))

    def air_velocity(self, t_s: float) -> np.ndarray | None:
        a = self._air
        if a is None or abs(t_s - a[0]) > self.cfg.air_max_age_s:
            return None
        return np.array([a[1], a[2]])

    def gnss(self, t_s: float, lat_deg: float, lon_deg: float, vel_ne_mps=None) -> None:
        """A good receiver fix: the reference is the receiver's; with its velocity and a recent air velocity, one
        wind sample."""
        self.wind_held = None
        v = None if vel_ne_mps is None else np.asarray(vel_ne_mps, float)
        air = self.air_velocity(t_s)
        if v is not None and np.all(np.isfinite(v)) and air is not None and np.hypot(*air) > 0:
            w = v - air
            self._wind.append((t_s, float(w[0]), float(w[1])))
            self._wind_sum += w
            while self._wind and self._wind[0][0] < t_s - self.cfg.wind_window_s:
                _, a, b = self._wind.popleft()
                self._wind_sum -= (a, b)
        self._set(t_s, float(lat_deg), float(lon_deg), v if v is not None and np.all(np.isfinite(v)) else self.vel)

    @property
    def wind_ne_mps(self) -> np.ndarray | None:
        if self.wind_held is not None:
            return self.wind_held
        return self._wind_sum / len(self._wind) if self._wind else None

    @property
    def wind_samples(self) -> int:
        return len(self._wind)

    def gust_stats(self, avg_s: float, walk_s: float = 60.0) -> tuple[float, float]:
        """What the wind's fast part (gusts, air-data noise) does to the dead reckoning, measured over the wind window
        (GNSS minus air velocity about its mean): (1-sigma per axis of its mean over ``avg_s``, m/s; the position
        random walk it drives, m/sqrt(s): sqrt(var(its integral over walk_s) / walk_s)). (0, 0) with too few samples."""
        if len(self._wind) < 20:
            return 0.0, 0.0
        a = np.asarray(self._wind, float)
        t, w = a[:, 0], a[:, 1:] - a[:, 1:].mean(axis=0)
        dt = float(t[-1] - t[0]) / (t.size - 1)  # the mean spacing (a receiver may repeat a fix's time stamp)
        if not dt > 0:
            return 0.0, 0.0

        def block(seconds: float) -> np.ndarray:  # running means over `seconds`
            n = max(1, int(round(seconds / dt)))
            if n >= len(w):
                return np.zeros((1, 2))
            c = np.cumsum(np.vstack([np.zeros((1, 2)), w]), axis=0)
            return (c[n:] - c[:-n]) / n

        sig_avg = float(np.sqrt(np.mean(block(max(avg_s, dt)) ** 2)))
        walk = float(np.sqrt(np.mean((block(walk_s) * walk_s) ** 2) / walk_s))
        return sig_avg, walk

    def mean_velocity(self, t0_s: float, t1_s: float) -> np.ndarray | None:
        """The reference's mean horizontal velocity over [t0, t1] (the kept states in it; None: none kept)."""
        v = [(a[3], a[4]) for a in self.hist if t0_s <= a[0] <= t1_s]
        return np.mean(np.asarray(v, float), axis=0) if v else None

    # -- dead reckoning ----------------------------------------------------------------------------
    def advance(self, t_s: float) -> bool:
        """Dead-reckon to t_s (no GNSS since the last fix). False before the first fix or wind sample."""
        if self.t is None or t_s <= self.t:
            return self.t is not None and self.wind_ne_mps is not None
        if self.wind_held is None:
            if not self._wind:
                return False
            self.wind_held = self._wind_sum / len(self._wind)
        air = self.air_velocity(t_s)
        if air is None:
            self.stale_steps += 1
            v = self.vel
        else:
            v = air + self.wind_held
        dt = t_s - self.t
        vm = 0.5 * (self.vel + v)
        rm, rn = radii_m(self.lat)
        lat = self.lat + math.degrees(vm[0] * dt / rm)
        lon = self.lon + math.degrees(vm[1] * dt / (rn * math.cos(math.radians(self.lat))))
        self._set(t_s, lat, lon, v)
        return True

    def _set(self, t_s: float, lat: float, lon: float, v: np.ndarray) -> None:
        self.t, self.lat, self.lon, self.vel = float(t_s), lat, lon, np.asarray(v, float).copy()
        o = self._out.update(self.t, self.vel)
        self.hist.append((self.t, lat, lon, float(v[0]), float(v[1]), float(o[0]), float(o[1])))
        while self.hist and self.hist[0][0] < self.t - self.cfg.history_s:
            self.hist.popleft()

    def at(self, t_s: float) -> tuple[float, float, float, float] | None:
        """(lat, lon, v_n, v_e) of the reference at t_s, linear between kept states; None outside the history."""
        r = self._interp(t_s)
        return None if r is None else r[:4]  # type: ignore[return-value]

    def output_velocity(self, t_s: float) -> np.ndarray | None:
        """The stated (low-passed) velocity N, E at t_s, linear between kept states; None outside the history."""
        r = self._interp(t_s)
        return None if r is None else np.array(r[4:6])

    def _interp(self, t_s: float) -> tuple[float, ...] | None:
        h = self.hist
        if not h or t_s < h[0][0] or t_s > h[-1][0]:
            return None
        lo, hi = 0, len(h) - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if h[mid][0] <= t_s:
                lo = mid
            else:
                hi = mid
        a, b = h[lo], h[hi]
        w = 0.0 if b[0] <= a[0] else (t_s - a[0]) / (b[0] - a[0])
        return tuple(a[i] + w * (b[i] - a[i]) for i in range(1, 7))
