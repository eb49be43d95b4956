"""One contract for every pipeline stage (companion.pipeline.stage.Stage): derived from Stage, lists from process()
and finish() for any item, Events out (with a topic and a finite time), str -> str metadata, str summary lines, and
the same outputs for the same input. All of them run in the gravity-aided replay pipeline on the bundled sample."""

from __future__ import annotations

import inspect
import math

import pytest

from companion.events import Event, StatusText
from companion.gravity.air_data_stage import AirDataGravityStage
from companion.gravity.sequential import SeqGravConfig
from companion.gravity.sequential_stage import SequentialGravityStage
from companion.gravity.stage import FixAcceptance, GravityMatchStage, gravity_replay_pipeline
from companion.inject import Injector
from companion.nav import Navigator
from companion.pipeline.denial import DenialErrorStage, GnssDenial, GnssDenialStage
from companion.pipeline.stage import Stage
from companion.sim.gravimeter import GravitySimStage
from companion.sources import read_events
from tests.conftest import SAMPLE_LOG
from tests.helpers import Collect, bumpy_map, subclasses

STAGES = {Navigator, Injector, GravityMatchStage, SequentialGravityStage, GnssDenialStage, DenialErrorStage,
          GravitySimStage}


def _bumpy_map():
    return bumpy_map(5, 3000.0, 25.0, 200, (50, 200))


@pytest.fixture(scope="module")
def events():
    evs = read_events(SAMPLE_LOG)
    return [e for e in evs if e.t_s <= evs[0].t_s + 90.0]


def _run(events, matcher="viterbi"):
    sink = Collect()
    # the sequential filter on the drone's 40 m circles: a fine tile and short signal window for the 25 m map
    seq = SeqGravConfig(n_particles=200, tile_cell_m=10.0, tile_half_m=1200.0, tile_margin_m=300.0, signal_window_m=200.0)
    pipe = gravity_replay_pipeline(sink, _bumpy_map(), GnssDenial(40.0), matcher=matcher, acceptance=FixAcceptance(),
                                   sigma_mgal=0.5, seq_config=seq)
    for ev in events:
        pipe.process(ev)
    pipe.finish()
    return pipe, sink.items


#: stages that cannot run in the gravity replay pipeline: the air-data reference needs a fixed wing's VFR_HUD air data,
#: which no shared log has (its own tests: tests/gravity/test_air_data_gravity.py, the ArduPlane SITL test)
OUTSIDE_REPLAY = {AirDataGravityStage}


def test_every_stage_of_the_package_is_under_contract_and_in_the_replay_pipeline(events):
    import companion.gravity.air_data_stage  # noqa: F401 - every stage module imported, whatever ran before

    product = {c for c in subclasses(Stage) if c.__module__.startswith("companion.") and not inspect.isabstract(c)}
    assert product == STAGES | OUTSIDE_REPLAY
    in_pipelines = set()
    for matcher in ("viterbi", "sequential"):
        pipe, _ = _run(events[:2000], matcher)
        in_pipelines |= {type(s) for s in pipe.stages}
    assert in_pipelines == STAGES


@pytest.mark.parametrize("matcher,record", [("viterbi", "MatchRecord"), ("sequential", "SequentialRecord")])
def test_stage_contract(events, matcher, record):
    pipe, items = _run(events, matcher)
    seen = {type(o) for o in items}
    assert {"FusedState", "GpsInputRecord", "GravityReading", record, "NavError"} <= {c.__name__ for c in seen}
    for o in items:
        assert isinstance(o, Event) and isinstance(o.topic, str) and o.topic.startswith("/") and math.isfinite(o.t_s)
        assert o.recorded
    for stage in pipe.stages:
        assert isinstance(stage, Stage)
        meta = stage.metadata()
        assert isinstance(meta, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in meta.items())
        assert all(isinstance(line, str) for line in stage.summary_lines())
        assert stage.finish() == [] or all(isinstance(o, Event) for o in stage.finish())
        assert stage.passes(StatusText(0.0, 6, "x")) or stage.filters
        out = stage.process(StatusText(events[-1].t_s + 1.0, 6, "an item this stage has no use for"))
        assert isinstance(out, list)
    # the same input gives the same outputs (compute times aside)
    _, again = _run(events, matcher)

    def key(o):
        d = o.to_dict()
        d.pop("compute_time_s", None)
        return type(o).__name__, repr(d)

    assert [key(o) for o in again] == [key(o) for o in items]
