"""The explanation as a sink of the drive loop (:mod:`wfviz.sinks`): each frame's
:class:`~wfviz.explain.types.FrameExplanation` published for the recording, the explain files
written, and the run's :class:`~wfviz.explain.report.ExplainSummary` published at the end."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from wfviz.evaluate import Points, Truth
from wfviz.explain.false_tracks import FalseCauses
from wfviz.explain.report import HELD, ExplainSummary, ExplainWriter, summarise
from wfviz.explain.truth import TruthCauses
from wfviz.explain.types import FrameExplanation
from wfviz.sinks import BaseSink, FrameTruth, RunEnd, Step, confirmed_points


class ExplainSink(BaseSink):
    """Causes of run ``run``'s misses and false tracks against ``truth`` (visible, hidden
    points), matched as the scores match them (its own :class:`~wfviz.sinks.FrameTruth`, the
    same function as :class:`~wfviz.sinks.ScoreSink`'s); ``tracker`` and ``config``: the run's
    tracker name and configuration; ``path``: write ``EXPLAIN.csv`` and ``EXPLAIN-false.csv``
    there (None: publish only, for the recording and the summary)."""

    def __init__(self, truth: tuple[Points, Points], gate: float, tracker: str, config: Any,
                 path: Path | None = None, run: int = 0) -> None:
        self.shown, self.hidden = truth
        self.boxes = Truth.of(truth).boxes
        self.gate, self.run = gate, run
        self.truth_causes = TruthCauses(tracker, config, gate)
        self.false_causes = FalseCauses(gate)
        self.rows: Counter[tuple[int, str]] = Counter()  # (target, cause): counts, not rows (long clips)
        self.false: Counter[str] = Counter()
        self.held: Counter[tuple[str, str]] = Counter()  # (latency / not_confirmed, the test that held it back)
        self.writer = ExplainWriter(path) if path is not None else None

    def publish(self, step: Step) -> None:
        f = step.frame.index
        result = step.results[self.run]
        boxes = self.boxes.get(f)
        ft = step.facts.get(FrameTruth, self.run)  # the ScoreSink's when it published first: the same values
        if ft is None or ft.gate != self.gate:
            ft = FrameTruth(self.shown.get(f, []), self.hidden.get(f, []), confirmed_points(result), self.gate, boxes)
        matches = ft.errors.matches
        truth = self.truth_causes.explain(result, ft.shown, ft.hidden, matches, boxes)
        false = self.false_causes.explain(result, ft.shown, ft.errors)
        self.rows.update((e.target_id, e.cause.value) for e in truth)
        self.false.update(e.cause.value for e in false)
        self.held.update((e.cause.value, e.test) for e in truth if e.cause in HELD)
        if self.writer is not None:
            self.writer.write(truth, false)
        step.facts.put(FrameExplanation(f, truth, false), self.run)

    def conclude(self, end: RunEnd) -> None:
        end.facts.put(summarise(self.rows.elements(), self.false.elements(), self.held.elements()), self.run)

    def finish(self, end: RunEnd) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.abort()
            self.writer = None


__all__ = ["ExplainSink", "ExplainSummary"]
