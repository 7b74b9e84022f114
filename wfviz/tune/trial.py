"""One trial of a tuning study: a configuration run over every clip and scored exactly as
``wfviz track`` followed by ``wfviz eval`` would score it (the tracks CSV is written and read
back), in whatever process runs it (a local worker or a Ray task)."""

from __future__ import annotations

import math
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wfviz.tune.clips import StudyClip

#: per-clip metrics of a trial (``wfviz eval``'s names): higher is better except ``fa`` and ``idsw``
METRICS = ("mota", "idf1", "pd", "fa", "idsw")


@dataclass(frozen=True)
class TrialTask:
    """What a worker needs: the trial ``number``, the tracker and its whole configuration (the
    TOML form), the clips, frames before ``stop``, the match ``gate`` and a folder for the
    trial's temporary tracks CSVs; ``cache``: replay the clips' prepared front-end frames where
    the tracker allows (:mod:`wfviz.tune.cache`)."""

    number: int
    tracker: str
    config: dict[str, dict[str, Any]]
    clips: tuple[StudyClip, ...]
    stop: int | None
    gate: float
    work: str
    cache: bool = True  # replay prepared frames where the tracker allows (wfviz.tune.cache)


@dataclass(frozen=True)
class TrialOutcome:
    """A trial's ``scores`` ({clip label: {metric: value}}) or its ``error``, its wall time, and
    the signal that cut it when it ran in the study's own process (its run caught it)."""

    number: int
    scores: dict[str, dict[str, float]] | None
    error: str | None
    seconds: float
    signal: int | None = None


def run_trial(task: TrialTask) -> TrialOutcome:
    """Run ``task`` (never raises: an error is the outcome's ``error``, one line)."""
    import warnings

    from wfviz.io.clip import ClipNote

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ClipNote)  # (noted once when the study opened the clips)
        return _run(task)


def _run(task: TrialTask) -> TrialOutcome:
    from wfviz.config import config_from_dict
    from wfviz.evaluate import evaluate
    from wfviz.io.clip import open_clip
    from wfviz.run import run
    from wfviz.trackers import TRACKERS, config_class, make_tracker
    from wfviz.tune.cache import cacheable, replay

    t0 = time.perf_counter()
    scores: dict[str, dict[str, float]] = {}
    try:
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
                summary = run(source, tracker, tracks_csv=csv_path, stop=task.stop)
                if summary.interrupted:
                    return TrialOutcome(task.number, None, "interrupted", time.perf_counter() - t0,
                                        summary.signal)
                result = evaluate(csv_path, clip.truth, gate=task.gate)
            finally:
                csv_path.unlink(missing_ok=True)
            scores[clip.label] = {"mota": result.mota, "idf1": result.idf1, "pd": result.pd,
                                  "fa": result.fa_per_frame, "idsw": float(result.id_switches)}
    except KeyboardInterrupt:
        return TrialOutcome(task.number, None, "interrupted", time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - a failing trial is recorded and the study goes on
        where = traceback.extract_tb(exc.__traceback__)[-1]
        error = f"{type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})"
        return TrialOutcome(task.number, None, error.replace("\n", " "), time.perf_counter() - t0)
    return TrialOutcome(task.number, scores, None, time.perf_counter() - t0)


def mean_scores(scores: dict[str, dict[str, float]], labels: list[str]) -> dict[str, float]:
    """Each metric averaged over the clips ``labels`` (NaN when a clip's value is NaN or no clip)."""
    out = {}
    for m in METRICS:
        values = [scores[label][m] for label in labels if label in scores]
        out[m] = sum(values) / len(values) if values and all(math.isfinite(v) for v in values) else math.nan
    return out
