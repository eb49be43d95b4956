"""GNSS gap filling (Aziez et al. 2021): KNN predictor, strapdown INS and Kalman integrator.

Streaming entry point: :class:`Navigator` (``process(event) -> outputs``, ``finish()``), configured by
:class:`NavigatorConfig`; :func:`run_navigator` is the batch replay of an event list. Outputs are the
dataclasses of :mod:`companion.nav.outputs`. Pure numerics: no I/O, asyncio or wall clock.
"""

from companion.nav.ins import StrapdownIns
from companion.nav.navigator import Navigator, NavigatorConfig, run_navigator
from companion.nav.knn_predictor import KnnConfig, KnnPredictor
from companion.nav.outputs import (
    OUTPUT_TYPES,
    FrameInfo,
    FusedState,
    MeasurementUpdate,
    ModeChange,
    NavigatorReset,
    PredictorPoint,
)

__all__ = [
    "Navigator", "NavigatorConfig", "run_navigator", "KnnPredictor", "KnnConfig", "StrapdownIns",
    "OUTPUT_TYPES", "FrameInfo", "FusedState", "MeasurementUpdate", "ModeChange", "NavigatorReset",
    "PredictorPoint",
]
