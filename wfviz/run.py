"""The drive loop: a tracker over a clip, each frame's result fed to the sinks
(:mod:`wfviz.sinks`: tracks CSV, recording, scores against truth, progress, timing). ``wfviz
record``, ``track``, ``demo`` (through :func:`run`) and ``bench`` (:mod:`wfviz.bench`) all use it."""

from __future__ import annotations

import dataclasses
import signal
import threading
import time
from collections.abc import Callable, Generator, Iterator, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from types import FrameType
from typing import Any

from wfviz.config import HorizonConfig, SuppressionConfig
from wfviz.evaluate import EvalResult, Points
from wfviz.io.clip import MIN_SIDE, check_frame_size
from wfviz.io.frames import Clip, Frame, read_ahead
from wfviz.io.outputs import check_writable
from wfviz.sinks import CallbackSink, RecordingSink, RunEnd, ScoreSink, Sink, Step, TracksSink
from wfviz.trackers.base import FrameResult, Tracker, TrackerConfig

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@dataclass(frozen=True)
class RunSummary:
    """What a run did: frames processed, wall time, confirmed track ids, the signal that
    stopped it (None if it ran to the end), skipped input frames, and the scores against
    truth when truth was given."""

    frames: int
    seconds: float
    tracker_ms: float
    confirmed: tuple[int, ...]
    interrupted: bool
    scores: EvalResult | None = None
    signal: int | None = None
    skipped: tuple[int, ...] = ()
    first: int | None = None
    last: int | None = None

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("inf")


