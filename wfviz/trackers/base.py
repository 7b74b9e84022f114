"""What every tracker returns per frame, and the tracker protocol."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from wfviz.config import HorizonConfig, SuppressionConfig
from wfviz.io.clip import MIN_SIDE
from wfviz.io.frames import Frame
from wfviz.stages.detection import Detections
from wfviz.stages.front_end import FrontEndResult
from wfviz.tracking import Prediction, TrackEvent, TrackState
from wfviz.tracking.confirmation import Thresholds
from wfviz.tracking.decision import Verdicts


@dataclass(frozen=True)
class FrameResult:
    """Common per-frame output: tracks after update, predictions with gates, detections,
    events (born, confirmed, deleted, ...) and stage timings in milliseconds; with a track
    manager (GEWC, fusion), its ``verdicts`` (every confirmation and deletion test's value and
    level) and ``detection_tracks`` (per detection, the track that took it or started from it,
    -1: none). None: the tracker reports neither."""

    index: int
    time: float
    tracks: tuple[TrackState, ...]
    predictions: tuple[Prediction, ...]
    detections: Detections
    events: tuple[TrackEvent, ...]
    timings: dict[str, float]
    verdicts: Verdicts | None = None
    detection_tracks: np.ndarray | None = None

    @property
    def confirmed_ids(self) -> set[int]:
        """The ids of this frame's confirmed tracks."""
        return {t.track_id for t in self.tracks if t.confirmed}


@dataclass(frozen=True, kw_only=True)
class FrontEndTrackResult(FrameResult):
    """What the trackers built on the shared front end (:mod:`wfviz.stages.front_end`: GEWC and
    fusion) report besides the common fields: the front end's own result ``front`` (scene
    geometry, residual, noise, camera motion, its detections), the tracks' Kalman innovations
    and, with the sequential test, its levels."""

    front: FrontEndResult
    innovations: dict[int, np.ndarray]
    thresholds: Thresholds | None = None  # tracking.confirm = "sprt"


class TrailSection(Protocol):
    """The part of every tracker's ``tracking`` section the drive loop and recorder read."""

    trail_length: int


class TrackerConfig(Protocol):
    """What every tracker's configuration carries (each is a frozen dataclass of sections)."""

    tracking: TrailSection


class Tracker(Protocol):
    """A tracker consumes frames in order and reports every stage."""

    name: str
    config: TrackerConfig

    def step(self, frame: Frame) -> FrameResult:
        """Process one frame."""
        ...

    def min_frame_side(self) -> int:
        """Smallest frame side (px) the configured windows fit in (:func:`min_side`); the drive
        loop refuses smaller frames with one line."""
        ...


def min_side(suppression: SuppressionConfig | None = None, horizon: HorizonConfig | None = None) -> int:
    """Smallest frame side the configured windows fit in (16 px with the defaults): the background
    suppression's window and, when enabled, the horizon's ground-side variance window below the
    edge (:data:`wfviz.io.clip.MIN_SIDE` at least)."""
    side = MIN_SIDE
    if suppression is not None:
        side = max(side, int(suppression.size))
    if horizon is not None and horizon.enabled:
        side = max(side, int(horizon.variance_window) // 2 + int(horizon.step) + 2)
    return side


class StageTimer:
    """Milliseconds per stage, the one timer of every tracker: :meth:`lap` adds the time since
    the previous lap to ``stage`` (stages may repeat; or a time measured in another thread), :meth:`skip` leaves time uncounted,
    :meth:`inner` times a stage nested in the current lap (and leaves it out of that lap);
    :meth:`done` adds ``total`` (since creation, plus stages timed elsewhere) and returns the dict."""

    def __init__(self, stages: tuple[str, ...] = ()) -> None:
        self.timings: dict[str, float] = dict.fromkeys(stages, 0.0)
        self._start = self._t0 = time.perf_counter()
        self._elsewhere = 0.0  # ms of stages timed in another thread

    def lap(self, stage: str, ms: float | None = None) -> None:
        """``ms``: the stage ran elsewhere (another thread: :class:`wfviz.pipeline.PrepareAhead`)
        and took that long; it is added, and the time since the previous lap is not counted."""
        t1 = time.perf_counter()
        self.timings[stage] = self.timings.get(stage, 0.0) + ((t1 - self._t0) * 1e3 if ms is None else ms)
        if ms is not None:
            self._elsewhere += ms
        self._t0 = t1

    def skip(self) -> None:
        """Start the next lap now: the time since the last lap is not counted."""
        self._t0 = time.perf_counter()

    @contextmanager
    def inner(self, stage: str) -> Iterator[None]:
        """Time the block as ``stage``; the lap in progress does not count it."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            self.timings[stage] = self.timings.get(stage, 0.0) + dt * 1e3
            self._t0 += dt

    def done(self) -> dict[str, float]:
        """The timings, with ``total``: the time since creation plus the stages timed in another
        thread (the frame's whole work, however many threads shared it)."""
        self.timings["total"] = (time.perf_counter() - self._start) * 1e3 + self._elsewhere
        return self.timings
