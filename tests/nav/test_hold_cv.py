"""Hold / constant-velocity model mixing of the kinematic filter (companion.nav.hold_cv) on simulated truth: the IMM
picks hold on a hover and CV on a constant-velocity track, and its blockage extrapolation follows the model it picked;
in the navigator's kinematic mode it is no worse than hold-last-fix on a hover."""

import math

import numpy as np
import pytest

from companion.events import Attitude, GnssFix
from companion.nav.hold_cv import CV, HOLD, HoldCvConfig, HoldCvFilter
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState

H = np.hstack([np.eye(3), np.zeros((3, 3))])
R = np.eye(3) * 0.3**2


def _track(velocity_mps, n, rng, noise_m=0.3, wander_m=0.0):
    """Fixes at 1 Hz: a hover (velocity 0, slow wander of wander_m) or a straight line at velocity_mps, with white
    noise of noise_m."""
    t = np.arange(n, dtype=float)
    p = np.outer(t, velocity_mps)
    p[:, 0] += wander_m * np.sin(2 * np.pi * t / 40.0)
    p[:, 1] += wander_m * np.cos(2 * np.pi * t / 55.0)
    return t, p + rng.normal(0, noise_m, p.shape), p


def _run(t, z, v0=(0.0, 0.0, 0.0)):
    f = HoldCvFilter(np.r_[z[0], v0], np.diag([9.0, 9.0, 25.0, 4.0, 4.0, 4.0]), 2.0)
    mus = []
    for k in range(1, len(t)):
        f.predict(t[k] - t[k - 1])
        f.update(z[k].reshape(3, 1), R, H)
        mus.append(f.mu.copy())
    return f, np.array(mus)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_hold_picked_on_a_simulated_hover(seed):
    rng = np.random.default_rng(seed)
    t, z, truth = _track(np.zeros(3), 60, rng, wander_m=0.3)
    f, mus = _run(t, z)
    assert mus[20:, HOLD].mean() > 0.8
    # a 5 s blockage: the mixture stays near the hover point, far closer than the velocity it had noisily learnt
    for _ in range(50):
        f.predict(0.1)
    assert np.hypot(*(f.x[0:2, 0] - truth[-1, :2])) < 1.0


@pytest.mark.parametrize("speed", [2.0, 5.0])
def test_cv_picked_on_a_simulated_constant_velocity_track(speed):
    rng = np.random.default_rng(4)
    v = np.array([speed * 0.8, speed * 0.6, 0.0])
    t, z, truth = _track(v, 60, rng)
    f, mus = _run(t, z, v0=v)
    assert mus[20:, CV].mean() > 0.9
    for _ in range(50):  # 5 s blockage: the mixture keeps flying the velocity (hold would be 5 x speed off; the rest
        f.predict(0.1)  # is the CV model's own velocity error from 0.3 m fixes, and the mode probability's decay)
    assert np.hypot(*(f.x[0:2, 0] - (truth[-1, :2] + 5.0 * v[:2]))) < 0.4 * 5.0 * speed


def test_cv_probability_grows_with_speed():
    """Hold while the vehicle wanders within a hover's speeds, CV from about the hover detector's 0.7 m/s bound on."""
    share = []
    for speed in (0.0, 0.3, 1.0, 1.5, 3.0):
        mus = [_run(*_track(np.array([speed, 0.0, 0.0]), 60, np.random.default_rng(s))[:2],
                    v0=(speed, 0.0, 0.0))[1][20:, CV].mean() for s in range(5)]
        share.append(float(np.mean(mus)))
    assert share[0] < 0.1 and share[1] < 0.2 and share[-1] > 0.95
    assert all(a < b for a, b in zip(share, share[1:]))


def test_switches_when_the_vehicle_stops():
    rng = np.random.default_rng(5)
    t1, z1, _ = _track(np.array([3.0, 0.0, 0.0]), 30, rng)
    t2 = np.arange(30, 70, dtype=float)
    z2 = np.tile(z1[-1] - rng.normal(0, 0.3, 3) + [3.0, 0, 0], (len(t2), 1)) + rng.normal(0, 0.3, (len(t2), 3))
    _, mus = _run(np.r_[t1, t2], np.vstack([z1, z2]), v0=(3.0, 0.0, 0.0))
    assert mus[20:29, CV].mean() > 0.9
    assert mus[-15:, HOLD].mean() > 0.8


