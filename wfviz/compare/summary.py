"""What a comparison (``wfviz compare``) found: every run's outcome, the parameters in which the
runs differ, where each run's Pd went and the disagreements (:class:`CompareSummary`), built from what the comparison's sinks published at the
end (:func:`summarize`), and its closing tables (:func:`format_summary`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from wfviz.compare.parameters import ParameterDifferences, format_differences, parameter_differences
from wfviz.compare.runs import RunSpec
from wfviz.evaluate import EvalResult
from wfviz.explain.report import ExplainSummary
from wfviz.explain.types import MISSES, Cause
from wfviz.sinks import RunEnd

#: the miss causes' column headings in the "where Pd went" table (pipeline order, :data:`MISSES`)
SHORT = {Cause.OUTSIDE_CIRCLE: "circle", Cause.OUTSIDE_REGION: "region", Cause.NOT_DETECTED: "not_det",
         Cause.LOST: "lost", Cause.NOT_ASSOCIATED: "not_assoc", Cause.LATENCY: "latency",
         Cause.NOT_CONFIRMED: "not_conf"}


@dataclass(frozen=True)
class RunOutcome:
    """One run of a comparison: label, tracker, its tracks CSV, milliseconds per frame as it
    would cost alone (its own time plus the shared front end's when another run paid it),
    confirmed tracks, its scores and where its Pd went (``explain``: the causes of its misses and
    false tracks; both None without truth), and its explain file (None: not written)."""

    label: str
    tracker: str
    tracks_csv: Path | None
    ms_per_frame: float
    confirmed: int
    scores: EvalResult | None
    group: int
    explain: ExplainSummary | None = None
    explain_csv: Path | None = None


@dataclass(frozen=True)
class CompareSummary:
    """What a comparison did: frames, wall seconds, every run's outcome, frames with a
    disagreement and marks by kind, the signal that stopped it (None: the end) and the
    parameters in which the runs differ (None: not known)."""

    frames: int
    seconds: float
    runs: tuple[RunOutcome, ...]
    disagreement_frames: int
    marks: dict[str, int]
    signal: int | None = None
    parameters: ParameterDifferences | None = None


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
              seconds: float | None = None, explain: list[Path | None] | None = None) -> CompareSummary:
    """The :class:`CompareSummary` of a comparison from what its sinks published at the end
    (the :class:`Comparison`, every run's scores and :class:`ExplainSummary`); ``tracks`` and
    ``explain``: each run's tracks CSV and explain file."""
    c = end.facts.get(Comparison)
    assert c is not None, "no DisagreementSink in the comparison"
    outcomes = tuple(RunOutcome(r.label, r.tracker, tracks[i] if tracks else None, c.ms_per_frame[i], c.confirmed[i],
                                end.facts.get(EvalResult, i), groups[i], end.facts.get(ExplainSummary, i),
                                explain[i] if explain else None) for i, r in enumerate(runs))
    return CompareSummary(end.frames, end.seconds if seconds is None else seconds, outcomes, c.disagreement_frames,
                          c.marks, end.signum, parameter_differences(runs))


def _num(v: float | None, fmt: str = ".3f") -> str:
    return "-" if v is None or v != v else format(v, fmt)


def _columns(head: list[str], rows: list[list[str]], left: int = 1) -> list[str]:
    """``head`` and ``rows`` as aligned lines: the first ``left`` columns to the left, the rest
    to the right, the last column (text) left as it is."""
    widths = [max(len(h), *(len(r[k]) for r in rows)) for k, h in enumerate(head)]
    last = len(head) - 1
    return ["  ".join(c if k == last else c.ljust(w) if k < left else c.rjust(w)
                      for k, (c, w) in enumerate(zip(cells, widths))).rstrip() for cells in (head, *rows)]


def format_causes(summary: CompareSummary) -> str:
    """Where each run's Pd went: a row per run with the count of each miss cause in pipeline
    order (:data:`~wfviz.explain.types.MISSES`), the matched points, the dominant miss cause and
    the false-track rows by cause; "" when no run has causes (no truth)."""
    runs = [r for r in summary.runs if r.explain is not None]
    if not runs:
        return ""
    head = ["run", *(SHORT[c] for c in MISSES), "matched", "dominant", "false-track rows"]
    rows = []
    for r in runs:
        e = r.explain
        assert e is not None
        false = sum(e.false_causes.values())
        by = ", ".join(f"{k} {n}" for k, n in sorted(e.false_causes.items(), key=lambda kv: (-kv[1], kv[0])) if n)
        rows.append([r.label, *(str(e.causes.get(c, 0)) for c in MISSES), str(e.causes.get(Cause.MATCHED, 0)),
                     e.dominant or "-", f"{false} ({by})" if false else "0"])
    first = runs[0].explain
    assert first is not None
    return "\n".join([f"where Pd went: {first.visible} visible truth points ({first.hidden} hidden), each miss "
                      f"by the first stage it did not pass", *_columns(head, rows, left=1)])


def format_summary(summary: CompareSummary) -> str:
    """The closing tables: a row per run (scores when truth was given), the parameters in which
    the runs differ, where each run's Pd went (with truth), then the disagreements."""
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
    causes = format_causes(summary)
    params = format_differences(summary.parameters) if summary.parameters is not None else ""
    return "\n".join([line(head), *map(line, rows), *(f"matched to truth: {rule}" for rule in rules),
                      *(["", params] if params else []),
                      *(["", causes, ""] if causes else []),
                      f"frames with a disagreement: {summary.disagreement_frames} of {summary.frames} ({kinds})"])
