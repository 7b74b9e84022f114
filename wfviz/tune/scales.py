"""Scales of a study's plots: a parameter's value on its search range (0 … 1), and an axis's
round range and ticks."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from wfviz.tune.space import Param


def unit_value(p: Param, value: Any) -> float:
    """``value`` of parameter ``p`` on its search range: 0 at ``low``, 1 at ``high`` (in log for
    a log-searched one, as the search samples it); a choice by its index, 0 first, 1 last."""
    if p.kind == "choice":
        n = len(p.choices)
        return p.choices.index(value) / (n - 1) if n > 1 else 0.5
    low, high, v = float(p.low), float(p.high), float(value)  # type: ignore[arg-type]
    if p.log:
        low, high, v = math.log(low), math.log(high), math.log(v)
    return (v - low) / (high - low) if high > low else 0.5


def range_text(p: Param) -> str:
    """The search range of ``p`` as a legend shows it: ``[3, 6]``, ``[0.05, 20] log``, ``{a, b}``."""
    if p.kind == "choice":
        return "{" + ", ".join(str(c) for c in p.choices) + "}"
    return f"[{p.low:g}, {p.high:g}]" + (" log" if p.log else "")


@dataclass(frozen=True)
class Axis:
    """A plot axis from ``low`` to ``high`` with ``ticks`` (round numbers, ends included)."""

    low: float
    high: float
    ticks: tuple[float, ...]

    def fraction(self, v: float) -> float:
        """Where ``v`` lies on the axis: 0 at ``low``, 1 at ``high``."""
        return (v - self.low) / (self.high - self.low)


def nice_axis(low: float, high: float, count: int = 5, floor: float | None = None,
              ceiling: float | None = None) -> Axis:
    """An axis covering ``[low, high]`` with about ``count`` intervals of 1, 2 or 5 times a power
    of ten, its ends on ticks and within ``[floor, ceiling]`` when given; a point (or no finite
    value) is widened."""
    if not (math.isfinite(low) and math.isfinite(high)):
        low, high = 0.0, 1.0
    if high - low < 1e-12:
        pad = max(abs(high) * 0.05, 0.05)
        low, high = low - pad, high + pad
    raw = (high - low) / count
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw * (1 - 1e-9))
    lo, hi = math.floor(low / step + 1e-9) * step, math.ceil(high / step - 1e-9) * step
    if floor is not None:
        lo = max(lo, floor)
    if ceiling is not None:
        hi = min(hi, ceiling)
    n = round((hi - lo) / step)
    ticks = tuple(round(lo + i * step, 12) for i in range(n + 1))
    if ticks[-1] < hi - step * 1e-6:
        ticks += (hi,)
    return Axis(lo, hi, ticks)
