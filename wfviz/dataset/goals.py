"""Conditions on a clip's scores: ``METRIC OP NUMBER`` joined by ``and`` / ``or`` (``and``
binds first; no brackets), e.g. ``"pd<0.9 or fa_per_frame>0.1"``. Parsed by a small tokenizer,
never evaluated as Python. A metric that is NaN (no visible truth) makes its condition false."""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

#: the metrics a condition may name (``wfviz eval``'s, as in results.csv)
METRICS = ("pd", "pd_settled", "fa_per_frame", "mota", "idf1", "hota", "id_switches")
OPS: dict[str, Callable[[float, float], bool]] = {
    "<=": operator.le, ">=": operator.ge, "==": operator.eq, "!=": operator.ne, "<": operator.lt, ">": operator.gt}
_TOKEN = re.compile(r"\s*(?:(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)(?![\w.])"
                    r"|(?P<op><=|>=|==|!=|<|>)|(?P<word>[A-Za-z_]\w*)|(?P<bad>\S+?))")


@dataclass(frozen=True)
class Condition:
    """``metric op value``."""

    metric: str
    op: str
    value: float

    def holds(self, scores: Mapping[str, float]) -> bool:
        v = scores.get(self.metric, math.nan)
        return v is not None and not math.isnan(v) and OPS[self.op](v, self.value)

    def __str__(self) -> str:
        return f"{self.metric}{self.op}{self.value:g}"


@dataclass(frozen=True)
class Goal:
    """An ``or`` of ``and``-groups of conditions, and the text it was parsed from."""

    text: str
    any_of: tuple[tuple[Condition, ...], ...]

    def holds(self, scores: Mapping[str, float]) -> bool:
        """True when one ``and``-group holds entirely on ``scores`` ({metric: value})."""
        return any(all(c.holds(scores) for c in group) for group in self.any_of)

    def __str__(self) -> str:
        return " or ".join(" and ".join(map(str, g)) for g in self.any_of)


def parse_goal(text: str, option: str = "--record-failing") -> Goal:
    """``text`` as a :class:`Goal`; a malformed one: ValueError naming ``option`` and the problem."""

    def bad(why: str) -> ValueError:
        return ValueError(f"{option} {text!r}: {why} (expected METRIC OP NUMBER joined by 'or'/'and', "
                          f"METRIC one of {', '.join(METRICS)}, OP one of < <= > >= == !=; "
                          f"e.g. \"pd<0.9 or fa_per_frame>0.1\")")

    tokens: list[tuple[str, str]] = []
    for m in _TOKEN.finditer(text):
        kind = m.lastgroup
        if kind is None:
            continue
        if kind == "bad":
            raise bad(f"unexpected {m.group(kind)!r}")
        tokens.append((kind, m.group(kind)))
    if not tokens:
        raise bad("empty")
    groups: list[tuple[Condition, ...]] = []
    current: list[Condition] = []
    i = 0
    while True:
        if i + 3 > len(tokens):
            raise bad("incomplete condition at the end")
        (k1, metric), (k2, op), (k3, number) = tokens[i:i + 3]
        if k1 != "word" or metric.lower() in ("and", "or"):
            raise bad(f"expected a metric, got {metric!r}")
        if metric not in METRICS:
            raise bad(f"unknown metric {metric!r}")
        if k2 != "op":
            raise bad(f"expected a comparison after {metric!r}, got {op!r}")
        if k3 != "num":
            raise bad(f"expected a number after {metric}{op}, got {number!r}")
        current.append(Condition(metric, op, float(number)))
        i += 3
        if i == len(tokens):
            break
        kind, joiner = tokens[i]
        if kind != "word" or joiner.lower() not in ("and", "or"):
            raise bad(f"expected 'and' or 'or', got {joiner!r}")
        if joiner.lower() == "or":
            groups.append(tuple(current))
            current = []
        i += 1
    groups.append(tuple(current))
    return Goal(text, tuple(groups))
