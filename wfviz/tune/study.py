"""A tuning study: Optuna searches a tracker's parameters against ground truth (T. Akiba et
al., "Optuna: a next-generation hyperparameter optimization framework", KDD 2019): TPE for one
objective, NSGA-II for the Pareto front of Pd against false tracks.

The search is batch-synchronous: ``workers`` trials are asked for, run, and told back in trial
order before the next batch is asked for, and each ask uses a sampler seeded from ``seed`` and
the trial's number. The trials depend only on the seed, ``workers`` and what finished before,
so a resumed study (the journal ``study.journal`` in the output folder), a local pool and a
Ray cluster all give the same trials. Validation clips are run and scored in every trial but
never reach the sampler. Trial 0 is the base configuration (the defaults), so every study
reports where it started. Constraints (:mod:`wfviz.tune.constraints`) are set on each
completed trial for the sampler and the choice of the best; with ``prune`` a trial stops once
its tune clips show it significantly worse than the best so far (:mod:`wfviz.tune.pruning`).
"""

from __future__ import annotations

import json
import math
import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wfviz.config import ConfigError
from wfviz.run import StopSignals
from wfviz.tune.clips import StudyClip
from wfviz.tune.constraints import Constraint
from wfviz.tune.folder import JOURNAL
from wfviz.tune.pruning import prune_rule, study_order
from wfviz.tune.space import Param, SearchSpace, config_dict, make_config
from wfviz.tune.trial import TrialOutcome, TrialTask, mean_scores, sum_counts
from wfviz.tune.workers import make_pool

#: objective name -> (metrics, directions)
OBJECTIVES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "mota": (("mota",), ("maximize",)),
    "idf1": (("idf1",), ("maximize",)),
    "hota": (("hota",), ("maximize",)),
    "pd": (("pd",), ("maximize",)),  # with a --constraint on false tracks: Pd under a budget
    "pareto": (("pd", "fa"), ("maximize", "minimize")),
}
STUDY_NAME = "wfviz-tune"
TPE_STARTUP = 8      # random trials before TPE models the history (Optuna's default is 10)
NSGA_POPULATION = 8  # NSGA-II generation size (small: a study of a few dozen trials still evolves)


@dataclass(frozen=True)
class StudySettings:
    """Everything that defines a study (checked again when it resumes: :meth:`fingerprint`) and
    how to run it (``workers`` and Ray may change between runs; the trials then differ from
    those of one uninterrupted run, since a batch's size decides what its trials know)."""

    tracker: str
    clips: tuple[StudyClip, ...]
    space: SearchSpace
    base: Any  # the tracker's configuration the trials start from
    objective: str = "mota"
    trials: int = 20
    seed: int = 0
    workers: int = 1
    stop: int | None = None
    gate: float = 3.0
    use_ray: bool = False
    ray_address: str | None = None
    cache: bool = True  # replay prepared front-end frames (wfviz.tune.cache; the same results)
    constraints: tuple[Constraint, ...] = ()  # bounds a trial must meet to be chosen
    prune: bool = False  # stop hopeless trials early (wfviz.tune.pruning)

    def fingerprint(self) -> dict[str, Any]:
        """What must not change between runs of one study (the constraints only when there are
        any, so that a study made before they existed resumes)."""
        out = {"tracker": self.tracker, "objective": self.objective, "seed": self.seed,
               "stop": self.stop, "gate": self.gate,
               "clips": [[c.label, c.spec, str(c.truth), c.role] for c in self.clips],
               "space": [p.__dict__ | {"choices": list(p.choices)} for p in self.space.params],
               "fixed": self.space.fixed, "base": config_dict(self.base)}
        if self.constraints:
            out["constraints"] = [c.text for c in self.constraints]
        return out


@dataclass
class StudyState:
    """Where a study stands: its finished trials (Optuna ``FrozenTrial``), whether it was
    interrupted, and the trials it ran this time."""

    trials: list[Any]
    interrupted: bool = False
    ran: int = 0
    notes: list[str] = field(default_factory=list)
    signal: int | None = None  # SIGINT or SIGTERM that stopped the run


