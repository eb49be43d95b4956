"""What the gap-filling pipeline emits: frozen dataclasses in SI with ``t_s`` on the vehicle clock.

They subclass :class:`companion.events.Event` so the recorder can derive an MCAP JSON schema from the
dataclass fields and serialise them with ``to_dict()`` (NaN -> null). Field types are limited to
float/int/bool/str, ``X | None`` and ``tuple[float, ...]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from companion.events import Event

#: Order of the error-state covariance diagonal in :class:`FusedState` (INS mode, 15 states).
INS_STATE_NAMES: tuple[str, ...] = (
    "pos_n_m", "pos_e_m", "pos_d_m",
    "vel_n_mps", "vel_e_mps", "vel_d_mps",
    "att_n_rad", "att_e_rad", "att_d_rad",
    "ba_x_mps2", "ba_y_mps2", "ba_z_mps2",
    "bg_x_radps", "bg_y_radps", "bg_z_radps",
)
#: Order of the covariance diagonal in kinematic mode (6 states).
KINEMATIC_STATE_NAMES: tuple[str, ...] = (
    "pos_n_m", "pos_e_m", "pos_d_m", "vel_n_mps", "vel_e_mps", "vel_d_mps",
)


@dataclass(frozen=True, slots=True)
class PredictorPoint(Event):
    """One KNN predictor point (Aziez 2021 eqs. 1, 3-4) at a 0.1 s step after the last real fix.

    Position is local NED (metres from :attr:`FrameInfo` reference) and geodetic. ``sigma_*`` is the
    predictor's own 1-sigma uncertainty, growing with ``age_s`` (time since the last real fix).
    ``method`` is "knn" or "cv" (constant-velocity fallback while the database is too small).
    """

    north_m: float
    east_m: float
    down_m: float
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    sigma_h_m: float
    sigma_v_m: float
    age_s: float
    method: str
    topic: ClassVar[str] = "/estimation/predictor"


@dataclass(frozen=True, slots=True)
class FusedState(Event):
    """Fused navigation state at 10 Hz.

    ``mode`` is "ins" (error-state KF around the strapdown INS) or "kinematic" (constant-velocity KF,
    used when the IMU is missing or too slow). ``cov_diag`` follows :data:`INS_STATE_NAMES` or
    :data:`KINEMATIC_STATE_NAMES`. ``measurement`` names the aids applied since the previous output, joined by
    "+" ("gnss", "predictor", "position_fix", "altitude", "zero_velocity", "rotor_drag", and "motion_prior" when
    the output position is mixed with it; "none"); ``innovation_ned_m`` is the
    innovation of the last position update applied (NaN when none), ``rejected`` how many measurements the
    innovation gate refused since the previous output. Attitude angles are NaN when unknown.
    """

    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    north_m: float
    east_m: float
    down_m: float
    vel_n_mps: float
    vel_e_mps: float
    vel_d_mps: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    cov_diag: tuple[float, ...]
    sigma_h_m: float
    sigma_v_m: float
    mode: str
    measurement: str
    innovation_ned_m: tuple[float, ...]
    rejected: int
    age_since_fix_s: float
    topic: ClassVar[str] = "/estimation/fused"


@dataclass(frozen=True, slots=True)
class MeasurementUpdate(Event):
    """One measurement offered to a Kalman filter: its innovation, normalised innovation squared and verdict.

    ``kind``: "gnss_pos", "gnss_vel", "predictor", "attitude", "altitude", "position_fix", "velocity_fix" (the
    velocity a PositionFix may carry), "zero_velocity", "rotor_drag" (companion.nav.measurements). ``filter``: "ins" or "kinematic".
    """

    kind: str
    filter: str
    innovation: tuple[float, ...]
    sigma: tuple[float, ...]
    nis: float
    gate: float
    accepted: bool
    topic: ClassVar[str] = "/estimation/update"


@dataclass(frozen=True, slots=True)
class ModeChange(Event):
    """The navigator chose or changed its mode; ``reason`` is the human-readable why (for MCAP metadata)."""

    mode: str
    reason: str
    imu_rate_hz: float
    topic: ClassVar[str] = "/estimation/mode"


@dataclass(frozen=True, slots=True)
class FrameInfo(Event):
    """The local NED frame's geodetic reference (altitude MSL), emitted once when it is fixed."""

    ref_lat_deg: float
    ref_lon_deg: float
    ref_alt_msl_m: float
    topic: ClassVar[str] = "/estimation/frame"


@dataclass(frozen=True, slots=True)
class NavigatorReset(Event):
    """The navigator reset (part of) its state to a measurement, as ArduPilot's EKF3 resets to GNSS after a GPS-glitch
    timeout. ``kind``: "reinit" (whole filter from the next fix after a stream gap), "gnss_gap" (position/velocity
    after a GNSS gap the fix did not pass the gate), "gnss_rejected" (persistent rejection of a good 3D fix),
    "attitude_rejected" (persistent rejection of the autopilot attitude). ``jump_*`` is the state change (NaN if
    there was no state before)."""

    kind: str
    reason: str
    filter: str  # "ins" | "kinematic"
    jump_pos_m: float
    jump_vel_mps: float
    topic: ClassVar[str] = "/estimation/reset"


OUTPUT_TYPES: tuple[type[Event], ...] = (
    PredictorPoint, FusedState, MeasurementUpdate, ModeChange, FrameInfo, NavigatorReset,
)