def test_pseudo_measurement_is_no_evidence():
    rng = np.random.default_rng(6)
    t, z, _ = _track(np.zeros(3), 20, rng)
    f, _ = _run(t, z)
    mu = f.mu.copy()
    f.update(z[-1].reshape(3, 1) + 5.0, R, H, evidence=False)
    assert np.array_equal(f.mu, mu)


def test_config_validated():
    with pytest.raises(ValueError):
        HoldCvConfig(dwell_s=0.0)


def _kin_hover_events(rng, n=90, wander_m=0.4):
    """A hovering vehicle without IMU (kinematic mode): 1 Hz fixes with a noisy receiver velocity, and the autopilot's
    attitude at 10 Hz (the stream goes on through a GNSS blockage)."""
    lat0, lon0, alt0 = -35.3632, 149.1652, 600.0
    ev, truth = [], []
    for k in range(n):
        t = 100.0 + k + 0.05
        pn, pe = wander_m * np.sin(2 * np.pi * t / 40.0), wander_m * np.cos(2 * np.pi * t / 55.0)
        truth.append((t, pn, pe))
        mn, me = pn + rng.normal(0, 0.2), pe + rng.normal(0, 0.2)
        vn, ve = rng.normal(0, 0.3, 2)
        ev.append(GnssFix(round(t, 6), 3, lat0 + mn / 111_000.0, lon0 + me / 91_000.0, alt0, float(vn), float(ve),
                          0.0, None, None, 12, 0.8, 1.2, 0.8, 1.2, 0.3, None, None))
    ev += [Attitude(round(100.0 + k / 10.0, 6), 0.0, 0.0, 0.0) for k in range(n * 10)]
    ev.sort(key=lambda x: x.t_s)
    return ev, np.array(truth), (lat0, lon0)


def test_kinematic_navigator_no_worse_than_hold_on_a_hover():
    rng = np.random.default_rng(7)
    ev, truth, (lat0, lon0) = _kin_hover_events(rng)
    gap = (150.0, 154.0)  # 4 s blockage (longer is a stream gap: GNSS only)
    kept = [e for e in ev if not gap[0] <= e.t_s < gap[1]]
    err = {}
    for name, on in (("mixed", True), ("cv", False)):
        out = run_navigator(kept, NavigatorConfig(kinematic_hold_cv=on))
        fs = [o for o in out if isinstance(o, FusedState) and gap[0] <= o.t_s < gap[1]]
        assert fs and all(o.mode == "kinematic" for o in fs)
        t = np.array([o.t_s for o in fs])
        n = np.interp(t, truth[:, 0], truth[:, 1])
        e = np.interp(t, truth[:, 0], truth[:, 2])
        dn = np.array([(o.lat_deg - lat0) * 111_000.0 for o in fs]) - n
        de = np.array([(o.lon_deg - lon0) * 91_000.0 for o in fs]) - e
        err[name] = math.sqrt(np.mean(dn**2 + de**2))
    last = [e for e in kept if isinstance(e, GnssFix) and e.t_s < gap[0]][-1]  # hold-last-fix: the fix as measured
    hn, he = (last.lat_deg - lat0) * 111_000.0, (last.lon_deg - lon0) * 91_000.0
    m = (truth[:, 0] >= gap[0]) & (truth[:, 0] < gap[1])
    hold = math.sqrt(np.mean((truth[m, 1] - hn) ** 2 + (truth[m, 2] - he) ** 2))
    assert err["mixed"] <= 1.1 * hold
    assert err["mixed"] < err["cv"]


