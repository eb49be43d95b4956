"""The navigator's measurements, one contract (as in nmayorov/pyins): each is a small object with its time, kind and
gate, and ``compute(state) -> (y, H, R)``: innovation ``y = z - h(state)``, Jacobian ``H = dh/d(error state)`` and
noise ``R``. Two state views: :class:`InsView` for the 15-state error-state KF (errors true minus estimate,
attitude ``C_true = (I + [psi x]) C_est``; companion.nav.outputs.INS_STATE_NAMES) and the 6-vector
``[p_ned, v_ned]`` of the constant-velocity KF. ``h_ins``/``h_kin`` are the measurement functions themselves (the
tests check H against their numerical Jacobian). One gate, :func:`gate`, on the normalised innovation squared."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from companion.constants import CHI2_1DOF_999, CHI2_2DOF_999, CHI2_3DOF_999
from companion.nav.linalg import solve


_SELECTIONS: dict[int, tuple[np.ndarray, slice]] = {}  # id -> (H, the states it picks), for the constants below


def _selection(rows: int, first: int) -> np.ndarray:
    """The constant Jacobian picking ``rows`` consecutive error states from ``first`` (read-only: shared)."""
    H = np.zeros((rows, 15))
    H[:, first:first + rows] = np.eye(rows)
    H.flags.writeable = False
    _SELECTIONS[id(H)] = (H, slice(first, first + rows))
    return H


def selected_columns(H: np.ndarray) -> slice | None:
    """The consecutive error states H picks when it is one of this module's selections (H = the identity's rows
    ``cols``: then P H' is ``P[:, cols]``), else None."""
    e = _SELECTIONS.get(id(H))
    return e[1] if e is not None and e[0] is H else None


def _diag3(a: float, b: float, c: float) -> np.ndarray:
    """np.diag([a, b, c]) in one call."""
    return np.array(((a, 0.0, 0.0), (0.0, b, 0.0), (0.0, 0.0, c)))


_H_POS, _H_NE, _H_VEL, _H_ATT = _selection(3, 0), _selection(2, 0), _selection(3, 3), _selection(3, 6)
_POSITION_ROWS = np.zeros(15, dtype=bool)
_POSITION_ROWS[0:3] = True
_POSITION_ROWS.flags.writeable = False
_VELOCITY_ROWS = np.zeros(15, dtype=bool)
_VELOCITY_ROWS[3:6] = True
_VELOCITY_ROWS.flags.writeable = False
_H_VNE = _selection(2, 3)
_H_DOWN = _selection(1, 2)


def skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class InsView:
    """The INS nominal state at a measurement's epoch: local NED position, NED velocity, body-to-NED DCM."""

    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    dcm: np.ndarray

    def perturbed(self, dx) -> InsView:
        """The true state for an error-state ``dx`` (position, velocity, psi; biases do not enter h)."""
        dx = np.asarray(dx, dtype=float)
        return InsView(self.pos_ned_m + dx[0:3], self.vel_ned_mps + dx[3:6], (np.eye(3) + skew(dx[6:9])) @ self.dcm)


def gate(y: np.ndarray, S: np.ndarray, chi2: float) -> tuple[float, bool]:
    """Normalised innovation squared y' S^-1 y and whether it passes the chi-square gate."""
    nis = float(y @ solve(S, y))
    return nis, nis <= chi2


