"""``wfviz tune`` end to end: resolve the clips, run the study, write its files, the report,
the study recording and the recordings of the best trials."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wfviz.synth.scenarios import SYNTH_PREFIX
from wfviz.tune.clips import StudyClip, study_clips, synth_truth, user_inputs
from wfviz.tune.folder import JOURNAL, StudyFolder
from wfviz.tune.outputs import ranked, trial_config, write_outputs
from wfviz.tune.space import SearchSpace
from wfviz.tune.study import StudySettings, StudyState, check_study, open_study, run_study
from wfviz.tune.workers import require_ray


@dataclass(frozen=True)
class TuneResult:
    """What a ``wfviz tune`` run did: the study's state, its settings, the files written and
    the signal (SIGINT, SIGTERM) that stopped it, if one did."""

    state: StudyState
    settings: StudySettings
    files: list[Path]
    signal: int | None = None


def prepare(tracker: str, tune: list[str], validate: list[str], out: Path, space: SearchSpace, base: Any,
            **options: Any) -> StudySettings:
    """The study's settings, its clips opened and their truth found (a ``synth:`` clip's is
    written into ``out/truth`` when the study runs). Nothing is written."""
    if not tune:
        raise ValueError("no clip to tune on (give at least one CLIP)")
    clips: tuple[StudyClip, ...] = tuple(study_clips(tune, validate, out / "truth"))
    return StudySettings(tracker, clips, space, base, **options)


def tune(settings: StudySettings, out: Path, *, record_best: int = 0, folds: int = 0,
         inputs: tuple[tuple[Path | None, str], ...] = (),
         on_batch: Callable[[StudyState], None] | None = None,
         on_stage: Callable[[str], None] | None = None) -> TuneResult:
    """Run the study in ``out``; then (also after Ctrl-C, with the finished trials) write
    ``trials.csv``, the best configuration(s), ``report.md`` with its plots, ``study.rrd`` and,
    with ``record_best`` K, recordings of the K best trials and of the base on every clip.

    Every check that can refuse the command runs before any file of the study is created or
    changed: Ray is there when asked for, every input (the clips, their truth, and ``inputs``
    such as the ``--config`` and ``--space`` files) lies out of reach of the study's files, the
    folder is free (locked for this process), it holds no file with the study's names that the
    study did not write, and a resumed study has the same settings (:func:`check_study`). A
    refused command leaves the folder as it was (a folder it had to create: removed again)."""
    if settings.use_ray:
        require_ray()
    folder = StudyFolder(out)
    files_in, folders_in = user_inputs(settings.clips)
    folder.check_inputs([*files_in, *((p, what) for p, what in inputs if p is not None)], folders_in)
    with folder.lock():
        folder.check_foreign()
        found = check_study(out, settings)
        # accepted: from here on the study's files are written
        folder.clear_stale()
        if found is None:
            folder.claim(out / JOURNAL)  # a new study: Optuna writes it
        study = open_study(out, settings, found)
        for clip in settings.clips:
            if clip.spec.startswith(SYNTH_PREFIX):  # to a temporary name, renamed; kept when the same
                folder.write(clip.truth, synth_truth(clip.spec, settings.stop))

        def batch(state: StudyState) -> None:
            write_outputs(folder, state.trials, settings)
            if on_batch is not None:
                on_batch(state)

        work = folder.work_dir()
        try:
            state = run_study(settings, study, work, batch)
        finally:
            import shutil

            shutil.rmtree(work, ignore_errors=True)  # the trials' temporary tracks CSVs
        stage = on_stage or (lambda _s: None)
        files = write_outputs(folder, state.trials, settings)
        stage("report")
        from wfviz.tune.report import write_report

        files += write_report(folder, state.trials, settings, folds)
        stage("study recording")
        from wfviz.record.study import record_study

        files.append(record_study(folder.claim(out / "study.rrd"), state.trials, settings))
        signum = state.signal
        if record_best > 0 and not state.interrupted:
            stage("recordings of the best trials")
            recorded, signum = record_trials(folder, state.trials, settings, record_best)
            files += recorded
    return TuneResult(state, settings, files, signum)


def record_trials(folder: StudyFolder, trials: list[Any], settings: StudySettings,
                  k: int) -> tuple[list[Path], int | None]:
    """Recordings (with truth) of the ``k`` best trials and the base trial on every clip:
    ``out/recordings/trial-N-<clip>.rrd``; and the signal that stopped them, if one did (the
    recording it cut keeps the frames done, the rest are not made)."""
    from wfviz.config import config_to_toml
    from wfviz.evaluate import read_truth
    from wfviz.io.clip import open_clip
    from wfviz.record_options import RecorderOptions
    from wfviz.run import run
    from wfviz.trackers import make_tracker

    chosen = ranked(trials, settings.objective)[:k]
    base = [t for t in trials if t.user_attrs.get("base") and t.values is not None]
    chosen += [t for t in base if t not in chosen]
    (folder.path / "recordings").mkdir(exist_ok=True)
    written: list[Path] = []
    for t in chosen:
        config = trial_config(settings, t)
        for clip in settings.clips:
            path = folder.claim(folder.path / "recordings" / f"trial-{t.number}-{clip.label}.rrd")
            source = open_clip(clip.spec)
            tracker = make_tracker(settings.tracker, config)
            options = RecorderOptions(source=clip.spec, config_text=config_to_toml(config), image_every=1,
                                      trail_length=config.tracking.trail_length)
            summary = run(source, tracker, recording=path, recorder_options=options, stop=settings.stop,
                          truth=read_truth(clip.truth), gate=settings.gate)
            written.append(path)
            if summary.interrupted:
                return written, summary.signal
    return written, None
