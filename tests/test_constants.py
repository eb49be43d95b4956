"""companion.constants: one receiver_sigma for every use of the receiver's own accuracy."""

from __future__ import annotations

import pytest

from companion.constants import CHI2_2DOF_999, UERE_M, receiver_sigma
from companion.events import GnssFix


def _fix(h_acc=None, v_acc=None, hdop=None, vdop=None):
    return GnssFix(0.0, 3, -35.0, 149.0, 500.0, None, None, None, None, None, 10, hdop, vdop, h_acc, v_acc, None,
                   None, None, 0)


def test_accuracy_first_then_dop_times_uere_then_none():
    assert receiver_sigma(_fix(1.2, 2.3, 0.9, 1.4)) == (1.2, 2.3)
    assert receiver_sigma(_fix(hdop=0.8, vdop=1.6)) == pytest.approx((0.8 * UERE_M, 1.6 * UERE_M))
    assert receiver_sigma(_fix(hdop=2.0, vdop=2.0), 1.5, 2.5) == (3.0, 5.0)  # separate horizontal / vertical UERE
    assert receiver_sigma(_fix()) == (None, None)


def test_a_reported_zero_is_no_report():
    assert receiver_sigma(_fix(h_acc=0.0, v_acc=0.0, hdop=1.0, vdop=0.0)) == (UERE_M, None)


def test_chi2_quantile():
    from scipy.stats import chi2

    assert CHI2_2DOF_999 == pytest.approx(chi2.ppf(0.999, 2), abs=1e-3)
