"""The mode selector alone (companion.nav.modes): which mode each stream calls for, and a ModeChange only when the
mode or the kind of reason changes."""

import pytest

from companion.nav.config import NavigatorConfig
from companion.nav.modes import ModeSelector
from companion.nav.outputs import ModeChange


def _selector(rate_hz: float, until_s: float = 10.0) -> ModeSelector:
    s = ModeSelector(NavigatorConfig())
    n = int(until_s * rate_hz)
    for k in range(n + 1):
        s.note_imu(k / rate_hz)
    return s


def test_warm_up_then_each_reason():
    s = _selector(50.0)
    assert s.choose(1.0, 0.0, 1.0, True) is None  # 1 s of stream < rate_window_s (2 s): no decision yet
    assert s.choose(10.0, 0.0, 10.0, True) == ("ins", "strapdown INS on IMU0 + error-state KF", "ins")
    assert s.choose(10.0, 0.0, 10.0, False)[0::2] == ("kinematic", "no_attitude")
    assert s.choose(10.0, 0.0, None, True)[0::2] == ("kinematic", "no_imu")
    assert s.choose(20.0, 0.0, 10.0, True)[0::2] == ("kinematic", "imu_stopped")  # silent > imu_timeout_s (3 s)
    slow = _selector(10.0)
    assert slow.imu_rate_hz(10.0) == pytest.approx(10.5)  # 21 samples in the last 2 s
    kind = slow.choose(10.0, 0.0, 10.0, True)
    assert kind[0::2] == ("kinematic", "low_rate") and "slower than the 20 Hz" in kind[1]


def test_ins_stays_while_its_imu_is_alive_and_switch_reports_changes_only():
    s = _selector(50.0)
    change = s.switch(10.0, *s.choose(10.0, 0.0, 10.0, True))
    assert isinstance(change, ModeChange) and change.mode == "ins" and change.imu_rate_hz == pytest.approx(50.5)
    assert s.mode == "ins" and s.choose(11.0, 0.0, 10.5, True) is None
    assert s.switch(11.0, "ins", "same", "ins") is None  # same mode, same kind of reason
    stop = s.choose(15.0, 0.0, 10.0, True)
    assert stop[0::2] == ("kinematic", "imu_stopped")
    assert s.switch(15.0, *stop).mode == "kinematic" and s.reason == stop[1]
