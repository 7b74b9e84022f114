"""Drive a tracker over a clip, feeding each frame's result to the sinks (CSV, recording)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from wfviz.evaluate import EvalResult, Points, evaluate_points, frame_errors
from wfviz.frames import Clip, Frame
from wfviz.outputs import TracksWriter, check_writable, commit
from wfviz.trackers import Tracker
from wfviz.trackers.base import FrameResult


@dataclass(frozen=True)
class RunSummary:
    """What a run did: frames processed, wall time, confirmed track ids, interruption, and
    the scores against truth when truth was given."""

    frames: int
    seconds: float
    tracker_ms: float
    confirmed: tuple[int, ...]
    interrupted: bool
    scores: EvalResult | None = None

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("inf")


def run(clip: Clip, tracker: Tracker, *, tracks_csv: Path | None = None, recording: Path | None = None,
        recorder_options: dict | None = None, start: int = 0, stop: int | None = None,
        truth: tuple[Points, Points] | None = None, gate: float = 3.0,
        on_frame: Callable[[Frame, FrameResult], None] | None = None) -> RunSummary:
    """Track ``clip`` frames ``start <= index < stop``; write outputs atomically.

    Outputs are written under ``NAME.part`` and renamed when the run ends, also when it is
    interrupted (Ctrl-C): the frames done are kept and ``interrupted`` is set. On any other
    error the partial files are removed. ``truth`` (visible, hidden points from
    :func:`wfviz.evaluate.read_truth`) adds per-frame errors to the recording and final scores
    over the frames processed.
    """
    for p in (tracks_csv, recording):
        if p is not None:
            check_writable(p)
    writer = TracksWriter(tracks_csv) if tracks_csv is not None else None
    recorder = None
    if recording is not None:
        from wfviz.record import open_recorder  # rerun is imported only when recording
        from wfviz.outputs import part_path
        recorder = open_recorder(tracker.name, part_path(recording), **(recorder_options or {}))
    frames, confirmed, interrupted = 0, set(), False
    shown, hidden = truth if truth is not None else ({}, {})
    done: list[int] = []
    tracked: Points = {}
    t_start = time.perf_counter()
    tracker_s = 0.0
    try:
        for frame in clip.frames(start, stop):
            t0 = time.perf_counter()
            result = tracker.step(frame)
            tracker_s += time.perf_counter() - t0
            confirmed.update(t.track_id for t in result.tracks if t.confirmed)
            if writer is not None:
                writer.write(frame.index, result.tracks)
            if recorder is not None:
                recorder.log(frame, result)
            if truth is not None:
                pts = [(t.track_id, t.x, t.y) for t in result.tracks if t.confirmed]
                tracked[frame.index] = pts
                done.append(frame.index)
                if recorder is not None:
                    f = frame.index
                    errors = frame_errors(pts, shown.get(f, []), gate, hidden.get(f, []))
                    recorder.log_truth(shown.get(f, []), hidden.get(f, []), errors)
            frames += 1
            if on_frame is not None:
                on_frame(frame, result)
    except KeyboardInterrupt:
        interrupted = True
    except BaseException:
        if writer is not None:
            writer.abort()
        if recorder is not None:
            recorder.close()
            from wfviz.outputs import part_path
            part_path(recording).unlink(missing_ok=True)  # type: ignore[arg-type]
        raise
    scores = None
    if truth is not None and done:
        span = set(done)
        scores = evaluate_points(tracked, {f: v for f, v in shown.items() if f in span}, gate,
                                 {f: v for f, v in hidden.items() if f in span})
    if writer is not None:
        writer.close()
    if recorder is not None:
        if scores is not None:
            from wfviz.evaluate import format_table
            recorder.log_scores(format_table(scores))
        if interrupted:
            recorder.log_message(f"interrupted after {frames} frames", level="WARN")
        recorder.close()
        commit(recording)  # type: ignore[arg-type]
    seconds = time.perf_counter() - t_start
    return RunSummary(frames, seconds, tracker_s * 1e3 / max(frames, 1), tuple(sorted(confirmed)),
                      interrupted, scores)
