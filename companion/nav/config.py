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

    Each group's comment says what the settings do; why a default has its value, with the measurements and the
    command behind them, is in the decision record it names (docs/decisions/). The benchmark that scores them is
    replay/gap_filling.py (replay/results/gap_filling.md).
    """

    knn: KnnConfig = field(default_factory=KnnConfig)
    imu_index: int = 0
    gnss_instance: int = 0  # GPS1 only (a second receiver may be a different, unrelated source)
    output_rate_hz: float = 10.0
    min_imu_rate_hz: float = 20.0
    rate_window_s: float = 2.0
    imu_timeout_s: float = 3.0  # no IMU for this long in INS mode -> kinematic fallback
    max_imu_step_s: float = 0.1  # longer IMU gaps are not integrated through (covariance inflated)
    # the strapdown steps at most this often: faster IMU samples are summed between its steps with coning and sculling
    # corrections (companion.nav.imu_accumulator); samples at or below it each step it (docs/decisions/0013)
    ins_rate_hz: float = 50.0
    reorder_window_s: float = 0.25
    # KNN predictor points fused between fixes and through a blockage, sigma x predictor_sigma_scale, the k-th point
    # after a fix with its variance x k (predictor_decorrelate): they share the fix's error (docs/decisions/0002)
    fuse_predictor: bool = True
    predictor_min_age_s: float = 0.0
    predictor_sigma_scale: float = 2.0
    predictor_decorrelate: bool = True
    fuse_attitude: bool = True
    fuse_attitude_yaw: bool = True  # once the heading check has confirmed it, offset-corrected (docs/decisions/0004)
    fuse_gnss_velocity: bool = True
    # a fix stamped t describes the vehicle at t - gnss_delay_s, its velocity gnss_vel_delay_s before that
    # (docs/decisions/0003)
    gnss_delay_s: float = 0.0
    gnss_vel_delay_s: float = 0.15
    # measure the GNSS latency online (companion.nav.gnss_lag) and use it instead of gnss_delay_s once observable;
    # needs ahrs_check (the autopilot attitude resolves the specific force). Off for log replays (the shared logs'
    # tuning); on for the live companion (companion.config.live_nav_defaults)
    gnss_delay_estimate: bool = False
    gnss_lag: GnssLagConfig = field(default_factory=GnssLagConfig)
    gate_chi2: float = CHI2_3DOF_999
    gate_reset_s: float = 5.0
    # "short_term": fixes fused with their fix-to-fix noise (short_term_sigma_* x max(1, HDOP)), so the filter follows
    # the receiver; "accuracy": with the receiver's accuracy (h_acc, or HDOP x UERE). The gate always uses the
    # accuracy (docs/decisions/0003)
    gnss_sigma_model: str = "short_term"
    position_fix_gate_chi2: float = CHI2_2DOF_999  # own gate for PositionFix (horizontal, 2 dof); no reset
    # a PositionFix corrects the INS position only (velocity, attitude and biases keep their estimates: a Schmidt
    # update, companion.nav.kalman). For fixes that are a running filter's output (the sequential gravity filter):
    # serially correlated, and carrying that filter's own velocity-error estimate, which the cross-covariance would
    # otherwise turn into velocity corrections at every fix (docs/decisions/0011). INS mode only: the kinematic
    # filter takes a PositionFix as it takes any position
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
    # twice the white noise of the shared logs' 50 Hz IMU samples on a vibrating airframe (docs/decisions/0002)
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
    # the autopilot's heading against GNSS, independently of the INS (companion.nav.monitors.AhrsHeadingCheck):
    # flagged above ahrs_max_offset_deg, cleared below ahrs_ok_offset_deg; a flagged autopilot's tilt is fused with
    # the error its heading induces, and the INS heading re-aligned to it + the offset (docs/decisions/0004)
    ahrs_check: bool = True
    ahrs_check_interval_s: float = 0.9
    ahrs_check_tau_s: float = 20.0
    ahrs_check_min_dv_mps: float = 2.0
    ahrs_check_min_coherence: float = 0.5
    ahrs_max_offset_deg: float = 30.0
    ahrs_ok_offset_deg: float = 15.0
    yaw_align_min_deg: float = 15.0
    yaw_align_sigma_rad: float = 0.1
    att_fuse_interval_s: float = 0.0  # autopilot attitude fused at most this often; 0: always (docs/decisions/0005)
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
    # a flagged autopilot's tilt: fused at all (fuse_flagged_tilt), and also without GNSS for gnss_gap_s
    # (fuse_flagged_tilt_in_gap); att_consistency inflates the tilt variance by its excess over GNSS velocity changes
    # (AhrsHeadingCheck, forgotten over att_nis_tau_s) (docs/decisions/0004)
    fuse_flagged_tilt_in_gap: bool = False
    fuse_flagged_tilt: bool = True
    att_consistency: bool = False
    att_nis_tau_s: float = 10.0
    att_nis_min_s: float = 3.0
    gnss_gap_s: float = 1.5
    # rotor drag (companion.nav.drag): the horizontal accelerometers of a multicopter measure its air velocity; the
    # model is learnt while GNSS aids and fused during a blockage. Motion prior (companion.nav.motion_prior): hold and
    # constant velocity, mixed by their learnt errors into the output during a blockage (docs/decisions/0007)
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
        if self.output_rate_hz <= 0 or self.min_imu_rate_hz <= 0 or self.ins_rate_hz <= 0:
            raise ValueError("rates must be positive")
        if self.reinit_gap_s <= self.max_imu_step_s or self.future_outlier_s <= 0 or self.future_confirm_n < 1:
            raise ValueError("reinit_gap_s must exceed max_imu_step_s; future_outlier_s > 0, future_confirm_n >= 1")
        if self.reorder_window_s < 0 or self.gnss_vel_delay_s < 0 or self.gnss_delay_s < 0 or self.gnss_gap_s < 0:
            raise ValueError("reorder_window_s, gnss_delay_s, gnss_vel_delay_s and gnss_gap_s must be >= 0")
        if self.gnss_sigma_model not in ("short_term", "accuracy"):
            raise ValueError("gnss_sigma_model must be 'short_term' or 'accuracy'")
