"""The report's PNG plots, each written whole to a temporary name and renamed, the base and the
best trial marked on every plot of trials: ``history.png`` (the objective over the trials),
``pareto.png`` (every study: Pd against false tracks on the tune clips, with the front),
``importance.png`` and, with validation clips, ``tune_vs_validation.png``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from wfviz.tune.folder import StudyFolder
from wfviz.tune.outputs import pareto_front, pd_fa
from wfviz.tune.study import OBJECTIVES, StudySettings

BASE_STYLE = {"marker": "s", "ms": 9, "mfc": "none", "mec": "black", "mew": 1.5, "ls": "none"}
BEST_STYLE = {"marker": "*", "ms": 13, "color": "C3", "mec": "black", "mew": 0.6, "ls": "none"}


def _mark(ax: Any, base: Any | None, best: Any | None, xy: Any) -> None:
    """Mark the base and the best trial at ``xy(trial)`` (skipped where it is not finite)."""
    both = base is not None and best is base
    for t, style, label in ((base, BASE_STYLE, "base (defaults)" + (", the best" if both else "")),
                            (None if both else best, BEST_STYLE, "best")):
        if t is None:
            continue
        x, y = xy(t)
        if math.isfinite(x) and math.isfinite(y):
            ax.plot([x], [y], label=f"{label}: trial {t.number}", zorder=5, **style)


def write_plots(folder: StudyFolder, trials: list[Any], settings: StudySettings, importance: dict[str, float],
                best: Any | None) -> list[Path]:
    """Write the plots of ``trials`` (``best``: the study's best, or its first Pareto point);
    returns the files."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics, directions = OBJECTIVES[settings.objective]
    done = sorted((t for t in trials if t.values is not None), key=lambda t: t.number)
    has_val = any(c.role == "validate" for c in settings.clips)
    base = next((t for t in done if t.user_attrs.get("base")), None)
    files: list[Path] = []
    if not done:
        return files
    fig, axes = plt.subplots(1, len(metrics), figsize=(6 * len(metrics), 3.6), squeeze=False)
    for ax, m, d in zip(axes[0], metrics, directions):
        n = [t.number for t in done]
        v = [t.user_attrs["tune"][m] for t in done]
        ax.plot(n, v, "o", ms=4, label="tune clips")
        running, run = [], None
        for x in v:
            run = x if run is None else (max(run, x) if d == "maximize" else min(run, x))
            running.append(run)
        ax.step(n, running, where="post", label="best so far")
        if has_val:
            ax.plot(n, [t.user_attrs["validate"][m] for t in done], "x", ms=4, label="validation clips")
        _mark(ax, base, best, lambda t, m=m: (t.number, t.user_attrs["tune"][m]))
        ax.set_xlabel("trial")
        ax.set_ylabel(m)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(_save(fig, folder.path / "history.png", folder))
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.plot([pd_fa(t)[1] for t in done], [pd_fa(t)[0] for t in done], "o", ms=4, alpha=0.5, label="trials")
    front = sorted(pareto_front(done), key=lambda t: pd_fa(t)[1])
    ax.plot([pd_fa(t)[1] for t in front], [pd_fa(t)[0] for t in front], "o-", color="C1", label="Pareto front")
    for t in front:
        ax.annotate(str(t.number), pd_fa(t)[::-1], fontsize=7)
    _mark(ax, base, best, lambda t: pd_fa(t)[::-1])
    ax.set_xlabel("false tracks per frame (tune clips)")
    ax.set_ylabel("Pd (tune clips)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(_save(fig, folder.path / "pareto.png", folder))
    if importance:
        fig, ax = plt.subplots(figsize=(6, 0.4 * len(importance) + 1.2))
        names = list(importance)[::-1]
        ax.barh(names, [importance[k] for k in names])
        ax.set_xlabel(f"importance for {metrics[0]} (PED-ANOVA, {len(done)} trials)")
        fig.tight_layout()
        files.append(_save(fig, folder.path / "importance.png", folder))
    if has_val:
        fig, axes = plt.subplots(1, len(metrics), figsize=(4.5 * len(metrics), 4), squeeze=False)
        for ax, m in zip(axes[0], metrics):
            x = [t.user_attrs["tune"][m] for t in done]
            y = [t.user_attrs["validate"][m] for t in done]
            ax.plot(x, y, "o", ms=4, label="trials")
            finite = [v for v in x + y if math.isfinite(v)]
            if finite:
                lo, hi = min(finite), max(finite)
                ax.plot([lo, hi], [lo, hi], "--", color="grey", lw=1)
            _mark(ax, base, best, lambda t, m=m: (t.user_attrs["tune"][m], t.user_attrs["validate"][m]))
            ax.set_xlabel(f"{m}, tune clips")
            ax.set_ylabel(f"{m}, validation clips")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.tight_layout()
        files.append(_save(fig, folder.path / "tune_vs_validation.png", folder))
    return files


def _save(fig: Any, path: Path, folder: StudyFolder) -> Path:
    import matplotlib.pyplot as plt

    from wfviz.io.outputs import replace_into, temp_path

    tmp = temp_path(folder.claim(path))
    try:
        fig.savefig(tmp, dpi=110, format="png")
        replace_into(tmp, path)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return path
