"""One trial of a tuning study: a configuration run over every clip and scored exactly as
``wfviz track`` followed by ``wfviz eval`` would score it (the tracks CSV is written and read
back), with the causes of its misses and false tracks counted as ``wfviz track --explain``
counts them (:mod:`wfviz.explain`), in whatever process runs it (a local worker or a Ray task)."""

from __future__ import annotations

import math
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wfviz.tune.clips import StudyClip
from wfviz.tune.pruning import ClipPruner, PruneRule

#: per-clip metrics of a trial (``wfviz eval``'s names): higher is better except ``fa`` and ``idsw``
METRICS = ("mota", "idf1", "hota", "pd", "fa", "idsw")


@dataclass(frozen=True)
class TrialTask:
    """What a worker needs: the trial ``number``, the tracker and its whole configuration (the
    TOML form), the clips, frames before ``stop``, the match ``gate`` and a folder for the
    trial's temporary tracks CSVs; ``cache``: replay the clips' prepared front-end frames where
    the tracker allows (:mod:`wfviz.tune.cache`); ``prune``: stop when the tune clips so far
    show the trial significantly worse than the best (:mod:`wfviz.tune.pruning`; the tune clips
    come first in ``clips``, in the study's order)."""

    number: int
    tracker: str
    config: dict[str, dict[str, Any]]
    clips: tuple[StudyClip, ...]
    stop: int | None
    gate: float
    work: str
    cache: bool = True  # replay prepared frames where the tracker allows (wfviz.tune.cache)
    prune: PruneRule | None = None


@dataclass(frozen=True)
class TrialOutcome:
    """A trial's ``scores`` ({clip label: {metric: value}}) or its ``error``, its wall time, the
    signal that cut it when it ran in the study's own process (its run caught it), where its
    Pd went on each clip (``causes``: {clip label: :func:`cause_counts`}), the counts behind
    its scores frame by frame (``frames``: {clip label: :func:`wfviz.tune.significance.pack`
    of :func:`wfviz.evaluate.evaluate_by_frame`'s counts}), for the report's intervals, and
    whether it was ``pruned`` (then ``scores`` holds the clips it ran)."""

    number: int
    scores: dict[str, dict[str, float]] | None
    error: str | None
    seconds: float
    signal: int | None = None
    causes: dict[str, dict[str, Any]] | None = None
    frames: dict[str, list[list[int]]] | None = None
    pruned: bool = False


def cause_counts(summary: Any) -> dict[str, Any]:
    """An :class:`~wfviz.explain.report.ExplainSummary` as JSON-ready counts: ``causes`` (every
    truth cause but hidden: visible points), ``false`` (every false-track cause: confirmed track
    points) and ``hidden`` points."""
    from wfviz.explain.types import MISSES, Cause, FalseCause

    return {"causes": {c.value: int(summary.causes.get(c, 0)) for c in (Cause.MATCHED, *MISSES)},
            "false": {c.value: int(summary.false_causes.get(c, 0)) for c in FalseCause},
            "hidden": int(summary.hidden)}


def dominant(counts: dict[str, Any] | None, part: str = "causes") -> str | None:
    """The most frequent miss cause of :func:`cause_counts` (``part`` "false": false-track
    cause); None when nothing was missed (no false track) or no counts."""
    from wfviz.explain.report import ExplainSummary

    if not counts or part not in counts:
        return None
    if part == "causes":
        return ExplainSummary(dict(counts["causes"]), {}).dominant
    top = max(((n, k) for k, n in counts["false"].items() if n), default=None)
    return top[1] if top is not None else None


def sum_counts(counts: list[dict[str, Any]]) -> dict[str, Any]:
    """The :func:`cause_counts` of several clips added up."""
    out: dict[str, Any] = {"causes": {}, "false": {}, "hidden": 0}
    for c in counts:
        for part in ("causes", "false"):
            for k, n in c[part].items():
                out[part][k] = out[part].get(k, 0) + n
        out["hidden"] += c["hidden"]
    return out


def run_trial(task: TrialTask) -> TrialOutcome:
    """Run ``task`` (never raises: an error is the outcome's ``error``, one line)."""
    import warnings

    from wfviz.io.clip import ClipNote

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ClipNote)  # (noted once when the study opened the clips)
        return _run(task)


