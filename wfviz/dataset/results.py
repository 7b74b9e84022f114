"""``results.csv`` (one row per clip) and the run's summary: totals, the per-clip table and the
causes summed over the clips (``summary.md``)."""

from __future__ import annotations

import csv
import hashlib
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wfviz.dataset.goals import METRICS, Goal
from wfviz.explain.types import MISSES, Cause, FalseCause
from wfviz.io.outputs import write_atomically

#: per-clip truth-point causes (matched, then the misses in pipeline order) and false-track causes
TRUTH_CAUSES = tuple(c.value for c in (Cause.MATCHED, *MISSES))
FALSE_CAUSES = tuple(c.value for c in FalseCause)
SCORES = (*METRICS, "cle_rms")
COLUMNS = ("label", "clip", "truth", "frames", "seconds", "ms_per_frame", "status", *SCORES, "goal",
           "dominant_miss_cause", "dominant_false_cause", *TRUTH_CAUSES, "hidden",
           *(f"false_{c}" for c in FALSE_CAUSES), "recording", "config_hash")
OWN_TRUTH = "(synthetic)"  # the truth column of a synth: clip


def config_hash(tracker: str, config: dict[str, Any], gate: float) -> str:
    """What a row's numbers depend on besides the clip: tracker, whole configuration, gate."""
    text = json.dumps({"tracker": tracker, "config": config, "gate": gate}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Row:
    """One clip's outcome: ``status`` "ok" or "failed: WHY"; ``scores`` ({metric: value}, empty
    without truth), ``causes`` (truth causes, then "hidden", then "false_<cause>": counts; empty
    without truth), ``recording`` ("" none). ``signal``: a signal stopped the clip (never
    written); ``notes``: the clip's warnings (printed, not written)."""

    label: str
    clip: str
    truth: str
    status: str
    frames: int = 0
    seconds: float = 0.0
    ms_per_frame: float = math.nan
    scores: dict[str, float] = field(default_factory=dict)
    causes: dict[str, int] = field(default_factory=dict)
    recording: str = ""
    config_hash: str = ""
    signal: int | None = None
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def scored(self) -> bool:
        return self.ok and bool(self.scores)

    def dominant(self, false: bool = False) -> str:
        """The most frequent miss cause ("" none missed; ``false``: false-track cause)."""
        names = [f"false_{c}" for c in FALSE_CAUSES] if false else [c.value for c in MISSES]
        top = max(((self.causes.get(n, 0), n) for n in names), default=(0, ""))
        return top[1].removeprefix("false_") if top[0] else ""

    def to_csv(self, goal: Goal | None) -> dict[str, str]:
        met = "" if goal is None or not self.scored else ("yes" if goal.holds(self.scores) else "no")
        out = {"label": self.label, "clip": self.clip, "truth": self.truth, "frames": str(self.frames),
               "seconds": f"{self.seconds:.3f}", "ms_per_frame": _num(self.ms_per_frame, ".3f"),
               "status": self.status, "goal": met, "recording": self.recording, "config_hash": self.config_hash}
        for m in SCORES:
            v = self.scores.get(m, math.nan)
            out[m] = str(int(v)) if m == "id_switches" and math.isfinite(v) else _num(v, ".4f")
        scored = bool(self.causes)
        out["dominant_miss_cause"] = self.dominant() if scored else ""
        out["dominant_false_cause"] = self.dominant(false=True) if scored else ""
        for name in (*TRUTH_CAUSES, "hidden", *(f"false_{c}" for c in FALSE_CAUSES)):
            out[name] = str(self.causes.get(name, 0)) if scored else ""
        return out

    @classmethod
    def from_csv(cls, r: dict[str, str]) -> Row:
        scores = {m: _float(r.get(m)) for m in SCORES if (r.get(m) or "") != ""}
        causes = {n: int(r[n]) for n in (*TRUTH_CAUSES, "hidden", *(f"false_{c}" for c in FALSE_CAUSES))
                  if (r.get(n) or "").strip().lstrip("-").isdigit()}
        return cls(r["label"], r.get("clip") or "", r.get("truth") or "", r.get("status") or "",
                   int(_float(r.get("frames")) if (r.get("frames") or "").strip() else 0),
                   _float(r.get("seconds")), _float(r.get("ms_per_frame")), scores, causes,
                   r.get("recording") or "", r.get("config_hash") or "")


def _num(v: float, fmt: str) -> str:
    return "" if v is None or not math.isfinite(v) else format(v, fmt)


def _float(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def cause_columns(counts: dict[str, Any] | None) -> dict[str, int]:
    """:func:`wfviz.tune.trial.cause_counts` as the row's flat cause columns."""
    if not counts:
        return {}
    out = {k: int(v) for k, v in counts["causes"].items()}
    out["hidden"] = int(counts["hidden"])
    out.update({f"false_{k}": int(v) for k, v in counts["false"].items()})
    return out


def read_results(path: Path) -> dict[str, Row]:
    """The rows of an earlier run's ``results.csv`` by label ({} when there is none); a file that
    is not one: ValueError."""
    if not path.is_file():
        return {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            if not {"label", "status", "config_hash"} <= set(header):
                raise ValueError(f"{path}: not the results of a `wfviz run` (no label, status and "
                                 f"config_hash columns); choose another --out folder")
            return {r["label"]: Row.from_csv(r) for r in reader if r.get("label")}
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ValueError(f"{path}: not the results of a `wfviz run` ({exc})") from None


def write_results(path: Path, rows: Iterable[Row], goal: Goal | None) -> None:
    """``rows`` as ``results.csv``, written to a temporary file and renamed (never half written)."""
    lines = [",".join(COLUMNS)]
    for row in rows:
        values = row.to_csv(goal)
        lines.append(",".join(_field(values[c]) for c in COLUMNS))
    write_atomically(path, "\r\n".join(lines) + "\r\n")


def _field(s: str) -> str:
    return '"' + s.replace('"', '""') + '"' if any(ch in s for ch in ',"\r\n') else s


@dataclass(frozen=True)
class Totals:
    """The run's totals over ``rows`` (the dataset's clips that have one)."""

    clips: int
    tracked: int
    failed: int
    scored: int
    mean_pd: float
    mean_fa: float
    goals_met: int
    frames: int
    seconds: float  # summed over the clips (tracking, every worker)
    causes: dict[str, int]

    @property
    def dominant(self) -> str:
        return Row("", "", "", "ok", causes=self.causes).dominant()


def totals(rows: list[Row], clips: int, goal: Goal | None) -> Totals:
    ok = [r for r in rows if r.ok]
    scored = [r for r in ok if r.scored]

    def mean(metric: str) -> float:
        vs = [r.scores.get(metric, math.nan) for r in scored]
        vs = [v for v in vs if math.isfinite(v)]
        return sum(vs) / len(vs) if vs else math.nan

    causes: dict[str, int] = {}
    for r in scored:
        for k, n in r.causes.items():
            causes[k] = causes.get(k, 0) + n
    met = sum(goal.holds(r.scores) for r in scored) if goal is not None else 0
    return Totals(clips, len(ok), len(rows) - len(ok), len(scored), mean("pd"), mean("fa_per_frame"), met,
                  sum(r.frames for r in ok), sum(r.seconds for r in ok), causes)


def running(t: Totals, goal: Goal | None) -> str:
    """The progress bar's running summary."""
    if not t.scored:
        return f"{t.tracked} tracked" + (f", {t.failed} failed" if t.failed else "")
    parts = [f"mean Pd {t.mean_pd:.3f}", f"FA/frame {t.mean_fa:.3f}"]
    if goal is not None:
        parts.append(f"goals {t.goals_met}/{t.scored}")
    if t.failed:
        parts.append(f"{t.failed} failed")
    return ", ".join(parts)


def format_totals(t: Totals, goal: Goal | None, wall: float | None = None, ran: int = 0) -> str:
    """The table printed at the end."""
    def num(v: float) -> str:
        return "-" if not math.isfinite(v) else f"{v:.3f}"

    rows = [("clips", str(t.clips)), ("tracked", f"{t.tracked}" + (f" ({t.failed} failed)" if t.failed else "")),
            ("scored", str(t.scored)), ("mean Pd", num(t.mean_pd)), ("mean FA/frame", num(t.mean_fa))]
    if goal is not None:
        rows.append(("goals met", f"{t.goals_met} of {t.scored}" + (f"  ({goal})" if t.scored else "")))
    rows.append(("total frames", str(t.frames)))
    fps = t.frames / t.seconds if t.seconds > 0 else math.nan
    rows.append(("fps", f"{fps:.1f} per worker (frames / summed clip time)" if math.isfinite(fps) else "-"))
    if wall is not None:
        rows.append(("this run", f"{ran} clips in {wall:.1f} s wall"))
    if t.causes:
        rows.append(("dominant miss cause", t.dominant or "none (nothing missed)"))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def summary_markdown(rows: list[Row], t: Totals, goal: Goal | None, *, dataset: str, tracker: str, gate: float,
                     config_hash: str, wall: float | None = None, ran: int = 0) -> str:
    """``summary.md``: the per-clip table, the totals and the causes summed over the clips."""
    def num(v: float, fmt: str = ".3f") -> str:
        return "–" if v is None or not math.isfinite(v) else format(v, fmt)

    lines = [f"# wfviz run: {dataset}", "",
             f"Tracker `{tracker}` (configuration {config_hash}), match gate {gate:g} px"
             + (f", goal `{goal}`" if goal is not None else "") + ".", "",
             "| clip | frames | Pd | Pd settled | FA/frame | MOTA | IDF1 | HOTA | ID sw | goal | most misses | "
             "ms/frame | status |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s = r.scores
        met = "" if goal is None or not r.scored else ("yes" if goal.holds(s) else "**no**")
        ids = s.get("id_switches", math.nan)
        lines.append(f"| {r.label} | {r.frames} | {num(s.get('pd', math.nan))} | {num(s.get('pd_settled', math.nan))} | "
                     f"{num(s.get('fa_per_frame', math.nan))} | {num(s.get('mota', math.nan))} | "
                     f"{num(s.get('idf1', math.nan))} | {num(s.get('hota', math.nan))} | "
                     f"{num(ids, '.0f')} | {met} | {r.dominant() if r.causes else ''} | "
                     f"{num(r.ms_per_frame, '.2f')} | {r.status.replace('|', '/')} |")
    lines += ["", "## Totals", "", "```", format_totals(t, goal, wall, ran), "```"]
    if t.causes:
        visible = sum(t.causes.get(c, 0) for c in TRUTH_CAUSES)
        lines += ["", "## Where Pd went (summed over the scored clips)", "",
                  f"{visible} visible truth points, {t.causes.get('hidden', 0)} hidden; "
                  f"dominant miss cause: {t.dominant or 'none'}.", "", "| cause | points | share |", "|---|---|---|"]
        for c in TRUTH_CAUSES:
            n = t.causes.get(c, 0)
            lines.append(f"| {c} | {n} | {100.0 * n / visible:.1f} % |" if visible else f"| {c} | {n} | – |")
        false = {c: t.causes.get(f"false_{c}", 0) for c in FALSE_CAUSES}
        lines += ["", f"False-track points: {sum(false.values())}"
                  + (" (" + ", ".join(f"{c} {n}" for c, n in sorted(false.items(), key=lambda kv: -kv[1]) if n) + ")"
                     if any(false.values()) else "") + "."]
    return "\n".join(lines) + "\n"
