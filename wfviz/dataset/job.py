"""One clip of a dataset → one row: the function the pools run (:mod:`wfviz.pools`), in this
process, a local worker or a Ray task.

A clip is tracked as ``wfviz track CLIP --tracks DIR/tracks/LABEL.csv --truth TRUTH --explain
DIR/explain/LABEL.csv`` would track it (:func:`wfviz.run.run`: the same sinks; the explain files
cost next to nothing beside the tracking). A clip to be recorded (``--record``: every one) is
recorded in that same run; a clip that ``--record-failing``'s condition picks is known only once
scored, and is then tracked once more with the recording (as ``wfviz record --truth``). Recording
costs about as much again as tracking (images logged and encoded, ~5 MB a 150-frame 320x256
clip), so recording every clip to keep the failing ones would cost more than running the few
failing ones twice whenever fewer than about half of them fail."""

from __future__ import annotations

import signal
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from wfviz.dataset.discover import DatasetClip
from wfviz.dataset.goals import Goal
from wfviz.dataset.results import OWN_TRUTH, Row, cause_columns


@dataclass(frozen=True)
class ClipTask:
    """What a worker needs for one clip: the tracker and its whole configuration (TOML form), the
    gate, the run's output folder, its configuration hash, and what to record (``record``: this
    clip, in its run; ``record_if``: when its scores meet this condition)."""

    clip: DatasetClip
    tracker: str
    config: dict[str, dict[str, Any]]
    gate: float
    out: str
    config_hash: str
    record: bool = False
    record_if: Goal | None = None


def outputs(out: Path, label: str) -> dict[str, Path]:
    """The files a clip's run writes in the output folder ``out``."""
    return {"tracks": out / "tracks" / f"{label}.csv", "explain": out / "explain" / f"{label}.csv",
            "explain_false": out / "explain" / f"{label}-false.csv",
            "recording": out / "recordings" / f"{label}.rrd"}


def failed(task: ClipTask, why: str) -> Row:
    """The row of a clip whose worker died (or whose Ray task failed)."""
    c = task.clip
    return Row(c.label, c.spec, c.truth or (OWN_TRUTH if c.synthetic else ""), f"failed: {why}",
               config_hash=task.config_hash)


def run_clip(task: ClipTask) -> Row:
    """Track, score, explain and maybe record ``task``'s clip (never raises: an error is the row's
    status, one line; a signal that stopped the clip is the row's ``signal``)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        row = _run(task)
    notes = tuple(dict.fromkeys(str(w.message).replace("\n", " ") for w in caught
                                if not issubclass(w.category, (DeprecationWarning, ResourceWarning))))
    return replace(row, notes=notes)


def _run(task: ClipTask) -> Row:
    from wfviz.config import config_from_dict, config_to_toml
    from wfviz.evaluate import read_truth
    from wfviz.explain.report import ExplainSummary
    from wfviz.io.clip import open_clip
    from wfviz.run import run
    from wfviz.trackers import config_class, make_tracker
    from wfviz.tune.trial import cause_counts

    clip = task.clip
    files = outputs(Path(task.out), clip.label)
    base = Row(clip.label, clip.spec, clip.truth or (OWN_TRUTH if clip.synthetic else ""), "ok",
               config_hash=task.config_hash)
    t0 = time.perf_counter()
    try:
        config = config_from_dict(task.config, config_class(task.tracker))
        source = open_clip(clip.spec)
        truth = (read_truth(clip.truth) if clip.truth
                 else source.truth_points() if hasattr(source, "truth_points") else None)

        def options() -> Any:
            from wfviz.record_options import RecorderOptions

            return RecorderOptions(source=clip.spec, config_text=config_to_toml(config),
                                   trail_length=config.tracking.trail_length)

        recording = files["recording"] if task.record else None
        summary = run(source, make_tracker(task.tracker, config), tracks_csv=files["tracks"], recording=recording,
                      recorder_options=options() if recording is not None else None, truth=truth, gate=task.gate,
                      explain=files["explain"] if truth is not None else None)
        if summary.interrupted:
            return replace(base, status="interrupted", signal=summary.signal)
        scores: dict[str, float] = {}
        causes: dict[str, int] = {}
        if summary.scores is not None:
            s = summary.scores
            scores = {"pd": s.pd, "pd_settled": s.pd_settled, "fa_per_frame": s.fa_per_frame, "mota": s.mota,
                      "idf1": s.idf1, "hota": s.hota, "id_switches": float(s.id_switches), "cle_rms": s.cle_rms}
            why = summary.facts.get(ExplainSummary)
            causes = cause_columns(cause_counts(why) if why is not None else None)
        if (recording is None and task.record_if is not None and scores and task.record_if.holds(scores)):
            recording = files["recording"]
            again = run(open_clip(clip.spec), make_tracker(task.tracker, config), recording=recording,
                        recorder_options=options(), truth=truth, gate=task.gate)
            if again.interrupted:
                files["recording"].unlink(missing_ok=True)  # a partial recording is no recording of the clip
                return replace(base, status="interrupted", signal=again.signal)
        _remove_stale(files, keep_recording=recording is not None, keep_explain=truth is not None)
        return replace(base, frames=summary.frames, seconds=summary.seconds, ms_per_frame=summary.tracker_ms,
                       scores=scores, causes=causes, recording=str(recording) if recording is not None else "")
    except KeyboardInterrupt:
        return replace(base, status="interrupted", signal=signal.SIGINT)
    except Exception as exc:  # noqa: BLE001 - a failing clip is a row; the dataset goes on
        _remove_stale(files, keep_recording=False, keep_explain=False, keep_tracks=False)
        where = traceback.extract_tb(exc.__traceback__)[-1]
        error = f"{type(exc).__name__}: {exc}" if isinstance(exc, (OSError, ValueError)) \
            else f"{type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})"
        return replace(base, status=f"failed: {error}".replace("\n", " "), seconds=time.perf_counter() - t0)


def _remove_stale(files: dict[str, Path], *, keep_recording: bool, keep_explain: bool,
                  keep_tracks: bool = True) -> None:
    """Remove what an earlier run of the clip left that this one did not write (a recording of a
    clip that now meets the goal, the outputs of a clip that now fails)."""
    drop = [] if keep_tracks else ["tracks"]
    drop += [] if keep_recording else ["recording"]
    drop += [] if keep_explain else ["explain", "explain_false"]
    for name in drop:
        files[name].unlink(missing_ok=True)
