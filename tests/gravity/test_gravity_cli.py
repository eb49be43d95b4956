"""Gravity-aided replay end to end through the CLI."""

from __future__ import annotations

import subprocess
import sys

from companion.record import iter_payloads, summarize
from tests.conftest import AK_MAP, SAMPLE_LOG, require


def _replay(tmp_path, name, *extra):
    out = tmp_path / f"{name}.mcap"
    res = subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(SAMPLE_LOG), "--out", str(out),
                          "--gravity-map", str(require(AK_MAP)), "--deny-gnss-after", "60", "--gravity-place",
                          "56.0,-144.0", "--gravity-sigma-mgal", "1.0", *extra], capture_output=True, text=True,
                         timeout=300)
    return res, out


def test_cli_gravity_replay_rejects_fixes_of_a_short_drone_track(tmp_path):
    """The sample drone flies 200 m circuits: on a 2' (~2-3.7 km) map its windows see no signal, so every fix is
    recorded as a rejected match and none reaches the navigator (fix acceptance on by default)."""
    import json

    res, out = _replay(tmp_path, "r")
    assert res.returncode == 0, res.stderr
    topics = {t.topic: t.count for t in summarize(out).topics}
    assert topics.get("/input/position_fix", 0) == 0
    matches = [json.loads(p) for _t, _ns, p in iter_payloads(out, "/gravity/match")]
    ok = [m for m in matches if m["ok"]]
    assert len(ok) >= 5 and not any(m["accepted"] for m in ok)
    assert all(m["reason"].startswith(("track", "signal")) for m in ok)
    assert not any(b'"position_fix"' in p for _t, _ns, p in iter_payloads(out, "/estimation/update"))


def test_cli_gravity_replay_records_fixes_and_gps_input_deterministically(tmp_path):
    res, out = _replay(tmp_path, "a", "--gravity-accept-all")
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert "horizontal error vs withheld GNSS" in res.stdout and "min after cut" in res.stdout
    topics = {t.topic: t.count for t in summarize(out).topics}
    assert topics["/inject/gps_input"] > 1000
    assert topics["/input/position_fix"] >= 5 and topics["/gravity/match"] >= topics["/input/position_fix"]
    assert topics["/input/gravity"] >= 60
    assert topics["/gravity/error"] > 100
    assert topics["/input/gnss"] > 800  # withheld fixes still recorded (truth)
    # the navigator saw the fixes: position_fix measurement updates exist
    assert any(b'"position_fix"' in p for _t, _ns, p in iter_payloads(out, "/estimation/update"))
    res2, out2 = _replay(tmp_path, "b", "--gravity-accept-all")
    assert res2.returncode == 0
    for topic in ("/input/position_fix", "/inject/gps_input", "/gravity/error"):
        assert list(iter_payloads(out, topic)) == list(iter_payloads(out2, topic))


def test_cli_gravity_options_need_each_other(tmp_path):
    res = subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(SAMPLE_LOG), "--out",
                          str(tmp_path / "x.mcap"), "--deny-gnss-after", "10"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "needs --gravity-map" in res.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_cli_gravity_replay_with_the_sequential_filter(tmp_path):
    """--matcher sequential: one /gravity/sequential record per reading (the simulated readings start at the cut),
    pinned to the navigator while its last GNSS fix is fresh, then the drone's 200 m circuits on a 2' map say
    no_signal and send no fix; the same replay twice gives the same fixes and GPS_INPUT."""
    import json

    res, out = _replay(tmp_path, "s", "--matcher", "sequential")
    assert res.returncode == 0, res.stderr
    assert "sequential-mpf" in res.stdout and "fixes sent" in res.stdout
    recs = [json.loads(p) for _t, _ns, p in iter_payloads(out, "/gravity/sequential")]
    topics = {t.topic: t.count for t in summarize(out).topics}
    assert len(recs) == topics["/input/gravity"] >= 60
    st = [r["status"] for r in recs]
    k = st.index("no_signal")  # the readings start at the cut: pinned while the last fix is fresh, then no signal
    assert k >= 1 and set(st[:k]) == {"anchored"} and set(st[k:]) == {"no_signal"}
    assert not any(r["sent"] for r in recs)
    assert topics.get("/input/position_fix", 0) == 0
    res2, out2 = _replay(tmp_path, "s2", "--matcher", "sequential")
    assert res2.returncode == 0

    def strip(payloads):
        out = []
        for _t, _ns, p in payloads:
            d = json.loads(p)
            d.pop("compute_time_s", None)
            out.append(d)
        return out

    assert strip(iter_payloads(out, "/gravity/sequential")) == strip(iter_payloads(out2, "/gravity/sequential"))
    assert list(iter_payloads(out, "/inject/gps_input")) == list(iter_payloads(out2, "/inject/gps_input"))
