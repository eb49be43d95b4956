"""The command line end to end: replay, inspect, live ingest, bad input, signals."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.record import iter_payloads, summarize
from tests.conftest import REPO, free_port, LOG171, LOG_AC402, LOG_ERLE, LOG_TLOG, REAL_LOGS, SAMPLE_LOG, require

COMPANION = [sys.executable, "-m", "companion.cli"]


def run_cli(*args, timeout=300, **kw):
    return subprocess.run([*COMPANION, *map(str, args)], capture_output=True, text=True, timeout=timeout, **kw)


@pytest.mark.parametrize("log", REAL_LOGS, ids=lambda p: p.stem[:24])
def test_replay_every_real_log_then_inspect(log, tmp_path):
    out = tmp_path / "r.mcap"
    res = run_cli("replay", require(log), "--out", out)
    assert "Traceback" not in res.stderr
    # the AC 4.0.2 log really ends with a cut-off record: replayed in full, flagged with exit 3
    assert res.returncode == (3 if log == LOG_AC402 else 0), res.stderr
    assert "GNSS rate" in res.stdout and "duration" in res.stdout
    s = summarize(out)
    assert s.finalised
    topics = {t.topic: t for t in s.topics}
    assert topics["/input/gnss"].count > 0 and topics["/map/gnss"].count > 0
    assert topics["/map/gnss"].schema_name == "foxglove.LocationFix"
    assert ("/input/imu" in topics) == (log != LOG_AC402)
    assert {"source", "config", "summary", "companion"} <= {name for name, _ in s.metadata}
    # too slow (tlog, ~1 Hz) or no IMU (AC 4.0.2): the navigator says it fell back, in the record and summary
    nav = dict(s.metadata)["Navigator"]
    expected_mode = "kinematic" if log in (LOG_TLOG, LOG_AC402) else "ins"
    assert nav["mode"] == expected_mode and nav["mode_reason"]
    assert f"mode: {expected_mode}" in res.stdout
    assert topics["/map/fused"].count > 100
    ins = run_cli("inspect", out)
    assert ins.returncode == 0 and "/input/gnss" in ins.stdout


def test_tlog_replay_shows_the_autopilots_track_and_log_for_foxglove(tmp_path):
    """The autopilot's own position (GLOBAL_POSITION_INT) is a Map track beside ours and its STATUSTEXT is on
    foxglove.Log; every LocationFix/Log is stamped with its UTC log time and each track has its own frame_id."""
    import json

    from pymavlink import mavutil

    out = tmp_path / "t.mcap"
    assert run_cli("replay", require(LOG_TLOG), "--out", out).returncode == 0
    log = mavutil.mavlink_connection(str(LOG_TLOG))
    positions = 0
    while (m := log.recv_match(type="GLOBAL_POSITION_INT")) is not None:
        positions += m.get_srcSystem() == 1 and m.get_srcComponent() == 1 and (m.lat, m.lon) != (0, 0)
    topics = {t.topic: t for t in summarize(out).topics}
    assert topics["/map/autopilot"].count == topics["/input/autopilot_position"].count == positions > 1000
    assert topics["/log/autopilot"].count == topics["/input/statustext"].count > 0
    assert topics["/log/autopilot"].schema_name == "foxglove.Log"
    frames: dict[str, set] = {}
    for topic, log_ns, data in iter_payloads(out):
        if topic.startswith(("/map/", "/log/")):
            p = json.loads(data)
            assert p["timestamp"]["sec"] * 10**9 + p["timestamp"]["nsec"] == log_ns > 1_500_000_000 * 10**9  # UTC
            frames.setdefault(topic, set()).add(p.get("frame_id"))
    tracks = {t: f for t, f in frames.items() if t.startswith("/map/")}
    assert {"/map/autopilot", "/map/gnss", "/map/fused"} <= set(tracks)
    assert all(len(f) == 1 for f in tracks.values()) and len(set.union(*tracks.values())) == len(tracks)


def test_erle_summary_reports_inflight_gap(tmp_path):
    res = run_cli("replay", require(LOG_ERLE), "--out", tmp_path / "e.mcap")
    assert res.returncode == 0
    assert "fix lost until the end of the stream" in res.stdout


def test_replay_twice_gives_identical_payloads(tmp_path):
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    for out in (a, b):
        assert run_cli("replay", require(LOG_ERLE), "--out", out).returncode == 0
    pa, pb = list(iter_payloads(a)), list(iter_payloads(b))
    assert len(pa) > 1000 and pa == pb


def test_replay_navigator_off_records_the_inputs_only(tmp_path):
    out = tmp_path / "off.mcap"
    res = run_cli("replay", require(LOG_ERLE), "--out", out, "--navigator", "off")
    assert res.returncode == 0, res.stderr
    topics = {t.topic: t.count for t in summarize(out).topics}
    assert topics["/input/imu"] > 5000 and topics["/map/gnss"] > 300
    assert not [t for t in topics if t.startswith(("/estimation", "/map/fused", "/map/predictor"))]
    assert run_cli("replay", require(LOG_ERLE), "--out", out, "--navigator", "off", "--gravity-map", "x.nc",
                   "--deny-gnss-after", "5").returncode == 2


def test_default_replay_uses_bundled_sample(tmp_path):
    require(SAMPLE_LOG)
    res = run_cli("replay", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "out" / "sample_flight.mcap").exists()
    assert "sample_flight.tlog" in res.stdout


def test_quiet_prints_no_summary(tmp_path):
    res = run_cli("replay", require(SAMPLE_LOG), "--out", tmp_path / "q.mcap", "-q")
    assert res.returncode == 0 and res.stdout == "" and res.stderr == "", res.stdout + res.stderr
    # a damaged log still says what is wrong with it, as warnings
    cut = tmp_path / "cut.bin"
    cut.write_bytes(require(LOG171).read_bytes()[:1_000_003])
    res = run_cli("replay", cut, "--out", tmp_path / "cut.mcap", "-q")
    assert res.returncode == 3 and res.stdout == "" and "WARNING" in res.stderr and "truncated" in res.stderr


def test_sim_record_makes_its_folder(tmp_path):
    """`sim --record` makes its record's folder as `run` does, here relative to the directory it runs in."""
    res = run_cli("sim", "--listen", "udpout:127.0.0.1:9", "--end", "1", "--speed", "5", "--record",
                  "out/sim/gps_input.jsonl", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "out" / "sim" / "gps_input.jsonl").is_file()


