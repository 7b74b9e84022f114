"""A tuning study in Rerun (``study.rrd``): a ``trial`` timeline with every objective (tune and
validation clips) and every parameter as a series, and the trials in the Pd / false-track
plane (:mod:`wfviz.record.study_plane`).

Entities: ``study/<role>/<metric>`` (role ``tune`` or ``validate``; metrics mota, idf1, hota,
pd, fa, idsw), ``study/params/<section.key>`` (numbers; choices as their index),
``study/params_scaled/<section.key>`` (the same on the parameter's search range, 0 … 1),
``study/plane/*`` (the scatter plot: ``trials``, ``defaults``, ``best``, ``front``, ``axes``,
``grid``, ``ticks``, ``titles``), ``study/trials`` and ``study/pareto`` (points in raw units:
x = false tracks per frame, y = Pd, on the tune clips; kept for readers of older files),
``study/log`` (one line per trial, failed ones with their error). One colour per metric and per
parameter (:mod:`wfviz.tune.palette`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import rerun as rr
import rerun.blueprint as rrb

from wfviz.io.outputs import replace_into, temp_path
from wfviz.record import study_plane
from wfviz.tune.outputs import pareto_front, pd_fa
from wfviz.tune.palette import metric_color, param_color
from wfviz.tune.scales import range_text, unit_value
from wfviz.tune.space import Param
from wfviz.tune.study import StudySettings
from wfviz.tune.trial import METRICS

APPLICATION_ID = "wfviz_study"
#: metrics on their own plot (a rate and a count); the others are scores, mostly within 0 … 1
_OWN_PLOT = ("fa", "idsw")
_INTERACTION = rrb.PlotInteraction(tooltip_mode="All", points_display="Always")
_RIGHT_TOP = rrb.PlotLegend(corner="RightTop")


def _room_for_legend(numbers: list[int]) -> rrb.TimeAxis:
    """The trial axis of a plot with a legend: its trials and room on the right for the legend."""
    first, last = (min(numbers), max(numbers)) if numbers else (0, 1)
    end = last + max(1, round(0.7 * (last - first + 1)))
    return rrb.TimeAxis(view_range=rr.TimeRange(start=rrb.TimeRangeBoundary.absolute(seq=first),
                                                end=rrb.TimeRangeBoundary.absolute(seq=end)))


def _metric_row(role: str, numbers: list[int]) -> rrb.Horizontal:
    scores = [m for m in METRICS if m not in _OWN_PLOT]
    views = [rrb.TimeSeriesView(origin=f"study/{role}", contents=[f"study/{role}/{m}" for m in scores],
                                name=f"{role} clips: {', '.join(scores)}", interaction=_INTERACTION,
                                axis_x=_room_for_legend(numbers), plot_legend=_RIGHT_TOP)]
    views += [rrb.TimeSeriesView(origin=f"study/{role}/{m}", name=f"{m}: {role}", interaction=_INTERACTION,
                                 plot_legend=rrb.PlotLegend(visible=False))
              for m in _OWN_PLOT if m in METRICS]
    return rrb.Horizontal(*views, column_shares=[2.0] + [1.0] * (len(views) - 1))


def _params_tabs(params: tuple[Param, ...], numbers: list[int]) -> rrb.Tabs:
    scaled = rrb.TimeSeriesView(origin="study/params_scaled", name="parameters on their search range (0 … 1)",
                                axis_y=rrb.ScalarAxis(range=(-0.05, 1.05)), axis_x=_room_for_legend(numbers),
                                plot_legend=_RIGHT_TOP, interaction=_INTERACTION)
    raw = [rrb.TimeSeriesView(origin=f"study/params/{p.name}", name=p.name, interaction=_INTERACTION,
                              plot_legend=rrb.PlotLegend(visible=False)) for p in params]
    return rrb.Tabs(scaled, *raw, active_tab=0)


def _blueprint(settings: StudySettings, roles: list[str], numbers: list[int]) -> rrb.Blueprint:
    """Left: a row of plots per role, the parameters (all on their ranges, or one in raw units
    a tab); right: the Pd / false-track plane above the trial log."""
    return rrb.Blueprint(rrb.Horizontal(
        rrb.Vertical(*[_metric_row(r, numbers) for r in roles], _params_tabs(settings.space.params, numbers),
                     row_shares=[1.0] * len(roles) + [1.3]),
        rrb.Vertical(study_plane.view(), rrb.TextLogView(origin="study/log", name="trials"), row_shares=[3.0, 1.0]),
    ), collapse_panels=True)


def _log_styles(rec: rr.RecordingStream, settings: StudySettings, roles: list[str]) -> None:
    """Each series' colour and name (static): a metric's the same for every role."""
    for role in roles:
        for m in METRICS:
            rec.log(f"study/{role}/{m}", rr.SeriesLines(colors=[metric_color(m)], names=m), static=True)
    for i, p in enumerate(settings.space.params):
        color = [param_color(i)]
        rec.log(f"study/params/{p.name}", rr.SeriesLines(colors=color, names=p.name), static=True)
        rec.log(f"study/params_scaled/{p.name}", rr.SeriesLines(colors=color, names=f"{p.name} {range_text(p)}"),
                static=True)


def _log_trial(rec: rr.RecordingStream, t: Any, settings: StudySettings, roles: list[str]) -> None:
    """A completed trial's metrics, parameters, raw Pd / false-track point and log line."""
    for role in roles:
        for m in METRICS:
            v = t.user_attrs.get(role, {}).get(m)
            if v is not None and v == v:
                rec.log(f"study/{role}/{m}", rr.Scalars(float(v)))
    for p in settings.space.params:
        v = t.params.get(p.name)
        if v is None:
            continue
        rec.log(f"study/params/{p.name}", rr.Scalars(float(p.choices.index(v)) if p.kind == "choice" else float(v)))
        rec.log(f"study/params_scaled/{p.name}", rr.Scalars(unit_value(p, v)))
    tune = t.user_attrs["tune"]
    rec.log("study/trials", rr.Points2D([[tune["fa"], tune["pd"]]], radii=rr.Radius.ui_points(4.0),
                                        labels=[str(t.number)], show_labels=False))
    rec.log("study/log", rr.TextLog(
        f"trial {t.number}: " + ", ".join(f"{m} {tune[m]:.3f}" for m in METRICS if m in tune)
        + " | " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in t.params.items()),
        level="INFO"))


