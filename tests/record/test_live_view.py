"""Live Foxglove view: a real WebSocket client (``websockets``) gets LocationFix messages from a real
``companion run`` process flying against the vehicle simulator.

The client offers both subprotocol names of the Foxglove WebSocket protocol: ``foxglove.websocket.v1``
(the published spec) and ``foxglove.sdk.v1`` (what foxglove-sdk 0.30 servers accept); the server picks one.
"""

from __future__ import annotations

import asyncio
import json
import signal
import struct
import subprocess
import threading
import time

import pytest

from companion.record.live_view import parse_endpoint
from tests.runtime.test_hil import Sim, run_companion

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # server -> client binary opcode
RESUBSCRIBE_S = 5.0


def test_parse_endpoint():
    assert parse_endpoint("8765") == ("127.0.0.1", 8765)
    assert parse_endpoint("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_endpoint("[::1]:9000") == ("::1", 9000)
    for bad in ("x", "host:", "1:99999"):
        with pytest.raises(ValueError):
            parse_endpoint(bad)


def _wait_for_port(proc, deadline_s: float) -> tuple[int, list[str]]:
    seen = []
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if "Foxglove live view on ws://" in line:
            return int(line.split("ws://", 1)[1].split()[0].rsplit(":", 1)[1]), seen
    raise AssertionError("no Foxglove server line from companion run: " + "".join(seen))


async def _receive_fixes(port: int, topics: set[str], want_each: int, timeout_s: float) -> list[dict]:
    """LocationFix messages from the server until every topic in ``topics`` gave ``want_each``.

    foxglove-sdk can advertise a channel made on its first message a moment before it takes subscriptions to it
    ("attempted to subscribe to unknown channel"): a channel silent for ``RESUBSCRIBE_S`` is subscribed again under a
    new subscription id, as a client seeing no data would."""
    import websockets

    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        subscribed: dict[int, str] = {}  # subscription id -> topic
        pending: dict[int, tuple[str, float]] = {}  # channel id -> (topic, when subscribed), until its first message
        got: list[dict] = []
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s

        async def subscribe(channels: list[tuple[int, str]]) -> None:
            subs = []
            for chan, topic in channels:
                sub_id = len(subscribed) + 1
                subscribed[sub_id] = topic
                pending[chan] = (topic, loop.time())
                subs.append({"id": sub_id, "channelId": chan})
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

        while any(sum(f["_topic"] == t for f in got) < want_each for t in topics):
            if loop.time() > end:
                raise TimeoutError(f"after {timeout_s} s: {[f['_topic'] for f in got][-20:]}")
            stale = [(c, t) for c, (t, since) in pending.items() if loop.time() - since > RESUBSCRIBE_S]
            if stale:
                await subscribe(stale)
            try:
                msg = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            if isinstance(msg, str):
                op = json.loads(msg)
                if op.get("op") == "advertise":
                    mine = []
                    for ch in op["channels"]:
                        if ch["topic"] in topics:
                            assert ch["schemaName"] == "foxglove.LocationFix" and ch["encoding"] == "json"
                            assert json.loads(ch["schema"])["title"] == "foxglove.LocationFix"
                            mine.append((ch["id"], ch["topic"]))
                    if mine:
                        await subscribe(mine)
            elif msg[0] == MESSAGE_DATA:
                sub_id, log_ns = struct.unpack_from("<IQ", msg, 1)
                fix = json.loads(msg[13:])
                fix["_topic"], fix["_log_ns"] = subscribed[sub_id], log_ns
                pending = {c: v for c, v in pending.items() if v[0] != fix["_topic"]}
                got.append(fix)
        return got


def test_foxglove_client_receives_live_location_fixes(tmp_path):
    # the flight outlasts any start-up delay of a loaded machine; the companion is stopped once the client has its fixes
    sim = Sim(tmp_path, "--start", 20, "--end", 400)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--foxglove", "0")
    fixes, failure, rest = [], None, []
    drain = threading.Thread(target=lambda: rest.extend(comp.stderr), daemon=True)  # a full stderr pipe would block it
    try:
        port, seen = _wait_for_port(comp, 120)
        drain.start()
        topics = {"/map/fused", "/map/gnss", "/map/gps_input"}  # the fused, GNSS and GPS_INPUT tracks
        try:
            fixes = asyncio.run(_receive_fixes(port, topics, want_each=10, timeout_s=180))
        except Exception as exc:  # say what the companion said, not only that the socket closed
            failure = exc
    finally:
        if comp.poll() is None:
            comp.send_signal(signal.SIGTERM)
        comp.wait(timeout=60)
        if drain.is_alive() or drain.ident is not None:
            drain.join(timeout=10)
        err = "".join(rest) if drain.ident is not None else comp.stderr.read()
        sim.finish()
    assert failure is None, f"{failure!r}; companion exit {comp.returncode}; stderr: {err[-3000:]}"
    assert "Traceback" not in err, err
    assert {f["_topic"] for f in fixes} == topics, [f["_topic"] for f in fixes]
    for f in fixes:
        assert -90 <= f["latitude"] <= 90 and -180 <= f["longitude"] <= 180 and not (f["latitude"] == 0 == f["longitude"])
        assert len(f["position_covariance"]) == 9
        assert f["_log_ns"] > 1_600_000_000 * 10**9  # the record's log time: UTC (the simulator's SYSTEM_TIME or host)
