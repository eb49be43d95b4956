"""The input side both gravity stages share (companion.gravity.stage.GravityMatchStage, the window matchers, and
companion.gravity.sequential_stage.SequentialGravityStage): the navigator's frame, the gravimeter readings queued
until a navigator state at or after their time arrives, and the states themselves."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from typing import Any

from companion.events import Event, GravityReading
from companion.nav.outputs import FrameInfo, FusedState
from companion.pipeline.denial import frame_of
from companion.pipeline.stage import Stage


class GravityReadingStage(Stage, ABC):
    """Base: ``process`` keeps the frame (``_frame``) and the finite readings (``_pending``, in time order) and hands
    each FusedState, once a frame is known, to ``_state``, which uses the readings it brackets."""

    def __init__(self) -> None:
        self._frame = None
        self._pending: deque[GravityReading] = deque()

    def process(self, item: Any) -> list[Event]:
        if isinstance(item, FrameInfo):
            self._frame = frame_of(item)
        elif isinstance(item, GravityReading):
            if math.isfinite(item.gravity_mgal):
                self._pending.append(item)
        elif isinstance(item, FusedState) and self._frame is not None:
            return self._state(item)
        return []

    @abstractmethod
    def _state(self, s: FusedState) -> list[Event]:
        """The outputs of a navigator state and of the queued readings it reaches."""
