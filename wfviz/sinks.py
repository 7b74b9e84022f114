"""What the drive loop (:func:`wfviz.run.drive`) feeds each frame's result to: the tracks CSV, the
recording, the scores against truth, progress callbacks and per-stage timing.

A sink takes every :class:`Step`, then either :meth:`Sink.finish` (the run ended, or was stopped
by a signal: complete the output) or :meth:`Sink.abort` (an error: remove what is partial). The
loop calls them in list order, so a sink may read one listed before it (the recording logs the
scores the :class:`ScoreSink` computed)."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from wfviz.evaluate import EvalResult, Points, evaluate_points, format_table, frame_errors
from wfviz.io.frames import Clip, Frame
from wfviz.io.outputs import OutputError, TracksWriter, replace_into, temp_path
from wfviz.trackers.base import FrameResult


@dataclass(frozen=True)
class Step:
    """One frame through the loop: the frame, the tracker's result, and the milliseconds spent
    waiting for the frame (its decoding, unless read ahead) and in ``tracker.step``."""

    frame: Frame
    result: FrameResult
    wait_ms: float
    step_ms: float


@dataclass(frozen=True)
class RunEnd:
    """How the loop ended: frames processed, and the signal that stopped it (None: the end)."""

    frames: int
    signum: int | None


class Sink(Protocol):
    """A consumer of the loop's steps."""

    def step(self, step: Step) -> None: ...

    def finish(self, end: RunEnd) -> None: ...

    def abort(self) -> None: ...


class TracksSink:
    """The tracks CSV (``frame,track_id,x,y,confirmed``), written to a temporary name and renamed
    into place when the run finishes."""

    def __init__(self, path: Path) -> None:
        self.writer: TracksWriter | None = TracksWriter(path)

    def step(self, step: Step) -> None:
        assert self.writer is not None
        self.writer.write(step.frame.index, step.result.tracks)

    def finish(self, end: RunEnd) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None  # complete: an abort later (another sink failing) keeps it

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.abort()
            self.writer = None


class ScoreSink:
    """Scores against truth (visible, hidden points) over the frames processed; ``scores`` is set
    when the run finishes."""

    def __init__(self, truth: tuple[Points, Points], gate: float) -> None:
        self.shown, self.hidden = truth
        self.gate = gate
        self.tracked: Points = {}
        self.scores: EvalResult | None = None

    def confirmed_points(self, result: FrameResult) -> list[tuple[int, float, float]]:
        return [(t.track_id, t.x, t.y) for t in result.tracks if t.confirmed]

    def step(self, step: Step) -> None:
        self.tracked[step.frame.index] = self.confirmed_points(step.result)

    def finish(self, end: RunEnd) -> None:
        if self.tracked:
            span = set(self.tracked)
            self.scores = evaluate_points(self.tracked, {f: v for f, v in self.shown.items() if f in span},
                                          self.gate, {f: v for f, v in self.hidden.items() if f in span})

    def abort(self) -> None:
        pass


