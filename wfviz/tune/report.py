"""``report.md`` of a study with its PNG plots (:mod:`wfviz.tune.plots`): the scores of the
base and the best trials and their gains over the base with intervals (:mod:`wfviz.tune.gains`:
is a gain more than noise, does it hold on the validation clips, how much did the search fit
the tune clips), where Pd went in the base and the best trials (which cause the search
reduced), and parameter importance with the number of trials it rests on."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from wfviz.tune.folder import StudyFolder
from wfviz.tune.gains import TrialGains, best_section, num, scores_section, trial_name, verdict
from wfviz.tune.outputs import pareto_front, ranked
from wfviz.tune.plots import write_plots
from wfviz.tune.study import OBJECTIVES, StudySettings, outcome_phrases
from wfviz.tune.trial import dominant, mean_scores

SHOWN = 10  # trials in the report's table
IMPORTANCE_TRIALS = 30  # below this many trials the importance is a hint (PED-ANOVA's top 10 %: 3 trials)
TARGET_QUANTILE = 0.1  # PED-ANOVA's default: the best 10 % of the trials against all of them
CAUSE_TRIALS = 4  # trials beside the base in the "where Pd went" tables (a Pareto front's first)


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
        lines.append(f"| {i + 1} | {', '.join(held)} | {best.number} | {num(score[best.number])} | {num(held_score)} |")
    mean = (lambda xs: sum(xs) / len(xs) if xs else math.nan)  # noqa: E731
    return lines, mean(ins), mean(outs)


def causes_table(trials: list[Any], role: str, best: Any) -> list[str]:
    """Where Pd went on the ``role`` clips ("tune", "validate") in each of ``trials`` (the base
    first), from their ``causes`` attribute: each miss cause in pipeline order and the matched
    points (count and share of the visible points), the dominant miss cause, and the false-track
    rows by cause (count and share of the false-track rows); with two trials the change from the
    first to the second. "-": no causes recorded (a trial run before wfviz counted them)."""
    from wfviz.explain.types import MISSES, Cause, FalseCause

    counts = [(t.user_attrs.get("causes") or {}).get(role) for t in trials]
    change = len(trials) == 2 and all(counts)
    names = [trial_name(t, best) for t in trials]
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


def importance_section(importance: dict[str, float], trials: int, metric: str) -> list[str]:
    """The importance section: the table, the number of completed ``trials`` it rests on and,
    below :data:`IMPORTANCE_TRIALS`, that it is a hint; a line saying why when there is none."""
    top = max(1, math.ceil(TARGET_QUANTILE * trials))
    md = [f"## Parameter importance (PED-ANOVA, for {metric})", ""]
    if not importance:
        return md + [f"Not computed: {trials} completed trial(s) (it needs at least 4, and 2 parameters searched).", ""]
    md += [f"From {trials} completed trials: how differently each parameter is spread in the best "
           f"{100 * TARGET_QUANTILE:.0f} % of them ({top} trial{'s' if top > 1 else ''}) than in all of them."]
    if trials < IMPORTANCE_TRIALS:
        md[-1] += (f" **With fewer than {IMPORTANCE_TRIALS} trials this is a hint, not a finding**: the best "
                   f"{top} decide it, and another seed can reorder it. Run more trials before dropping a "
                   "parameter from the space.")
    md += ["", "| parameter | importance |", "|---|---:|"]
    return md + [f"| {k} | {v:.3f} |" for k, v in importance.items()] + [""]


def write_report(folder: StudyFolder, trials: list[Any], settings: StudySettings, folds: int = 0) -> list[Path]:
    """Write ``report.md`` and its plots; returns the files."""
    metrics, directions = OBJECTIVES[settings.objective]
    done = [t for t in trials if t.values is not None]
    failed = [t for t in trials if t.state.name == "FAIL"]
    infeasible, pruned = outcome_phrases(trials, settings)
    tune_clips = [c.label for c in settings.clips if c.role == "tune"]
    val_clips = [c.label for c in settings.clips if c.role == "validate"]
    importance = _importance(trials, settings)
    plots = write_plots(folder, trials, settings, importance, (ranked(trials, settings.objective) or [None])[0])
    md = [f"# Tuning study: tracker `{settings.tracker}`, objective `{settings.objective}`", "",
          f"- tune clips: {', '.join(tune_clips)}",
          f"- validation clips: {', '.join(val_clips) if val_clips else 'none'}"
          + ("" if val_clips else " (give `--validate CLIP` for an honest check; see below)"),
          f"- trials: {len(done)} completed{infeasible}, {pruned}{len(failed)} failed; seed {settings.seed}, "
          f"{settings.workers} at a time; frames "
          + (f"0–{settings.stop - 1}" if settings.stop else "all") + f"; match gate {settings.gate:g} px"
          + " (or inside the truth's box where it has w,h)",
          f"- objective: {' and '.join(f'{d} {m}' for m, d in zip(metrics, directions))}, averaged over the tune clips"
          + ("; the validation clips are scored in every trial and never used to choose" if val_clips else ""),
          ""]
    best = ranked(trials, settings.objective)
    base = [t for t in done if t.user_attrs.get("base")]
    shown = base + [t for t in (best[:1] if settings.objective != "pareto" else pareto_front(done)) if t not in base]
    roles = ["tune"] + (["validate"] if val_clips else [])
    gains = TrialGains(base[0] if base else None, {"tune": tune_clips, "validate": val_clips})
    md += scores_section(shown, best[0] if best else None, gains, metrics[0], roles)
    if best and settings.objective != "pareto":
        sentence = verdict(best[0], gains, metrics[0], bool(val_clips))
        md += [sentence, ""] if sentence else []
    if done:
        md += _where_pd_went(done, base, best, settings, val_clips)
    if folds >= 2 and not val_clips and done and len(tune_clips) >= 2:
        lines, ins, outs = folds_table(trials, settings, folds)
        md += [f"## Leave-clips-out cross-validation ({folds} folds)", "",
               "For each fold the trial that scores best on the other folds is chosen and scored on the "
               "held-out fold. The sampler saw every clip, so this checks the choice of trial, not "
               "the search; `--validate` clips are the stricter check.", "", *lines, "",
               f"Mean {metrics[0]}: {num(ins)} on the folds that chose, {num(outs)} held out "
               f"(gap {num(ins - outs, '+.3f')}).", ""]
    md += best_section(best, SHOWN, gains, metrics, settings.space.names, bool(val_clips))
    md += importance_section(importance, len(done), metrics[0])
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
