"""Where trials run: in this process, in local worker processes, or as Ray tasks
(:mod:`wfviz.pools`). Every kind runs the same :func:`wfviz.tune.trial.run_trial` on a batch of
tasks and returns the outcomes in the batch's order, so a study gives the same trials whichever
runs it."""

from __future__ import annotations

from wfviz.pools import Pool, require_ray, worker_count
from wfviz.pools import make_pool as _make_pool
from wfviz.tune.trial import TrialOutcome, TrialTask, run_trial

__all__ = ["make_pool", "require_ray", "worker_count"]


def trial_failed(task: TrialTask, why: str) -> TrialOutcome:
    """The outcome of a trial whose worker died."""
    return TrialOutcome(task.number, None, why, 0.0)


def make_pool(workers: int, ray_address: str | None, use_ray: bool) -> Pool:
    """The runner of trials for ``--workers`` and ``--ray``."""
    return _make_pool(workers, ray_address, use_ray, run_trial, trial_failed, name="wfviz-tune-worker")
