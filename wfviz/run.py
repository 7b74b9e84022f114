"""Drive a tracker over a clip, feeding each frame's result to the sinks (CSV, recording)."""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from wfviz.evaluate import EvalResult, Points, evaluate_points, frame_errors
from wfviz.io.clip import MIN_SIDE, check_frame_size
from wfviz.io.frames import Clip, Frame, read_ahead
from wfviz.io.outputs import OutputError, TracksWriter, check_writable, replace_into, temp_path
from wfviz.trackers import Tracker
from wfviz.trackers.base import FrameResult

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


def min_frame_side(config: Any) -> int:
    """Smallest frame side the configured windows fit in (16 px with the defaults)."""
    side = MIN_SIDE
    suppression = getattr(config, "suppression", None)
    if suppression is not None:
        side = max(side, int(suppression.size))
    horizon = getattr(config, "horizon", None)
    if horizon is not None and horizon.enabled:  # ground-side variance window below the edge
        side = max(side, int(horizon.variance_window) // 2 + int(horizon.step) + 2)
    return side


def run(clip: Clip, tracker: Tracker, *, tracks_csv: Path | None = None, recording: Path | None = None,
        recorder_options: dict | None = None, start: int = 0, stop: int | None = None,
        truth: tuple[Points, Points] | None = None, gate: float = 3.0,
        on_frame: Callable[[Frame, FrameResult], None] | None = None) -> RunSummary:
    """Track ``clip`` frames ``start <= index < stop``; write outputs atomically.

    Outputs are written to unique temporary files beside them
    (:func:`wfviz.io.outputs.temp_path`) and renamed when the run ends. SIGINT and SIGTERM
    (and a KeyboardInterrupt raised elsewhere) stop the run after the current frame: the
    frames done are flushed, the recording is closed and renamed, ``interrupted`` and
    ``signal`` are set. On any error, or when no frame was processed, the partial files are
    removed (no frames: ValueError). ``truth`` (visible, hidden points from
    :func:`wfviz.evaluate.read_truth`) adds per-frame errors to the recording and final scores
    over the frames processed.
    """
    source = getattr(clip, "path", clip.name)
    check_frame_size(clip.shape, source, min_frame_side(getattr(tracker, "config", None)))
    with StopSignals() as signals:
        for p in (tracks_csv, recording):
            if p is not None:
                check_writable(p)
        writer = TracksWriter(tracks_csv) if tracks_csv is not None else None
        recorder = None
        rec_temp = None
        try:
            if recording is not None:
                from wfviz.record import open_recorder  # rerun is imported only when recording
                rec_temp = temp_path(recording)
                recorder = open_recorder(tracker.name, rec_temp, **(recorder_options or {}))
        except BaseException:
            if writer is not None:
                writer.abort()
            if rec_temp is not None:
                rec_temp.unlink(missing_ok=True)
            raise
        frames, confirmed, interrupted = 0, set(), False
        shown, hidden = truth if truth is not None else ({}, {})
        done: list[int] = []
        tracked: Points = {}
        log_skipped = _SkipLog(clip)
        first = last = None
        t_start = time.perf_counter()
        tracker_s = 0.0
        stream = read_ahead(clip.frames(start, stop))
        try:
            for frame in stream:
                if signals.signum is not None:  # arrived while reading: start no new frame
                    break
                t0 = time.perf_counter()
                result = tracker.step(frame)
                tracker_s += time.perf_counter() - t0
                confirmed.update(t.track_id for t in result.tracks if t.confirmed)
                if writer is not None:
                    writer.write(frame.index, result.tracks)
                if recorder is not None:
                    with _recording_errors(recording):
                        recorder.log(frame, result)
                        log_skipped(recorder)
                if truth is not None:
                    pts = [(t.track_id, t.x, t.y) for t in result.tracks if t.confirmed]
                    tracked[frame.index] = pts
                    done.append(frame.index)
                    if recorder is not None:
                        f = frame.index
                        errors = frame_errors(pts, shown.get(f, []), gate, hidden.get(f, []))
                        recorder.log_truth(shown.get(f, []), hidden.get(f, []), errors)
                frames += 1
                first = frame.index if first is None else first
                last = frame.index
                if on_frame is not None:
                    on_frame(frame, result)
                if signals.signum is not None:
                    break
        except KeyboardInterrupt:  # not installed (other thread) or raised by a callback
            signals.signum = signals.signum or signal.SIGINT
        except BaseException:
            _abort(writer, recorder, rec_temp)
            raise
        finally:
            getattr(stream, "close", lambda: None)()
        interrupted = signals.signum is not None
        if frames == 0 and not interrupted:
            _abort(writer, recorder, rec_temp)
            raise ValueError(f"{source}: no frames in the selected range (start={start}, stop={stop})")
        try:
            scores = None
            if truth is not None and done:
                span = set(done)
                scores = evaluate_points(tracked, {f: v for f, v in shown.items() if f in span}, gate,
                                         {f: v for f, v in hidden.items() if f in span})
            if writer is not None:
                writer.close()
                writer = None
            if recorder is not None:
                if scores is not None:
                    from wfviz.evaluate import format_table
                    recorder.log_scores(format_table(scores))
                log_skipped(recorder)
                if interrupted:
                    name = signal.Signals(signals.signum).name  # type: ignore[arg-type]
                    recorder.log_message(f"interrupted by {name} after {frames} frames", level="WARN")
                with _recording_errors(recording):
                    recorder.close()
                replace_into(rec_temp, recording)  # type: ignore[arg-type]
        except BaseException:
            _abort(writer, None, rec_temp)
            raise
    seconds = time.perf_counter() - t_start
    skipped = tuple(sorted(getattr(clip, "skipped", None) or ()))
    return RunSummary(frames, seconds, tracker_s * 1e3 / max(frames, 1), tuple(sorted(confirmed)),
                      interrupted, scores, signals.signum, skipped, first, last)


class _SkipLog:
    """Logs each new skipped-input problem of the clip once in the recording's ``log``."""

    def __init__(self, clip: Clip) -> None:
        self.skipped: dict[int, str] | None = getattr(clip, "skipped", None)
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


@contextmanager
def _recording_errors(recording: Path | None) -> Iterator[None]:
    """Rerun's file writer failing (a full disk: "File-writer thread shut down prematurely") as
    a one-line OutputError naming the recording."""
    try:
        yield
    except RuntimeError as exc:
        raise OutputError(f"{recording}: cannot write the recording ({exc}; is the disk full?)") from None


def _abort(writer: TracksWriter | None, recorder: Any, rec_temp: Path | None) -> None:
    """Close and remove every partial output."""
    if writer is not None:
        writer.abort()
    if recorder is not None:
        try:
            recorder.close()
        except Exception:  # noqa: BLE001 - the file is removed anyway
            pass
    if rec_temp is not None:
        rec_temp.unlink(missing_ok=True)
