"""What the drive loop (:func:`wfviz.run.drive`) feeds each frame's results to: the tracks CSV, the
recording, the scores against truth, progress callbacks, per-stage timing (and ``wfviz
compare``'s disagreement finder and comparison recording, :mod:`wfviz.compare.session`).

Each frame, the loop first has every sink ``publish`` what it computes of the frame into the
step's :class:`Facts` (a run's matches and errors against truth, the disagreements of a
comparison), then gives every sink the ``step``. At the end every sink ``conclude``'s (publishes
what it computed of the whole run into the end's facts: the scores) before any ``finish``'es (the
run ended, or a signal stopped it: complete the output); on an error every sink ``abort``'s
instead (removes what is partial). A sink reads what others publish, never the other sinks, so
their order in the list does not matter."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from wfviz.io.frames import Clip, Frame
from wfviz.io.outputs import OutputError, TextOutput, replace_into, temp_path
from wfviz.record_options import RecorderOptions
from wfviz.trackers.base import FrameResult
from wfviz.tracking import TrackState

if TYPE_CHECKING:  # the scoring is imported where a run has truth only (`wfviz track` starts sooner)
    from wfviz.evaluate import Box, EvalResult, FrameErrors, Point, Points

T = TypeVar("T")

TRACKS_HEADER = ["frame", "track_id", "x", "y", "confirmed", "vx", "vy", "meeting"]


class Facts:
    """What the sinks computed of one frame (or, at the end, of the whole run), one value per
    type and run (``run``: the index in the stepper's runs; 0 for a single tracker)."""

    def __init__(self) -> None:
        self._values: dict[tuple[type, int], object] = {}

    def put(self, value: object, run: int = 0) -> None:
        self._values[type(value), run] = value

    def get(self, kind: type[T], run: int = 0) -> T | None:
        value = self._values.get((kind, run))
        return value if isinstance(value, kind) else None


@dataclass(frozen=True)
class Step:
    """One frame through the loop: the frame, each run's result (one run: a single tracker),
    the milliseconds spent waiting for the frame (its decoding, unless read ahead) and in the
    stepper's step, each run's milliseconds as it would cost alone, and what the sinks
    published of the frame."""

    frame: Frame
    results: tuple[FrameResult, ...]
    wait_ms: float
    step_ms: float
    run_ms: tuple[float, ...] = ()
    facts: Facts = field(default_factory=Facts)

    @property
    def result(self) -> FrameResult:
        """The (first) run's result."""
        return self.results[0]


@dataclass(frozen=True)
class RunEnd:
    """How the loop ended: frames processed, the signal that stopped it (None: the end), wall
    seconds since the first frame was asked for, and what the sinks published of the run."""

    frames: int
    signum: int | None
    seconds: float = 0.0
    facts: Facts = field(default_factory=Facts)


class Sink(Protocol):
    """A consumer of the loop's steps (see the module docstring for the order of the calls)."""

    def publish(self, step: Step) -> None: ...

    def step(self, step: Step) -> None: ...

    def conclude(self, end: RunEnd) -> None: ...

    def finish(self, end: RunEnd) -> None: ...

    def abort(self) -> None: ...


class BaseSink:
    """A sink that does nothing: subclasses override what they need."""

    def publish(self, step: Step) -> None:
        pass

    def step(self, step: Step) -> None:
        pass

    def conclude(self, end: RunEnd) -> None:
        pass

    def finish(self, end: RunEnd) -> None:
        pass

    def abort(self) -> None:
        pass


def confirmed_points(result: FrameResult) -> list[Point]:
    """(track_id, x, y) of the confirmed tracks of a result: what is scored against truth."""
    return [(t.track_id, t.x, t.y) for t in result.tracks if t.confirmed]


class TracksWriter(TextOutput):
    """Tracks CSV: ``frame,track_id,x,y,confirmed,vx,vy,meeting``, one row per live track,
    written to a unique temporary file and renamed to ``path`` by :meth:`close`.

    ``backfill``: a column ``backfilled`` more, and when the run is complete the rows a track
    wrote while tentative are rewritten as confirmed (``backfilled`` 1) if it was confirmed
    later: a confirmed track reported from its first frame, for the offline analysis of a
    recorded clip (a live system cannot know it yet). The rows are streamed through a second
    temporary file at :meth:`close`; only the confirmed tracks' ids are kept meanwhile."""

    def __init__(self, path: Path, backfill: bool = False) -> None:
        super().__init__(path, ",".join(TRACKS_HEADER + (["backfilled"] if backfill else [])))
        self.backfill = backfill
        self.confirmed: set[int] = set()  # ids of the tracks confirmed so far

    def write_tracks(self, frame: int, tracks: tuple[TrackState, ...]) -> None:
        """Append the rows of one frame."""
        end = ",0\r\n" if self.backfill else "\r\n"
        self.write("".join(
            f"{frame},{t.track_id},{t.x:.3f},{t.y:.3f},{t.confirmed:d},{t.vx:.3f},{t.vy:.3f},{t.meeting:d}{end}"
            for t in tracks))  # the csv module's dialect (\r\n), plain numbers need no quoting
        if self.backfill:
            self.confirmed.update(t.track_id for t in tracks if t.confirmed)

    def close(self) -> None:
        """Flush, rewrite the backfilled rows (``backfill``), rename into place."""
        if not self.backfill:
            super().close()
            return
        try:
            self._fh.close()
            final = temp_path(self.path)
            try:
                with open(self.temp, newline="", encoding="utf-8") as src, \
                        open(final, "w", newline="", encoding="utf-8") as dst:
                    dst.write(src.readline())
                    for line in src:
                        f = line.split(",", 5)
                        if f[4] == "0" and int(f[1]) in self.confirmed:
                            rest = f[5].rsplit(",", 1)[0]
                            line = f"{f[0]},{f[1]},{f[2]},{f[3]},1,{rest},1\r\n"
                        dst.write(line)
            except BaseException:
                final.unlink(missing_ok=True)
                raise
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write ({exc.strerror or exc})") from None
        self.temp.unlink(missing_ok=True)
        self.temp = final
        replace_into(final, self.path)


class TracksSink(BaseSink):
    """The tracks CSV (``frame,track_id,x,y,confirmed``) of run ``run``, written to a temporary
    name and renamed into place when the run finishes (``backfill``: :class:`TracksWriter`)."""

    def __init__(self, path: Path, run: int = 0, backfill: bool = False) -> None:
        self.writer: TracksWriter | None = TracksWriter(path, backfill)
        self.run = run

    def step(self, step: Step) -> None:
        assert self.writer is not None
        self.writer.write_tracks(step.frame.index, step.results[self.run].tracks)

    def finish(self, end: RunEnd) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None  # complete: an abort later (another sink failing) keeps it

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.abort()
            self.writer = None


class FrameTruth:
    """Run ``run``'s confirmed tracks on a frame against the frame's truth: the visible and
    hidden targets, and (computed when first asked) the frame's errors, matched as the scores
    match them (:func:`wfviz.evaluate.frame_errors`, with the targets' ``boxes`` {target_id:
    (w, h)} when the truth has them). Published by :class:`ScoreSink`."""

    def __init__(self, shown: list[Point], hidden: list[Point], points: list[Point], gate: float,
                 boxes: dict[int, Box] | None = None) -> None:
        self.shown, self.hidden, self.points, self.gate = shown, hidden, points, gate
        self.boxes = boxes

    @cached_property
    def errors(self) -> FrameErrors:
        from wfviz.evaluate import frame_errors

        return frame_errors(self.points, self.shown, self.gate, self.hidden, self.boxes)


@dataclass(frozen=True)
class BackfilledScores:
    """A run's scores with every confirmed track reported from its first frame (its tentative
    rows counted as confirmed: ``--backfill``), besides the online ones."""

    result: EvalResult


class ScoreSink(BaseSink):
    """Scores of run ``run`` against truth (visible, hidden points; a :class:`~wfviz.evaluate.Truth`
    brings its boxes) over the frames processed: publishes each frame's :class:`FrameTruth` and,
    at the end, the :class:`EvalResult` (``scores`` is set then too) and, with ``backfill``, the
    :class:`BackfilledScores`."""

    def __init__(self, truth: tuple[Points, Points], gate: float, run: int = 0, backfill: bool = False) -> None:
        from wfviz.evaluate import Truth

        self.shown, self.hidden = truth
        self.boxes = Truth.of(truth).boxes
        self.gate = gate
        self.run = run
        self.backfill = backfill
        self.tracked: Points = {}
        self.tentative: Points = {}  # with backfill: the tentative tracks' points
        self.scores: EvalResult | None = None

    def publish(self, step: Step) -> None:
        f = step.frame.index
        points = confirmed_points(step.results[self.run])
        self.tracked[f] = points
        if self.backfill:
            self.tentative[f] = [(t.track_id, t.x, t.y) for t in step.results[self.run].tracks if not t.confirmed]
        step.facts.put(FrameTruth(self.shown.get(f, []), self.hidden.get(f, []), points, self.gate,
                                  self.boxes.get(f)), self.run)

    def conclude(self, end: RunEnd) -> None:
        from wfviz.evaluate import evaluate_points

        if self.tracked:
            span = set(self.tracked)
            shown = {f: v for f, v in self.shown.items() if f in span}
            hidden = {f: v for f, v in self.hidden.items() if f in span}
            self.scores = evaluate_points(self.tracked, shown, self.gate, hidden, self.boxes)
            end.facts.put(self.scores, self.run)
            if self.backfill:
                ever = {i for pts in self.tracked.values() for i, _, _ in pts}
                full = {f: pts + [p for p in self.tentative.get(f, []) if p[0] in ever]
                        for f, pts in self.tracked.items()}
                end.facts.put(BackfilledScores(evaluate_points(full, shown, self.gate, hidden, self.boxes)),
                              self.run)


class RecordingSink(BaseSink):
    """The Rerun recording of run ``run`` (:mod:`wfviz.record`; rerun is imported only here,
    when recording): every stage of every frame, the clip's skipped-input problems, per-frame
    errors against truth and the final scores when a :class:`ScoreSink` publishes them, and a
    warning when a signal stopped the run. Written to a temporary name, renamed into place on
    finish."""

    def __init__(self, path: Path, tracker: str, clip: Clip, options: RecorderOptions | None = None,
                 run: int = 0) -> None:
        from wfviz.record import open_recorder

        self.path, self.temp = path, temp_path(path)
        self.run = run
        self.skip_log = _SkipLog(clip)
        self.frames = 0
        try:
            self.recorder: Any = open_recorder(tracker, self.temp, options or RecorderOptions())
        except BaseException:
            self.temp.unlink(missing_ok=True)
            raise

    def step(self, step: Step) -> None:
        rec = self.recorder
        with self._errors():
            rec.log(step.frame, step.results[self.run])
            self.skip_log(rec)
        truth = step.facts.get(FrameTruth, self.run)
        if truth is not None:
            rec.log_truth(truth.shown, truth.hidden, truth.errors)
        from wfviz.explain.types import FrameExplanation

        explanation = step.facts.get(FrameExplanation, self.run)
        if explanation is not None:  # an ExplainSink's (wfviz.explain)
            rec.log_explanation(explanation)
        self.frames += 1

    def finish(self, end: RunEnd) -> None:
        from wfviz.evaluate import EvalResult, format_table

        rec = self.recorder
        scores = end.facts.get(EvalResult, self.run)
        if scores is not None:
            rec.log_scores(format_table(scores))
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


class CallbackSink(BaseSink):
    """Calls ``fn(frame, result)`` with each frame (progress bars, samplers; last in the list,
    it is called after the other sinks took the frame)."""

    def __init__(self, fn: Callable[[Frame, FrameResult], None]) -> None:
        self.fn = fn

    def step(self, step: Step) -> None:
        self.fn(step.frame, step.result)


@dataclass(frozen=True)
class StageTiming:
    """Milliseconds per frame for one stage: median, mean, 95th percentile."""

    stage: str
    median: float
    mean: float
    p95: float


class TimingSink(BaseSink):
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

    def timings(self) -> tuple[StageTiming, tuple[StageTiming, ...]]:
        """Decoding, then each stage (``total`` last)."""
        order = [s for s in self.stages if s != "total"] + (["total"] if "total" in self.stages else [])
        return _timing("decode", self.decode), tuple(_timing(s, self.stages[s]) for s in order)


def _timing(stage: str, values: list[float]) -> StageTiming:
    a = np.asarray(values, dtype=np.float64)
    return StageTiming(stage, float(np.median(a)), float(a.mean()), float(np.percentile(a, 95)))
