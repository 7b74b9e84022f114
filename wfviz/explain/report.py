"""The explain files and "where Pd went": ``EXPLAIN.csv`` (a cause per truth point per frame),
``EXPLAIN-false.csv`` (a cause per false confirmed track point), and their summary (counts and
shares of each cause in pipeline order, overall and per target; the false-track causes)."""

from __future__ import annotations

import csv
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from wfviz.evaluate import TruthError
from wfviz.explain.types import MISSES, Cause, FalseCause, FalseExplanation, TruthExplanation
from wfviz.io.outputs import TextOutput

EXPLAIN_HEADER = ("frame", "target_id", "cause", "detail", "significance", "det_dist", "track_id",
                  "x", "y", "residual", "change", "threshold", "test", "statistic", "level", "pred_dist", "pred_gate")
#: the causes whose rows name the confirmation test that held their tentative track back
HELD = (Cause.LATENCY, Cause.NOT_CONFIRMED)
FALSE_HEADER = ("frame", "track_id", "cause", "detail", "x", "y")

#: the stage a point has passed once it is past each miss cause (the funnel's rows)
PASSED = {Cause.OUTSIDE_CIRCLE: "inside the imaging circle", Cause.OUTSIDE_REGION: "in the searched region",
          Cause.NOT_DETECTED: "detected", Cause.LOST: "not on a lost track", Cause.NOT_ASSOCIATED: "on a track",
          Cause.LATENCY: "old enough to confirm", Cause.NOT_CONFIRMED: "confirmed and matched"}


def false_path(path: Path) -> Path:
    """Where the false-track causes go beside ``path`` (``EXPLAIN.csv`` -> ``EXPLAIN-false.csv``)."""
    return path.with_name(f"{path.stem}-false{path.suffix or '.csv'}")


def _num(v: float, fmt: str = ".2f") -> str:
    return "" if v is None or math.isnan(v) else format(v, fmt)


def _text(s: str) -> str:
    """A CSV field: quoted when it holds a comma, quote or line break."""
    if any(ch in s for ch in ',"\r\n'):
        return '"' + s.replace('"', '""') + '"'
    return s


class ExplainWriter:
    """Both explain files, written to temporary names and renamed into place by :meth:`close`."""

    def __init__(self, path: Path) -> None:
        self.truth = TextOutput(path, ",".join(EXPLAIN_HEADER))
        try:
            self.false = TextOutput(false_path(path), ",".join(FALSE_HEADER))
        except BaseException:
            self.truth.abort()
            raise

    def write(self, truth: Iterable[TruthExplanation], false: Iterable[FalseExplanation]) -> None:
        """Append one frame's rows."""
        self.truth.write("".join(
            f"{e.frame},{e.target_id},{e.cause.value},{_text(e.detail)},{_num(e.significance)},{_num(e.det_dist, '.3f')},"
            f"{'' if e.track_id is None else e.track_id},{e.x:.3f},{e.y:.3f},{_num(e.residual)},{_num(e.change)},"
            f"{_num(e.threshold)},{_text(e.test)},{_num(e.statistic, '.4g')},{_num(e.level, '.4g')},"
            f"{_num(e.pred_dist, '.3f')},{_num(e.pred_gate, '.3f')}\r\n"
            for e in truth))
        self.false.write("".join(f"{e.frame},{e.track_id},{e.cause.value},{_text(e.detail)},{e.x:.3f},{e.y:.3f}\r\n"
                                 for e in false))

    def close(self) -> None:
        self.truth.close()
        self.false.close()

    def abort(self) -> None:
        self.truth.abort()
        self.false.abort()


@dataclass(frozen=True)
class ExplainSummary:
    """Where Pd went: ``causes`` of the visible truth points (counts), the same ``per_target``,
    the ``hidden`` points, the ``false_causes`` of the false confirmed track points, and
    ``held_back``: for ``latency`` and ``not_confirmed``, {cause: {test: points}}, the
    confirmation test that held each point's tentative track back ("" none named)."""

    causes: dict[str, int]
    per_target: dict[int, dict[str, int]]
    hidden: int = 0
    false_causes: dict[str, int] = field(default_factory=dict)
    held_back: dict[str, dict[str, int]] = field(default_factory=dict)

    @property
    def visible(self) -> int:
        return sum(self.causes.values())

    @property
    def missed(self) -> int:
        return self.visible - self.causes.get(Cause.MATCHED, 0)

    @property
    def dominant(self) -> str | None:
        """The most frequent miss cause (None: nothing missed)."""
        misses = [(self.causes.get(c, 0), c.value) for c in MISSES if self.causes.get(c, 0)]
        return max(misses)[1] if misses else None

    def funnel(self) -> list[tuple[str, int, int]]:
        """(cause, points it took, points left past it), in pipeline order, from the visible ones."""
        left, rows = self.visible, []
        for c in MISSES:
            n = self.causes.get(c, 0)
            left -= n
            rows.append((c.value, n, left))
        return rows

    def to_dict(self) -> dict:
        """JSON-ready: counts, shares, the funnel, per target, false-track causes."""
        v = max(self.visible, 1)
        return {"visible": self.visible, "hidden": self.hidden, "matched": self.causes.get(Cause.MATCHED, 0),
                "missed": self.missed, "dominant_miss_cause": self.dominant,
                "causes": {c.value: {"count": self.causes.get(c, 0), "share": self.causes.get(c, 0) / v}
                           for c in (Cause.MATCHED, *MISSES)},
                "funnel": [{"cause": c, "count": n, "left": left} for c, n, left in self.funnel()],
                "per_target": {str(t): {"visible": sum(c.values()), **c} for t, c in sorted(self.per_target.items())},
                "false_tracks": {"rows": sum(self.false_causes.values()), "causes": dict(self.false_causes)},
                "held_back": {c: dict(t) for c, t in self.held_back.items()}}


