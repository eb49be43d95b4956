"""The 2-D Monte Carlo scenario model of the gravity-matching benchmarks: a planar track (`ScenarioTrack`), the
INS drift along it (psi-angle error model) and the gravimeter (noise, Eotvos). Not the flight simulator
(companion.sim.flight): no attitude, no IMU samples, no MAVLink; it is what the papers' designs need, fast.

Everything is in metres north/east of a LocalGravityMap frame. Every random draw takes the caller's
numpy Generator, so a scenario is reproducible from its seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from companion.constants import EARTH_RATE_RADPS, G0_MPS2, WGS84_A_M
from companion.gravity.eotvos import correct_eotvos_mgal, eotvos_from_ne_mgal
from companion.gravity.maps import LocalGravityMap

UG_MPS2 = 1e-6 * G0_MPS2
DEGPH_RADPS = np.radians(1.0) / 3600.0


# ---- trajectories --------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScenarioTrack:
    t_s: np.ndarray  # (n,)
    pos_ne_m: np.ndarray  # (n, 2)
    vel_ne_mps: np.ndarray  # (n, 2)
    acc_ne_mps2: np.ndarray  # (n, 2)
    heading_rad: np.ndarray  # (n,) from north, clockwise

    def __len__(self) -> int:
        return self.t_s.size

    def distance_m(self) -> np.ndarray:
        """Cumulative along-track distance."""
        return np.r_[0.0, np.cumsum(np.hypot(*np.diff(self.pos_ne_m, axis=0).T))]


@dataclass(frozen=True)
class Segment:
    """Constant speed and curvature for duration_s (curvature 1/m, positive turns right/clockwise)."""

    duration_s: float
    curvature_per_m: float = 0.0


def turn(angle_deg: float, radius_m: float, speed_mps: float) -> Segment:
    """A turn of angle_deg (positive = right) on radius_m at speed_mps."""
    dur = abs(np.radians(angle_deg)) * radius_m / speed_mps
    return Segment(dur, np.sign(angle_deg) / radius_m)


def make_trajectory(speed_mps: float, segments: Sequence[Segment], dt_s: float = 1.0, heading0_deg: float = 90.0,
                    start_ne_m=(0.0, 0.0)) -> ScenarioTrack:
    """Piecewise constant-curvature track at constant speed (straight: curvature 0)."""
    if speed_mps <= 0 or dt_s <= 0 or not segments:
        raise ValueError("need speed > 0, dt > 0 and at least one segment")
    total = sum(s.duration_s for s in segments)
    t = np.arange(0.0, total + 0.5 * dt_s, dt_s)
    durs = np.array([s.duration_s for s in segments], float)
    ends = np.cumsum(durs)
    starts = ends - durs
    seg_rate = speed_mps * np.array([s.curvature_per_m for s in segments])  # heading rate rad/s
    h_start = np.radians(heading0_deg) + np.r_[0.0, np.cumsum(seg_rate * durs)[:-1]]
    idx = np.minimum(np.searchsorted(ends, t, side="right"), len(segments) - 1)
    rate = seg_rate[idx]
    heading = h_start[idx] + rate * (t - starts[idx])  # exact piecewise-linear heading
    vel = speed_mps * np.column_stack([np.cos(heading), np.sin(heading)])
    pos = np.asarray(start_ne_m, float) + np.r_[np.zeros((1, 2)), np.cumsum(0.5 * (vel[1:] + vel[:-1]) * np.diff(t)[:, None], axis=0)]
    acc = rate[:, None] * speed_mps * np.column_stack([-np.sin(heading), np.cos(heading)])
    return ScenarioTrack(t, pos, vel, acc, heading)


# ---- INS error model -----------------------------------------------------------------------------
@dataclass(frozen=True)
class InsErrorModel:
    """Free-inertial error sources; biases are drawn once per run (1-sigma per axis), noises per step."""

    gyro_bias_degph: float = 0.01
    accel_bias_ug: float = 100.0
    gyro_arw_deg_rthr: float = 0.001
    accel_vrw_ug_rthz: float = 10.0
    init_pos_sigma_m: float = 0.0
    init_vel_sigma_mps: float = 0.0
    init_tilt_sigma_rad: float = 2e-5
    init_heading_sigma_rad: float = 1e-4
    # > 0: the INS's attitude is held by an attitude reference (an AHRS that the companion's navigator fuses, as on
    # a vehicle with a tactical-grade IMU): psi is then that reference's error, first-order Gauss-Markov with this
    # time constant and these stationary sigmas (exact discretisation, stationary start), not the integral of the
    # gyro errors, and the Schuler feedback is cut (the reference, not the INS position, sets the vertical); the
    # gyro terms and init_tilt/heading are unused. Mirrors companion.gravity.sequential_backends.error_dynamics.
    attitude_tau_s: float = 0.0
    attitude_tilt_sigma_rad: float = 0.0
    attitude_heading_sigma_rad: float = 0.0


@dataclass(frozen=True)
class InsOutput:
    pos_ne_m: np.ndarray
    vel_ne_mps: np.ndarray
    pos_err_ne_m: np.ndarray
    psi_ned_rad: np.ndarray
    gyro_bias_radps: np.ndarray  # drawn body-frame biases of this run
    accel_bias_mps2: np.ndarray


def simulate_ins(traj: ScenarioTrack, lat0_deg: float, model: InsErrorModel, rng: np.random.Generator) -> InsOutput:
    """Propagate the psi-angle error model (Titterton & Weston) along the true trajectory.

    dr' = dv;  dv' = f x psi + bias_a^n + noise - (g/R) dr  (Schuler);  psi' = -w_in x psi - bias_g^n - noise,
    with w_in = earth rate + transport rate at the true latitude; body biases rotate with heading. With
    model.attitude_tau_s > 0, psi is the attitude reference's Gauss-Markov error and the Schuler term is cut.
    """
    n = len(traj)
    R = WGS84_A_M
    g = G0_MPS2
    bg = rng.normal(0.0, model.gyro_bias_degph * DEGPH_RADPS, 3)
    ba = rng.normal(0.0, model.accel_bias_ug * UG_MPS2, 3)
    dt = np.diff(traj.t_s, prepend=traj.t_s[0])
    dt[0] = 0.0
    sq = np.sqrt(np.maximum(dt, 1e-12))
    wn_g = rng.normal(0.0, 1.0, (n, 3)) * (np.radians(model.gyro_arw_deg_rthr) / 60.0) / sq[:, None]
    wn_a = rng.normal(0.0, 1.0, (n, 2)) * (model.accel_vrw_ug_rthz * UG_MPS2) / sq[:, None]
    # an initial position error is a constant offset of the computed frame (psi-angle consistent: it
    # does not excite the Schuler loop), so it is added to the output, not to the error state
    off_n, off_e = rng.normal(0.0, model.init_pos_sigma_m, 2)
    rn = re = 0.0
    vn, ve = rng.normal(0.0, model.init_vel_sigma_mps, 2)
    pn, pe = rng.normal(0.0, model.init_tilt_sigma_rad, 2)
    pd = rng.normal(0.0, model.init_heading_sigma_rad)
    held = model.attitude_tau_s > 0
    if held:  # drawn after the free-INS draws, so a free INS's runs are unchanged by this mode
        att_sig = np.array([model.attitude_tilt_sigma_rad, model.attitude_tilt_sigma_rad, model.attitude_heading_sigma_rad])
        pn, pe, pd = rng.normal(0.0, 1.0, 3) * att_sig  # stationary start
        a_gm = np.exp(-dt / model.attitude_tau_s)
        att_w = rng.normal(0.0, 1.0, (n, 3)) * att_sig * np.sqrt(1.0 - a_gm**2)[:, None]
    schuler = 0.0 if held else g / R
    lat = np.radians(lat0_deg) + traj.pos_ne_m[:, 0] / R
    ch, sh = np.cos(traj.heading_rad), np.sin(traj.heading_rad)
    out_r = np.empty((n, 2))
    out_v = np.empty((n, 2))
    out_p = np.empty((n, 3))
    for k in range(n):
        h = dt[k]
        if h > 0:
            cl, sl = np.cos(lat[k]), np.sin(lat[k])
            vN, vE = traj.vel_ne_mps[k]
            aN, aE = traj.acc_ne_mps2[k]
            wx = EARTH_RATE_RADPS * cl + vE / R
            wy = -vN / R
            wz = -EARTH_RATE_RADPS * sl - vE * np.tan(lat[k]) / R
            # body -> nav (yaw only; ship is level)
            egn = ch[k] * bg[0] - sh[k] * bg[1] + wn_g[k, 0]
            ege = sh[k] * bg[0] + ch[k] * bg[1] + wn_g[k, 1]
            egd = bg[2] + wn_g[k, 2]
            ban = ch[k] * ba[0] - sh[k] * ba[1] + wn_a[k, 0]
            bae = sh[k] * ba[0] + ch[k] * ba[1] + wn_a[k, 1]
            # psi' = -w x psi - eps
            dpn = -(wy * pd - wz * pe) - egn
            dpe = -(wz * pn - wx * pd) - ege
            dpd = -(wx * pe - wy * pn) - egd
            # dv' = f x psi + grad - (g/R) dr, f = (aN, aE, -g)
            dvn = aE * pd + g * pe + ban - schuler * rn
            dve = -g * pn - aN * pd + bae - schuler * re
            vn += h * dvn
            ve += h * dve
            rn += h * vn  # semi-implicit Euler keeps the Schuler loop stable
            re += h * ve
            if held:
                pn, pe, pd = a_gm[k] * np.array([pn, pe, pd]) + att_w[k]
            else:
                pn += h * dpn
                pe += h * dpe
                pd += h * dpd
        out_r[k] = rn, re
        out_v[k] = vn, ve
        out_p[k] = pn, pe, pd
    out_r += (off_n, off_e)
    return InsOutput(traj.pos_ne_m + out_r, traj.vel_ne_mps + out_v, out_r, out_p, bg, ba)


# ---- gravimeter ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class GravimeterModel:
    noise: Literal["gaussian", "residuals"] = "gaussian"
    sigma_mgal: float = 1.0  # Gaussian mode
    bias_mgal: float = 0.0
    eotvos: bool = True  # add the Eotvos effect of the true motion to the reading
    residual_spacing_m: float = 330.0  # along-track spacing of the residual series (ship_03 median)


def gravimeter_noise_mgal(model: GravimeterModel, dist_m: np.ndarray, rng: np.random.Generator,
                          residuals_mgal: np.ndarray | None = None) -> np.ndarray:
    """Noise at along-track distances dist_m: Gaussian, or a contiguous block of real residuals."""
    n = dist_m.size
    if model.noise == "gaussian":
        return model.bias_mgal + rng.normal(0.0, model.sigma_mgal, n)
    if residuals_mgal is None or residuals_mgal.size < 2:
        raise ValueError("residual noise mode needs the ship-minus-satellite residual series")
    idx = np.rint((dist_m - dist_m[0]) / model.residual_spacing_m).astype(np.intp)
    start = rng.integers(0, residuals_mgal.size)
    return model.bias_mgal + residuals_mgal[(start + idx) % residuals_mgal.size]


@dataclass(frozen=True)
class RunData:
    """One simulated run: truth, INS, raw and Eotvos-corrected gravity."""

    t_s: np.ndarray
    true_ne_m: np.ndarray
    true_vel_ne_mps: np.ndarray
    ins_ne_m: np.ndarray
    ins_vel_ne_mps: np.ndarray
    gravity_raw_mgal: np.ndarray  # map(true) + noise + Eotvos
    gravity_mgal: np.ndarray  # corrected with eqs. 5-6 using INS velocity and latitude
    map_true_mgal: np.ndarray


def simulate_run(lmap: LocalGravityMap, traj: ScenarioTrack, ins_model: InsErrorModel, grav_model: GravimeterModel,
                 rng: np.random.Generator, residuals_mgal: np.ndarray | None = None,
                 lat_deg_if_local: float = 45.0) -> RunData:
    ins = simulate_ins(traj, lmap.frame.ref_lat_deg if lmap.frame else lat_deg_if_local, ins_model, rng)
    g_true = lmap.interp_ne(traj.pos_ne_m[:, 0], traj.pos_ne_m[:, 1])
    noise = gravimeter_noise_mgal(grav_model, traj.distance_m(), rng, residuals_mgal)

    def lat_of(north):
        return lmap.lat_deg_at(north) if lmap.frame else np.full(np.shape(north), lat_deg_if_local)

    raw = g_true + noise
    corrected = raw
    if grav_model.eotvos:
        raw = raw + eotvos_from_ne_mgal(traj.vel_ne_mps, lat_of(traj.pos_ne_m[:, 0]))
        corrected = correct_eotvos_mgal(raw, ins.vel_ne_mps, lat_of(ins.pos_ne_m[:, 0]))  # eq. 6
    return RunData(traj.t_s, traj.pos_ne_m, traj.vel_ne_mps, ins.pos_ne_m, ins.vel_ne_mps, raw, corrected, g_true)


def record_by_distance(dist_m: np.ndarray, spacing_m: float) -> np.ndarray:
    """Indices of samples recorded every spacing_m of sailed distance (Gao sec. 2.1), first sample included."""
    marks = np.arange(0.0, dist_m[-1] + 1e-9, spacing_m)
    return np.unique(np.minimum(np.searchsorted(dist_m, marks), dist_m.size - 1))
