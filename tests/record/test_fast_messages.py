"""The recorder's fast paths give what the slow ones gave: mcap's own add_message, byte for byte; orjson's payloads,
value for value against the standard library's json of to_dict()."""

from __future__ import annotations

import asyncio
import json
import math

import numpy as np
from mcap.writer import CompressionType, Writer

from companion.pipeline.core import build_pipeline, run_source
from companion.record import Recorder, iter_payloads
from companion.record.fast_messages import fast_add_message
from companion.record.schemas import drop_unknown
from companion.sources import FileSource
from tests.conftest import LOG_ERLE, SAMPLE_LOG, require


def _write(path, fast: bool, compression):
    rng = np.random.default_rng(7)
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=1 << 62, compression=compression)
        w.start("", "test")
        sid = w.register_schema("s", "jsonschema", b"{}")
        chans = [w.register_channel(f"/t{i}", "json", sid) for i in range(3)]
        add = fast_add_message(w) if fast else w.add_message
        assert add is not None
        seq = [0, 0, 0]
        for k in range(3000):
            c = int(rng.integers(0, 3))
            t = int(rng.integers(0, 10**12))  # out of order on purpose: start/end times are min/max
            add(chans[c], t, rng.bytes(int(rng.integers(0, 200))), t + 5, seq[c])
            seq[c] += 1
            if k % 700 == 699:
                w.flush()  # several chunks, and a chunk's indexes start afresh
        w.finish()
    return path.read_bytes()


def test_fast_add_message_writes_the_same_bytes_as_mcap(tmp_path):
    for comp in (CompressionType.NONE, CompressionType.ZSTD):
        slow = _write(tmp_path / "slow.mcap", False, comp)
        fast = _write(tmp_path / "fast.mcap", True, comp)
        assert len(slow) > 100_000 and fast == slow


class _Both(Recorder):
    """A recorder that also keeps what the standard library's json made of each payload before."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.stdlib: list[bytes] = []
        self.had_unknown: list[bool] = []

    def write(self, item, topic=None):
        d = item.to_dict()
        self.stdlib.append(json.dumps(drop_unknown(d), separators=(",", ":"), allow_nan=False).encode())
        self.had_unknown.append(b"null" in json.dumps(d).replace("NaN", "null").encode())
        super().write(item, topic)

    def write_location(self, topic, t_s, lat_deg, lon_deg, alt_m, cov_enu_m2=None, **kw):
        self.stdlib.append(None)  # a dict payload: compared below through _dumps itself
        self.had_unknown.append(False)
        super().write_location(topic, t_s, lat_deg, lon_deg, alt_m, cov_enu_m2, **kw)

    def write_log(self, *a, **kw):
        self.stdlib.append(None)  # a dict payload, as write_location's
        self.had_unknown.append(False)
        super().write_log(*a, **kw)


def test_payloads_equal_the_stdlib_json_in_value(tmp_path):
    """Every payload of two replays (a dataflash log with the INS, a tlog with NaN innovations), decoded, equals the
    standard library's encoding of to_dict() with its unknown values left out, decoded; the bytes differ only in how
    some floats are spelt."""
    spelled_differently = 0
    unknown_left_out = 0
    for log in (require(LOG_ERLE), SAMPLE_LOG):
        out = tmp_path / f"{log.stem}.mcap"
        rec = _Both(out)
        pipe = build_pipeline(rec)
        asyncio.run(run_source(FileSource(log), pipe))
        rec.close()
        payloads = [p for p in iter_payloads(out)]
        data = [p[-1] if isinstance(p, tuple) else p for p in payloads]
        assert len(data) == len(rec.stdlib) > 1000
        for new, old, item_nulls in zip(data, rec.stdlib, rec.had_unknown):
            if old is None:
                continue
            a, b = json.loads(new), json.loads(old)
            assert a == b, (new, old)
            assert b"null" not in new
            unknown_left_out += item_nulls
            spelled_differently += new != old
    assert unknown_left_out > 0  # payloads with NaN or None fields went through (and left them out)
    assert spelled_differently > 0  # the comparison saw floats orjson spells otherwise (1e-7 vs 1e-07)


def test_recorder_dumps_falls_back_for_what_orjson_refuses():
    from companion.record.recorder import _dumps

    assert json.loads(_dumps({"big": 2**70, "x": math.nan})) == {"big": 2**70}  # unknown values are left out
    assert json.loads(_dumps({"a": np.float32(0.5), "b": np.arange(3)})) == {"a": 0.5, "b": [0, 1, 2]}
