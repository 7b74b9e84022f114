"""``report.md`` of a study with its PNG plots: the history, the Pareto front, parameter
importance, tune against validation scores (the gap says whether the search fitted the clips
it saw), and where Pd went in the base and the best trials (which cause the search reduced)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from wfviz.tune.folder import StudyFolder
from wfviz.tune.outputs import pareto_front, pd_fa, ranked
from wfviz.tune.study import OBJECTIVES, StudySettings
from wfviz.tune.trial import METRICS, dominant, mean_scores

SHOWN = 10  # trials in the report's table
CAUSE_TRIALS = 4  # trials beside the base in the "where Pd went" tables (a Pareto front's first)


def _f(v: Any, fmt: str = ".3f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return format(v, fmt) if isinstance(v, float) else str(v)


def folds_table(trials: list[Any], settings: StudySettings, k: int) -> tuple[list[str], float, float]:
    """Leave-clips-out cross-validation of the *choice* of trial: the tune clips split into
    ``k`` folds (in order, round robin); for each fold the best trial on the other folds is
    scored on the held-out fold. Returns table lines and the mean in-sample and held-out
    objective. The sampler saw every clip, so this checks the selection, not the search."""
    metric = OBJECTIVES[settings.objective][0][0]
    labels = [c.label for c in settings.clips if c.role == "tune"]
    done = [t for t in trials if t.values is not None]
    lines = ["| fold | held-out clips | chosen trial | its score on the other folds | on the held-out fold |",
             "|---|---|---:|---:|---:|"]
    ins, outs = [], []
    for i in range(k):
        held = labels[i::k]
        rest = [lab for lab in labels if lab not in held]
        if not held or not rest:
            continue
        score = {t.number: mean_scores(t.user_attrs["scores"], rest)[metric] for t in done}
        best = max(done, key=lambda t: (score[t.number], -t.number))
        held_score = mean_scores(best.user_attrs["scores"], held)[metric]
        ins.append(score[best.number])
        outs.append(held_score)
        lines.append(f"| {i + 1} | {', '.join(held)} | {best.number} | {_f(score[best.number])} | {_f(held_score)} |")
    mean = (lambda xs: sum(xs) / len(xs) if xs else math.nan)  # noqa: E731
    return lines, mean(ins), mean(outs)


def _trial_name(t: Any, best: Any) -> str:
    return f"{t.number} (base)" if t.user_attrs.get("base") else f"{t.number} (best)" if t is best else str(t.number)


def causes_table(trials: list[Any], role: str, best: Any) -> list[str]:
    """Where Pd went on the ``role`` clips ("tune", "validate") in each of ``trials`` (the base
    first), from their ``causes`` attribute: each miss cause in pipeline order and the matched
    points (count and share of the visible points), the dominant miss cause, and the false-track
    rows by cause (count and share of the false-track rows); with two trials the change from the
    first to the second. "-": no causes recorded (a trial run before wfviz counted them)."""
    from wfviz.explain.types import MISSES, Cause, FalseCause

    counts = [(t.user_attrs.get("causes") or {}).get(role) for t in trials]
    change = len(trials) == 2 and all(counts)
    names = [_trial_name(t, best) for t in trials]
    lines = ["| cause | " + " | ".join(f"trial {n}" for n in names)
             + (f" | {names[1]} − {names[0]}" if change else "") + " |",
             "|---|" + "---:|" * (len(trials) + change)]

    def row(name: str, part: str, key: str | None) -> str:
        cells, values = [], []
        for c in counts:
            if not c:
                cells.append("-")
                continue
            whole = sum(c[part].values())
            n = c[part].get(key, 0) if key is not None else whole
            values.append(n)
            cells.append(f"{n} ({100.0 * n / whole:.1f} %)" if key is not None and whole else str(n))
        if change:
            cells.append(f"{values[1] - values[0]:+d}" if values[1] != values[0] else "0")
        return f"| {name} | " + " | ".join(cells) + " |"

    lines += [row(c.value, "causes", c.value) for c in MISSES]
    lines.append(row(f"**{Cause.MATCHED.value}**", "causes", Cause.MATCHED.value))
    lines.append("| dominant miss cause | " + " | ".join("-" if not c else dominant(c) or "none" for c in counts)
                 + (" | |" if change else " |"))
    lines.append(row("false-track rows", "false", None))
    lines += [row(f"false: {f.value}", "false", f.value) for f in FalseCause
              if any(c and c["false"].get(f.value, 0) for c in counts)]
    return lines


def reduced(base: Any, best: Any, role: str) -> str:
    """A sentence naming the miss cause ``best`` reduced most against ``base`` on the ``role``
    clips, and those it increased; "" without both trials' causes."""
    from wfviz.explain.types import MISSES

    a, b = ((t.user_attrs.get("causes") or {}).get(role) for t in (base, best))
    if not a or not b:
        return ""
    drops = [(a["causes"].get(c.value, 0) - b["causes"].get(c.value, 0), c.value) for c in MISSES]
    gain, cause = max(drops, key=lambda d: d[0])  # the first in pipeline order among equals
    text = (f"Trial {best.number} has {gain} fewer `{cause}` misses than the base ({a['causes'][cause]} → "
            f"{b['causes'][cause]}), the largest reduction of any cause" if gain > 0
            else f"Trial {best.number} reduces no miss cause against the base")
    rise = [f"`{c}` (+{-n})" for n, c in drops if n < 0]
    return text + ("; it has more " + ", ".join(rise) if rise else "") + "."


