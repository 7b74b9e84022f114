"""Early stopping of hopeless trials (``--prune``): a trial runs its tune clips one by one, in
an order fixed for the study (seeded), and after each clip Optuna's ``WilcoxonPruner`` compares
its scores so far with the best trial's on the same clips (a paired, one-sided Wilcoxon
signed-rank test); when the trial is significantly worse it stops, and is recorded as pruned.

The decision is made where the trial runs (a local worker or a Ray task), against the best
trial among those finished before its batch was asked for, so it depends on the seed,
``--workers`` and the finished trials only, as the trials themselves do."""

from __future__ import annotations

import random
import warnings
from dataclasses import dataclass
from typing import Any

from wfviz.tune.clips import StudyClip

P_THRESHOLD = 0.1  # WilcoxonPruner's default: prune when p < 0.1 that the trial is not worse
STARTUP_CLIPS = 2  # paired clips before a trial may be pruned (WilcoxonPruner's default)


@dataclass(frozen=True)
class PruneRule:
    """What a worker needs to prune a trial: the objective's per-clip ``metric`` (maximised),
    the ``reference`` trial's score on each tune clip in the study's clip order (the best
    trial so far, number ``against``), the test's ``p_threshold`` and the clips it needs first
    (``startup``)."""

    metric: str
    reference: tuple[float, ...]
    against: int
    p_threshold: float = P_THRESHOLD
    startup: int = STARTUP_CLIPS


def study_order(clips: tuple[StudyClip, ...], seed: int) -> tuple[StudyClip, ...]:
    """The order every trial of a study runs its clips in: the tune clips shuffled by ``seed``
    (the same for every trial, so the pruner compares like with like from the first clip on),
    then the validation clips as given."""
    tune = [c for c in clips if c.role == "tune"]
    random.Random(seed).shuffle(tune)
    return (*tune, *(c for c in clips if c.role != "tune"))


def prune_rule(trials: list[Any], metric: str, tune_labels: list[str]) -> PruneRule | None:
    """The rule for the next trials: against the best of ``trials`` (completed, feasible, scored
    on every tune clip; ties: the earlier) on ``metric``; None when there is none yet.
    ``tune_labels``: the tune clips in :func:`study_order`."""
    from optuna.trial import TrialState

    from wfviz.tune.constraints import feasible

    done = [t for t in trials if t.state == TrialState.COMPLETE and t.values is not None and feasible(t)
            and all(label in t.user_attrs.get("scores", {}) for label in tune_labels)]
    if not done:
        return None
    best = max(done, key=lambda t: (t.values[0], -t.number))
    return PruneRule(metric, tuple(float(best.user_attrs["scores"][label][metric]) for label in tune_labels),
                     best.number)


class ClipPruner:
    """Optuna's ``WilcoxonPruner`` over one trial's tune clips: an in-memory study holding the
    reference trial (its score per clip as intermediate values, step = the clip's position in
    the study's order) and this trial, which reports each clip's score as it comes."""

    def __init__(self, rule: PruneRule) -> None:
        import optuna

        self.metric = rule.metric
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # WilcoxonPruner is marked experimental
            pruner = optuna.pruners.WilcoxonPruner(p_threshold=rule.p_threshold, n_startup_steps=rule.startup)
        self._study = optuna.create_study(direction="maximize", pruner=pruner,
                                          sampler=optuna.samplers.RandomSampler(seed=0))
        steps = dict(enumerate(rule.reference))
        self._study.add_trial(optuna.trial.create_trial(value=sum(rule.reference) / len(rule.reference),
                                                        intermediate_values=steps))
        self._trial = self._study.ask()

    def should_stop(self, step: int, value: float) -> bool:
        """Report the score ``value`` of the tune clip at position ``step``; whether the trial
        is now significantly worse than the reference."""
        self._trial.report(value, step)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # (a NaN score is never pruned on; Optuna warns)
            return bool(self._trial.should_prune())
