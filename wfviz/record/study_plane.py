"""The Pd / false-track plane of ``study.rrd`` (``study/plane/*``): a scatter plot drawn in a 2D
view, since Rerun's plots (0.41) put time on x. The plot box is ``WIDTH`` by ``HEIGHT`` scene
units with y flipped (Pd grows upwards); its axes, grid, tick labels and titles are drawn as
lines and labelled points. Every completed trial so far is one point of one batch logged at each
trial, so the cloud stays: at trial N it holds every completed trial up to N."""

from __future__ import annotations

import math
from typing import Any

import rerun as rr
import rerun.blueprint as rrb

from wfviz.tune.outputs import pareto_front, pd_fa, ranked
from wfviz.tune.palette import AXIS_COLOR, BEST_COLOR, DEFAULTS_COLOR, FRONT_COLOR, TRIAL_COLOR
from wfviz.tune.scales import Axis, nice_axis

ORIGIN = "study/plane"
WIDTH, HEIGHT = 160.0, 100.0  # the plot box, scene units
X_TITLE = "false tracks per frame (tune clips)"
Y_TITLE = "Pd (tune clips)"
_GRID_COLOR = (70, 74, 80)
_SIZES = {"trials": 4.0, "front": 4.0, "defaults": 7.0, "best": 5.5}  # marks' radii, UI points
_COLORS = {"trials": TRIAL_COLOR, "front": FRONT_COLOR, "defaults": DEFAULTS_COLOR, "best": BEST_COLOR}


def placed(trials: list[Any]) -> list[Any]:
    """The completed trials with a finite Pd and false-track rate (the plane's points)."""
    return [t for t in trials if t.values is not None and all(math.isfinite(v) for v in pd_fa(t))]


def plane_axes(trials: list[Any]) -> tuple[Axis, Axis]:
    """The x (false tracks per frame, from 0) and y (Pd, within 0 … 1) axes that hold ``trials``."""
    pts = [pd_fa(t) for t in placed(trials)]
    fa_max = max((fa for _, fa in pts), default=0.0)
    x = nice_axis(0.0, fa_max if fa_max > 0 else 0.1, floor=0.0)
    y = nice_axis(min((p for p, _ in pts), default=0.0), max((p for p, _ in pts), default=1.0),
                  floor=0.0, ceiling=1.0)
    return x, y


def to_scene(x: Axis, y: Axis, fa: float, pd: float) -> tuple[float, float]:
    """Scene position of (false tracks per frame, Pd): y flipped, so that Pd grows upwards."""
    return WIDTH * x.fraction(fa), HEIGHT * (1.0 - y.fraction(pd))


def view(name: str = "Pd against false tracks per frame (tune clips)") -> rrb.Spatial2DView:
    """The plane's 2D view, framed on the plot box with its labels."""
    return rrb.Spatial2DView(origin=ORIGIN, name=name, visual_bounds=rrb.VisualBounds2D(
        x_range=(-0.2 * WIDTH, 1.1 * WIDTH), y_range=(-0.2 * HEIGHT, 1.2 * HEIGHT)))


def _tick(v: float) -> str:
    return f"{v:.4g}"


def log_axes(rec: rr.RecordingStream, x: Axis, y: Axis) -> None:
    """The axes, grid, tick labels and axis titles (static)."""
    grid = [[to_scene(x, y, v, y.low), to_scene(x, y, v, y.high)] for v in x.ticks[1:]]
    grid += [[to_scene(x, y, x.low, v), to_scene(x, y, x.high, v)] for v in y.ticks[1:]]
    rec.log(f"{ORIGIN}/grid", rr.LineStrips2D(grid, colors=[_GRID_COLOR], radii=rr.Radius.ui_points(0.5),
                                              draw_order=1.0), static=True)
    tick = 0.02 * HEIGHT
    strips = [[(0.0, 0.0), (0.0, HEIGHT), (WIDTH, HEIGHT)]]
    strips += [[(px, HEIGHT), (px, HEIGHT + tick)] for px, _ in (to_scene(x, y, v, y.low) for v in x.ticks)]
    strips += [[(-tick, py), (0.0, py)] for _, py in (to_scene(x, y, x.low, v) for v in y.ticks)]
    rec.log(f"{ORIGIN}/axes", rr.LineStrips2D(strips, colors=[AXIS_COLOR], radii=rr.Radius.ui_points(1.0),
                                              draw_order=2.0), static=True)
    positions = [(px, HEIGHT + 2 * tick) for px, _ in (to_scene(x, y, v, y.low) for v in x.ticks)]
    positions += [(-5 * tick, py) for _, py in (to_scene(x, y, x.low, v) for v in y.ticks)]
    rec.log(f"{ORIGIN}/ticks", rr.Points2D(positions, labels=[_tick(v) for v in x.ticks + y.ticks],
                                           colors=[AXIS_COLOR], radii=rr.Radius.ui_points(0.1), show_labels=True,
                                           draw_order=2.0), static=True)
    rec.log(f"{ORIGIN}/titles", rr.Points2D([(WIDTH / 2, HEIGHT + 9 * tick), (0.0, -3 * tick)],
                                            labels=[X_TITLE, Y_TITLE], colors=[AXIS_COLOR],
                                            radii=rr.Radius.ui_points(0.1), show_labels=True, draw_order=2.0),
            static=True)


