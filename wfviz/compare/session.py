"""``wfviz compare`` through the drive loop (:func:`wfviz.run.drive`): every run over the same
frames (decoded once; a :class:`~wfviz.compare.runs.RunGroup` steps them), each run's tracks CSV,
scores and causes of its misses and false tracks as ``wfviz record`` computes them (the same
sinks, one per run: :class:`~wfviz.explain.sink.ExplainSink` with truth), the disagreement finder
(:class:`DisagreementSink`, :mod:`wfviz.compare.differences`) and one recording of them all
(:class:`wfviz.record.compare.CompareRecorder`), all sinks."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from wfviz.compare.differences import KINDS, Disagreements
from wfviz.compare.runs import RunGroup, RunSpec, check_fit, check_labels, make_trackers
from wfviz.compare.summary import CompareSummary, Comparison, summarize
from wfviz.evaluate import Points, Truth
from wfviz.io.frames import Clip
from wfviz.io.outputs import check_writable
from wfviz.record_options import RecorderOptions
from wfviz.run import StopSignals, drive, open_sinks
from wfviz.sinks import BaseSink, RunEnd, ScoreSink, Sink, Step, TracksSink, confirmed_points


class DisagreementSink(BaseSink):
    """Finds where the runs disagree (:class:`Disagreements`): publishes each frame's
    :class:`FrameComparison` and, at the end, the :class:`Comparison`."""

    def __init__(self, labels: list[str], gate: float, truth: tuple[Points, Points] | None) -> None:
        self.diff = Disagreements(labels, gate)
        self.truth = Truth.of(truth) if truth is not None else None
        self.ms_total = [0.0] * len(labels)
        self.confirmed: list[set[int]] = [set() for _ in labels]
        self.marks = dict.fromkeys(KINDS, 0)
        self.disagreeing = 0

    def publish(self, step: Step) -> None:
        f = step.frame.index
        for i, (result, ms) in enumerate(zip(step.results, step.run_ms)):
            self.ms_total[i] += ms
            self.confirmed[i] |= result.confirmed_ids
        points = [confirmed_points(r) for r in step.results]
        if self.truth is not None:
            cmp = self.diff.update(f, points, self.truth.shown.get(f, []), self.truth.hidden.get(f, []),
                                   self.truth.boxes.get(f))
        else:
            cmp = self.diff.update(f, points, None, ())
        self.disagreeing += bool(cmp.marks)
        for m in cmp.marks:
            self.marks[m.kind] += 1
        step.facts.put(cmp)

    def conclude(self, end: RunEnd) -> None:
        n = max(end.frames, 1)
        end.facts.put(Comparison(self.disagreeing, dict(self.marks), tuple(ms / n for ms in self.ms_total),
                                 tuple(len(c) for c in self.confirmed)))


class _Progress(BaseSink):
    """Calls ``fn(frames done)`` after every frame."""

    def __init__(self, fn: Callable[[int], None]) -> None:
        self.fn, self.frames = fn, 0

    def step(self, step: Step) -> None:
        self.frames += 1
        self.fn(self.frames)


def compare(clip: Clip, runs: list[RunSpec], *, recording: Path | None, tracks: list[Path | None],
            truth: tuple[Points, Points] | None = None, gate: float = 3.0,
            options: RecorderOptions | None = None, start: int = 0, stop: int | None = None,
            on_frame: Callable[[int], None] | None = None, explain: list[Path | None] | None = None) -> CompareSummary:
    """Run every ``runs`` tracker over frames ``start <= index < stop`` of ``clip`` through the
    drive loop (:func:`wfviz.run.drive`, a :class:`RunGroup`), writing ``tracks[i]`` (a CSV per
    run, as ``wfviz track`` writes it), ``explain[i]`` (with truth: the run's ``EXPLAIN.csv`` and
    ``EXPLAIN-false.csv``, as ``wfviz track --explain`` writes them) and ``recording``
    (``options``: its source and images; the clip's name when no source is given), every output
    to a temporary name renamed at the end (removed on an error; kept with the frames done on
    SIGINT/SIGTERM). With ``truth`` every run's scores and causes are computed (the summary's
    ``scores`` and ``explain``). An explain file without truth: ValueError."""
    from wfviz.explain.report import false_path
    from wfviz.explain.sink import ExplainSink

    check_labels(runs)
    explain = list(explain) if explain is not None else [None] * len(runs)
    if len(explain) != len(runs) or len(tracks) != len(runs):
        raise ValueError(f"compare: {len(runs)} runs, {len(tracks)} tracks CSVs, {len(explain)} explain files")
    wanted = [p for p in explain if p is not None]
    if wanted and truth is None:
        raise ValueError(f"{wanted[0]}: explaining the runs needs truth (--truth FILE)")
    name = str(clip.path) if clip.path is not None else clip.name
    check_fit(clip.shape, name, runs)
    trackers, groups = make_trackers(runs)
    stepper = RunGroup(trackers)
    for p in (*tracks, *wanted, *map(false_path, wanted), recording):
        if p is not None:
            check_writable(p)
    options = options or RecorderOptions()
    if not options.source:
        options = replace(options, source=name)
    labels = [r.label for r in runs]
    openers: list[Callable[[], Sink]] = []
    for i in range(len(runs)):
        if truth is not None:
            openers.append(functools.partial(ScoreSink, truth, gate, run=i))
            openers.append(functools.partial(ExplainSink, truth, gate, runs[i].tracker, runs[i].config, explain[i],
                                             run=i))
        path = tracks[i]
        if path is not None:
            openers.append(functools.partial(TracksSink, path, run=i))
    openers.append(lambda: DisagreementSink(labels, gate, truth))
    if recording is not None:
        def recorder() -> Sink:
            from wfviz.record.compare import CompareRecorder

            return CompareRecorder(recording, runs, groups, options, truth=truth is not None)

        openers.append(recorder)
    if on_frame is not None:
        openers.append(lambda: _Progress(on_frame))
    t_start = time.perf_counter()
    with StopSignals() as signals:
        sinks = open_sinks(openers)
        done = drive(clip, stepper, sinks, start=start, stop=stop, signals=signals)
    end = RunEnd(done.frames, done.signal, facts=done.facts)
    return summarize(runs, groups, end, tracks, time.perf_counter() - t_start, explain)
