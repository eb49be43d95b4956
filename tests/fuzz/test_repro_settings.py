"""Settings and files an adversarial user gives `companion run` / `replay`: an output that is an input (key, config,
log, map), a NUL byte, a device or FIFO as an input, durations with no floor, argument errors. Each ends at once with
one line and exit 2, and nothing is overwritten; `companion run` never replaces a record unless told (--force)."""

from __future__ import annotations

import hashlib

import pytest

from replay.fuzz.settings import CASES, make_files
from tests.fuzz.conftest import one_line_error, run_cli


def _sha(p) -> str:
    return hashlib.sha256(open(p, "rb").read()).hexdigest()


@pytest.fixture
def files(tmp_path):
    return make_files(tmp_path)


@pytest.mark.parametrize("case", list(CASES))
def test_bad_setting_or_file_is_one_line_exit_2_and_overwrites_nothing(files, case):
    before = {k: _sha(files[k]) for k in ("key", "cfg", "log")}
    res = run_cli(*CASES[case](files), timeout=60)
    assert one_line_error(res), (res.returncode, res.stderr[-800:])
    assert {k: _sha(files[k]) for k in ("key", "cfg", "log")} == before


def test_run_never_replaces_a_record_unless_forced(files):
    out = files["dir"] / "live.mcap"
    first = run_cli("run", "--config", files["cfg"], "--out", out, "--duration", "0.5", "-q", timeout=120)
    assert first.returncode == 0 and out.exists(), first.stderr[-600:]
    sha = _sha(out)
    again = run_cli("run", "--config", files["cfg"], "--out", out, "--duration", "0.5", "-q", timeout=120)
    assert again.returncode == 0 and _sha(out) == sha, again.stderr[-600:]
    assert (files["dir"] / "live_2.mcap").exists() and "recording to" in again.stderr
    out.write_bytes(b"an older record")
    forced = run_cli("run", "--config", files["cfg"], "--out", out, "--duration", "0.5", "-q", "--force", timeout=120)
    assert forced.returncode == 0 and not (files["dir"] / "live_3.mcap").exists()
    assert _sha(out) == sha  # replaced by this run's record (the same bytes: nothing from the vehicle, one clock)