def _optuna():
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


def check_study(out: Path, settings: StudySettings) -> Any | None:
    """The study in ``out`` when its journal exists and its settings match ``settings``; None
    when there is no journal yet. A journal that cannot be read, or holds a study with other
    settings, is refused (``ValueError``, one line). Nothing is written."""
    journal = out / JOURNAL
    if not journal.is_file():
        return None
    study = load_journal(journal)
    stored = study.user_attrs.get("settings")
    now = json.loads(json.dumps(settings.fingerprint()))
    if stored != now:
        keys = set(now) | set(stored if isinstance(stored, dict) else {})
        diff = sorted(k for k in keys if not isinstance(stored, dict) or stored.get(k) != now.get(k))
        raise ValueError(f"{out}: holds a study with other settings ({', '.join(diff)} differ); "
                         "resume it with the same command, or use another --out")
    return study


def open_study(out: Path, settings: StudySettings, study: Any | None = None) -> Any:
    """The study ``study`` that :func:`check_study` accepted in ``out``, or (None) a new one
    created there (its journal written); either way with the base trial queued unless it ran."""
    if study is not None:
        _enqueue_base(study, settings)  # again, if a stopped run cut it short
        return study
    optuna = _optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / JOURNAL)))
    study = optuna.create_study(study_name=STUDY_NAME, storage=storage,
                                directions=list(OBJECTIVES[settings.objective][1]))
    study.set_user_attr("settings", json.loads(json.dumps(settings.fingerprint())))
    _enqueue_base(study, settings)
    return study


def load_journal(journal: Path) -> Any:
    """The wfviz study in the journal file ``journal`` (errors name the file and the problem)."""
    optuna = _optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    try:
        storage = JournalStorage(JournalFileBackend(str(journal)))
        return optuna.load_study(study_name=STUDY_NAME, storage=storage)
    except KeyError:
        raise ValueError(f"{journal}: holds no wfviz study; use another --out") from None
    except Exception as exc:  # noqa: BLE001 - a truncated, replaced or foreign file: JSON, Optuna or OS errors
        what = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"{journal}: not a readable study journal ({what})") from None


def _enqueue_base(study: Any, settings: StudySettings) -> None:
    """Queue trial 0, the base configuration as it is, unless it ran or waits already."""
    from optuna.trial import TrialState

    if any(t.user_attrs.get("base") for t in finished(study)
           + study.get_trials(deepcopy=False, states=(TrialState.WAITING,))):
        return
    start = {p.name: _base_value(settings.base, p) for p in settings.space.params}
    if all(_inside(p, v) for p, v in zip(settings.space.params, start.values())):
        study.enqueue_trial(start, user_attrs={"base": True})


def _base_value(base: Any, p: Param) -> Any:
    section, key = p.name.split(".", 1)
    return getattr(getattr(base, section), key)


def _inside(p: Param, v: Any) -> bool:
    if p.kind == "choice":
        return v in p.choices
    return v is not None and p.low <= v <= p.high


def _sampler(settings: StudySettings, position: int):
    """The sampler of the study's ``position``-th finished trial: seeded from the study's seed
    and the position (not the trial number, which trials cut short by a stopped run use up), its
    other settings fixed, so that what it proposes depends on the finished trials only."""
    optuna = _optuna()
    seed = (settings.seed * 1_000_003 + position) % 2**32
    if settings.objective == "pareto":
        return optuna.samplers.NSGAIISampler(seed=seed, population_size=NSGA_POPULATION)
    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=TPE_STARTUP)


def _suggest(trial: Any, p: Param) -> Any:
    if p.kind == "choice":
        return trial.suggest_categorical(p.name, list(p.choices))
    if p.kind == "int":
        return trial.suggest_int(p.name, int(p.low), int(p.high), step=p.step or 1, log=p.log)
    return trial.suggest_float(p.name, p.low, p.high, log=p.log)


UNFINISHED = ("interrupted", "not finished (the study was stopped)")  # errors of trials cut short


