"""The configuration parameters in which the runs of ``wfviz compare`` differ: each run's
resolved configuration (a ``--run`` config file, a study's trial, the defaults) flattened to
``section.key`` values and compared among the runs of the same tracker (runs of different
trackers have different parameters: they are not compared)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from wfviz.compare.runs import RunSpec
from wfviz.config import toml_value


def flatten(config: Any, prefix: str = "") -> dict[str, str]:
    """A configuration dataclass as ``{"section.key": value}``, each value as its TOML text
    (``"auto"`` for None), in the order of the fields."""
    out: dict[str, str] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            out.update(flatten(value, f"{prefix}{f.name}."))
        else:
            out[f"{prefix}{f.name}"] = toml_value(value)
    return out


@dataclass(frozen=True)
class TrackerDifferences:
    """The runs of one tracker (``labels``, two or more) and the parameters in which they
    differ: (``section.key``, the value in each run) in the order of the configuration."""

    tracker: str
    labels: tuple[str, ...]
    rows: tuple[tuple[str, tuple[str, ...]], ...]


@dataclass(frozen=True)
class ParameterDifferences:
    """The parameter differences of a comparison: per tracker with two runs or more its
    :class:`TrackerDifferences`, and the runs alone with their tracker (``alone``: (label,
    tracker)), whose parameters are not compared."""

    trackers: tuple[TrackerDifferences, ...]
    alone: tuple[tuple[str, str], ...]

    @property
    def count(self) -> int:
        """Parameters that differ, over all trackers."""
        return sum(len(t.rows) for t in self.trackers)


def parameter_differences(runs: Sequence[RunSpec]) -> ParameterDifferences:
    """Where the runs' resolved configurations differ, among the runs of each tracker."""
    by_tracker: dict[str, list[RunSpec]] = {}
    for r in runs:
        by_tracker.setdefault(r.tracker, []).append(r)
    groups, alone = [], []
    for tracker, members in by_tracker.items():
        if len(members) < 2:
            alone.append((members[0].label, tracker))
            continue
        flat = [flatten(r.config) for r in members]
        rows = tuple((key, tuple(f[key] for f in flat)) for key in flat[0] if len({f[key] for f in flat}) > 1)
        groups.append(TrackerDifferences(tracker, tuple(r.label for r in members), rows))
    return ParameterDifferences(tuple(groups), tuple(alone))


def format_differences(diff: ParameterDifferences) -> str:
    """The differences as text: per tracker a line naming its runs, then a ``section.key``
    row with the value in each run (aligned columns), or that their configurations are the
    same; a line for the runs of different trackers."""
    lines: list[str] = []
    for t in diff.trackers:
        if not t.rows:
            lines.append(f"parameters: the {t.tracker} runs ({', '.join(t.labels)}) have the same configuration")
            continue
        lines.append(f"parameters that differ between the {t.tracker} runs:")
        table = [("parameter", t.labels), *t.rows]
        widths = [max(len(k) for k, _ in table), *(max(len(v[i]) for _, v in table) for i in range(len(t.labels)))]
        for key, values in table:
            lines.append("  " + "  ".join(c.ljust(w) for c, w in zip((key, *values), widths)).rstrip())
    if diff.alone and (diff.trackers or len(diff.alone) > 1):
        lines.append("different trackers, parameters not compared: "
                     + ", ".join(f"{label} ({tracker})" for label, tracker in diff.alone))
    return "\n".join(lines)


def differences_markdown(diff: ParameterDifferences) -> str:
    """The differences as a Markdown document: a table per tracker (a column per run)."""
    parts: list[str] = []
    for t in diff.trackers:
        if not t.rows:
            parts.append(f"The {t.tracker} runs ({', '.join(t.labels)}) have the same configuration.")
            continue
        parts.append("\n".join([f"Parameters that differ between the **{t.tracker}** runs:", "",
                                "| parameter | " + " | ".join(t.labels) + " |",
                                "|---|" + "---|" * len(t.labels),
                                *(f"| `{key}` | " + " | ".join(f"`{v}`" for v in values) + " |"
                                  for key, values in t.rows)]))
    if diff.alone and (diff.trackers or len(diff.alone) > 1):
        parts.append("Different trackers, parameters not compared: "
                     + ", ".join(f"**{label}** ({tracker})" for label, tracker in diff.alone) + ".")
    return "\n\n".join(parts)