class StopSignals:
    """While active, SIGINT and SIGTERM only set ``signum`` (checked between frames); the
    previous handlers are restored on exit. Inert outside the main thread."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old if old is not None else signal.SIG_DFL)
        self._old.clear()


def min_frame_side(config: TrackerConfig | None) -> int:
    """Smallest frame side the configured windows fit in (16 px with the defaults): the
    background suppression's window and the horizon's ground-side variance window below the
    edge, for the trackers whose configuration has those sections."""
    side = MIN_SIDE
    sections = [getattr(config, f.name) for f in dataclasses.fields(config)] if dataclasses.is_dataclass(config) else []
    for section in sections:
        if isinstance(section, SuppressionConfig):
            side = max(side, int(section.size))
        elif isinstance(section, HorizonConfig) and section.enabled:
            side = max(side, int(section.variance_window) // 2 + int(section.step) + 2)
    return side


def drive(clip: Clip, tracker: Tracker, sinks: Sequence[Sink], *, start: int = 0, stop: int | None = None,
          ahead: bool = True, signals: StopSignals | None = None) -> RunSummary:
    """The one loop: frames ``start <= index < stop`` of ``clip`` through ``tracker``, each
    :class:`~wfviz.sinks.Step` to every sink in order, then every sink's ``finish`` (or, on an
    error, every sink's ``abort``, and the error goes on).

    ``ahead`` decodes frames in a background thread while the tracker works
    (:func:`wfviz.io.frames.read_ahead`); without it a step's ``wait_ms`` is the decoding time.
    SIGINT and SIGTERM (and a KeyboardInterrupt raised by a sink) stop the run after the current
    frame; the sinks then finish with the frames done. ``signals``: an active :class:`StopSignals`
    of the caller (a signal that arrived while it opened the sinks stops the run before its first
    frame). No frame in the range: ValueError.
    """
    source = str(clip.path) if clip.path is not None else clip.name
    try:
        check_frame_size(clip.shape, source, min_frame_side(tracker.config))
    except BaseException:
        _abort(sinks)
        raise
    frames, confirmed, first, last = 0, set(), None, None
    tracker_ms = 0.0
    with (nullcontext(signals) if signals is not None else StopSignals()) as signals:
        t_start = time.perf_counter()
        stream = read_ahead(clip.frames(start, stop)) if ahead else _generator(clip.frames(start, stop))
        try:
            while True:
                t0 = time.perf_counter()
                frame = next(stream, None)
                t1 = time.perf_counter()
                if frame is None or signals.signum is not None:  # a signal while reading: no new frame
                    break
                result = tracker.step(frame)
                step = Step(frame, result, (t1 - t0) * 1e3, (time.perf_counter() - t1) * 1e3)
                tracker_ms += step.step_ms
                confirmed.update(t.track_id for t in result.tracks if t.confirmed)
                frames += 1  # counted before the sinks: one that raises KeyboardInterrupt had it
                first = frame.index if first is None else first
                last = frame.index
                for sink in sinks:
                    sink.step(step)
                if signals.signum is not None:
                    break
        except KeyboardInterrupt:  # not installed (other thread) or raised by a sink
            signals.signum = signals.signum or signal.SIGINT
        except BaseException:
            _abort(sinks)
            raise
        finally:
            stream.close()
        if frames == 0 and signals.signum is None:
            _abort(sinks)
            raise ValueError(f"{source}: no frames in the selected range (start={start}, stop={stop})")
        end = RunEnd(frames, signals.signum)
        try:
            for sink in sinks:
                sink.finish(end)
        except BaseException:
            _abort(sinks)
            raise
    return RunSummary(frames, time.perf_counter() - t_start, tracker_ms / max(frames, 1), tuple(sorted(confirmed)),
                      signals.signum is not None, None, signals.signum, tuple(sorted(clip.skipped)), first, last)


def run(clip: Clip, tracker: Tracker, *, tracks_csv: Path | None = None, recording: Path | None = None,
        recorder_options: dict | None = None, start: int = 0, stop: int | None = None,
        truth: tuple[Points, Points] | None = None, gate: float = 3.0,
        on_frame: Callable[[Frame, FrameResult], None] | None = None) -> RunSummary:
    """Track ``clip`` frames ``start <= index < stop`` with the usual sinks (what ``wfviz
    record``, ``track`` and ``demo`` run): the tracks CSV, the recording, scores against
    ``truth`` (visible, hidden points from :func:`wfviz.evaluate.read_truth`, or a synthetic
    clip's :meth:`truth_points`) and ``on_frame``.

    Outputs are written to unique temporary files beside them
    (:func:`wfviz.io.outputs.temp_path`) and renamed when the run ends; on a signal the frames
    done are kept (``interrupted`` and ``signal`` set), on any error, or when no frame was
    processed, the partial files are removed (no frames: ValueError).
    """
    source = str(clip.path) if clip.path is not None else clip.name
    check_frame_size(clip.shape, source, min_frame_side(tracker.config))
    for p in (tracks_csv, recording):
        if p is not None:
            check_writable(p)
    sinks: list[Sink] = []
    score = ScoreSink(truth, gate) if truth is not None else None
    with StopSignals() as signals:  # a signal while the outputs open: they are kept, empty
        try:
            if score is not None:
                sinks.append(score)
            if tracks_csv is not None:
                sinks.append(TracksSink(tracks_csv))
            if recording is not None:
                sinks.append(RecordingSink(recording, tracker.name, clip, recorder_options, score))
            if on_frame is not None:
                sinks.append(CallbackSink(on_frame))
        except BaseException:
            _abort(sinks)
            raise
        summary = drive(clip, tracker, sinks, start=start, stop=stop, signals=signals)
    return replace(summary, scores=score.scores) if score is not None else summary


def _generator(frames: Iterator[Frame]) -> Generator[Frame, None, None]:
    """``frames`` as a generator (closing it closes the source when the source can close)."""
    try:
        yield from frames
    finally:
        close = getattr(frames, "close", None)  # an Iterator need not be a generator
        if close is not None:
            close()


def _abort(sinks: Sequence[Sink]) -> None:
    """Every sink removes what it has written so far."""
    for sink in sinks:
        sink.abort()