def _where_pd_went(done: list[Any], base: list[Any], best: list[Any], settings: StudySettings,
                   val_clips: list[str]) -> list[str]:
    """The report's "Where Pd went" section: the base against the best trial (a Pareto study:
    against the first :data:`CAUSE_TRIALS` of the front), on the tune clips and on the
    validation clips."""
    front = {t.number for t in pareto_front(done)} if settings.objective == "pareto" else set()
    top = best[:1] if settings.objective != "pareto" else [t for t in best if t.number in front]
    shown = base + [t for t in top if t not in base][:CAUSE_TRIALS]
    md = ["## Where Pd went", "",
          "Every visible truth point of the clips (summed over them) by the first stage of the pipeline it did "
          "not pass, as `wfviz track --explain` counts them (docs/debugging.md): count and share of the visible "
          "points; then the false confirmed track points by cause. \"-\": a trial run before causes were "
          "counted.", ""]
    for role, title in (("tune", "Tune clips"), ("validate", "Validation clips")):
        if role == "validate" and not val_clips:
            continue
        md += [f"### {title}", "", *causes_table(shown, role, best[0] if best else None), ""]
        if len(shown) == 2 and shown[0] in base:
            sentence = reduced(shown[0], shown[1], role)
            md += [sentence, ""] if sentence else []
        elif shown == base and best and best[0] in base:
            md += ["The base is the best trial: no other trial to compare it with.", ""]
    return md