def finished(study: Any) -> list[Any]:
    """The study's trials that ended (completed, pruned, or failed on their own), in trial
    order; trials cut short by Ctrl-C or a stopped run are left out (the study asks for others)."""
    from optuna.trial import TrialState

    return [t for t in study.get_trials(deepcopy=False)
            if t.state in (TrialState.COMPLETE, TrialState.PRUNED)
            or (t.state == TrialState.FAIL and t.user_attrs.get("error") not in UNFINISHED)]


def _close_stale(study: Any) -> int:
    """Trials a stopped run left running: recorded as failed (they are asked for again)."""
    from optuna.trial import TrialState

    stale = [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.RUNNING]
    for t in stale:  # (Optuna has no public call for another process's running trial)
        study._storage.set_trial_user_attr(t._trial_id, "error", UNFINISHED[1])
        study.tell(t.number, state=TrialState.FAIL)
    return len(stale)


def run_study(settings: StudySettings, study: Any, work: Path,
              on_batch: Callable[[StudyState], None] | None = None) -> StudyState:
    """Run trials until ``study`` (:func:`open_study`) has ``settings.trials`` finished ones (a
    failed trial counts), the trials' tracks CSVs in ``work``, calling ``on_batch`` after each
    batch (outputs, progress). Ctrl-C or SIGTERM ends the running trials (recorded as failed,
    "interrupted") and keeps every finished one."""
    from optuna.trial import TrialState

    metrics = OBJECTIVES[settings.objective][0]
    state = StudyState(finished(study))
    stale = _close_stale(study)
    if stale:
        state.notes.append(f"{stale} trial(s) left running by a stopped run recorded as failed")
    tune_labels = [c.label for c in settings.clips if c.role == "tune"]
    valid_labels = [c.label for c in settings.clips if c.role == "validate"]
    order = study_order(settings.clips, settings.seed)  # every trial runs its clips in this order
    ordered_tune = [c.label for c in order if c.role == "tune"]
    from wfviz.trackers import config_class

    cls = config_class(settings.tracker)
    remaining = max(1, settings.trials - len(finished(study)))
    pool = make_pool(min(settings.workers, remaining), settings.ray_address, settings.use_ray)
    cut = False  # a trial was cut short (in this process, its own run caught the signal)
    caught: int | None = None  # the signal such a trial caught
    try:
        with StopSignals() as signals:
            def stop() -> bool:
                return cut or signals.signum is not None

            while len(finished(study)) < settings.trials and not stop():
                done = len(finished(study))
                batch = min(settings.workers, settings.trials - done)
                rule = prune_rule(finished(study), metrics[0], ordered_tune) if settings.prune else None
                asked, tasks = [], []
                for i in range(batch):
                    study.sampler = _sampler(settings, done + i)
                    trial = study.ask()
                    params = {p.name: _suggest(trial, p) for p in settings.space.params}
                    try:
                        config = make_config(cls, params, settings.space.fixed, settings.base)
                    except ConfigError as exc:  # a sampled combination the tracker refuses
                        trial.set_user_attr("error", f"invalid configuration: {exc}")
                        study.tell(trial, state=TrialState.FAIL)
                        state.ran += 1
                        continue
                    asked.append(trial)
                    tasks.append(TrialTask(trial.number, settings.tracker, config_dict(config),
                                           order, settings.stop, settings.gate,
                                           str(work), settings.cache, rule))
                outcomes = pool.run(tasks, stop) if tasks else []
                for trial, task, outcome in zip(asked, tasks, outcomes):
                    _tell(study, trial, outcome, settings, tune_labels, valid_labels, task.prune)
                    state.ran += 1
                state.trials = finished(study)
                cut = any(o is None or o.error == "interrupted" for o in outcomes)
                caught = caught or next((o.signal for o in outcomes if o is not None and o.signal), None)
                if on_batch is not None:
                    on_batch(state)
            state.interrupted = stop() and len(finished(study)) < settings.trials
            state.signal = signals.signum if state.interrupted else None
            if state.interrupted and state.signal is None:  # a trial run in this process caught it
                state.signal = caught or signal.SIGINT
    finally:
        pool.close()
    state.trials = finished(study)
    return state