def record_study(path: Path, trials: list[Any], settings: StudySettings) -> Path:
    """Write ``path`` (a temporary name renamed when complete)."""
    roles = ["tune"] + (["validate"] if any(c.role == "validate" for c in settings.clips) else [])
    tmp = temp_path(path)
    rec = rr.RecordingStream(APPLICATION_ID)
    try:
        # a file sink, not rec.save: save() passes the name as a str Rust cannot take when it is not UTF-8
        rec.set_sinks(rr.FileSink(str(tmp)), default_blueprint=_blueprint(settings, roles, [t.number for t in trials]))
        _log_styles(rec, settings, roles)
        x, y = study_plane.plane_axes(trials)
        study_plane.log_axes(rec, x, y)
        done: list[Any] = []
        for t in sorted(trials, key=lambda t: t.number):
            rec.set_time("trial", sequence=t.number)
            if t.values is None:
                cut = t.user_attrs.get("pruned")
                text = (f"trial {t.number} pruned after {cut['after']} of {cut['of']} tune clips" if cut
                        else f"trial {t.number} failed: {t.user_attrs.get('error', '')}")
                rec.log("study/log", rr.TextLog(text, level="INFO" if cut else "WARN"))
                continue
            done.append(t)
            _log_trial(rec, t, settings, roles)
            study_plane.log_step(rec, x, y, done, settings.objective)
        front = sorted(pareto_front(done), key=lambda t: pd_fa(t)[1])
        if front:
            rec.log("study/pareto", rr.Points2D([[pd_fa(t)[1], pd_fa(t)[0]] for t in front],
                                                 labels=[f"trial {t.number}" for t in front],
                                                 colors=[230, 60, 60], radii=rr.Radius.ui_points(6.0)),
                    static=True)
        rec.flush()
        rec.disconnect()
        replace_into(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
