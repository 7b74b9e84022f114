"""A tuning study in Rerun (``study.rrd``): a ``trial`` timeline with every objective (tune and
validation clips) and every parameter as a series, and the trials in the Pd / false-track
plane with the Pareto front marked.

Entities: ``study/<role>/<metric>`` (role ``tune`` or ``validate``; metrics mota, idf1, hota, pd,
fa, idsw), ``study/params/<section.key>`` (numbers; choices as their index), ``study/trials``
and ``study/pareto`` (points: x = false tracks per frame, y = Pd, on the tune clips),
``study/log`` (one line per trial, failed ones with their error)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import rerun as rr
import rerun.blueprint as rrb

from wfviz.io.outputs import replace_into, temp_path
from wfviz.tune.outputs import pareto_front, pd_fa
from wfviz.tune.study import StudySettings
from wfviz.tune.trial import METRICS

APPLICATION_ID = "wfviz_study"


def _blueprint(settings: StudySettings, roles: list[str]) -> rrb.Blueprint:
    plots = [rrb.TimeSeriesView(origin=f"study/{r}", name=f"{r} clips") for r in roles]
    return rrb.Blueprint(rrb.Horizontal(
        rrb.Vertical(*plots, rrb.TimeSeriesView(origin="study/params", name="parameters")),
        rrb.Vertical(rrb.Spatial2DView(origin="study", contents=["study/trials", "study/pareto"],
                                       name="Pd against false tracks per frame"),
                     rrb.TextLogView(origin="study/log", name="trials")),
    ), collapse_panels=True)


def record_study(path: Path, trials: list[Any], settings: StudySettings) -> Path:
    """Write ``path`` (a temporary name renamed when complete)."""
    roles = ["tune"] + (["validate"] if any(c.role == "validate" for c in settings.clips) else [])
    tmp = temp_path(path)
    rec = rr.RecordingStream(APPLICATION_ID)
    try:
        # a file sink, not rec.save: save() passes the name as a str Rust cannot take when it is not UTF-8
        rec.set_sinks(rr.FileSink(str(tmp)), default_blueprint=_blueprint(settings, roles))
        done = []
        for t in sorted(trials, key=lambda t: t.number):
            rec.set_time("trial", sequence=t.number)
            if t.values is None:
                rec.log("study/log", rr.TextLog(f"trial {t.number} failed: {t.user_attrs.get('error', '')}",
                                                level="WARN"))
                continue
            done.append(t)
            for role in roles:
                for m in METRICS:
                    v = t.user_attrs.get(role, {}).get(m)
                    if v is not None and v == v:
                        rec.log(f"study/{role}/{m}", rr.Scalars(float(v)))
            for p in settings.space.params:
                v = t.params.get(p.name)
                if v is None:
                    continue
                value = float(p.choices.index(v)) if p.kind == "choice" else float(v)
                rec.log(f"study/params/{p.name}", rr.Scalars(value))
            tune = t.user_attrs["tune"]
            rec.log("study/trials", rr.Points2D([[tune["fa"], tune["pd"]]], radii=rr.Radius.ui_points(4.0),
                                                labels=[str(t.number)], show_labels=False))
            rec.log("study/log", rr.TextLog(
                f"trial {t.number}: " + ", ".join(f"{m} {tune[m]:.3f}" for m in METRICS if m in tune)
                + " | " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                    for k, v in t.params.items())))
        front = sorted(pareto_front(done), key=lambda t: pd_fa(t)[1])
        if front:
            rec.log("study/pareto", rr.Points2D([[t.user_attrs["tune"]["fa"], t.user_attrs["tune"]["pd"]] for t in front],
                                                 labels=[f"trial {t.number}" for t in front],
                                                 colors=[230, 60, 60], radii=rr.Radius.ui_points(6.0)),
                    static=True)
        rec.flush()
        rec.disconnect()
        replace_into(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