def summarise(truth: Iterable[tuple[int, str]], false: Iterable[str] = (),
              held: Iterable[tuple[str, str]] = ()) -> ExplainSummary:
    """The summary of (target_id, cause) truth rows, false-track causes and the (cause, test)
    of the ``latency`` and ``not_confirmed`` rows."""
    causes: Counter = Counter()
    per: dict[int, Counter] = {}
    hidden = 0
    for tid, cause in truth:
        if cause == Cause.HIDDEN:
            hidden += 1
            continue
        causes[cause] += 1
        per.setdefault(tid, Counter())[cause] += 1
    tests: dict[str, Counter] = {}
    for cause, test in held:
        tests.setdefault(str(cause), Counter())[test] += 1
    return ExplainSummary({str(k): v for k, v in causes.items()},
                          {t: {str(k): v for k, v in c.items()} for t, c in per.items()}, hidden,
                          {str(k): v for k, v in Counter(false).most_common()},
                          {str(c): dict(tests[c.value].most_common()) for c in HELD if c.value in tests})


def format_summary(s: ExplainSummary) -> str:
    """Plain text: the funnel from visible to matched with each cause's count and share, the
    dominant miss cause, per target, then the false-track causes."""
    v = s.visible
    pct = (lambda n: f"{100.0 * n / v:5.1f} %") if v else (lambda n: "    - ")
    matched = s.causes.get(Cause.MATCHED, 0)
    lines = [f"where Pd went: {v} visible truth points ({s.hidden} hidden), {matched} matched"
             + (f" (Pd {matched / v:.3f})" if v else "")]
    for cause, n, left in s.funnel():
        passed = PASSED[Cause(cause)]
        lines.append(f"  - {cause:<15} {n:>6}  {pct(n)}   -> {passed:<26} {left:>6}")
    if s.dominant:
        lines.append(f"  dominant miss cause: {s.dominant} ({pct(s.causes[s.dominant]).strip()} of visible)")
    for cause, tests in s.held_back.items():
        lines.append(f"  {cause} held back by: " + ", ".join(f"{t or 'no test named'} {n}" for t, n in tests.items()))
    if s.per_target:
        names = [c.value for c in MISSES]
        short = {"outside_circle": "circle", "outside_region": "region", "not_detected": "not_det",
                 "not_associated": "not_assoc", "latency": "latency", "not_confirmed": "not_conf", "lost": "lost"}
        lines.append("")
        lines.append(f"  {'target':>6} {'visible':>7} {'matched':>7} " + " ".join(f"{short[n]:>9}" for n in names))
        for t, c in sorted(s.per_target.items()):
            lines.append(f"  {t:>6} {sum(c.values()):>7} {c.get('matched', 0):>7} "
                         + " ".join(f"{c.get(n, 0):>9}" for n in names))
    total = sum(s.false_causes.values())
    lines.append("")
    if total:
        lines.append(f"false-track rows: {total} (" + ", ".join(
            f"{k} {n}" for k, n in sorted(s.false_causes.items(), key=lambda kv: -kv[1])) + ")")
    else:
        lines.append("false-track rows: 0")
    return "\n".join(lines)


def read_explain(path: Path) -> ExplainSummary:
    """The summary of an ``EXPLAIN.csv`` (and of ``EXPLAIN-false.csv`` beside it, when there);
    a malformed file: :class:`~wfviz.evaluate.TruthError` naming file and line."""
    name = path.name
    rows: list[tuple[int, str]] = []
    held: list[tuple[str, str]] = []
    valid = {c.value for c in Cause}
    named = {c.value for c in HELD}
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            missing = [c for c in EXPLAIN_HEADER[:7] if c not in header]
            if missing:
                raise TruthError(f"{name}:1: missing column {missing[0]!r}: not an explain file "
                                 f"(header: {','.join(header) or 'none'})")
            for row in reader:
                cause = (row.get("cause") or "").strip()
                if cause not in valid:
                    raise TruthError(f"{name}:{reader.line_num}: column 'cause': {cause!r} is not a cause "
                                     f"({', '.join(sorted(valid))})")
                try:
                    rows.append((int(row["target_id"]), cause))
                    if cause in named and "test" in header:  # explain files before the column: none
                        held.append((cause, (row.get("test") or "").strip()))
                except (TypeError, ValueError):
                    raise TruthError(f"{name}:{reader.line_num}: column 'target_id': "
                                     f"{row.get('target_id')!r} is not an integer") from None
        false: list[str] = []
        fp = false_path(path)
        if fp.is_file():
            fvalid = {c.value for c in FalseCause}
            with open(fp, newline="", encoding="utf-8-sig") as fh:
                freader = csv.DictReader(fh)
                if "cause" not in (freader.fieldnames or []):
                    raise TruthError(f"{fp.name}:1: missing column 'cause'")
                for row in freader:
                    cause = (row.get("cause") or "").strip()
                    if cause not in fvalid:
                        raise TruthError(f"{fp.name}:{freader.line_num}: column 'cause': {cause!r} is not a "
                                         f"false-track cause")
                    false.append(cause)
    except UnicodeDecodeError as e:
        raise TruthError(f"{name}: not UTF-8 text ({e.reason})") from None
    except csv.Error as e:
        raise TruthError(f"{name}: not a valid CSV file ({e})") from None
    return summarise(rows, false, held)
