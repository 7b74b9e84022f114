"""Constraints of a study (``--constraint "fa_per_frame<=0.1"``): a bound on a metric averaged
over the tune clips, which a trial must meet to be chosen. Each becomes an Optuna constraint
(``Trial.set_constraint``: the violation, feasible at zero or less), which TPE and NSGA-II take
into account when they sample and :func:`feasible` when the best trial is chosen."""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass
from typing import Any

#: metric a constraint may bound (``wfviz eval``'s names) -> the trial's metric
#: (:data:`wfviz.tune.trial.METRICS`, the short names of trials.csv, also accepted)
CONSTRAINT_METRICS: dict[str, str] = {
    "pd": "pd", "fa_per_frame": "fa", "mota": "mota", "idf1": "idf1", "hota": "hota", "id_switches": "idsw",
}
_ALIASES = {short: name for name, short in CONSTRAINT_METRICS.items()}
_FORM = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(<=|>=|=<|=>|<|>|==|=)\s*(\S+)\s*$")


@dataclass(frozen=True)
class Constraint:
    """``metric`` (a :data:`CONSTRAINT_METRICS` name) ``op`` ("<=" or ">=") ``bound``, on the
    metric averaged over the tune clips."""

    metric: str
    op: str
    bound: float

    @property
    def text(self) -> str:
        """The constraint as written back (its key in the journal and the report)."""
        return f"{self.metric}{self.op}{self.bound:g}"

    def violation(self, means: dict[str, float]) -> float:
        """How far the tune-clip means ``means`` ({trial metric: value}) are past the bound
        (zero or less: met). NaN when the metric is."""
        value = means[CONSTRAINT_METRICS[self.metric]]
        return value - self.bound if self.op == "<=" else self.bound - value


def parse_constraint(text: str) -> Constraint:
    """``METRIC<=VALUE`` or ``METRIC>=VALUE``; a ``ValueError`` (one line naming the text and the
    problem) otherwise."""
    names = ", ".join(CONSTRAINT_METRICS)
    m = _FORM.match(text)
    if m is None:
        raise ValueError(f"--constraint '{text}': expected METRIC<=VALUE or METRIC>=VALUE "
                         f"(METRIC one of {names})")
    metric, op, bound = m.group(1).lower(), m.group(2), m.group(3)
    metric = _ALIASES.get(metric, metric)
    if metric not in CONSTRAINT_METRICS:
        close = difflib.get_close_matches(metric, CONSTRAINT_METRICS, n=1)
        hint = f"did you mean '{close[0]}'? " if close else ""
        raise ValueError(f"--constraint '{text}': unknown metric '{metric}' ({hint}available: {names})")
    if op not in ("<=", ">="):
        raise ValueError(f"--constraint '{text}': use <= or >= (not {op}): a bound is met at equality")
    try:
        value = float(bound)
    except ValueError:
        raise ValueError(f"--constraint '{text}': '{bound}' is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"--constraint '{text}': the bound must be a finite number")
    return Constraint(metric, op, value)


def parse_constraints(texts: list[str]) -> tuple[Constraint, ...]:
    """Every ``--constraint``; the same constraint given twice is refused."""
    out = tuple(parse_constraint(t) for t in texts)
    seen = [c.text for c in out]
    twice = sorted({t for t in seen if seen.count(t) > 1})
    if twice:
        raise ValueError(f"--constraint '{twice[0]}': given twice")
    return out


def feasible(trial: Any) -> bool:
    """Whether an Optuna trial meets every constraint set on it (a trial without any does)."""
    return all(v <= 0.0 for v in trial.constraints.values())
