"""The drive loop: a stepper (one tracker, or ``wfviz compare``'s group of runs) over a clip,
each frame's results fed to the sinks (:mod:`wfviz.sinks`: tracks CSV, recording, scores against
truth, progress, timing, the comparison). ``wfviz record``, ``track``, ``demo`` (through
:func:`run`), ``bench`` (:mod:`wfviz.bench`) and ``compare`` (:mod:`wfviz.compare.session`) all
use it."""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Generator, Iterator, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, Protocol

from wfviz.io.clip import check_frame_size
from wfviz.io.frames import Clip, Frame, read_ahead
from wfviz.io.outputs import check_writable
from wfviz.pipeline import SinkThread, deliver, prepare_ahead, restore
from wfviz.record_options import RecorderOptions
from wfviz.sinks import CallbackSink, Facts, RecordingSink, RunEnd, ScoreSink, Sink, Step, TracksSink
from wfviz.trackers.base import FrameResult, Tracker

if TYPE_CHECKING:  # the scoring is imported where a run has truth only
    from wfviz.evaluate import EvalResult, Points

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@dataclass(frozen=True)
class RunSummary:
    """What a run did: frames processed, wall time, confirmed track ids, the signal that
    stopped it (None if it ran to the end), skipped input frames, the scores against truth
    when truth was given, and what the sinks published of the whole run."""

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
    facts: Facts = field(default_factory=Facts)

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


class Stepper(Protocol):
    """What the drive loop steps through the frames: one tracker (:class:`SingleRun`) or a
    group of runs (``wfviz compare``'s :class:`wfviz.compare.runs.RunGroup`)."""

    def min_frame_side(self) -> int:
        """Smallest frame side every run's configured windows fit in."""
        ...

    def advance(self, frame: Frame) -> tuple[tuple[FrameResult, ...], tuple[float, ...]]:
        """Every run's result on ``frame``, and each run's milliseconds as it would cost alone."""
        ...


class SingleRun:
    """One tracker as a :class:`Stepper`."""

    def __init__(self, tracker: Tracker) -> None:
        self.tracker = tracker

    def min_frame_side(self) -> int:
        return self.tracker.min_frame_side()

    def advance(self, frame: Frame) -> tuple[tuple[FrameResult, ...], tuple[float, ...]]:
        t0 = time.perf_counter()
        result = self.tracker.step(frame)
        return (result,), ((time.perf_counter() - t0) * 1e3,)


def drive(clip: Clip, stepper: Stepper, sinks: Sequence[Sink], *, start: int = 0, stop: int | None = None,
          ahead: bool = True, signals: StopSignals | None = None, threads: int = 1) -> RunSummary:
    """The one loop: frames ``start <= index < stop`` of ``clip`` through ``stepper`` (one
    tracker: :class:`SingleRun`), each :class:`~wfviz.sinks.Step` published by every sink, then
    to every sink; at the end every sink concludes, then finishes (or, on an error, every sink
    aborts, and the error goes on). See :mod:`wfviz.sinks`.

    ``ahead`` decodes frames in a background thread while the tracker works
    (:func:`wfviz.io.frames.read_ahead`); without it a step's ``wait_ms`` is the decoding time.
    SIGINT and SIGTERM (and a KeyboardInterrupt raised by a sink) stop the run after the current
    frame; the sinks then finish with the frames done. ``signals``: an active :class:`StopSignals`
    of the caller (a signal that arrived while it opened the sinks stops the run before its first
    frame). No frame in the range: ValueError. The summary's ``confirmed`` are the (first) run's.
    ``threads`` ≥ 2: a pipeline of threads (:mod:`wfviz.pipeline`): frames decoded ahead, a
    single tracker's stages before detection run ahead of it where they do not depend on its
    tracks, and the sinks in their own thread; the same outputs. 1: ``ahead`` only.
    """
    source = str(clip.path) if clip.path is not None else clip.name
    try:
        check_frame_size(clip.shape, source, stepper.min_frame_side())
    except BaseException:
        _abort(sinks)
        raise
    frames, confirmed, first, last = 0, set(), None, None
    tracker_ms = 0.0
    with (nullcontext(signals) if signals is not None else StopSignals()) as signals:
        t_start = time.perf_counter()
        piped = threads > 1
        stream = read_ahead(clip.frames(start, stop)) if ahead or piped else _generator(clip.frames(start, stop))
        early = prepare_ahead(stepper.tracker) if piped and isinstance(stepper, SingleRun) else None
        if early is not None:
            stream = early.feed(stream)
        out = SinkThread(sinks) if piped else None
        try:
            while True:
                t0 = time.perf_counter()
                frame = next(stream, None)
                t1 = time.perf_counter()
                if frame is None or signals.signum is not None:  # a signal while reading: no new frame
                    break
                c1 = time.thread_time()
                results, run_ms = stepper.advance(frame)
                work = (time.perf_counter() - t1) * 1e3
                if early is not None:  # threads share the GIL: the work is this thread's CPU time
                    work = (time.thread_time() - c1) * 1e3 + early.last_ms  # and the front end's
                    run_ms = (work,)
                step = Step(frame, results, (t1 - t0) * 1e3, work, run_ms)
                tracker_ms += step.step_ms
                confirmed |= results[0].confirmed_ids
                frames += 1  # counted before the sinks: one that raises KeyboardInterrupt had it
                first = frame.index if first is None else first
                last = frame.index
                if out is not None:
                    out.send(step)
                else:
                    deliver(sinks, step)
                if signals.signum is not None:
                    break
            if out is not None:
                out.drain()
        except KeyboardInterrupt:  # not installed (other thread) or raised by a sink
            signals.signum = signals.signum or signal.SIGINT
            if out is not None:
                _drain_after_stop(out)
        except BaseException:
            if out is not None:
                _drain_after_stop(out, error=True)
            _abort(sinks)
            raise
        finally:
            stream.close()
            if early is not None:
                restore(stepper.tracker, early)
        if frames == 0 and signals.signum is None:
            _abort(sinks)
            raise ValueError(f"{source}: no frames in the selected range (start={start}, stop={stop})")
        end = RunEnd(frames, signals.signum, time.perf_counter() - t_start)
        try:
            for sink in sinks:
                sink.conclude(end)
            for sink in sinks:
                sink.finish(end)
        except BaseException:
            _abort(sinks)
            raise
    return RunSummary(frames, time.perf_counter() - t_start, tracker_ms / max(frames, 1), tuple(sorted(confirmed)),
                      signals.signum is not None, None, signals.signum, tuple(sorted(clip.skipped)), first, last,
                      end.facts)