def _plots(folder: StudyFolder, trials: list[Any], settings: StudySettings, importance: dict[str, float]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics, directions = OBJECTIVES[settings.objective]
    done = sorted((t for t in trials if t.values is not None), key=lambda t: t.number)
    has_val = any(c.role == "validate" for c in settings.clips)
    files = []
    if not done:
        return files
    fig, axes = plt.subplots(1, len(metrics), figsize=(6 * len(metrics), 3.6), squeeze=False)
    for ax, m, d in zip(axes[0], metrics, directions):
        n = [t.number for t in done]
        v = [t.user_attrs["tune"][m] for t in done]
        ax.plot(n, v, "o", ms=4, label="tune clips")
        best, run = [], None
        for x in v:
            run = x if run is None else (max(run, x) if d == "maximize" else min(run, x))
            best.append(run)
        ax.step(n, best, where="post", label="best so far")
        if has_val:
            ax.plot(n, [t.user_attrs["validate"][m] for t in done], "x", ms=4, label="validation clips")
        ax.set_xlabel("trial")
        ax.set_ylabel(m)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(folder.path / "history.png")
    _save(fig, files[-1], folder)
    if settings.objective == "pareto":
        fig, ax = plt.subplots(figsize=(5.5, 4))
        ax.plot([pd_fa(t)[1] for t in done], [pd_fa(t)[0] for t in done], "o", ms=4, alpha=0.5, label="trials")
        front = sorted(pareto_front(done), key=lambda t: pd_fa(t)[1])
        ax.plot([pd_fa(t)[1] for t in front], [pd_fa(t)[0] for t in front], "o-", color="C3", label="Pareto front")
        for t in front:
            ax.annotate(str(t.number), pd_fa(t)[::-1], fontsize=7)
        ax.set_xlabel("false tracks per frame (tune clips)")
        ax.set_ylabel("Pd (tune clips)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        files.append(folder.path / "pareto.png")
        _save(fig, files[-1], folder)
    if importance:
        fig, ax = plt.subplots(figsize=(6, 0.4 * len(importance) + 1.2))
        names = list(importance)[::-1]
        ax.barh(names, [importance[k] for k in names])
        ax.set_xlabel(f"importance for {metrics[0]} (PED-ANOVA)")
        fig.tight_layout()
        files.append(folder.path / "importance.png")
        _save(fig, files[-1], folder)
    if has_val:
        fig, axes = plt.subplots(1, len(metrics), figsize=(4.5 * len(metrics), 4), squeeze=False)
        for ax, m in zip(axes[0], metrics):
            x = [t.user_attrs["tune"][m] for t in done]
            y = [t.user_attrs["validate"][m] for t in done]
            ax.plot(x, y, "o", ms=4)
            finite = [v for v in x + y if math.isfinite(v)]
            if finite:
                lo, hi = min(finite), max(finite)
                ax.plot([lo, hi], [lo, hi], "--", color="grey", lw=1)
            ax.set_xlabel(f"{m}, tune clips")
            ax.set_ylabel(f"{m}, validation clips")
            ax.grid(alpha=0.3)
        fig.tight_layout()
        files.append(folder.path / "tune_vs_validation.png")
        _save(fig, files[-1], folder)
    return files


def _save(fig: Any, path: Path, folder: StudyFolder) -> None:
    import matplotlib.pyplot as plt

    from wfviz.io.outputs import temp_path, replace_into

    tmp = temp_path(folder.claim(path))
    try:
        fig.savefig(tmp, dpi=110, format="png")
        replace_into(tmp, path)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)


def _importance(trials: list[Any], settings: StudySettings) -> dict[str, float]:
    """PED-ANOVA importance of each parameter for the (first) objective (S. Watanabe et al.,
    "PED-ANOVA: efficiently quantifying hyperparameter importance in arbitrary subspaces",
    IJCAI 2023; Optuna's, no further dependency): how much each parameter's distribution differs
    between the best trials and all of them. Empty with too few trials."""
    done = [t for t in trials if t.values is not None]
    if len(done) < 4 or len(settings.space.params) < 2:
        return {}
    import warnings

    import optuna
    from optuna.importance import PedAnovaImportanceEvaluator, get_param_importances

    sign = -1.0 if OBJECTIVES[settings.objective][1][0] == "maximize" else 1.0  # it ranks low values best
    study = optuna.create_study(directions=list(OBJECTIVES[settings.objective][1]))
    study.add_trials(done)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return get_param_importances(study, evaluator=PedAnovaImportanceEvaluator(),
                                         target=lambda t: sign * t.values[0])
    except Exception:  # noqa: BLE001 - too few distinct values: no importance to show
        return {}


def write_report(folder: StudyFolder, trials: list[Any], settings: StudySettings, folds: int = 0) -> list[Path]:
    """Write ``report.md`` and its plots; returns the files."""
    metrics, directions = OBJECTIVES[settings.objective]
    done = [t for t in trials if t.values is not None]
    failed = [t for t in trials if t.values is None]
    tune_clips = [c.label for c in settings.clips if c.role == "tune"]
    val_clips = [c.label for c in settings.clips if c.role == "validate"]
    importance = _importance(trials, settings)
    plots = _plots(folder, trials, settings, importance)
    md = [f"# Tuning study: tracker `{settings.tracker}`, objective `{settings.objective}`", "",
          f"- tune clips: {', '.join(tune_clips)}",
          f"- validation clips: {', '.join(val_clips) if val_clips else 'none'}"
          + ("" if val_clips else " (give `--validate CLIP` for an honest check; see below)"),
          f"- trials: {len(done)} completed, {len(failed)} failed; seed {settings.seed}, "
          f"{settings.workers} at a time; frames "
          + (f"0–{settings.stop - 1}" if settings.stop else "all") + f"; match gate {settings.gate:g} px"
          + " (or inside the truth's box where it has w,h)",
          f"- objective: {' and '.join(f'{d} {m}' for m, d in zip(metrics, directions))}, averaged over the tune clips"
          + ("; the validation clips are scored in every trial and never used to choose" if val_clips else ""),
          ""]
    best = ranked(trials, settings.objective)
    base = [t for t in done if t.user_attrs.get("base")]
    shown = base + [t for t in (best[:1] if settings.objective != "pareto" else pareto_front(done)) if t not in base]
    md += ["## Tune and validation scores", ""]
    roles = ["tune"] + (["validate"] if val_clips else [])
    head = "| trial | " + " | ".join(f"{r} {m}" for r in roles for m in METRICS)
    head += " | gap (tune − validation) " + metrics[0] if val_clips else ""
    md += [head + " |", "|" + "---|" * (1 + len(roles) * len(METRICS) + (1 if val_clips else 0))]
    for t in shown:
        name = _trial_name(t, best[0])
        row = f"| {name} | " + " | ".join(_f(t.user_attrs[r][m]) for r in roles for m in METRICS)
        if val_clips:
            row += f" | {_f(t.user_attrs['tune'][metrics[0]] - t.user_attrs['validate'][metrics[0]], '+.3f')}"
        md.append(row + " |")
    md.append("")
    if val_clips and best and base and settings.objective != "pareto":
        b, d0 = best[0], base[0]
        gain_t = b.user_attrs["tune"][metrics[0]] - d0.user_attrs["tune"][metrics[0]]
        gain_v = b.user_attrs["validate"][metrics[0]] - d0.user_attrs["validate"][metrics[0]]
        verdict = ("holds on the validation clips" if gain_v >= 0 else
                   "does **not** hold on the validation clips (the search fitted the tune clips)")
        md += [f"The best trial gains {gain_t:+.3f} {metrics[0]} over the base on the tune clips and "
               f"{gain_v:+.3f} on the validation clips: the gain {verdict}.", ""]
    if done:
        md += _where_pd_went(done, base, best, settings, val_clips)
    if folds >= 2 and not val_clips and done and len(tune_clips) >= 2:
        lines, ins, outs = folds_table(trials, settings, folds)
        md += [f"## Leave-clips-out cross-validation ({folds} folds)", "",
               "For each fold the trial that scores best on the other folds is chosen and scored on the "
               "held-out fold. The sampler saw every clip, so this checks the choice of trial, not "
               "the search; `--validate` clips are the stricter check.", "", *lines, "",
               f"Mean {metrics[0]}: {_f(ins)} on the folds that chose, {_f(outs)} held out "
               f"(gap {_f(ins - outs, '+.3f')}).", ""]
    md += [f"## Best {min(SHOWN, len(best))} trials", ""]
    names = settings.space.names
    md += ["| trial | " + " | ".join(f"{m}" for m in metrics) + " | " + " | ".join(names) + " | s |",
           "|" + "---|" * (2 + len(metrics) + len(names))]
    for t in best[:SHOWN]:
        md.append(f"| {t.number} | " + " | ".join(_f(v) for v in t.values) + " | "
                  + " | ".join(_f(t.params.get(n), ".4g") for n in names)
                  + f" | {_f(t.user_attrs.get('seconds'), '.1f')} |")
    md.append("")
    if importance:
        md += [f"## Parameter importance (PED-ANOVA, for {metrics[0]})", "",
               "| parameter | importance |", "|---|---:|"]
        md += [f"| {k} | {v:.3f} |" for k, v in importance.items()] + [""]
    if failed:
        md += ["## Failed trials", ""] + [f"- trial {t.number}: {t.user_attrs.get('error', 'failed')}"
                                          for t in sorted(failed, key=lambda t: t.number)] + [""]
    if plots:
        md += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in plots] + [""]
    md += ["## Files", "",
           "- `trials.csv`: every trial, its parameters and scores (averaged and per clip)",
           "- " + ("`best-N.toml` per Pareto point, listed in `pareto.csv`" if settings.objective == "pareto"
                   else "`best.toml`: the best trial's whole configuration, for `--config`"),
           "- `study.rrd`: the study in Rerun (`rerun study.rrd`: a `trial` timeline)",
           "- `study.journal`: the Optuna journal; the same command resumes the study", ""]
    return [folder.write(folder.path / "report.md", "\n".join(md)), *plots]
