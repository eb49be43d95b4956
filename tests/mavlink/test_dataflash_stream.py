"""The streaming dataflash reader against pymavlink's DFReader: the same rows with the same values on every shared
dataflash log, in the same order, whatever the block size; memory bounded by the block, not the file."""

from __future__ import annotations

import math

import pytest

from companion.mavlink.dataflash import WANTED
from companion.mavlink.dataflash_stream import DataflashStream
from tests.conftest import REAL_LOGS, require

BIN_LOGS = [p for p in REAL_LOGS if p.suffix == ".bin"]
ALL_TYPES = WANTED + ["PARM", "MODE", "BARO", "CTUN", "NTUN", "EKF1", "AHR2", "RCOU", "CURR", "VER", "GPS2", "GPA2"]


def _stream_rows(path, wanted, block_bytes=1 << 18):
    s = DataflashStream(path, wanted, block_bytes)
    rows = []
    while (block := s.next_block()) is not None:
        for r, k in block.order:
            if r is not None:
                rows.append((r.fmt.name, {c: v[k] for c, v in r.cols.items()}))
    s.close()
    return rows, s


def _pymavlink_rows(path, wanted):
    from pymavlink import DFReader

    log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    rows = []
    while (m := log.recv_match(type=wanted)) is not None:
        d = m.to_dict()
        d.pop("mavpackettype")
        rows.append((m.get_type(), d))
    return rows


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("log", BIN_LOGS, ids=lambda p: p.stem[:24])
def test_every_row_equals_pymavlinks(log):
    path = require(log)
    ours, stream = _stream_rows(path, ALL_TYPES)
    ref = _pymavlink_rows(path, ALL_TYPES)
    assert len(ours) == len(ref) > 1000
    for (n1, d1), (n2, d2) in zip(ours, ref):
        assert n1 == n2 and d1.keys() == d2.keys(), (n1, n2)
        bad = [c for c in d1 if not _same(d1[c], d2[c])]
        assert not bad, (n1, {c: (d1[c], d2[c]) for c in bad})
    assert stream.skipped_bytes == 0 and stream.unfit == {}


def test_block_size_does_not_change_the_rows():
    path = require(BIN_LOGS[0])
    ref, _ = _stream_rows(path, WANTED)
    for block in (100, 4099, 1 << 16):  # records across block boundaries, blocks smaller than a record
        rows, _ = _stream_rows(path, WANTED, block)
        assert rows == ref


_PEAK_RSS = """
import resource, sys
from companion.mavlink.dataflash import WANTED
from companion.mavlink.dataflash_stream import DataflashStream
s = DataflashStream(sys.argv[1], WANTED)
n = 0
while (block := s.next_block()) is not None:
    n += len(block.order)
print(n, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def test_memory_is_bounded_by_the_block(tmp_path):
    """A log of 20 copies of one flight's records reads in the peak memory of the flight alone (pymavlink's reader
    maps the file and indexes every record: its memory grows with the file)."""
    import subprocess
    import sys

    data = require(BIN_LOGS[0]).read_bytes()
    body = data[data.find(b"\xa3\x95", 20_000):]  # records after the FMT block: one log, 20 times as long
    big = tmp_path / "long.bin"
    with open(big, "wb") as f:
        f.write(data)
        for _ in range(19):
            f.write(body)
    runs = [subprocess.run([sys.executable, "-c", _PEAK_RSS, str(p)], capture_output=True, text=True, timeout=600)
            for p in (require(BIN_LOGS[0]), big)]
    (n1, rss1), (n20, rss20) = [tuple(map(int, r.stdout.split())) for r in runs]
    assert n20 > 19 * n1
    assert rss20 < 1.2 * rss1, (rss1, rss20)
