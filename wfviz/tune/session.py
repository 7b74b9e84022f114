"""``wfviz tune`` end to end: resolve the clips, run the study, write its files, the report,
the study recording and the recordings of the best trials."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wfviz.tune.clips import StudyClip, study_clips
from wfviz.tune.outputs import ranked, trial_config, write_outputs
from wfviz.tune.space import SearchSpace
from wfviz.tune.study import StudySettings, StudyState, run_study


@dataclass(frozen=True)
class TuneResult:
    """What a ``wfviz tune`` run did: the study's state, its settings and the files written."""

    state: StudyState
    settings: StudySettings
    files: list[Path]


def prepare(tracker: str, tune: list[str], validate: list[str], out: Path, space: SearchSpace, base: Any,
            **options: Any) -> StudySettings:
    """The study's settings, its clips opened and their truth found (or written for ``synth:``
    clips into ``out/truth``)."""
    if not tune:
        raise ValueError("no clip to tune on (give at least one CLIP)")
    clips: tuple[StudyClip, ...] = tuple(study_clips(tune, validate, out / "truth", options.get("stop")))
    return StudySettings(tracker, clips, space, base, **options)


def tune(settings: StudySettings, out: Path, *, record_best: int = 0, folds: int = 0,
         on_batch: Callable[[StudyState], None] | None = None,
         on_stage: Callable[[str], None] | None = None) -> TuneResult:
    """Run the study in ``out``; then (also after Ctrl-C, with the finished trials) write
    ``trials.csv``, the best configuration(s), ``report.md`` with its plots, ``study.rrd`` and,
    with ``record_best`` K, recordings of the K best trials and of the base on every clip."""
    def batch(state: StudyState) -> None:
        write_outputs(out, state.trials, settings)
        if on_batch is not None:
            on_batch(state)

    state = run_study(settings, out, batch)
    import shutil

    shutil.rmtree(out / "work", ignore_errors=True)  # the trials' temporary tracks CSVs
    stage = on_stage or (lambda _s: None)
    files = write_outputs(out, state.trials, settings)
    stage("report")
    from wfviz.tune.report import write_report

    files += write_report(out, state.trials, settings, folds)
    stage("study recording")
    from wfviz.record.study import record_study

    files.append(record_study(out / "study.rrd", state.trials, settings))
    if record_best > 0 and not state.interrupted:
        stage("recordings of the best trials")
        files += record_trials(out, state.trials, settings, record_best)
    return TuneResult(state, settings, files)


def record_trials(out: Path, trials: list[Any], settings: StudySettings, k: int) -> list[Path]:
    """Recordings (with truth) of the ``k`` best trials and the base trial on every clip:
    ``out/recordings/trial-N-<clip>.rrd``."""
    from wfviz.config import config_to_toml
    from wfviz.evaluate import read_truth
    from wfviz.io.clip import open_clip
    from wfviz.run import run
    from wfviz.trackers import make_tracker

    chosen = ranked(trials, settings.objective)[:k]
    base = [t for t in trials if t.user_attrs.get("base") and t.values is not None]
    chosen += [t for t in base if t not in chosen]
    folder = out / "recordings"
    folder.mkdir(exist_ok=True)
    written = []
    for t in chosen:
        config = trial_config(settings, t)
        for clip in settings.clips:
            path = folder / f"trial-{t.number}-{clip.label}.rrd"
            source = open_clip(clip.spec)
            tracker = make_tracker(settings.tracker, config)
            options = dict(source=clip.spec, config_text=config_to_toml(config), image_every=1,
                           trail_length=config.tracking.trail_length)
            summary = run(source, tracker, recording=path, recorder_options=options, stop=settings.stop,
                          truth=read_truth(clip.truth), gate=settings.gate)
            written.append(path)
            if summary.interrupted:
                return written
    return written
