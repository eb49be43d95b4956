"""A heading that a GNSS-denied autopilot's estimate cannot move: the vehicle's own z-gyro, integrated.

The air-data reference (companion.gravity.air_data) needs a heading. The autopilot's (EKF3's ATTITUDE yaw) follows the
fixes the companion sends it in a GNSS outage (docs/decisions/0012); the gyro does not. The heading rate is the body
rates levelled by the autopilot's roll and pitch (ZYX Euler kinematics):

    psi' = (q sin(roll) + r cos(roll)) / cos(pitch)

with roll and pitch interpolated to each gyro sample's time (a sample waits for the next ATTITUDE), integrated
(trapezoid) into ``I(t)``. While GNSS is good, ``d(t) = I(t) - yaw(t)`` (yaw: ATTITUDE, unwrapped) is
fitted by a line ``a + b t`` over the last ``window_s``: ``b`` is the z-gyro bias (plus the earth rate's vertical
part), ``a`` the alignment. The heading is ``I(t) - (a + b t)``. At a GNSS loss the fit is frozen (``freeze``):
nothing from the yaw in the outage reaches the heading; the fit resumes when GNSS is back (``thaw``).

Its stated 1-sigma error ``tau`` after the freeze (``sigma_rad``) is

    sigma^2 = sigma_a^2 + (sigma_b tau)^2 + arw^2 tau + walk^2 tau^3 / 3

with sigma_a, sigma_b the fit's (its residual scatter over ``n = span / yaw_corr_s`` independent samples: the yaw's
errors are correlated; floored by ``align_floor_deg``, the yaw's own error with GNSS: sigma_a at it, sigma_b at the
slope it makes across the window, sqrt(12) floor / span), ``arw`` the integration's
angle random walk and ``walk`` the bias's in-run drift (a rate random walk). The same four terms are the gravity
filter's heading-error and z-gyro-bias states (companion.gravity.sequential ``InsErrorSpec.air_heading``).
Pure: vehicle time only.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

DEGPH = math.radians(1.0) / 3600.0  # rad/s per deg/h
#: gravity.air_gyro_source -> the ImuSample index its gyro arrives as (companion.mavlink.decode)
GYRO_SOURCES = {"RAW_IMU": 0, "HIGHRES_IMU": 3}


def heading_rate_radps(gyro_frd_radps, roll_rad: float, pitch_rad: float) -> float:
    """The yaw (heading) rate of body rates (p, q, r) at a roll and pitch: (q sin roll + r cos roll) / cos pitch."""
    _, q, r = (float(v) for v in gyro_frd_radps)
    c = math.cos(pitch_rad)
    return (q * math.sin(roll_rad) + r * math.cos(roll_rad)) / (c if abs(c) > 1e-3 else math.copysign(1e-3, c))


def wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class GyroHeadingConfig:
    window_s: float = 1200.0  # the bias and alignment are fitted over this much of the latest GNSS period
    min_fit_s: float = 60.0  # ... once it spans this long (before: no heading)
    yaw_corr_s: float = 120.0  # the reference yaw's errors are correlated over this long (EKF3: minutes)
    align_floor_deg: float = 0.5  # the alignment is never stated better than this (the yaw's own error with GNSS)
    arw_deg_rth: float = 0.5  # angle random walk of the integration (sensor noise, sampling in turns), deg/sqrt(h)
    bias_walk_degph_rth: float = 5.0  # the bias's in-run drift, deg/h per sqrt(h)
    max_gap_s: float = 0.5  # a longer gap between gyro samples is counted (the rate is bridged linearly)
    max_att_age_s: float = 0.5  # a roll/pitch older than this does not level a sample (the sample is skipped)

    def __post_init__(self) -> None:
        if not (self.window_s > self.min_fit_s > 0 and self.yaw_corr_s > 0 and self.align_floor_deg >= 0
                and self.arw_deg_rth >= 0 and self.bias_walk_degph_rth >= 0 and self.max_gap_s > 0):
            raise ValueError("gyro heading: windows > 0 (window_s > min_fit_s), sigmas >= 0")


class GyroHeading:
    """``attitude`` (roll, pitch, and the yaw to learn from while ``learn``) and ``gyro`` (body rates) in, in time
    order; ``heading_rad(t)`` out (None until the fit spans ``min_fit_s``); ``freeze``/``thaw`` at a GNSS loss/return."""

    def __init__(self, cfg: GyroHeadingConfig | None = None) -> None:
        self.cfg = cfg or GyroHeadingConfig()
        self._att: tuple[float, float, float] | None = None  # t, roll, pitch
        self._t: float | None = None  # last gyro sample
        self._rate = 0.0
        self.integral_rad = 0.0  # I(t) at the last gyro sample
        self._d: deque[tuple[float, float]] = deque()  # (t, I - yaw unwrapped) while learning
        self._t0: float | None = None  # time origin of the sums
        self._s = [0.0] * 5  # n, sum t, sum d, sum t^2, sum t d  (t relative to _t0)
        self._line: tuple[float, float] | None = None  # a, b (time origin _t0) of the current window
        self._fit: tuple[float, float, float, float, float] | None = None  # a, b, sigma_a, sigma_b, t_end
        self.frozen_t: float | None = None
        self.gaps = 0  # gyro gaps longer than max_gap_s
        self.unlevelled = 0  # gyro samples without a recent roll/pitch
        self._prev_att: tuple[float, float, float] | None = None
        self._pending: deque[tuple[float, tuple]] = deque()  # gyro samples newer than the last attitude

    # -- inputs ------------------------------------------------------------------------------------
    def gyro(self, t_s: float, gyro_frd_radps) -> None:
        """A gyro sample: integrated once an attitude at or after its time has arrived (roll and pitch interpolated to
        its time: in turbulence q and roll are correlated, and a roll held from up to one ATTITUDE period earlier
        rectifies q sin(roll) into a drift of tens of deg/h); until then it waits, at most ``max_att_age_s``."""
        self._pending.append((float(t_s), tuple(gyro_frd_radps)))
        a = self._att
        while self._pending and (a is None or self._pending[0][0] < a[0] - self.cfg.max_att_age_s
                                 or t_s - self._pending[0][0] > self.cfg.max_att_age_s):
            self._integrate(*self._pending.popleft())  # no attitude around it: levelled by the last (or counted)

    def _levelled(self, t_s: float) -> tuple[float, float] | None:
        a, p = self._att, self._prev_att
        if a is None or abs(t_s - a[0]) > self.cfg.max_att_age_s and (p is None or abs(t_s - p[0]) > self.cfg.max_att_age_s):
            return None
        if p is not None and p[0] <= t_s <= a[0] and a[0] > p[0]:
            w = (t_s - p[0]) / (a[0] - p[0])
            return p[1] + w * wrap_pi(a[1] - p[1]), p[2] + w * (a[2] - p[2])
        return a[1], a[2]

    def _integrate(self, t_s: float, gyro_frd_radps) -> None:
        lv = self._levelled(t_s)
        if lv is None:
            self.unlevelled += 1
            return
        rate = heading_rate_radps(gyro_frd_radps, lv[0], lv[1])
        if not math.isfinite(rate):
            return
        if self._t is not None:
            dt = t_s - self._t
            if dt <= 0:
                return
            if dt > self.cfg.max_gap_s:
                self.gaps += 1
            self.integral_rad += 0.5 * (self._rate + rate) * dt
        self._t, self._rate = float(t_s), rate

    def attitude(self, t_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float, learn: bool) -> None:
        self._prev_att, self._att = self._att, (float(t_s), float(roll_rad), float(pitch_rad))
        while self._pending and self._pending[0][0] <= t_s:
            self._integrate(*self._pending.popleft())
        if learn and self.frozen_t is None and self._t is not None and abs(t_s - self._t) <= self.cfg.max_gap_s:
            self._learn(float(t_s), self.integral_at(t_s) - float(yaw_rad))

    def _learn(self, t_s: float, d: float) -> None:
        if self._d:
            d = self._d[-1][1] + wrap_pi(d - self._d[-1][1])  # unwrap against the last sample
        if self._t0 is None:
            self._t0 = t_s
        self._d.append((t_s, d))
        self._add(t_s, d, +1.0)
        while self._d and self._d[0][0] < t_s - self.cfg.window_s:
            self._add(*self._d.popleft(), -1.0)
        self._line = self._fit = None

    def _add(self, t_s: float, d: float, sign: float) -> None:
        x = t_s - self._t0
        s = self._s
        s[0] += sign
        s[1] += sign * x
        s[2] += sign * d
        s[3] += sign * x * x
        s[4] += sign * x * d

    # -- the fit -----------------------------------------------------------------------------------
    def line(self) -> tuple[float, float] | None:
        """(a, b) of d = a + b (t - t0) over the window, or None (span < min_fit_s)."""
        if self._line is not None:
            return self._line
        if len(self._d) < 3 or self._d[-1][0] - self._d[0][0] < self.cfg.min_fit_s:
            return None
        n, st, sd, stt, std = self._s
        sxx = stt - st * st / n
        if not sxx > 0:
            return None
        b = (std - st * sd / n) / sxx
        self._line = ((sd - b * st) / n, b)
        return self._line

    def fit(self) -> tuple[float, float, float, float, float] | None:
        """(a, b, sigma_a at the window's end, sigma_b, the window's end) or None (span < min_fit_s)."""
        if self._fit is not None:
            return self._fit
        ln = self.line()
        if ln is None:
            return None
        a, b = ln
        n = self._s[0]
        t_end = self._d[-1][0]
        span = t_end - self._d[0][0]
        res2 = sum((d - a - b * (t - self._t0)) ** 2 for t, d in self._d) / max(n - 2, 1)
        n_ind = max(2.0, span / self.cfg.yaw_corr_s)
        # n_ind independent samples spread evenly over the span: var(slope) = s^2 12 / (n span^2); the line at the
        # window's end (span / 2 from its centre): s^2 (1/n + 3/n) = 4 s^2 / n
        # ... and never better than a drift of the yaw by its own error (align_floor_deg) across the window would make it
        sig_b = max(math.sqrt(res2 * 12.0 / (n_ind * span * span)),
                    math.sqrt(12.0) * math.radians(self.cfg.align_floor_deg) / span)
        sig_a = math.hypot(math.sqrt(4.0 * res2 / n_ind), math.radians(self.cfg.align_floor_deg))
        self._fit = (a, b, sig_a, sig_b, t_end)
        return self._fit

    def integral_at(self, t_s: float) -> float:
        """I(t): the last sample's integral, carried at the last rate to t_s."""
        if self._t is None:
            return math.nan
        return self.integral_rad + self._rate * (t_s - self._t)

    def heading_rad(self, t_s: float) -> float | None:
        ln = self.line()
        if ln is None or self._t is None:
            return None
        a, b = ln
        return wrap_pi(self.integral_at(t_s) - (a + b * (t_s - self._t0)))

    @property
    def bias_radps(self) -> float | None:
        ln = self.line()
        return None if ln is None else ln[1]

    # -- a GNSS outage -----------------------------------------------------------------------------
    def freeze(self, t_s: float) -> None:
        """A GNSS loss: the fit (bias and alignment) is kept as it is, whatever yaw comes in."""
        if self.frozen_t is None:
            self.fit()
            self.frozen_t = float(t_s)

    def thaw(self) -> None:
        self.frozen_t = None

    def sigmas(self) -> tuple[float, float, float, float] | None:
        """(sigma_a rad, sigma_b rad/s, arw rad/sqrt(s), bias walk rad/s/sqrt(s)) of the current fit."""
        f = self.fit()
        if f is None:
            return None
        c = self.cfg
        return f[2], f[3], math.radians(c.arw_deg_rth) / 60.0, c.bias_walk_degph_rth * DEGPH / 60.0

    def sigma_rad(self, t_s: float) -> float | None:
        """The stated 1-sigma heading error at t_s: since the freeze (module doc), or the alignment's while learning."""
        s = self.sigmas()
        if s is None:
            return None
        sa, sb, arw, walk = s
        f = self._fit
        tau = max(0.0, t_s - (self.frozen_t if self.frozen_t is not None else f[4]))
        return math.sqrt(sa * sa + (sb * tau) ** 2 + arw * arw * tau + walk * walk * tau**3 / 3.0)
