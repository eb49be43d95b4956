"""The measurement contract: every measurement's H is the numerical Jacobian of its h(state), and its gate rejects
a 10-sigma outlier and accepts a 1-sigma one."""

import numpy as np
import pytest

from companion.nav.ins import dcm_from_quat, quat_from_euler
from companion.nav.measurements import (
    AltitudeMeasurement,
    AttitudeMeasurement,
    DragMeasurement,
    HorizontalPositionMeasurement,
    HorizontalVelocityMeasurement,
    InsView,
    PositionMeasurement,
    VelocityMeasurement,
    gate,
)

C_EST = dcm_from_quat(quat_from_euler(0.1, -0.2, 1.0))
C_MEAS = dcm_from_quat(quat_from_euler(0.1 + 0.02, -0.2 - 0.01, 1.0))

FAMILY = {
    "gnss_pos": PositionMeasurement(1.0, "gnss_pos", (1.0, 2.0, -3.0), 0.5, 0.8, (1.5, 2.5)),
    "predictor": PositionMeasurement(1.0, "predictor", (1.0, 2.0, -3.0), 2.0, 3.0),
    "gnss_vel": VelocityMeasurement(1.0, "gnss_vel", (3.0, -1.0, 0.2), 0.3),
    "attitude": AttitudeMeasurement(1.0, "attitude", c_meas=C_MEAS, var_rad2=(9e-4, 9e-4, 0.01)),
    "altitude": AltitudeMeasurement(1.0, "altitude", z_down_m=-10.0, sigma_m=3.0),
    "position_fix": HorizontalPositionMeasurement(1.0, "position_fix", (5.0, -4.0), 20.0, 30.0),
    "velocity_fix": HorizontalVelocityMeasurement(1.0, "velocity_fix", (2.0, -1.0), 0.4, 0.6),
    "zero_velocity": VelocityMeasurement(1.0, "zero_velocity", (0.0, 0.0, 0.0), 0.3),
    "rotor_drag": DragMeasurement(1.0, "rotor_drag", (-0.6, 0.2), 0.3, (2.0, -1.0), (0.05, -0.02), (0.04, 0.01, 0.06)),
}
STATE = InsView(np.array([0.5, 1.5, -2.0]), np.array([2.5, -0.5, 0.1]), C_EST)
X_KIN = np.array([0.5, 1.5, -2.0, 2.5, -0.5, 0.1])


def _num_jac(f, x0, n, eps=1e-6):
    y0 = f(np.zeros(n))
    J = np.zeros((y0.size, n))
    for i in range(n):
        d = np.zeros(n)
        d[i] = eps
        J[:, i] = (f(d) - f(-d)) / (2 * eps)
    return J


@pytest.mark.parametrize("name", sorted(FAMILY))
def test_H_is_the_numerical_jacobian_of_h(name):
    m = FAMILY[name]
    J = _num_jac(lambda dx: m.h_ins(STATE.perturbed(dx)), STATE, 15)
    y, H, R = m.compute_ins(STATE)  # H as the filter gets it (the rotor drag's depends on the state)
    # attitude: exact at c_meas = C_est, first order in the 0.02 rad disagreement here
    assert np.allclose(H, J, atol=0.03 if name == "attitude" else 1e-6), (H, J)
    assert np.allclose(y, m.z() - m.h_ins(STATE)) and H.shape == (y.size, 15) and R.shape == (y.size, y.size)
    if hasattr(m, "h_kin"):
        for delay_s in (0.0, 0.2):
            Jk = _num_jac(lambda dx: m.h_kin(X_KIN + dx, delay_s), X_KIN, 6)
            assert np.allclose(m.H_kin(delay_s), Jk, atol=1e-6)


@pytest.mark.parametrize("name", sorted(FAMILY))
def test_gate_rejects_10_sigma_and_accepts_1_sigma(name):
    m = FAMILY[name]
    R = m.R() if m.R_gate() is None else np.maximum(m.R(), m.R_gate())
    P = np.eye(15) * 1e-12  # a confident filter: S is R
    H = m.compute_ins(STATE)[1]
    S = H @ P @ H.T + R
    u = np.ones(R.shape[0]) / np.sqrt(R.shape[0])  # unit direction in whitened innovation space
    L = np.linalg.cholesky(S)
    assert np.isclose(gate(L @ u, S, m.gate_chi2)[0], 1.0)
    assert gate(1.0 * L @ u, S, m.gate_chi2)[1]
    assert not gate(10.0 * L @ u, S, m.gate_chi2)[1]
