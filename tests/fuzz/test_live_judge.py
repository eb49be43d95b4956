"""The live fuzz judge: "deaf" means no fresh GPS_INPUT in the quiet window after the faults, which exists only when
the SIGTERM is not itself one of the faults."""

from types import SimpleNamespace

import pytest

from replay.fuzz.link import LiveResult, judge_live


@pytest.mark.parametrize("sigterm_is_a_fault,deaf", [(False, True), (True, False)])
def test_deaf_only_where_a_quiet_window_exists(tmp_path, sigterm_is_a_fault, deaf):
    res = LiveResult("s", "tcp", started=True, exit_code=0, sigterm_to_exit_s=0.1, fresh_after_faults=0,
                     hearing_judged=not sigterm_is_a_fault)
    judge_live(res, SimpleNamespace(gps_inputs=[]), SimpleNamespace(stderr="", out=tmp_path / "none.mcap"))
    assert ("deaf" in res.violations) == deaf
    assert "mcap" in res.violations  # no record written: still judged