class RecordingSink:
    """The Rerun recording (:mod:`wfviz.record`; rerun is imported only here, when recording):
    every stage of every frame, the clip's skipped-input problems, per-frame errors against
    truth and the final scores when a :class:`ScoreSink` is given, and a warning when a signal
    stopped the run. Written to a temporary name, renamed into place on finish."""

    def __init__(self, path: Path, tracker: str, clip: Clip, options: dict[str, Any] | None = None,
                 scores: ScoreSink | None = None) -> None:
        from wfviz.record import open_recorder

        self.path, self.temp = path, temp_path(path)
        self.scores = scores
        self.skip_log = _SkipLog(clip)
        self.frames = 0
        try:
            self.recorder: Any = open_recorder(tracker, self.temp, **(options or {}))
        except BaseException:
            self.temp.unlink(missing_ok=True)
            raise

    def step(self, step: Step) -> None:
        rec = self.recorder
        with self._errors():
            rec.log(step.frame, step.result)
            self.skip_log(rec)
        if self.scores is not None:
            f, s = step.frame.index, self.scores
            shown, hidden = s.shown.get(f, []), s.hidden.get(f, [])
            rec.log_truth(shown, hidden, frame_errors(s.confirmed_points(step.result), shown, s.gate, hidden))
        self.frames += 1

    def finish(self, end: RunEnd) -> None:
        rec = self.recorder
        if self.scores is not None and self.scores.scores is not None:
            rec.log_scores(format_table(self.scores.scores))
        self.skip_log(rec)
        if end.signum is not None:
            name = signal.Signals(end.signum).name
            rec.log_message(f"interrupted by {name} after {end.frames} frames", level="WARN")
        with self._errors():
            rec.close()
        try:
            replace_into(self.temp, self.path)
        finally:
            rec.end_live()  # a live view lost or stalled waits only once the file is in place

    def abort(self) -> None:
        try:
            self.recorder.close()
        except Exception:  # noqa: BLE001 - the file is removed anyway
            pass
        self.temp.unlink(missing_ok=True)
        self.recorder.end_live()

    @contextmanager
    def _errors(self) -> Iterator[None]:
        """Rerun's file writer failing (a full disk: "File-writer thread shut down prematurely")
        as a one-line OutputError naming the recording."""
        try:
            yield
        except RuntimeError as exc:
            raise OutputError(f"{self.path}: cannot write the recording ({exc}; is the disk full?)") from None


class _SkipLog:
    """Logs each new skipped-input problem of the clip once in the recording's ``log``."""

    def __init__(self, clip: Clip) -> None:
        self.skipped = clip.skipped
        self.seen = 0
        self.reported: set[str] = set()

    def __call__(self, recorder: Any) -> None:
        if not self.skipped or len(self.skipped) == self.seen:
            return
        self.seen = len(self.skipped)
        for problem in dict.fromkeys(self.skipped.values()):
            if problem not in self.reported:
                self.reported.add(problem)
                recorder.log_message(f"skipped: {problem}", level="WARN")


class CallbackSink:
    """Calls ``fn(frame, result)`` after the other sinks took the frame (progress bars, samplers)."""

    def __init__(self, fn: Callable[[Frame, FrameResult], None]) -> None:
        self.fn = fn

    def step(self, step: Step) -> None:
        self.fn(step.frame, step.result)

    def finish(self, end: RunEnd) -> None:
        pass

    def abort(self) -> None:
        pass


@dataclass(frozen=True)
class StageTiming:
    """Milliseconds per frame for one stage: median, mean, 95th percentile."""

    stage: str
    median: float
    mean: float
    p95: float


class TimingSink:
    """Per-stage milliseconds (the tracker's ``timings``) and the wait for each frame (decoding),
    leaving out the first ``warmup`` frames."""

    def __init__(self, warmup: int = 3) -> None:
        self.warmup = warmup
        self.seen = 0
        self.shape: tuple[int, int] = (0, 0)
        self.decode: list[float] = []
        self.stages: dict[str, list[float]] = {}

    def step(self, step: Step) -> None:
        self.seen += 1
        self.shape = step.frame.image.shape[:2]
        if self.seen <= self.warmup:
            return
        self.decode.append(step.wait_ms)
        for stage, ms in step.result.timings.items():
            self.stages.setdefault(stage, []).append(ms)

    def finish(self, end: RunEnd) -> None:
        pass

    def abort(self) -> None:
        pass

    def timings(self) -> tuple[StageTiming, tuple[StageTiming, ...]]:
        """Decoding, then each stage (``total`` last)."""
        order = [s for s in self.stages if s != "total"] + (["total"] if "total" in self.stages else [])
        return _timing("decode", self.decode), tuple(_timing(s, self.stages[s]) for s in order)


def _timing(stage: str, values: list[float]) -> StageTiming:
    a = np.asarray(values, dtype=np.float64)
    return StageTiming(stage, float(np.median(a)), float(a.mean()), float(np.percentile(a, 95)))