def test_readme_sim_example_runs_from_any_directory(tmp_path):
    """The README's hardware-in-the-loop pair, as written (a free port, the flight and the run shortened), from a
    directory that is not the checkout: `companion` on PATH, --record making its folder."""
    import re
    import shlex

    block = re.search(r"```sh\n(companion sim [^\n]*)\n(companion run [^\n]*)\n```", (REPO / "README.md").read_text())
    assert block, "the README's sim example"
    port = str(free_port())
    sim_argv, run_argv = (shlex.split(line.split("#")[0].replace("5760", port).rstrip(" &")) for line in block.groups())
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    sim = subprocess.Popen([*sim_argv, "--end", "26", "--speed", "2"], cwd=tmp_path, env=env, text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert sim.stdout.readline().startswith("sim:")  # about to listen
        run_argv[run_argv.index("--duration") + 1] = "5"
        res = subprocess.run(run_argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
        assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-2000:]
        assert sim.wait(timeout=120) == 0, sim.stderr.read()
    finally:
        if sim.poll() is None:
            sim.kill()
    assert (tmp_path / "out" / "sim.jsonl").stat().st_size > 0  # GPS_INPUT received, in the folder it made


BAD_INPUTS = {
    "random": lambda: np.random.default_rng(1).bytes(50_000),
    "empty": lambda: b"",
    "text": lambda: b"timestamp,lat,lon\n1,2,3\n" * 100,
    "truncated_tiny": lambda: require(LOG171).read_bytes()[:2500],
}


@pytest.mark.parametrize("kind", BAD_INPUTS)
def test_bad_input_clear_error_no_traceback(kind, tmp_path):
    bad = tmp_path / f"bad_{kind}.bin"
    bad.write_bytes(BAD_INPUTS[kind]())
    out = tmp_path / "bad.mcap"
    res = run_cli("replay", bad, "--out", out)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr and res.stderr.startswith("companion: error:")
    assert len(res.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_truncated_bin_replays_what_is_there_and_says_so(tmp_path):
    cut = tmp_path / "cut.bin"
    cut.write_bytes(require(LOG171).read_bytes()[:1_000_003])
    res = run_cli("replay", cut, "--out", tmp_path / "cut.mcap")
    assert res.returncode == 3 and "Traceback" not in res.stderr
    assert "truncated" in res.stdout
    s = summarize(tmp_path / "cut.mcap")
    imu = sum(t.count for t in s.topics if t.topic.startswith("/input/imu"))
    assert s.finalised and imu > 10_000  # ~1/3 of the file: three IMUs at 50 Hz


@pytest.mark.parametrize("name", ["log.bin", "log.tlog"])
def test_out_that_is_the_input_is_refused_before_anything_is_opened(name, tmp_path):
    src = require(LOG_ERLE if name.endswith(".bin") else LOG_TLOG)
    log = tmp_path / name
    log.write_bytes(src.read_bytes()[:200_000])
    before = log.read_bytes()
    alias = tmp_path / "alias.mcap"
    os.link(log, alias)  # the same file under another name
    for out in (log, tmp_path / "." / name, alias):
        res = run_cli("replay", log, "--out", out)
        assert res.returncode == 2 and "refusing to overwrite" in res.stderr, res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
        assert log.read_bytes() == before


def test_missing_file_and_bad_url():
    res = run_cli("replay", "/nonexistent/x.bin")
    assert res.returncode == 2 and "no such file" in res.stderr
    res = run_cli("run", "--connect", "udpin:localhost")
    assert res.returncode == 2 and "SCHEME:HOST:PORT" in res.stderr
    # a missing serial device is retried (tests/fuzz/test_repro_live.py); a malformed one is refused at start
    res = run_cli("run", "--connect", "/dev/does-not-exist,12345")
    assert res.returncode == 2 and "baud rate 12345 is not supported" in res.stderr
    res = run_cli("run", "--connect", "/dev/shm")
    assert res.returncode == 2 and "not a character device" in res.stderr


def test_replay_sigterm_finalises_record(tmp_path):
    out = tmp_path / "t.mcap"
    proc = subprocess.Popen(
        [*COMPANION, "replay", require(LOG_TLOG), "--out", out, "--realtime", "20", "-v"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    head = []  # wait until the replay runs with its signal handlers (start-up takes seconds on a loaded machine)
    while not any("replaying" in line for line in head):
        line = proc.stderr.readline()
        assert line, f"companion replay ended before replaying: {''.join(head)}"
        head.append(line)
    deadline = time.monotonic() + 120  # ... and its first chunk is on disk: events are flowing
    while not (out.exists() and out.stat().st_size > 4096) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    stderr = "".join(head) + stderr
    assert proc.returncode == 130 and "Traceback" not in stderr
    assert "stopped by   SIGTERM" in stdout
    s = summarize(out)
    assert s.finalised and sum(t.count for t in s.topics) > 0


def _free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def _tlog_frames(path: Path, n: int) -> list[bytes]:
    from pymavlink import mavutil

    log = mavutil.mavlogfile(str(path))
    frames = []
    while len(frames) < n:
        m = log.recv_msg()
        if m is None:
            break
        if m.get_type() != "BAD_DATA":
            frames.append(m.get_msgbuf())
    return frames


def test_live_udp_ingest_records_events(tmp_path):
    """A real tlog's frames sent over UDP to `companion run --connect udpin:...` come out as events."""
    port = _free_udp_port()
    out = tmp_path / "live.mcap"
    proc = subprocess.Popen(
        [*COMPANION, "run", "--connect", f"udpin:127.0.0.1:{port}", "--out", out, "--duration", "8"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    frames = _tlog_frames(require(LOG_TLOG), 4000)
    head = []  # wait until the link is open (a loaded machine takes seconds to start Python)
    while not any("link opened" in line for line in head):
        line = proc.stderr.readline()
        assert line, f"companion run ended before opening the link: {''.join(head)}"
        head.append(line)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for i, f in enumerate(frames):
            tx.sendto(f, ("127.0.0.1", port))
            if i % 200 == 0:
                time.sleep(0.02)
    stdout, stderr = proc.communicate(timeout=60)
    stderr = "".join(head) + stderr
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    s = summarize(out)
    counts = {t.topic: t.count for t in s.topics}
    imu = sum(n for topic, n in counts.items() if topic.startswith("/input/imu"))
    assert counts.get("/input/gnss", 0) > 50 and imu > 100
    assert "other system 255/190" in stdout  # the ground station's messages were dropped, and said so


def test_log_without_any_gnss_fix_says_so(tmp_path):
    """log171's first 33 s have GPS rows but no fix: a cut there replays cleanly and warns."""
    cut = tmp_path / "nofix.bin"
    cut.write_bytes(require(LOG171).read_bytes()[:300_000])
    res = run_cli("replay", cut, "--out", tmp_path / "nofix.mcap")
    assert res.returncode == 3 and "Traceback" not in res.stderr  # 3: the cut leaves a partial last record
    assert "GNSS messages present but never a usable fix" in res.stdout
    assert "no GNSS fix in the whole stream" in res.stdout
    topics = {t.topic: t.count for t in summarize(tmp_path / "nofix.mcap").topics}
    assert topics["/input/gnss"] > 10 and "/map/gnss" not in topics


def test_realtime_pacing_follows_vehicle_time(tmp_path):
    t0 = time.perf_counter()
    res = run_cli("replay", require(LOG_ERLE), "--out", tmp_path / "rt.mcap", "--realtime", "40")
    wall = time.perf_counter() - t0
    assert res.returncode == 0
    assert wall >= 112.0 / 40  # 112 s of vehicle time at 40x cannot finish sooner


def test_terminal_labels_and_help(capsys):
    from companion.cli import _short_label, build_parser

    name = "replay ac33dev_pixhawk1_quad_2015-11-21_dronekit-la-testdata_log171.bin"
    short = _short_label(name, 22)
    assert len(short) == 22 and short.startswith("replay ac") and short.endswith(".bin")
    assert _short_label("navigator", 12) == "navigator"
    from companion.cli import _stage_label, _stage_metadata

    class GravityMatchStage:  # noqa: D401 - a stand-in stage
        def metadata(self):
            return {"unset": None, "printed_none": "None", "empty": "", "count": 0}

    assert _stage_label(GravityMatchStage()) == "gravitymatch"  # fits the 12-column field whole
    assert _stage_metadata(GravityMatchStage()) == {"count": "0"}  # no value prints None
    text = build_parser().format_help()
    assert "``" not in text and "exit codes" in text and "130" in text
    with pytest.raises(SystemExit):
        build_parser().parse_args(["inspect", "--help"])
    inspect_help = capsys.readouterr().out
    assert "an .mcap record" in inspect_help and "  2 " in inspect_help and "  3 " not in inspect_help
    with pytest.raises(SystemExit):
        build_parser().parse_args(["replay", "--help"])
    replay_help = capsys.readouterr().out
    assert "  3    the log was truncated" in replay_help and "--duration" not in replay_help.split("exit codes:")[1]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "--help"])
    assert "SIGTERM (systemd stop)" in capsys.readouterr().out.split("exit codes:")[1]


@pytest.mark.parametrize("columns", [80, 100, 60])
def test_progress_bar_fits_the_terminal_with_a_long_log_name(columns):
    from tqdm import tqdm

    from companion.cli import _bar_label

    desc = _bar_label("replay ac33dev_erle-pxf_quad_2014-11-06_GPS_issues1_inflight-gps-loss.bin", columns)
    line = tqdm.format_meter(509_000, 593_000, 6.5, ncols=columns, prefix=desc, unit="B", unit_scale=True)
    bar = line.split("|")[1]
    assert len(line) <= columns and len(bar) >= 10, line  # the bar is drawn and nothing is cut ...
    assert line.rstrip().endswith("B/s]") and "<00:01" in line, line  # ... ETA and rate included


def test_summary_lines_wrap_to_the_terminal(monkeypatch):
    from companion.cli import _summary_line

    monkeypatch.setenv("COLUMNS", "80")
    text = _summary_line("navigator", "mode_reason: IMU0 slower than the 20 Hz strapdown mechanisation needs: "
                                      "kinematic hold / constant-velocity IMM")
    lines = text.splitlines()
    assert len(lines) == 2 and all(len(x) <= 80 for x in lines)
    assert lines[1].startswith(" " * 13) and lines[1][13] != " "  # under the text, not under the label


def test_collect_benchmarks_help_writes_nothing():
    bench = REPO / "BENCHMARKS.md"
    before = bench.read_bytes() if bench.exists() else None
    proc = subprocess.run([sys.executable, "-m", "replay.collect_benchmarks", "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "usage:" in proc.stdout
    assert (bench.read_bytes() if bench.exists() else None) == before


def test_errors_under_journald_have_the_error_priority(tmp_path):
    import os

    env = {**os.environ, "JOURNAL_STREAM": "8:1234"}
    res = subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(tmp_path / "missing.tlog")],
                         capture_output=True, text=True, timeout=120, env=env, cwd=REPO)
    assert res.returncode == 2 and res.stderr.startswith("<3>companion: error: "), res.stderr


def test_logging_under_journald_has_priorities_and_no_timestamps(monkeypatch):
    import io
    import logging

    from companion.logsetup import configure

    monkeypatch.setenv("JOURNAL_STREAM", "8:1234")
    buf = io.StringIO()
    configure(0, 0, stream=buf)
    logging.getLogger("companion.runtime").warning("link lost: nothing for 3 s")
    logging.getLogger("companion.runtime").debug("not shown at the default level")
    monkeypatch.delenv("JOURNAL_STREAM")
    configure(0, 0)
    assert buf.getvalue() == "<4>WARNING companion.runtime: link lost: nothing for 3 s\n"