@dataclass(frozen=True)
class Measurement:
    """Base: ``t_s``, ``kind`` (MeasurementUpdate.kind); subclasses add ``gate_chi2``. ``R_gate()`` (None: R) is the
    noise the gate judges the innovation with (the receiver's own accuracy for GNSS); ``delay_s`` the epoch offset
    (None: the navigator's gnss_delay_s)."""

    t_s: float
    kind: str

    delay_s = None  # class attribute, not a field

    def R_gate(self) -> np.ndarray | None:
        return None

    def gain_rows_ins(self) -> np.ndarray | None:
        """The error states the update may correct (boolean, 15); None: every state."""
        return None

    def compute_ins(self, s: InsView) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.z() - self.h_ins(s), self.H_ins(), self.R()

    def compute_kin(self, x: np.ndarray, delay_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.z() - self.h_kin(x, delay_s), self.H_kin(delay_s), self.R()


@dataclass(frozen=True)
class PositionMeasurement(Measurement):
    """A 3-D position in local NED: a GNSS fix ("gnss_pos", gated with the receiver accuracy ``gate_sigma``) or a KNN
    predictor point ("predictor", Aziez 2021 eqs. 1, 3-4, with its own growing sigma)."""

    z_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_h_m: float = 1.0
    sigma_v_m: float = 1.0
    gate_sigma: tuple[float, float] | None = None
    gate_chi2: float = CHI2_3DOF_999

    def z(self):
        return np.asarray(self.z_ned_m, dtype=float)

    def R(self):
        h2 = self.sigma_h_m**2
        return _diag3(h2, h2, self.sigma_v_m**2)

    def R_gate(self):
        g = self.gate_sigma
        return None if g is None else _diag3(g[0] ** 2, g[0] ** 2, g[1] ** 2)

    def h_ins(self, s: InsView):
        return s.pos_ned_m

    def H_ins(self):
        return _H_POS

    def h_kin(self, x, delay_s):
        return x[0:3] - x[3:6] * delay_s  # the fix describes the vehicle at t - delay

    def H_kin(self, delay_s):
        return _h_kin_position(delay_s)


@functools.lru_cache(maxsize=32)
def _h_kin_position(delay_s: float) -> np.ndarray:
    """[I, -delay I]: a fix describes the vehicle at t - delay (read-only: cached per delay)."""
    H = np.zeros((3, 6))
    H[:, 0:3] = np.eye(3)
    H[:, 3:6] = -delay_s * np.eye(3)
    H.flags.writeable = False
    return H


@dataclass(frozen=True)
class HorizontalPositionMeasurement(Measurement):
    """A non-GNSS horizontal position (companion.events.PositionFix, e.g. gravity matching) at its own epoch."""

    z_ne_m: tuple[float, float] = (0.0, 0.0)
    sigma_n_m: float = 1.0
    sigma_e_m: float = 1.0
    gate_chi2: float = CHI2_2DOF_999
    # True: it corrects the INS position only (NavigatorConfig.position_fix_position_only)
    position_only: bool = False
    delay_s = 0.0

    def gain_rows_ins(self) -> np.ndarray | None:
        return _POSITION_ROWS if self.position_only else None

    def z(self):
        return np.asarray(self.z_ne_m, dtype=float)

    def R(self):
        return np.diag([self.sigma_n_m**2, self.sigma_e_m**2])

    def h_ins(self, s: InsView):
        return s.pos_ned_m[:2]

    def H_ins(self):
        return _H_NE

    def h_kin(self, x, delay_s):
        return x[0:2]

    def H_kin(self, delay_s):
        H = np.zeros((2, 6))
        H[:, 0:2] = np.eye(2)
        return H


@dataclass(frozen=True)
class HorizontalVelocityMeasurement(Measurement):
    """The horizontal velocity a non-GNSS producer sends with its PositionFix ("velocity_fix": the sequential gravity
    filter's estimate of the navigator's velocity, companion.gravity.sequential_stage), at the fix's epoch."""

    z_ne_mps: tuple[float, float] = (0.0, 0.0)
    sigma_n_mps: float = 1.0
    sigma_e_mps: float = 1.0
    gate_chi2: float = CHI2_2DOF_999
    # True: it corrects the INS velocity only (NavigatorConfig.position_fix_position_only: each part of a fix
    # corrects the states it measures)
    velocity_only: bool = False
    delay_s = 0.0

    def gain_rows_ins(self) -> np.ndarray | None:
        return _VELOCITY_ROWS if self.velocity_only else None

    def z(self):
        return np.asarray(self.z_ne_mps, dtype=float)

    def R(self):
        return np.diag([self.sigma_n_mps**2, self.sigma_e_mps**2])

    def h_ins(self, s: InsView):
        return s.vel_ned_mps[:2]

    def H_ins(self):
        return _H_VNE

    def h_kin(self, x, delay_s):
        return x[3:5]

    def H_kin(self, delay_s):
        H = np.zeros((2, 6))
        H[:, 3:5] = np.eye(2)
        return H


@dataclass(frozen=True)
class VelocityMeasurement(Measurement):
    """A NED velocity: GNSS ("gnss_vel", INS filter only; ``delay_s`` its latency) or the zero-velocity
    pseudo-measurement of a detected hover ("zero_velocity", companion.nav.hover)."""

    z_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_mps: float = 0.3
    gate_chi2: float = CHI2_3DOF_999
    delay_s: float | None = None

    def z(self):
        return np.asarray(self.z_ned_mps, dtype=float)

    def R(self):
        v = self.sigma_mps**2
        return _diag3(v, v, v)

    def h_ins(self, s: InsView):
        return s.vel_ned_mps

    def H_ins(self):
        return _H_VEL

    def h_kin(self, x, delay_s):
        return x[3:6]

    def H_kin(self, delay_s):
        H = np.zeros((3, 6))
        H[:, 3:6] = np.eye(3)
        return H


@dataclass(frozen=True)
class AttitudeMeasurement(Measurement):
    """The autopilot's attitude as a DCM ``c_meas`` (INS filter only). Innovation: the small-angle rotation
    psi with ``c_meas = (I + [psi x]) C_est``, i.e. ``y = vee(c_meas C_est^T)``; so ``h = -vee(c_meas C^T)``
    against ``z = 0``. Tilt-only when the yaw sigma is huge (see NavigatorConfig.fuse_attitude_yaw)."""

    c_meas: np.ndarray = None  # type: ignore[assignment]
    var_rad2: tuple[float, float, float] = (9e-4, 9e-4, 1e6)  # about N, E, D
    gate_chi2: float = CHI2_3DOF_999

    def z(self):
        return np.zeros(3)

    def R(self):
        return _diag3(*self.var_rad2)

    def h_ins(self, s: InsView):
        E = self.c_meas @ s.dcm.T
        return -0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])

    def H_ins(self):
        return _H_ATT


