"""Backup activation with ``backup_fix_when_armed = False``: a 3D fix while disarmed (ArduPilot's arming check), no
fix once armed beside a healthy receiver (no GPS_AUTO_SWITCH switch to this instance when the receiver is lost), and
the fix type back in an outage only with an aid the autopilot lacks."""

from companion.events import FixType, Heartbeat
from companion.inject import InjectConfig, Injector

from tests.inject.test_inject import fix, state, tick


def _heartbeat(t_s, armed):
    return Heartbeat(t_s=t_s, system_id=1, component_id=1, vehicle_type=2, autopilot=3, armed=armed, custom_mode=4)


def test_no_fix_while_armed_beside_a_healthy_receiver():
    inj = Injector(InjectConfig(mode="shadow", aid_valid_s=60.0, backup_fix_when_armed=False))
    inj.process(fix(9.95))
    inj.process(_heartbeat(9.96, armed=False))
    (rec,) = tick(inj, state(t_s=10.0))
    assert rec.fix_type == FixType.FIX_3D  # disarmed: the instance must pass the arming check
    inj.process(_heartbeat(10.05, armed=True))
    inj.process(fix(10.15))
    (rec,) = tick(inj, state(t_s=10.2))
    assert rec.fix_type == FixType.NO_FIX and "armed beside a healthy receiver" in rec.fix_reason
    inj.process(fix(10.3, fix_type=1))  # the receiver is lost: no aid, so still no fix
    (rec,) = tick(inj, state(t_s=10.4, sigma_h=2.0))
    assert rec.fix_type == FixType.NO_FIX and "dead-reckons alone" in rec.fix_reason
    (rec,) = tick(inj, state(t_s=11.0, sigma_h=2.0, measurement="position_fix"))
    assert rec.fix_type == FixType.FIX_3D  # an aid the autopilot lacks: the help case keeps its fix
    inj.process(fix(11.1))  # the receiver is back: armed beside it, no fix again
    (rec,) = tick(inj, state(t_s=11.2, measurement="gnss"))
    assert rec.fix_type == FixType.NO_FIX
    inj.process(_heartbeat(11.25, armed=False))
    (rec,) = tick(inj, state(t_s=11.4, measurement="gnss"))
    assert rec.fix_type == FixType.FIX_3D


def test_default_keeps_the_fix_while_armed():
    inj = Injector(InjectConfig(mode="shadow"))
    inj.process(_heartbeat(9.9, armed=True))
    inj.process(fix(9.95))
    (rec,) = tick(inj, state(t_s=10.0))
    assert rec.fix_type == FixType.FIX_3D


def test_gnss_loss_sends_while_disarmed_for_the_arming_check_then_only_in_an_outage():
    inj = Injector(InjectConfig(mode="shadow", activate="gnss_loss", recover_s=2.0, gnss_timeout_s=0.6))
    inj.process(fix(9.95))
    assert tick(inj, state(t_s=10.0)) == []  # armed state unknown (no HEARTBEAT, e.g. a dataflash log): nothing
    inj.process(_heartbeat(10.05, armed=False))
    inj.process(fix(10.1))
    (rec,) = tick(inj, state(t_s=10.2))
    assert rec.fix_type == FixType.FIX_3D  # disarmed: every configured GPS needs a 3D fix to arm
    inj.process(_heartbeat(10.25, armed=True))
    inj.process(fix(10.3))
    assert tick(inj, state(t_s=10.4)) == []  # armed beside a healthy receiver: nothing
    on = inj.process(fix(10.5, fix_type=1))
    assert on and on[0].active
    (rec,) = tick(inj, state(t_s=10.6, sigma_h=2.0))
    assert rec.fix_type == FixType.FIX_3D  # the outage: the companion's own solution, with its covariance's fix type
