"""A study's files: ``trials.csv`` (every trial), ``best.toml`` (or one ``best-N.toml`` per
Pareto point and ``pareto.csv``), each written whole to a temporary name and renamed."""

from __future__ import annotations

import io
import csv
import math
from pathlib import Path
from typing import Any

from wfviz.tune.constraints import feasible
from wfviz.tune.folder import StudyFolder
from wfviz.tune.space import best_toml, make_config
from wfviz.tune.study import StudySettings
from wfviz.tune.trial import METRICS, dominant


def ranked(trials: list[Any], objective: str) -> list[Any]:
    """Completed trials that meet the study's constraints (pruned ones have no score), best
    first: by the objective (ties: the earlier trial); for ``pareto`` the front (non-dominated in
    Pd and false tracks) by Pd, then the rest by Pd."""
    done = [t for t in trials if t.values is not None and t.state.name == "COMPLETE" and feasible(t)]
    if objective != "pareto":
        return sorted(done, key=lambda t: (-t.values[0], t.number))
    front = pareto_front(done)
    ids = {t.number for t in front}
    rest = [t for t in done if t.number not in ids]
    return (sorted(front, key=lambda t: (-t.values[0], t.values[1], t.number))
            + sorted(rest, key=lambda t: (-t.values[0], t.values[1], t.number)))


def pd_fa(trial: Any) -> tuple[float, float]:
    """A completed trial's Pd and false tracks per frame on the tune clips."""
    tune = trial.user_attrs["tune"]
    return tune["pd"], tune["fa"]


def pareto_front(trials: list[Any]) -> list[Any]:
    """Completed trials that meet the study's constraints and no other such trial beats on both
    Pd (higher) and false tracks per frame (lower) on the tune clips."""
    done = [(t, pd_fa(t)) for t in trials if t.values is not None and feasible(t)]

    def beaten(a: tuple[float, float]) -> bool:
        return any(b[0] >= a[0] and b[1] <= a[1] and (b[0] > a[0] or b[1] < a[1]) for _, b in done)
    return [t for t, v in done if not beaten(v)]


def _num(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return repr(v) if isinstance(v, float) else str(v)


def trials_csv(trials: list[Any], settings: StudySettings) -> str:
    """``trials.csv``: number, state (complete, pruned, fail), seconds, error, whether it meets
    the constraints (with ``--constraint``), every parameter, every metric averaged
    over the tune clips and the validation clips, the dominant miss and false-track causes over
    each (empty: none, or a trial run before causes were counted), then every metric per clip."""
    params = settings.space.names
    labels = [c.label for c in settings.clips]
    roles = ["tune"] + (["validate"] if any(c.role == "validate" for c in settings.clips) else [])
    checked = bool(settings.constraints)  # a feasible column: 1 meets every --constraint, 0 not
    head = (["trial", "state", "seconds", "base", "error"] + (["feasible"] if checked else []) + params
            + [f"{r}_{m}" for r in roles for m in METRICS]
            + [f"{r}_dominant_{part}" for r in roles for part in ("miss", "false")]
            + [f"{label}_{m}" for label in labels for m in METRICS])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for t in sorted(trials, key=lambda t: t.number):
        ua = t.user_attrs
        row = [t.number, t.state.name.lower(), _num(ua.get("seconds")), int(bool(ua.get("base"))),
               ua.get("error", "")]
        if checked:
            row += [int(feasible(t)) if t.state.name == "COMPLETE" else ""]
        row += [_num(t.params.get(p)) for p in params]
        for r in roles:
            row += [_num(ua.get(r, {}).get(m)) for m in METRICS]
        causes = ua.get("causes") or {}
        for r in roles:
            row += [dominant(causes.get(r), part) or "" for part in ("causes", "false")]
        scores = ua.get("scores", {})
        for label in labels:
            row += [_num(scores.get(label, {}).get(m)) for m in METRICS]
        w.writerow(row)
    return buf.getvalue()


def reproduce_command(settings: StudySettings, toml: Path, clip_spec: str, truth: Path) -> str:
    """The commands that reproduce a trial's score on one clip."""
    stop = f" --stop {settings.stop}" if settings.stop is not None else ""
    gate = f" --gate {settings.gate!r}" if settings.gate != 3.0 else ""
    return (f"wfviz track {clip_spec} --tracker {settings.tracker} --config {toml} --tracks t.csv{stop}"
            f" && wfviz eval t.csv {truth}{gate}")


def trial_config(settings: StudySettings, trial: Any) -> Any:
    """The whole configuration a trial ran."""
    from wfviz.trackers import config_class

    return make_config(config_class(settings.tracker), dict(trial.params), settings.space.fixed, settings.base)


def _header(settings: StudySettings, trial: Any, toml: Path) -> str:
    ua = trial.user_attrs
    lines = [f"wfviz tune: trial {trial.number} of the study in {toml.parent} (tracker {settings.tracker}, "
             f"objective {settings.objective})"]
    for role in ("tune", "validate"):
        if role in ua:
            lines.append(f"{role}: " + ", ".join(f"{m} {ua[role][m]:.4f}" for m in METRICS if m in ua[role]))
    first = settings.clips[0]
    lines.append("reproduce: " + reproduce_command(settings, toml, first.spec, first.truth))
    return "\n".join(lines)


def write_outputs(folder: StudyFolder, trials: list[Any], settings: StudySettings) -> list[Path]:
    """Write ``trials.csv`` and the best configuration(s); returns the files written. A Pareto
    point no longer on the front loses its ``best-N.toml`` (only files the study wrote go)."""
    out = folder.path
    written = [folder.write(out / "trials.csv", trials_csv(trials, settings))]
    best = ranked(trials, settings.objective)
    if not best:
        return written
    if settings.objective != "pareto":
        path = out / "best.toml"
        folder.write(path, best_toml(trial_config(settings, best[0]), _header(settings, best[0], path)))
        return written + [path]
    front = pareto_front(trials)
    ids = {t.number for t in front}
    rows = ["trial,pd,fa,config"]
    for t in (t for t in best if t.number in ids):
        path = out / f"best-{t.number}.toml"
        folder.write(path, best_toml(trial_config(settings, t), _header(settings, t, path)))
        rows.append(f"{t.number},{t.values[0]!r},{t.values[1]!r},{path.name}")
        written.append(path)
    for stale in folder.owned("best-*.toml"):  # points an earlier batch had on the front
        if stale not in written:
            folder.remove(stale)
    folder.write(out / "pareto.csv", "\n".join(rows) + "\n")
    return written + [out / "pareto.csv"]
