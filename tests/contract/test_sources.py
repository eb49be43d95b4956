"""One contract for every companion.sources.base.Source: an async iterator of events in SI with its own
SourceInfo, a progress() answer, an aclose() that may be called twice, and SourceError (a sentence for the user)
for input it cannot use."""

from __future__ import annotations

import asyncio
import os
import socket
import threading
import time

import numpy as np
import pytest

from companion.events import Event
from companion.gravity import GravityMap, LocalGravityMap
from companion.gravity.placement import Placement
from companion.sim.gravimeter import SimulatedGravimeter, SimulatedGravitySource
from companion.sources import FileSource
from companion.sources.base import Source, SourceError, SourceInfo
from companion.sources.gravity import SerialGravitySource, UdpGravitySource
from tests.conftest import SAMPLE_LOG, free_port
from tests.helpers import subclasses


def _flat_map():
    ax = np.arange(-5000.0, 5001.0, 100.0)
    return LocalGravityMap(GravityMap(np.add.outer(ax, ax) * 1e-3, ax, ax, "local_m"))


def _udp(tmp_path):
    port = free_port(socket.SOCK_DGRAM)

    def send():
        time.sleep(0.3)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"GRAV,1.0,10.5\nGRAV,2.0,11.5,0.5\n", ("127.0.0.1", port))

    threading.Thread(target=send, daemon=True).start()
    return UdpGravitySource("127.0.0.1", port)


def _serial(tmp_path):
    master, slave = os.openpty()

    def send():  # once the port is open (opening it flushes what is waiting)
        time.sleep(0.5)
        os.write(master, b"GRAV,1.0,10.5\nGRAV,2.0,11.5\n")

    threading.Thread(target=send, daemon=True).start()
    src = SerialGravitySource(os.ttyname(slave), 115200)
    src._test_fds = (master, slave)
    return src


def _simulated(tmp_path):
    grav = SimulatedGravimeter(_flat_map(), Placement(), np.random.default_rng(0))
    return SimulatedGravitySource(grav, [(float(t), 10.0 * t, 0.0) for t in range(5)])


#: every Source of the package: a factory of a working one, and one of a source its input makes unusable
SOURCES = {
    FileSource: (lambda tmp_path: FileSource(SAMPLE_LOG), lambda tmp_path: FileSource(tmp_path / "missing.tlog")),
    UdpGravitySource: (_udp, None),
    SerialGravitySource: (_serial, lambda tmp_path: SerialGravitySource(str(tmp_path / "no-such-tty"))),
    SimulatedGravitySource: (_simulated, None),
}


def test_every_source_of_the_package_is_under_contract():
    import companion.runtime.runner  # noqa: F401 - the live runtime and its link: no Source of their own

    assert companion.runtime.runner.Runtime

    product = {c for c in subclasses(Source) if c.__module__.startswith("companion.") and not c.__name__.startswith("_")}
    assert product == set(SOURCES)


async def _take(src: Source, n: int, timeout_s: float = 10.0) -> list:
    out: list = []

    async def run():
        async for ev in src:
            out.append(ev)
            if len(out) >= n:
                break

    try:
        await asyncio.wait_for(run(), timeout_s)
    except asyncio.TimeoutError:
        pass
    await src.aclose()
    await src.aclose()  # twice is fine
    return out


@pytest.mark.parametrize("cls", list(SOURCES), ids=lambda c: c.__name__)
def test_source_contract(cls, tmp_path):
    make, make_bad = SOURCES[cls]
    src = make(tmp_path)
    try:
        assert isinstance(src.info, SourceInfo) and src.info.kind and src.info.location
        p = src.progress()
        assert p is None or (len(p) == 2 and 0 <= p[0] <= p[1])
        events = asyncio.run(_take(src, 2))
        assert len(events) == 2
        assert all(isinstance(e, Event) and np.isfinite(e.t_s) for e in events)
        assert events[0].t_s <= events[1].t_s
    finally:
        for fd in getattr(src, "_test_fds", ()):
            os.close(fd)
    if make_bad is not None:
        with pytest.raises(SourceError) as err:
            asyncio.run(_take(make_bad(tmp_path), 1))
        assert str(err.value) and "Traceback" not in str(err.value)
