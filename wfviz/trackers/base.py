"""What every tracker returns per frame, and the tracker protocol."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from wfviz.detection import Detections
from wfviz.frames import Frame
from wfviz.tracking import Prediction, TrackEvent, TrackState


@dataclass(frozen=True)
class FrameResult:
    """Common per-frame output: tracks after update, predictions with gates, detections,
    events (born, confirmed, deleted, ...) and stage timings in milliseconds."""

    index: int
    time: float
    tracks: tuple[TrackState, ...]
    predictions: tuple[Prediction, ...]
    detections: Detections
    events: tuple[TrackEvent, ...]
    timings: dict[str, float]


class Tracker(Protocol):
    """A tracker consumes frames in order and reports every stage."""

    name: str

    def step(self, frame: Frame) -> FrameResult:
        """Process one frame."""
        ...
