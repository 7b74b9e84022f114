"""What a comparison (``wfviz compare``) found: every run's outcome and the disagreements
(:class:`CompareSummary`), built from what the comparison's sinks published at the end
(:func:`summarize`), and its closing table (:func:`format_summary`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from wfviz.compare.runs import RunSpec
from wfviz.evaluate import EvalResult
from wfviz.sinks import RunEnd


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


@dataclass(frozen=True)
class Comparison:
    """What the :class:`DisagreementSink` publishes at the end: frames with a disagreement,
    marks by kind, and per run its milliseconds per frame as it would cost alone and its
    confirmed tracks."""

    disagreement_frames: int
    marks: dict[str, int]
    ms_per_frame: tuple[float, ...]
    confirmed: tuple[int, ...]


def summarize(runs: list[RunSpec], groups: list[int], end: RunEnd, tracks: list[Path | None] | None = None,
              seconds: float | None = None) -> CompareSummary:
    """The :class:`CompareSummary` of a comparison from what its sinks published at the end
    (the :class:`Comparison`, every run's scores)."""
    c = end.facts.get(Comparison)
    assert c is not None, "no DisagreementSink in the comparison"
    outcomes = tuple(RunOutcome(r.label, r.tracker, tracks[i] if tracks else None, c.ms_per_frame[i], c.confirmed[i],
                                end.facts.get(EvalResult, i), groups[i]) for i, r in enumerate(runs))
    return CompareSummary(end.frames, end.seconds if seconds is None else seconds, outcomes, c.disagreement_frames,
                          c.marks, end.signum)


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
    rules = sorted({r.scores.match_rule for r in summary.runs if r.scores is not None})
    return "\n".join([line(head), *map(line, rows), *(f"matched to truth: {rule}" for rule in rules),
                      f"frames with a disagreement: {summary.disagreement_frames} of {summary.frames} ({kinds})"])