def open_sinks(openers: Sequence[Callable[[], Sink]]) -> list[Sink]:
    """Every sink opened in order; on an error (or a KeyboardInterrupt) the ones already open
    abort (remove what they created) and the error goes on."""
    sinks: list[Sink] = []
    try:
        for opener in openers:
            sinks.append(opener())
    except BaseException:
        _abort(sinks)
        raise
    return sinks


def run(clip: Clip, tracker: Tracker, *, tracks_csv: Path | None = None, recording: Path | None = None,
        recorder_options: RecorderOptions | None = None, start: int = 0, stop: int | None = None,
        truth: tuple[Points, Points] | None = None, gate: float = 3.0, explain: Path | None = None,
        on_frame: Callable[[Frame, FrameResult], None] | None = None, backfill: bool = False,
        threads: int = 1) -> RunSummary:
    """Track ``clip`` frames ``start <= index < stop`` with the usual sinks (what ``wfviz
    record``, ``track`` and ``demo`` run): the tracks CSV, the recording, scores against
    ``truth`` (visible, hidden points from :func:`wfviz.evaluate.read_truth`, or a synthetic
    clip's :meth:`truth_points`) and ``on_frame``. With truth, the causes of the misses and false
    tracks (:mod:`wfviz.explain`) go to the recording, to ``explain`` (``EXPLAIN.csv`` and
    ``EXPLAIN-false.csv``) and, summarised, to the summary's facts (an
    :class:`~wfviz.explain.report.ExplainSummary`); without truth nothing is computed.
    ``backfill``: the tracks CSV reports every confirmed track from its first frame
    (:class:`~wfviz.sinks.TracksWriter`), and with truth the facts hold those scores too
    (:class:`~wfviz.sinks.BackfilledScores`). ``threads``: see :func:`drive` (the same outputs).

    Outputs are written to unique temporary files beside them
    (:func:`wfviz.io.outputs.temp_path`) and renamed when the run ends; on a signal the frames
    done are kept (``interrupted`` and ``signal`` set), on any error, or when no frame was
    processed, the partial files are removed (no frames: ValueError).
    """
    stepper = SingleRun(tracker)
    source = str(clip.path) if clip.path is not None else clip.name
    check_frame_size(clip.shape, source, stepper.min_frame_side())
    if explain is not None and truth is None:
        raise ValueError(f"{explain}: --explain needs truth (--truth FILE)")
    for p in (tracks_csv, recording, explain):
        if p is not None:
            check_writable(p)
    openers: list[Callable[[], Sink]] = []
    if truth is not None:
        openers.append(lambda: ScoreSink(truth, gate, backfill=backfill))
        from wfviz.explain.sink import ExplainSink

        openers.append(lambda: ExplainSink(truth, gate, tracker.name, tracker.config, explain))
    if tracks_csv is not None:
        openers.append(lambda: TracksSink(tracks_csv, backfill=backfill))
    if recording is not None:
        openers.append(lambda: RecordingSink(recording, tracker.name, clip, recorder_options))
    if on_frame is not None:
        openers.append(lambda: CallbackSink(on_frame))
    with StopSignals() as signals:  # a signal while the outputs open: they are kept, empty
        sinks = open_sinks(openers)
        summary = drive(clip, stepper, sinks, start=start, stop=stop, signals=signals, threads=threads)
    if truth is None:
        return summary
    from wfviz.evaluate import EvalResult

    return replace(summary, scores=summary.facts.get(EvalResult))


def _generator(frames: Iterator[Frame]) -> Generator[Frame, None, None]:
    """``frames`` as a generator (closing it closes the source when the source can close)."""
    try:
        yield from frames
    finally:
        close = getattr(frames, "close", None)  # an Iterator need not be a generator
        if close is not None:
            close()


def _drain_after_stop(out: SinkThread, error: bool = False) -> None:
    """The sink thread ended: the steps queued before a stop are delivered (``error``: dropped,
    the run is failing, and a second error there is not raised over the first)."""
    try:
        out.drain(deliver=not error)
    except BaseException:  # the first stop or error is the one reported
        if not error:
            raise


def _abort(sinks: Sequence[Sink]) -> None:
    """Every sink removes what it has written so far."""
    for sink in sinks:
        sink.abort()