def _label(t: Any, objective: str) -> str:
    pd, fa = pd_fa(t)
    text = f"trial {t.number}: Pd {pd:.3f}, {fa:.4g} false tracks/frame"
    if objective != "pareto":
        v = t.user_attrs["tune"].get(objective)
        if v is not None:
            text += f", {objective} {v:.3f}"
    return text


def log_step(rec: rr.RecordingStream, x: Axis, y: Axis, done: list[Any], objective: str) -> None:
    """The plane after the completed trials ``done``, the last one the current trial: every one
    of them, the best trial (for ``pareto``: the front's trials), the Pareto front, and the
    defaults when the current trial is the base one."""
    pts = placed(done)
    if not pts:
        return
    scene = {t.number: to_scene(x, y, pd_fa(t)[1], pd_fa(t)[0]) for t in pts}
    rec.log(f"{ORIGIN}/trials", rr.Points2D([scene[t.number] for t in pts], labels=[_label(t, objective) for t in pts],
                                            colors=[TRIAL_COLOR], radii=rr.Radius.ui_points(_SIZES["trials"]), show_labels=False,
                                            draw_order=10.0))
    front = sorted(pareto_front(pts), key=lambda t: (pd_fa(t)[1], pd_fa(t)[0]))
    rec.log(f"{ORIGIN}/front", rr.LineStrips2D([[scene[t.number] for t in front]], colors=[FRONT_COLOR],
                                               radii=rr.Radius.ui_points(1.5), labels=["Pareto front"],
                                               show_labels=False, draw_order=5.0))
    new = done[-1]
    if new.user_attrs.get("base") and new.number in scene:  # stays from its trial on
        rec.log(f"{ORIGIN}/defaults", rr.Points2D([scene[new.number]], labels=[f"defaults (trial {new.number})"],
                                                  colors=[DEFAULTS_COLOR], radii=rr.Radius.ui_points(_SIZES["defaults"]),
                                                  show_labels=False, draw_order=30.0))
    pareto = objective == "pareto"
    best = front if pareto else ranked(pts, objective)[:1]  # none while no trial meets the constraints
    if best:
        names = [f"trial {t.number}" for t in best] if pareto else [f"best: trial {best[0].number}"]
        rec.log(f"{ORIGIN}/best", rr.Points2D([scene[t.number] for t in best], labels=names, colors=[BEST_COLOR],
                                              radii=rr.Radius.ui_points(_SIZES["best"]), show_labels=pareto,
                                              draw_order=40.0))
    base = [t for t in pts if t.user_attrs.get("base")]
    entries = [("trials", f"trials ({len(pts)})"), ("front", "Pareto front")]
    entries += [("defaults", f"defaults: trial {base[0].number}")] if base else []
    entries += [("best", "best: the front" if pareto else f"best: trial {best[0].number}")] if best else []
    log_legend(rec, entries)


def log_legend(rec: rr.RecordingStream, entries: list[tuple[str, str]]) -> None:
    """The legend (``study/plane/legend``): a row of marks above the plot box, each labelled
    (the marks themselves show their labels on hover only, so that none hides another)."""
    xs = [WIDTH * (0.25 + 0.65 * i / max(1, len(entries) - 1)) for i in range(len(entries))]
    rec.log(f"{ORIGIN}/legend", rr.Points2D([(x, -0.1 * HEIGHT) for x in xs], labels=[text for _, text in entries],
                                            colors=[_COLORS[k] for k, _ in entries],
                                            radii=rr.Radius.ui_points([_SIZES[k] for k, _ in entries]), show_labels=True,
                                            draw_order=40.0))
