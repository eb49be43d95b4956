"""What ``companion replay`` of one log and of a fleet (companion.replay_job) share: the record's closing metadata, the
test for a damaged log, the chunk interval. Light: the command line imports it before any heavy package."""

from __future__ import annotations

import json

#: a replay closes an MCAP chunk every 10 s of vehicle time (the live process: every second, for durability). The
#: writer keeps an index entry per chunk until the file is finalised: with 1 s chunks that index holds 15 MiB of a 3 h
#: replay's memory
REPLAY_FLUSH_INTERVAL_S = 10.0


def stage_metadata(stage) -> dict[str, str]:
    """What a stage says about itself (companion.pipeline.stage.Stage.metadata); unset values left out."""
    return {k: str(v) for k, v in stage.metadata().items() if v is not None and str(v) not in ("", "None")}


def finish_record(recorder, source, pipeline, config: dict, stopped_by: str | None) -> None:
    """The record's closing metadata (source, settings, each stage's, the stream summary), then close it."""
    info = source.info
    meta = {"kind": info.kind, "location": info.location}
    meta.update({f"detail.{k}": v for k, v in info.details.items()})
    for i, w in enumerate(info.warnings + pipeline.stats.warnings()):
        meta[f"warning.{i}"] = w
    recorder.add_metadata("source", meta)
    recorder.add_metadata("config", {k: str(v) for k, v in config.items()})
    for stage in pipeline.stages:
        meta = stage_metadata(stage)
        if meta:
            recorder.add_metadata(type(stage).__name__, meta)
    summary = pipeline.stats.as_dict()
    summary["stopped_by"] = stopped_by or "end of input"
    recorder.add_metadata("summary", {"json": json.dumps(summary, sort_keys=True)})
    recorder.close()


def damaged_warning(warning: str) -> bool:
    """Whether a reader's warning says the log is truncated or corrupt."""
    return warning.startswith(("truncated", "stopped reading", "skipped", "the last"))


def damaged(source) -> bool:
    """Whether the reader met a truncated or corrupt log (everything readable was still replayed)."""
    return any(damaged_warning(w) for w in source.info.warnings)