@dataclass(frozen=True)
class AltitudeMeasurement(Measurement):
    """The autopilot's (barometric) altitude, offset-corrected, as local down (m) at its own epoch."""

    z_down_m: float = 0.0
    sigma_m: float = 3.0
    gate_chi2: float = CHI2_1DOF_999
    delay_s = 0.0

    def z(self):
        return np.array([self.z_down_m])

    def R(self):
        return np.array([[self.sigma_m**2]])

    def h_ins(self, s: InsView):
        return s.pos_ned_m[2:3]

    def H_ins(self):
        return _H_DOWN

    def h_kin(self, x, delay_s):
        return x[2:3]

    def H_kin(self, delay_s):
        H = np.zeros((1, 6))
        H[0, 2] = 1.0
        return H


@dataclass(frozen=True)
class DragMeasurement(Measurement):
    """Rotor drag (companion.nav.drag, Leishman et al. 2014 eqs. 3-5): the horizontal specific force in body FRD,
    ``h = -k (C^T (v - w))_xy + b`` with the learnt coefficient ``k``, wind ``w`` and accelerometer bias ``b`` (INS
    filter only). ``R`` is the 2 x 2 noise (rows ``r_mps4``: xx, xy, yy), the fit's parameter uncertainty included."""

    z_frd_mps2: tuple[float, float] = (0.0, 0.0)
    k_per_s: float = 0.2
    wind_ne_mps: tuple[float, float] = (0.0, 0.0)
    bias_frd_mps2: tuple[float, float] = (0.0, 0.0)
    r_mps4: tuple[float, float, float] = (0.04, 0.0, 0.04)
    gate_chi2: float = CHI2_2DOF_999
    delay_s = 0.0

    def z(self):
        return np.asarray(self.z_frd_mps2, dtype=float)

    def R(self):
        a, b, c = self.r_mps4
        return np.array([[a, b], [b, c]])

    def _air_body(self, s: InsView):
        va = s.vel_ned_mps - np.array([self.wind_ne_mps[0], self.wind_ne_mps[1], 0.0])
        return va, s.dcm.T @ va

    def h_ins(self, s: InsView):
        return -self.k_per_s * self._air_body(s)[1][:2] + np.asarray(self.bias_frd_mps2, dtype=float)

    def H_ins(self, s: InsView):
        """d/d(dv) = -k C^T; d/d(psi) = -k C^T [v_air x] (C_true^T = C^T (I - [psi x]))."""
        va, _vb = self._air_body(s)
        H = np.zeros((2, 15))
        H[:, 3:6] = -self.k_per_s * s.dcm.T[:2]
        H[:, 6:9] = -self.k_per_s * (s.dcm.T @ skew(va))[:2]
        return H

    def compute_ins(self, s: InsView):
        return self.z() - self.h_ins(s), self.H_ins(s), self.R()