def outcome_phrases(trials: list[Any], settings: StudySettings) -> tuple[str, str]:
    """For a summary of ``trials``: how many completed trials miss the constraints (" (2 outside
    fa_per_frame<=0.1: never chosen)", or "") and how many were pruned ("3 pruned, ", or "")."""
    from optuna.trial import TrialState

    from wfviz.tune.constraints import feasible

    done = [t for t in trials if t.state == TrialState.COMPLETE]
    outside = sum(not feasible(t) for t in done)
    pruned = sum(t.state == TrialState.PRUNED for t in trials)
    bounds = ", ".join(c.text for c in settings.constraints)
    return (f" ({outside} outside {bounds}: never chosen)" if settings.constraints else "",
            f"{pruned} pruned, " if settings.prune or pruned else "")


def causes_attr(causes: dict[str, dict[str, Any]], tune_labels: list[str],
                valid_labels: list[str]) -> dict[str, Any]:
    """A trial's ``causes`` user attribute: where its Pd went (:func:`wfviz.tune.trial.cause_counts`)
    summed over the tune clips (``tune``) and the validation clips (``validate``, when there are
    any)."""
    out = {"tune": sum_counts([causes[label] for label in tune_labels if label in causes])}
    if valid_labels:
        out["validate"] = sum_counts([causes[label] for label in valid_labels if label in causes])
    return out


def _tell(study: Any, trial: Any, outcome: TrialOutcome | None, settings: StudySettings,
          tune_labels: list[str], valid_labels: list[str], rule: Any) -> None:
    """Record ``outcome`` in ``trial``: failed (its error), pruned (the clips it ran, ``pruned``:
    after how many tune clips, against which trial) or completed (its scores, the causes, and
    each constraint's violation, ``Trial.set_constraint``)."""
    from optuna.trial import TrialState

    metrics = OBJECTIVES[settings.objective][0]
    if outcome is not None and outcome.pruned and outcome.scores is not None:
        trial.set_user_attr("scores", outcome.scores)
        trial.set_user_attr("seconds", outcome.seconds)
        ran = sum(label in outcome.scores for label in tune_labels)
        trial.set_user_attr("pruned", {"after": ran, "of": len(tune_labels),
                                       "against": rule.against if rule is not None else None})
        study.tell(trial, state=TrialState.PRUNED)
        return
    if outcome is None or outcome.scores is None:
        trial.set_user_attr("error", outcome.error if outcome is not None else "interrupted")
        if outcome is not None:
            trial.set_user_attr("seconds", outcome.seconds)
        study.tell(trial, state=TrialState.FAIL)
        return
    tuned = mean_scores(outcome.scores, tune_labels)
    trial.set_user_attr("scores", outcome.scores)
    trial.set_user_attr("tune", tuned)
    if valid_labels:
        trial.set_user_attr("validate", mean_scores(outcome.scores, valid_labels))
    if outcome.causes:
        trial.set_user_attr("causes", causes_attr(outcome.causes, tune_labels, valid_labels))
    if outcome.frames:
        trial.set_user_attr("frames", outcome.frames)
    trial.set_user_attr("seconds", outcome.seconds)
    values = [tuned[m] for m in metrics]
    if not all(math.isfinite(v) for v in values):
        trial.set_user_attr("error", "objective is not a number (no truth point in the scored frames?)")
        study.tell(trial, state=TrialState.FAIL)
        return
    violations = {c.text: c.violation(tuned) for c in settings.constraints}
    unknown = [k for k, v in violations.items() if not math.isfinite(v)]
    if unknown:
        trial.set_user_attr("error", f"constraint {unknown[0]}: the metric is not a number")
        study.tell(trial, state=TrialState.FAIL)
        return
    for key, v in violations.items():
        trial.set_constraint(key, v)
    study.tell(trial, values)
