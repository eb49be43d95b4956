"""The pipeline: a source's events through the stages (navigator, gravity matching, injector, ...) into the record.

:mod:`companion.pipeline.stage` holds the `Stage` base every stage derives from, :mod:`companion.pipeline.core` the
pipeline itself and :func:`build_pipeline`, :mod:`companion.pipeline.denial` the GNSS denial filter of replays.
"""

from companion.pipeline.core import GNSS_MAP_TOPIC, Pipeline, Sink, build_pipeline, run_source, wall_time_s

__all__ = ["GNSS_MAP_TOPIC", "Pipeline", "Sink", "build_pipeline", "run_source", "wall_time_s"]
