"""``wfviz compare``'s loop: every run over the same frames (decoded once), each run's tracks
CSV and scores as ``wfviz record`` writes them, the disagreements
(:mod:`wfviz.compare.differences`) and one recording of them all (:mod:`wfviz.record.compare`)."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wfviz.compare.differences import KINDS, Disagreements, FrameComparison
from wfviz.compare.runs import RunSpec, SharedSource, check_labels, make_trackers
from wfviz.evaluate import EvalResult, Points
from wfviz.io.clip import check_frame_size
from wfviz.io.frames import Clip, read_ahead
from wfviz.io.outputs import check_writable
from wfviz.record_options import EXACT_EVERY, PREVIEW_QUALITY
from wfviz.run import StopSignals, min_frame_side
from wfviz.sinks import RunEnd, ScoreSink, Step, TracksSink


@dataclass(frozen=True)
class RunOutcome:
    """One run of a comparison: label, tracker, its tracks CSV, milliseconds per frame as it
    would cost alone (its own time plus the shared front end's when another run paid it),
    confirmed tracks, and its scores (None without truth)."""

    label: str
    tracker: str
    tracks_csv: Path | None
    ms_per_frame: float
    confirmed: int
    scores: EvalResult | None
    group: int


@dataclass(frozen=True)
class CompareSummary:
    """What a comparison did: frames, wall seconds, every run's outcome, frames with a
    disagreement and marks by kind, and the signal that stopped it (None: the end)."""

    frames: int
    seconds: float
    runs: tuple[RunOutcome, ...]
    disagreement_frames: int
    marks: dict[str, int]
    signal: int | None = None


def compare(clip: Clip, runs: list[RunSpec], *, recording: Path | None, tracks: list[Path | None],
            truth: tuple[Points, Points] | None = None, gate: float = 3.0, image_every: int = 1,
            exact_every: int = EXACT_EVERY, jpeg_quality: int = PREVIEW_QUALITY,
            source: str = "", start: int = 0, stop: int | None = None,
            on_frame: Callable[[int], None] | None = None) -> CompareSummary:
    """Run every ``runs`` tracker over frames ``start <= index < stop`` of ``clip``, writing
    ``tracks[i]`` (a CSV per run) and ``recording``, every output to a temporary name renamed at
    the end (removed on an error; kept with the frames done on SIGINT/SIGTERM)."""
    check_labels(runs)
    name = str(clip.path) if clip.path is not None else clip.name
    for r in runs:
        check_frame_size(clip.shape, name, min_frame_side(r.config))
    for p in (*tracks, recording):
        if p is not None:
            check_writable(p)
    trackers, groups = make_trackers(runs)
    labels = [r.label for r in runs]
    diff = Disagreements(labels, gate)
    scores = [ScoreSink(truth, gate) if truth is not None else None for _ in runs]
    writers: list[TracksSink | None] = []
    recorder: Any = None
    ms_total = [0.0] * len(runs)
    confirmed: list[set[int]] = [set() for _ in runs]
    marks = dict.fromkeys(KINDS, 0)
    disagreeing = frames = 0

    def abort() -> None:
        for w in writers:
            if w is not None:
                w.abort()
        if recorder is not None:
            recorder.abort()

    t_start = time.perf_counter()
    stepper = _Stepper(trackers)
    with StopSignals() as signals:
        try:
            writers = [TracksSink(p) if p is not None else None for p in tracks]
            if recording is not None:
                from wfviz.record.compare import CompareRecorder

                recorder = CompareRecorder(recording, runs, groups, source=source or name,
                                           image_every=image_every, exact_every=exact_every,
                                           jpeg_quality=jpeg_quality, truth=truth is not None, gate=gate)
            stream = read_ahead(clip.frames(start, stop))
            try:
                for frame in stream:
                    if signals.signum is not None:
                        break
                    results, ms = [], []
                    for i, (trk, result, own) in enumerate(stepper.step(frame)):
                        source = getattr(getattr(trk, "front", None), "source", None)
                        alone = own + (source.shared_ms() if isinstance(source, SharedSource) else 0.0)
                        step = Step(frame, result, 0.0, own)
                        for sink in (scores[i], writers[i]):
                            if sink is not None:
                                sink.step(step)
                        results.append(result)
                        ms.append(alone)
                        ms_total[i] += alone
                        confirmed[i].update(t.track_id for t in result.tracks if t.confirmed)
                    points = [[(t.track_id, t.x, t.y) for t in r.tracks if t.confirmed] for r in results]
                    shown = hidden = None
                    if truth is not None:
                        shown, hidden = truth[0].get(frame.index, []), truth[1].get(frame.index, [])
                    cmp: FrameComparison = diff.update(frame.index, points, shown, hidden or ())
                    disagreeing += bool(cmp.marks)
                    for m in cmp.marks:
                        marks[m.kind] += 1
                    if recorder is not None:
                        recorder.log(frame, results, cmp, ms, shown, hidden)
                    frames += 1
                    if on_frame is not None:
                        on_frame(frames)
            except KeyboardInterrupt:
                signals.signum = signals.signum or signal.SIGINT
            finally:
                stream.close()
            if frames == 0 and signals.signum is None:
                raise ValueError(f"{name}: no frames in the selected range (start={start}, stop={stop})")
            end = RunEnd(frames, signals.signum)
            for s in scores:
                if s is not None:
                    s.finish(end)
            for w in writers:
                if w is not None:
                    w.finish(end)
            outcomes = tuple(RunOutcome(r.label, r.tracker, tracks[i], ms_total[i] / max(frames, 1),
                                        len(confirmed[i]), scores[i].scores if scores[i] is not None else None,
                                        groups[i]) for i, r in enumerate(runs))
            summary = CompareSummary(frames, time.perf_counter() - t_start, outcomes, disagreeing, marks,
                                     signals.signum)
            if recorder is not None:
                recorder.finish(summary)
        except BaseException:
            abort()
            raise
    return summary


class _Stepper:
    """Steps every tracker on a frame, in run order, timing each. (Stepping the front-end
    groups in threads gained nothing on 2 cores: the frame reader and Rerun's writer threads
    already use the second core; docs/performance.md.)"""

    def __init__(self, trackers: list[Any]) -> None:
        self.trackers = trackers

    def step(self, frame: Any) -> list[tuple[Any, Any, float]]:
        """Per run, in run order: (tracker, result, its milliseconds)."""
        out = []
        for trk in self.trackers:
            t0 = time.perf_counter()
            result = trk.step(frame)
            out.append((trk, result, (time.perf_counter() - t0) * 1e3))
        return out


def _num(v: float | None, fmt: str = ".3f") -> str:
    return "-" if v is None or v != v else format(v, fmt)


def format_summary(summary: CompareSummary) -> str:
    """The closing table: a row per run (scores when truth was given), then the disagreements."""
    scored = any(r.scores is not None for r in summary.runs)
    head = ["run", "tracker", "ms/frame", "confirmed"] + (
        ["MOTA", "IDF1", "Pd", "FA/frame", "switches", "CLE px"] if scored else [])
    rows = []
    for r in summary.runs:
        row = [r.label, r.tracker, _num(r.ms_per_frame, ".2f"), str(r.confirmed)]
        if scored:
            s = r.scores
            row += ([_num(s.mota), _num(s.idf1), _num(s.pd), _num(s.fa_per_frame), str(s.id_switches),
                     _num(s.cle_mean, ".2f")] if s is not None else ["-"] * 6)
        rows.append(row)
    widths = [max(len(h), *(len(r[k]) for r in rows)) for k, h in enumerate(head)]
    line = lambda cells: "  ".join(c.ljust(w) if k < 2 else c.rjust(w)  # noqa: E731
                                   for k, (c, w) in enumerate(zip(cells, widths)))
    kinds = ", ".join(f"{k} {n}" for k, n in summary.marks.items() if n) or "none"
    return "\n".join([line(head), *map(line, rows),
                      f"frames with a disagreement: {summary.disagreement_frames} of {summary.frames} ({kinds})"])
