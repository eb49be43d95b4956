"""The navigator's settings (companion.nav.navigator.Navigator): sensor noise, gates, aids and monitors."""

from __future__ import annotations

from dataclasses import dataclass, field

from companion.constants import CHI2_2DOF_999, CHI2_3DOF_999
from companion.nav.drag import DragConfig
from companion.nav.gnss_lag import GnssLagConfig
from companion.nav.hold_cv import HoldCvConfig
from companion.nav.hover import HoverConfig
from companion.nav.knn_predictor import KnnConfig
from companion.nav.motion_prior import MotionPriorConfig


@dataclass(frozen=True)
class NavigatorConfig:
    """Navigator settings. Defaults are for a small ArduPilot multicopter with a u-blox receiver.

    Noise levels: ArduPilot logs its IMU as 50 Hz filtered samples on a vibrating airframe, so the
    effective white noise is far above the sensor datasheet (per-sample std ~1 m/s^2 and ~0.03 rad/s in
    the shared logs, i.e. ~0.15 m/s^2/rtHz and ~0.005 rad/s/rtHz). The defaults are twice that: chosen on
    the shared logs' in-between fill and 4/8 s blockages (replay/gap_filling.py), where they did a few per
    cent better than 1x; there was no held-out log then, so treat that tuning as in-sample. The settings of
    the blockage aids below (rotor drag, motion prior, yaw and flagged-tilt handling, ``gnss_vel_delay_s``)
    were chosen on two logs (ac313, Erle PXF) with log171 held out (replay/results/gap_filling.md).
    ``predictor_sigma_scale``: a predictor point extrapolates the last fix, so its error is correlated with
    that fix, which the filter has already used; treating it as independent makes the filter
    overconfident (position NEES ~2 per axis on simulated flights). Its sigma is scaled by this factor.
    Rechecked on the blockages with everything else at its default (replay.gap_filling --offsets 4 --no-stream-gaps
    --set predictor_sigma_scale=X; ac313 + Erle PXF, log171 held out), X = 1.5 / 2 / 3 / 4 / 6: tuning logs 1 s 0.49 /
    0.51 / 0.53 / 0.54 / 0.55, 8 s 3.37 / 3.35 / 3.33 / 3.43 / 3.43 m; held-out log171 8 s 2.90 / 2.70 / 2.60 / 2.57 /
    2.56 m; Erle PXF 8 s 1.15 / 1.30 / 1.44 / 1.87 / 1.92 x its best baseline (hold); pooled 8 s 3.24 / 3.18 / 3.14 /
    3.21 / 3.20 m. No value is better everywhere; 2 stays.
    ``predictor_decorrelate``: the k-th point fused after a fix has its variance multiplied by k: the
    points of one recursion share the anchor's and the neighbours' error, so 80 points in an 8 s blockage
    must not count as 80 independent measurements (that pulled the INS towards the predictor's drift).
    ``gnss_sigma_model``: truth and product frame are the receiver's own solution, whose error wanders
    slowly (metres over minutes) but is smooth from fix to fix. "short_term" updates with the
    fix-to-fix noise (``short_term_sigma_*`` x max(1, HDOP)) so the filter follows the receiver instead of
    averaging it; "accuracy" uses the receiver's accuracy (h_acc, or HDOP x UERE), right for white fix
    noise. The innovation gate always uses the accuracy sigma, so a glitch is judged on the receiver's own
    error scale. ``fuse_attitude_yaw``: the autopilot's heading is fused only while the heading check below
    has measured it consistent with GNSS, and corrected by the offset it measured (in the Erle log the
    autopilot's heading is ~90 deg off; fused before the check flags it, it ruins the fill). At 1 Hz GNSS a
    loitering vehicle shows the INS too little acceleration to hold its own heading (it wandered +-20 deg
    from the autopilot's in the ac313 log), and a heading error d turns the specific force into an
    acceleration error d |a_h| during a blockage.
    ``gnss_delay_s``: a fix stamped t describes the vehicle at t - delay (receiver latency; ArduPilot's EKF
    assumes ~0.2 s for a u-blox). Fixes and predictor points are compared with the INS state of that
    epoch, kept in a short per-IMU-step history that follows every correction. Modelled for positions it
    makes the output a real-time estimate, which the 1 Hz in-between fill scores against the receiver's
    lagged fixes (0.35 vs 0.29 m), so the default is 0: the position follows the receiver's epoch.
    ``gnss_vel_delay_s``: the receiver's velocity describes the vehicle this much before its position does:
    on all three 50 Hz shared logs the GNSS velocity best matches the derivative of the GNSS positions
    0.10-0.15 s earlier (ac313 0.15, Erle 0.10, log171 0.15 s). It is compared with the INS velocity of that
    epoch (t - gnss_delay_s - gnss_vel_delay_s) while no measured latency is in use: taken as simultaneous
    with the position, it teaches the filter a wrong tilt and accelerometer bias during manoeuvres, which drive
    the drift once GNSS stops (1 Hz fill 0.29 -> 0.24 m, 8 s blockages on ac313 and Erle 3.8 -> 3.4 m).
    ``ahrs_check``: the autopilot attitude is only as good as its heading. A DCM AHRS corrects tilt with
    GNSS acceleration resolved through its heading, so a wrong heading (the Erle PXF log: compass ~90 deg
    off) also corrupts its roll/pitch during manoeuvres. The navigator checks the autopilot's heading
    against GNSS, independently of its own INS state: horizontal GNSS velocity changes over
    >= ``ahrs_check_interval_s`` are compared with the integral of the IMU specific force resolved with
    the autopilot's attitude over the same interval (gravity and Coriolis have ~no horizontal part);
    with exponential forgetting (``ahrs_check_tau_s``) the heading offset is the angle of
    sum(dv_gnss * conj(dv_ahrs)) (complex N + iE), valid once both sums of squares exceed
    ``ahrs_check_min_dv_mps``^2 and the normalised coherence is >= ``ahrs_check_min_coherence``. If the
    offset exceeds ``ahrs_max_offset_deg`` the autopilot attitude is declared inconsistent (until the
    offset falls below ``ahrs_ok_offset_deg``). Its tilt is then fused with a sigma that includes the error
    a heading offset d induces: the AHRS levels on an acceleration rotated by d, off by 2 sin(d/2) |a_h|,
    i.e. a tilt error of about 2 sin(d/2) a_rms / g, with a_rms the recent RMS horizontal GNSS
    acceleration (added in quadrature to ``att_sigma_tilt_rad``). The INS heading, which was
    initialised from the autopilot, is re-aligned to autopilot heading + offset (a coarse in-motion
    alignment, cf. Groves 2013 sec. 14.2; the KF's psi is a small-angle state and absorbs a large heading
    error only slowly) when it differs from that by more than ``yaw_align_min_deg`` and 3 x the KF's yaw
    sigma; the yaw variance is then reset to ``yaw_align_sigma_rad``^2.
    ``fuse_flagged_tilt_in_gap``: once the heading check flags the autopilot, its tilt is fused (with the
    inflated sigma) only while GNSS aids (no gap of ``gnss_gap_s``): in a blockage its tilt, off by degrees
    in manoeuvres, would make the INS confident in a wrong tilt; without it the INS's own tilt uncertainty
    grows and the motion prior takes the weight (Erle PXF: 8 s blockage 2.3 m instead of 7.0 m).
    ``fuse_flagged_tilt``: False stops the flagged autopilot's tilt altogether, also while GNSS aids (off by
    default: replay.gap_filling --offsets 4 --lengths 4 8 --set fuse_flagged_tilt=false on the three 50 Hz logs:
    Erle PXF, the only one flagged, 8 s 1.29 -> 0.94 x the best baseline but 4 s 1.34 -> 1.36; pooled 4 s
    1.68 -> 1.75 m, 8 s 3.23 -> 3.18 m).
    ``att_consistency``: covariance matching of the autopilot's tilt against GNSS, independent of the INS
    (AhrsHeadingCheck._tilt_residual, companion.nav.consistency): the tilt variance fused is att_sigma_tilt_rad^2
    times the forgotten (``att_nis_tau_s``) mean excess of the GNSS-minus-autopilot velocity-change residual, when
    that exceeds 1 and ``att_nis_min_s`` of evidence is in (needs ``ahrs_check``). The INS's own attitude
    innovations cannot show a biased autopilot: fused at 10-50 Hz its tilt pulls the INS along (an NIS monitor on
    them stayed at 1 with a 3 deg bias in simulation and changed no 4 or 8 s benchmark number on the 50 Hz logs).
    tau 10 s and the noise terms are from the model, not tuned. Off by default: on the shared logs (1 Hz GNSS,
    --offsets 4) it improved the Erle PXF log (4 s 1.34 -> 1.19 x the best baseline, 8 s 1.29 -> 1.25) but
    held-out log171 moved 6.09 -> 6.14 m at 15 s and 19.53 -> 19.57 m at 30 s (pooled 15 s 6.83 -> 6.85 m):
    not a clear gain off the log that motivated it.
    ``att_fuse_interval_s``: the autopilot's attitude is a filter's output whose error persists from sample to
    sample; fused at every sample (0, 10-50 Hz) as independent measurements it makes the INS as sure of the autopilot's
    tilt as of a perfect one. On the shared logs fusing it at most every X s helps, measured with the motion prior's
    blend_min_age_s at 6 s (replay.gap_filling --offsets 4 --no-stream-gaps --set att_fuse_interval_s=X; tuning logs
    ac313 and Erle PXF, log171 held out): the tuning logs' 1 / 4 / 8 / 15 / 30 s blockage H RMSE for X = 0 / 0.5 / 1 /
    1.5 / 2 s: 0.51 / 0.48 / 0.48 / 0.48 / 0.47, 1.58 / 1.52 / 1.62 / 1.59 / 1.61, 3.35 / 3.24 / 3.12 / 3.11 / 3.13,
    7.13 / 7.20 / 7.19 / 7.16 / 7.23, 27.99 / 24.71 / 22.85 / 22.12 / 22.22 m (2 s: Erle PXF's one 30 s blockage
    4.6 -> 10.9 m); held-out log171, 0 -> 1.5 s: 1 s 0.33 -> 0.38, 4 s 0.85 -> 0.72, 8 s 2.70 -> 2.62, 15 s 6.08 ->
    6.00, 30 s 19.53 -> 14.94 m; pooled 8 s 3.18 -> 2.97 m, 30 s 26.60 -> 20.95 m; Erle PXF 8 s 1.30 -> 0.67 x the
    best baseline but 4 s 1.03 -> 1.39 x. But on the suite's simulated flights, whose autopilot attitude is truth plus
    white noise, 1.5 s loses what every sample adds: 7 tests fail (an 8 s blockage's largest error 6.5 m against
    < 3 m, a 90 deg heading offset's realigned yaw error 27 deg against < 20 deg, the simulated gravity chain 8 position
    fixes against >= 10, ...). Which is right depends on how long a given autopilot's error persists, which is not
    measured online; so every sample is fused (0) until it is. Two measures of that persistence (both tables from
    python -m replay.attitude_persistence): the autocorrelation of the tilt innovations (every sample fused) at 0.1 /
    0.5 / 1 / 3 s is ac313 0.91 / 0.69 / 0.43 / 0.03, Erle PXF 0.99 / 0.88 / 0.71 / 0.22, log171 0.75 / 0.41 / 0.27 /
    0.05, on the simulated flights -0.07-0.01 at every lag. But fusing once per its e-folding time, learnt online while
    GNSS aids, runs away: fused less often, the INS drifts between fusions and the innovations correlate the more, so
    the learnt time went to the 3 s limit on ac313 and Erle PXF (pooled 8 s 3.03 m, 15 s 6.82 -> 7.14 m, held-out
    log171 15 s 6.08 -> 6.45 m, Erle PXF's 30 s blockage 2.5 x hold; not kept). The measure that does not depend on
    the fusion, the autopilot's attitude change against the gyros' integration over the same lag (a constant gyro bias
    removed; RMS per tilt axis at 0.1 / 1 / 5 s): simulated flights 2.47 / 2.44 / 2.57 deg (flat: white), ac313 0.04 /
    0.24 / 0.72, Erle PXF 0.21 / 0.81 / 1.96 deg (growing as a random walk to 5 s, no saturation), log171 0.31 / 9.35 /
    0.63 deg (its ATT and IMU line up at zero time offset; not understood). So it gives no correlation time that
    would set the interval.
    ``rotor_drag`` (companion.nav.drag) and ``motion_prior`` (companion.nav.motion_prior) are described in
    their modules: the multicopter's horizontal accelerometers as an air-velocity measurement during a
    blockage, and hold / constant velocity mixed into the output by what they were worth on this flight.
    """

    knn: KnnConfig = field(default_factory=KnnConfig)
    imu_index: int = 0
    gnss_instance: int = 0  # GPS1 only (a second receiver may be a different, unrelated source)
    output_rate_hz: float = 10.0
    min_imu_rate_hz: float = 20.0
    rate_window_s: float = 2.0
    imu_timeout_s: float = 3.0  # no IMU for this long in INS mode -> kinematic fallback
    max_imu_step_s: float = 0.1  # longer IMU gaps are not integrated through (covariance inflated)
    reorder_window_s: float = 0.25
    fuse_predictor: bool = True
    predictor_min_age_s: float = 0.0
    predictor_sigma_scale: float = 2.0
    predictor_decorrelate: bool = True
    fuse_attitude: bool = True
    fuse_attitude_yaw: bool = True
    fuse_gnss_velocity: bool = True
    gnss_delay_s: float = 0.0
    gnss_vel_delay_s: float = 0.15
    # measure the GNSS latency online (companion.nav.gnss_lag) and use it instead of gnss_delay_s once observable;
    # needs ahrs_check (the autopilot attitude resolves the specific force). Off for log replays (the shared logs'
    # tuning above); on for the live companion (companion.config.live_nav_defaults)
    gnss_delay_estimate: bool = False
    gnss_lag: GnssLagConfig = field(default_factory=GnssLagConfig)
    gate_chi2: float = CHI2_3DOF_999
    gate_reset_s: float = 5.0
    gnss_sigma_model: str = "short_term"  # "short_term" | "accuracy"
    position_fix_gate_chi2: float = CHI2_2DOF_999  # own gate for PositionFix (horizontal, 2 dof); no reset
    # a PositionFix corrects the INS position only (velocity, attitude and biases keep their estimates: a Schmidt
    # update, companion.nav.kalman). For fixes that are a running filter's output (the sequential gravity filter):
    # serially correlated, and carrying that filter's own velocity-error estimate, which the cross-covariance would
    # otherwise turn into velocity corrections at every fix (a live ship run: 13 m/s of velocity error from 1-5 km
    # fixes in 5 minutes). INS mode only: the kinematic filter takes a PositionFix as it takes any position
    position_fix_position_only: bool = False
    short_term_sigma_h_m: float = 0.3
    short_term_sigma_v_m: float = 0.5
    uere_h_m: float = 1.5
    uere_v_m: float = 2.5
    default_sigma_h_m: float = 2.5
    default_sigma_v_m: float = 4.0
    min_sigma_h_m: float = 0.3
    gnss_vel_sigma_mps: float = 0.3
    att_sigma_tilt_rad: float = 0.03
    att_sigma_yaw_rad: float = 0.1
    accel_noise_mps2_rthz: float = 0.3
    gyro_noise_radps_rthz: float = 0.01
    accel_bias_sigma_mps2: float = 0.3
    gyro_bias_sigma_radps: float = 0.02
    bias_tau_s: float = 300.0
    init_sigma_att_rad: float = 0.05
    init_sigma_yaw_rad: float = 0.2
    kinematic_accel_sigma_mps2: float = 2.0
    # kinematic mode: hold and constant velocity as an IMM, mixed by their innovation likelihoods (companion.nav.hold_cv)
    kinematic_hold_cv: bool = True
    hold_cv: HoldCvConfig = field(default_factory=HoldCvConfig)
    ahrs_check: bool = True
    ahrs_check_interval_s: float = 0.9
    ahrs_check_tau_s: float = 20.0
    ahrs_check_min_dv_mps: float = 2.0
    ahrs_check_min_coherence: float = 0.5
    ahrs_max_offset_deg: float = 30.0
    ahrs_ok_offset_deg: float = 15.0
    yaw_align_min_deg: float = 15.0
    yaw_align_sigma_rad: float = 0.1
    att_fuse_interval_s: float = 0.0
    # vertical aid from the autopilot's altitude (AutopilotAltitude, GLOBAL_POSITION_INT; barometric on ArduPilot):
    # while GNSS positions arrive, only the offset between that altitude and ours is learnt (datum, baro bias; time
    # constant alt_offset_tau_s); once none has been fused for alt_gnss_gap_s, the offset-corrected altitude is fused
    # with alt_sigma_m. Off by default (a short blockage does not need it); gravity_nav_config turns it on.
    fuse_autopilot_alt: bool = False
    alt_sigma_m: float = 3.0
    alt_gnss_gap_s: float = 2.0
    alt_offset_tau_s: float = 60.0
    # zero-velocity pseudo-measurement (companion.nav.hover): while the detector says hover and no fix has come for
    # zupt_min_age_s, a zero NED velocity with zupt_sigma_mps is fused every zupt_interval_s.
    zero_velocity: bool = True
    hover: HoverConfig = field(default_factory=HoverConfig)
    zupt_sigma_mps: float = 0.3
    zupt_interval_s: float = 1.0
    zupt_min_age_s: float = 1.5
    fuse_flagged_tilt_in_gap: bool = False
    fuse_flagged_tilt: bool = True
    att_consistency: bool = False
    att_nis_tau_s: float = 10.0
    att_nis_min_s: float = 3.0
    gnss_gap_s: float = 1.5
    # rotor drag (companion.nav.drag): the horizontal accelerometers of a multicopter measure its air velocity; the
    # model is learnt while GNSS aids and fused during a blockage. Motion prior (companion.nav.motion_prior): hold and
    # constant velocity, mixed by their learnt errors, multiplied into the output during a blockage.
    rotor_drag: bool = True
    drag: DragConfig = field(default_factory=DragConfig)
    motion_prior: bool = True
    motion: MotionPriorConfig = field(default_factory=MotionPriorConfig)
    # recovery (companion.nav.recovery): a stream gap (no event at all) longer than reinit_gap_s is not ticked
    # through and re-initialises the filter at the next fix; the first fix after a GNSS gap that long resets
    # position/velocity if outside the gate; reset_after_n_rejected consecutive (or gate_reset_s of) rejected good
    # 3D fixes reset position/velocity to GNSS, att_reset_after_n_rejected rejected autopilot attitudes the tilt,
    # with the fix's (the initial attitude's) variance x reset_cov_scale. An event more than future_outlier_s
    # ahead of the stream is held until future_confirm_n consecutive events confirm the jump, else dropped.
    reinit_gap_s: float = 5.0
    reset_after_rejection: bool = True
    reset_after_n_rejected: int = 30
    att_reset_after_n_rejected: int = 50
    reset_cov_scale: float = 4.0
    future_outlier_s: float = 30.0
    future_confirm_n: int = 3

    def __post_init__(self) -> None:
        if self.output_rate_hz <= 0 or self.min_imu_rate_hz <= 0:
            raise ValueError("rates must be positive")
        if self.reinit_gap_s <= self.max_imu_step_s or self.future_outlier_s <= 0 or self.future_confirm_n < 1:
            raise ValueError("reinit_gap_s must exceed max_imu_step_s; future_outlier_s > 0, future_confirm_n >= 1")
        if self.reorder_window_s < 0 or self.gnss_vel_delay_s < 0 or self.gnss_delay_s < 0 or self.gnss_gap_s < 0:
            raise ValueError("reorder_window_s, gnss_delay_s, gnss_vel_delay_s and gnss_gap_s must be >= 0")
        if self.gnss_sigma_model not in ("short_term", "accuracy"):
            raise ValueError("gnss_sigma_model must be 'short_term' or 'accuracy'")