class _ReferenceImm:
    """The IMM written as in the textbook (Bar-Shalom, Li & Kirubarajan sec. 11.6.6), with numpy's eye / sum and the
    likelihood computed at every update: HoldCvFilter computes the same operations in the same order, faster."""

    def __init__(self, x0, P0, accel_sigma_mps2, config=HoldCvConfig()):
        from companion.nav.kalman import KalmanFilter

        self.c, self.s = config, accel_sigma_mps2
        self.models = [KalmanFilter(6, 3), KalmanFilter(6, 3)]
        hold = self.models[HOLD]
        hold.x = np.asarray(x0, float).reshape(6, 1).copy()
        hold.x[3:6, 0] = 0.0
        hold.P = np.asarray(P0, float).copy()
        hold.P[3:6, :] = 0.0
        hold.P[:, 3:6] = 0.0
        hold.P[3:6, 3:6] = np.eye(3) * 1e-4
        self.models[CV].x, self.models[CV].P = np.asarray(x0, float).reshape(6, 1).copy(), np.asarray(P0, float).copy()
        self.mu = np.array([0.5, 0.5])
        self._combine()

    def predict(self, dt):
        p = 1.0 - math.exp(-dt / self.c.dwell_s)
        M = np.array([[1.0 - p, p], [p, 1.0 - p]])
        c = M.T @ self.mu
        xs, Ps = [m.x for m in self.models], [m.P for m in self.models]
        for j, m in enumerate(self.models):
            w = M[:, j] * self.mu / c[j]
            x0 = w[0] * xs[0] + w[1] * xs[1]
            m.x, m.P = x0, sum(w[i] * (Ps[i] + (xs[i] - x0) @ (xs[i] - x0).T) for i in range(2))
        self.mu = c
        F = np.eye(6)
        F[3:6, 3:6] = 0.0
        Q = np.zeros((6, 6))
        Q[0:3, 0:3] = np.eye(3) * (self.c.hold_speed_mps * dt) ** 2
        Q[3:6, 3:6] = np.eye(3) * 1e-4
        self.models[HOLD].predict(F, Q)
        Fc = np.eye(6)
        Fc[0:3, 3:6] = np.eye(3) * dt
        s2 = self.s**2
        Qc = np.zeros((6, 6))
        Qc[0:3, 0:3] = np.eye(3) * dt**4 / 4 * s2
        Qc[0:3, 3:6] = Qc[3:6, 0:3] = np.eye(3) * dt**3 / 2 * s2
        Qc[3:6, 3:6] = np.eye(3) * dt**2 * s2
        self.models[CV].predict(Fc, Qc)
        self._combine()

    def update(self, z, R_, H_, evidence=True):
        like = np.empty(2)
        for j, m in enumerate(self.models):
            y = z - H_ @ m.x
            S = H_ @ m.P @ H_.T + R_
            like[j] = float(np.exp(-0.5 * (y.T @ np.linalg.inv(S) @ y).item())
                            / math.sqrt(max(np.linalg.det(2 * math.pi * S), 1e-300)))
            m.update(z, R=R_, H=H_)
        if evidence:
            mu = self.mu * like
            if mu.sum() > 0 and math.isfinite(mu.sum()):
                self.mu = mu / mu.sum()
            self.mu = np.clip(self.mu, self.c.min_prob, 1.0 - self.c.min_prob)
            self.mu /= self.mu.sum()
        self._combine()

    def _combine(self):
        xs = [m.x for m in self.models]
        self.x = self.mu[0] * xs[0] + self.mu[1] * xs[1]
        self.P = sum(self.mu[j] * (m.P + (xs[j] - self.x) @ (xs[j] - self.x).T) for j, m in enumerate(self.models))


@pytest.mark.parametrize("seed", [0, 1])
def test_imm_equals_the_textbook_formulation(seed):
    """Mixed steps (uneven dt, fixes as evidence, pseudo-measurements that are not, a delayed-fix Jacobian with -0.0
    entries): every state, covariance and mode probability equal to the textbook's to 1e-12 over 400 steps (the
    mixture's spread as one outer product and the closed-form small inverse change the rounding, nothing else)."""
    rng = np.random.default_rng(seed)
    x0, P0 = np.r_[rng.normal(0, 5, 3), rng.normal(0, 1, 3)], np.diag([9.0, 9.0, 25.0, 4.0, 4.0, 4.0])
    a, b = HoldCvFilter(x0, P0, 2.0), _ReferenceImm(x0, P0, 2.0)
    Hd = np.hstack([np.eye(3), -0.2 * np.eye(3)])
    v = rng.normal(0, 2, 3)
    for k in range(400):
        dt = float(rng.choice([0.1, 0.1, 0.05, 0.37, 1.0]))
        a.predict(dt)
        b.predict(dt)
        z = (v * k * 0.1 + rng.normal(0, 0.5, 3)).reshape(3, 1)
        evidence = bool(k % 7 == 0)
        Hk = Hd if k % 3 == 0 else H
        a.update(z, R, Hk, evidence=evidence)
        b.update(z, R, Hk, evidence=evidence)
        for u, w in ((a.x, b.x), (a.P, b.P), (a.mu, b.mu)):
            np.testing.assert_allclose(u, w, rtol=1e-12, atol=1e-12 * np.abs(w).max())