def _track(source: Any, tracker: Any, task: TrialTask, csv_path: Path, truth: Path) -> tuple[Any, dict[str, Any]]:
    """``tracker`` over ``source`` (frames before ``task.stop``), writing the tracks CSV
    ``csv_path`` as ``wfviz track`` does, and the causes of its misses and false tracks against
    ``truth`` (:func:`cause_counts`): the run's summary and those counts."""
    from wfviz.evaluate import read_truth
    from wfviz.explain.report import ExplainSummary
    from wfviz.explain.sink import ExplainSink
    from wfviz.run import SingleRun, StopSignals, drive, open_sinks
    from wfviz.sinks import TracksSink

    points = read_truth(truth)
    with StopSignals() as signals:  # as wfviz.run.run: a signal stops the run after its frame
        sinks = open_sinks([lambda: TracksSink(csv_path),
                            lambda: ExplainSink(points, task.gate, task.tracker, tracker.config)])
        summary = drive(source, SingleRun(tracker), sinks, stop=task.stop, signals=signals)
    why = summary.facts.get(ExplainSummary)
    assert why is not None, "the ExplainSink concluded no summary"
    return summary, cause_counts(why)


def _run(task: TrialTask) -> TrialOutcome:
    from wfviz.config import config_from_dict
    from wfviz.evaluate import evaluate_by_frame
    from wfviz.io.clip import open_clip
    from wfviz.trackers import TRACKERS, config_class, make_tracker
    from wfviz.tune.cache import cacheable, replay
    from wfviz.tune.significance import pack

    t0 = time.perf_counter()
    scores: dict[str, dict[str, float]] = {}
    causes: dict[str, dict[str, Any]] = {}
    frames: dict[str, list[list[int]]] = {}
    step = 0  # tune clips run
    last = sum(c.role == "tune" for c in task.clips) - 1  # after the last one a trial has its score
    try:
        pruner = ClipPruner(task.prune) if task.prune is not None else None
        config = config_from_dict(task.config, config_class(task.tracker))
        work = Path(task.work)
        work.mkdir(parents=True, exist_ok=True)
        for clip in task.clips:
            csv_path = work / f"trial-{task.number}-{clip.label}-{os.getpid()}.csv"
            if task.cache and cacheable(task.tracker, config):
                source, prepared = replay(clip.spec, task.stop, config)
                tracker = TRACKERS[task.tracker].tracker(config, source=prepared)
            else:
                source, tracker = open_clip(clip.spec), make_tracker(task.tracker, config)
            try:
                summary, causes[clip.label] = _track(source, tracker, task, csv_path, clip.truth)
                if summary.interrupted:
                    return TrialOutcome(task.number, None, "interrupted", time.perf_counter() - t0,
                                        summary.signal)
                result, counts = evaluate_by_frame(csv_path, clip.truth, gate=task.gate)
                frames[clip.label] = pack(counts)
            finally:
                csv_path.unlink(missing_ok=True)
            scores[clip.label] = {"mota": result.mota, "idf1": result.idf1, "hota": result.hota, "pd": result.pd,
                                  "fa": result.fa_per_frame, "idsw": float(result.id_switches)}
            if pruner is not None and clip.role == "tune" and step < last:
                if pruner.should_stop(step, scores[clip.label][pruner.metric]):
                    return TrialOutcome(task.number, scores, None, time.perf_counter() - t0, causes=causes,
                                        frames=frames, pruned=True)
                step += 1
    except KeyboardInterrupt:
        return TrialOutcome(task.number, None, "interrupted", time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - a failing trial is recorded and the study goes on
        where = traceback.extract_tb(exc.__traceback__)[-1]
        error = f"{type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})"
        return TrialOutcome(task.number, None, error.replace("\n", " "), time.perf_counter() - t0)
    return TrialOutcome(task.number, scores, None, time.perf_counter() - t0, causes=causes, frames=frames)


def mean_scores(scores: dict[str, dict[str, float]], labels: list[str]) -> dict[str, float]:
    """Each metric averaged over the clips ``labels`` (NaN when a clip's value is NaN or missing,
    as in a trial scored before the metric was added, or no clip)."""
    out = {}
    for m in METRICS:
        values = [scores[label].get(m, math.nan) for label in labels if label in scores]
        out[m] = sum(values) / len(values) if values and all(math.isfinite(v) for v in values) else math.nan
    return out
