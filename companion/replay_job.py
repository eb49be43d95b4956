"""One log's replay without a terminal: the job `companion replay` runs for each log of a fleet, in a worker process or
on a Dask worker; the record it writes is the single replay's (companion.replay_common).

:func:`replay_job` never raises for a bad log: whatever goes wrong (unreadable input, a crash in a stage, a full
disk) comes back as a row with exit code 2 and the reason, so one log never stops the others. The row is small and
plain (str, int, float, None): what the fleet summary tabulates (companion.fleet).
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

from companion.events import Heartbeat, StatusText
from companion.replay_common import REPLAY_FLUSH_INTERVAL_S, damaged, damaged_warning, finish_record

EXIT_OK, EXIT_ERROR, EXIT_DAMAGED = 0, 2, 3
#: ArduPilot's version banner (STATUSTEXT / dataflash MSG), e.g. "APM:Copter V3.5.7 (b11c6af3)", "ArduPlane V4.3.0"
_FIRMWARE = re.compile(r"\b(?:APM:|Ardu)(Copter|Plane|Rover|Sub|Tracker|Blimp)\b[^\n]*?\bV\d+\.\d+\S*")


class VehicleFacts:
    """Notes what the stream says about the vehicle: the first autopilot HEARTBEAT's MAV_TYPE and the firmware banner
    (a fleet summary's columns); shown every input event before the pipeline."""

    def __init__(self) -> None:
        self.vehicle_type: int | None = None
        self.firmware: str | None = None

    def see(self, item: Any) -> None:
        t = type(item)
        if t is Heartbeat:
            if self.vehicle_type is None:
                self.vehicle_type = item.vehicle_type
        elif t is StatusText and self.firmware is None:
            m = _FIRMWARE.search(item.text)
            if m:
                self.firmware = m.group(0)

    def vehicle(self, firmware: str | None) -> str | None:
        """MAV_TYPE's name (quadrotor, fixed wing, ...) when a heartbeat gave it, else the firmware's kind (copter)."""
        if self.vehicle_type is not None:
            from companion.mavlink.dialect import mavlink

            entry = mavlink.enums["MAV_TYPE"].get(self.vehicle_type)
            if entry is not None:
                return entry.name.removeprefix("MAV_TYPE_").lower().replace("_", " ")
        m = _FIRMWARE.search(firmware or "")
        return m.group(1).lower() if m else None


def _row(log: Path, out: Path) -> dict[str, Any]:
    return {"log": str(log), "record": str(out), "exit_code": EXIT_ERROR, "error": "", "duration_s": None,
            "vehicle": None, "firmware": None, "gnss_hz": None, "imu_hz": None, "gnss_fixes": 0, "gnss_gaps": 0,
            "gnss_gap_s": 0.0, "stream_gaps": 0, "events": 0, "warnings": 0, "cpu_s": None}


def replay_job(log: str, out: str, navigator: bool = True) -> dict[str, Any]:
    """Replay ``log`` into the MCAP ``out`` (as ``companion replay LOG --out OUT``) and return its summary row.
    Never raises for a bad log: the row's exit code (0 ok, 2 not replayed, 3 damaged but replayed) and error say."""
    import asyncio

    from companion import __version__
    from companion.pipeline.core import build_pipeline
    from companion.record import Recorder
    from companion.record.clock import RecordClock, find_utc_offset
    from companion.sources import FileSource, SourceError

    t0 = time.process_time()
    log_p, out_p = Path(log), Path(out)
    row = _row(log_p, out_p)
    recorder = pipeline = source = None
    try:
        if log_p.resolve() == out_p.resolve():
            raise SourceError(f"--out {out_p} is the input {log_p}: refusing to overwrite it")
        source = FileSource(log_p)
        out_p.parent.mkdir(parents=True, exist_ok=True)
        utc = find_utc_offset(log_p)
        recorder = Recorder(out_p, clock=RecordClock(*utc) if utc else RecordClock(), raise_errors=True,
                            flush_interval_s=REPLAY_FLUSH_INTERVAL_S)
        facts = VehicleFacts()
        pipeline = build_pipeline(recorder, navigator=navigator)
        asyncio.run(_drive(source, pipeline, facts))
        config = {"command": "replay", "log": str(log_p), "realtime_factor": None, "companion_version": __version__}
        finish_record(recorder, source, pipeline, config, None)
        recorder = None
        if damaged(source):
            row["exit_code"] = EXIT_DAMAGED
            row["error"] = next(w for w in source.info.warnings if damaged_warning(w))
        else:
            row["exit_code"] = EXIT_OK
    except Exception as err:  # noqa: BLE001 - one bad log never stops the fleet: its row says what happened
        row["error"] = str(err) if isinstance(err, SourceError) else f"{type(err).__name__}: {err}"
        row["exit_code"] = EXIT_ERROR
        if recorder is not None:
            try:
                recorder.close()
            except Exception:  # noqa: BLE001 - the first error is the one to report
                pass
        if pipeline is None or not pipeline.stats.counts:
            out_p.unlink(missing_ok=True)  # no empty record left behind
    finally:
        if source is not None:
            try:
                asyncio.run(source.aclose())
            except Exception:  # noqa: BLE001
                pass
    if pipeline is not None and pipeline.stats.counts:
        _fill(row, source, pipeline, facts)
    row["cpu_s"] = round(time.process_time() - t0, 3)
    return row


async def _drive(source, pipeline, facts: VehicleFacts) -> None:
    """companion.pipeline.core.run_source as fast as possible, each input event shown to ``facts`` first."""
    async for ev in source:
        facts.see(ev)
        pipeline.process(ev)
    pipeline.finish()


def _fill(row: dict[str, Any], source, pipeline, facts: VehicleFacts) -> None:
    st = pipeline.stats
    firmware = source.info.details.get("firmware") or facts.firmware
    imu = st.imu_rates_hz().get(0)
    gaps = st.gnss_gaps()
    row.update(duration_s=round(st.duration_s, 1), firmware=firmware, vehicle=facts.vehicle(firmware),
               gnss_hz=None if st.gnss_rate_hz is None else round(st.gnss_rate_hz, 2),
               imu_hz=None if imu is None else round(imu, 1), gnss_fixes=st.gnss_fixes, gnss_gaps=len(gaps),
               gnss_gap_s=round(sum(g.duration_s for g in gaps), 1), stream_gaps=len(st.stream_gaps()),
               events=sum(st.counts.values()), warnings=len(source.info.warnings + st.warnings()))
