"""``study.rrd`` of ``wfviz tune`` read back: every trial stays a point of the Pd / false-track
plane with labelled axes, the defaults and the best marked; parameters on their search range;
one colour per metric and parameter; and ``wfviz screenshot`` on it, checked in the picture."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rerun.chunk import RrdReader

from conftest import needs_vulkan, wfviz
from wfviz.record.study import record_study
from wfviz.trackers import config_class
from wfviz.tune.clips import StudyClip
from wfviz.tune.space import parse_space
from wfviz.tune.study import StudySettings

SPACE = {"detection": {"k_sigma": {"low": 3.0, "high": 6.0}},
         "tracking": {"false_tracks_per_1000": {"low": 0.05, "high": 20.0, "log": True},
                      "confirm": {"choices": ["sprt", "hits"]}}}
#: (Pd, false tracks per frame) of trials 0 … 9 on the tune clips; trial 4 fails
POINTS = [(0.80, 0.10), (0.62, 0.02), (0.70, 0.05), (0.91, 0.22), None, (0.75, 0.15),
          (0.66, 0.18), (0.86, 0.07), (0.72, 0.25), (0.95, 0.30)]
K_SIGMA = [4.0, 3.0, 6.0, 3.5, 5.0, 4.5, 5.5, 3.2, 4.8, 5.9]
FTP = [1.0, 0.05, 20.0, 0.3, 2.0, 5.0, 0.1, 10.0, 0.7, 15.0]


def _mota(pd: float, fa: float) -> float:
    return pd - 0.5 * fa


def _trials() -> list[Any]:
    from optuna.distributions import CategoricalDistribution, FloatDistribution
    from optuna.trial import TrialState, create_trial

    dists = {"detection.k_sigma": FloatDistribution(3.0, 6.0),
             "tracking.false_tracks_per_1000": FloatDistribution(0.05, 20.0, log=True),
             "tracking.confirm": CategoricalDistribution(["sprt", "hits"])}
    out = []
    for i, point in enumerate(POINTS):
        params = {"detection.k_sigma": K_SIGMA[i], "tracking.false_tracks_per_1000": FTP[i],
                  "tracking.confirm": ["sprt", "hits"][i % 2]}
        if point is None:
            t = create_trial(state=TrialState.FAIL, params=params, distributions=dists,
                             user_attrs={"error": "a failing clip"})
        else:
            pd, fa = point
            scores = {"mota": _mota(pd, fa), "idf1": pd - 0.1, "pd": pd, "fa": fa, "idsw": float(i % 3)}
            attrs = {"tune": scores, "validate": {k: v * 0.9 for k, v in scores.items()}} | (
                {"base": True} if i == 0 else {})
            t = create_trial(values=[scores["mota"]], params=params, distributions=dists, user_attrs=attrs)
        t.number = i
        out.append(t)
    return out


def _settings(objective: str = "mota") -> StudySettings:
    cls = config_class("gewc")
    clips = (StudyClip("a", "synth:a", Path("a.csv"), "tune"), StudyClip("v", "synth:v", Path("v.csv"), "validate"))
    return StudySettings("gewc", clips, parse_space(SPACE, cls), cls(), objective=objective)


@pytest.fixture(scope="module")
def study_rrd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("study") / "study.rrd"
    return record_study(path, _trials(), _settings())


def _rows(rrd: Path) -> tuple[dict[str, list[tuple[int, dict[str, Any]]]], dict[str, dict[str, Any]]]:
    """Entity -> [(trial, row)] in trial order, and entity -> its static row."""
    rows: dict[str, list[tuple[int, dict[str, Any]]]] = defaultdict(list)
    static: dict[str, dict[str, Any]] = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch().to_pylist()
        for row in batch:
            if chunk.is_static:
                static.setdefault(chunk.entity_path, {}).update({k: v for k, v in row.items() if v is not None})
            elif row.get("trial") is not None:
                rows[chunk.entity_path].append((row["trial"], row))
    for r in rows.values():
        r.sort(key=lambda x: x[0])
    return rows, static


def _latest(rows: list[tuple[int, dict[str, Any]]], trial: int) -> dict[str, Any] | None:
    at = [r for t, r in rows if t <= trial]
    return at[-1] if at else None


def _axis_map(static: dict[str, dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Scene coordinate -> value of each axis, fitted to the tick labels: (slope, offset) for x
    (from the labels below the box, one row) and for y (the labels left of it, one column)."""
    ticks = static["/study/plane/ticks"]
    pos, labels = np.array(ticks["Points2D:positions"]), [float(s) for s in ticks["Points2D:labels"]]
    below = pos[:, 1] == pos[:, 1].max()
    left = pos[:, 0] == pos[:, 0].min()
    assert below.sum() >= 3 and left.sum() >= 3 and not (below & left).any(), pos
    vals = np.array(labels)
    fx = np.polyfit(pos[below, 0], vals[below], 1)
    fy = np.polyfit(pos[left, 1], vals[left], 1)
    assert np.allclose(np.polyval(fx, pos[below, 0]), vals[below], atol=1e-6), "x ticks not evenly spaced (float32 positions)"
    assert np.allclose(np.polyval(fy, pos[left, 1]), vals[left], atol=1e-6), "y ticks not evenly spaced"
    return fx, fy


def test_every_trial_stays_a_point_on_labelled_axes(study_rrd: Path) -> None:
    """After each trial the plane's ``trials`` batch holds every completed trial so far, each at
    its (false tracks, Pd) as the tick labels read it, y up; the failed trial is not there."""
    rows, static = _rows(study_rrd)
    fx, fy = _axis_map(static)
    assert fx[0] > 0 and fy[0] < 0, "x must grow rightwards and Pd upwards (scene y flipped)"
    titles = static["/study/plane/titles"]["Points2D:labels"]
    assert any("false tracks per frame" in s for s in titles) and any(s.startswith("Pd") for s in titles)
    done = [i for i, p in enumerate(POINTS) if p is not None]
    for trial in range(len(POINTS)):
        row = _latest(rows["/study/plane/trials"], trial)
        expected = [i for i in done if i <= trial]
        assert row is not None and len(row["Points2D:positions"]) == len(expected), trial
        numbers = [int(s.split(":")[0].split()[1]) for s in row["Points2D:labels"]]
        assert numbers == expected
        for n, (x, y) in zip(numbers, row["Points2D:positions"]):
            pd, fa = POINTS[n]
            assert np.polyval(fx, x) == pytest.approx(fa, abs=1e-6)
            assert np.polyval(fy, y) == pytest.approx(pd, abs=1e-6)
    # every point inside the axes' range
    xs = [x for x, _ in row["Points2D:positions"]]
    ys = [y for _, y in row["Points2D:positions"]]
    strips = static["/study/plane/axes"]["LineStrips2D:strips"][0]
    (x0, y0), (x1, y1) = np.min(strips, axis=0), np.max(strips, axis=0)
    assert x0 <= min(xs) and max(xs) <= x1 and y0 <= min(ys) and max(ys) <= y1


def test_defaults_and_best_are_marked(study_rrd: Path) -> None:
    """The defaults (trial 0) stay marked from trial 0 on; the best mark follows the best MOTA
    so far, and at the end sits on the study's best trial; the legend names both."""
    rows, static = _rows(study_rrd)
    fx, fy = _axis_map(static)

    def where(pos: list[float]) -> tuple[float, float]:
        return float(np.polyval(fy, pos[1])), float(np.polyval(fx, pos[0]))

    last = len(POINTS) - 1
    defaults = _latest(rows["/study/plane/defaults"], last)
    assert defaults is not None and defaults["Points2D:labels"] == ["defaults (trial 0)"]
    assert where(defaults["Points2D:positions"][0]) == pytest.approx(POINTS[0])
    for trial in range(len(POINTS)):
        so_far = [i for i, p in enumerate(POINTS[:trial + 1]) if p is not None]
        best = max(so_far, key=lambda i: (_mota(*POINTS[i]), -i))
        row = _latest(rows["/study/plane/best"], trial)
        assert row is not None and row["Points2D:labels"] == [f"best: trial {best}"], trial
        assert where(row["Points2D:positions"][0]) == pytest.approx(POINTS[best])
    legend = _latest(rows["/study/plane/legend"], last)
    assert legend is not None and legend["Points2D:labels"] == [
        f"trials ({sum(p is not None for p in POINTS)})", "Pareto front", "defaults: trial 0", f"best: trial {best}"]
    colors = {static_or_row["Points2D:colors"][0]
              for static_or_row in (defaults, _latest(rows["/study/plane/best"], last),
                                    _latest(rows["/study/plane/trials"], last))}
    assert len(colors) == 3, "defaults, best and the other trials need their own colours"


def test_pareto_study_marks_its_front(tmp_path: Path) -> None:
    """A ``pareto`` study: the best marks are the front's trials (no other beats them on both)."""
    rrd = record_study(tmp_path / "p.rrd", [_with_values(t) for t in _trials()], _settings("pareto"))
    rows, _ = _rows(rrd)
    row = _latest(rows["/study/plane/best"], len(POINTS) - 1)
    assert row is not None
    marked = sorted(int(s.split()[1]) for s in row["Points2D:labels"])
    pts = {i: p for i, p in enumerate(POINTS) if p is not None}
    front = sorted(i for i, (pd, fa) in pts.items()
                   if not any(q[0] >= pd and q[1] <= fa and q != (pd, fa) for q in pts.values()))
    assert marked == front and len(front) >= 3
    strip = _latest(rows["/study/plane/front"], len(POINTS) - 1)
    assert strip is not None and len(strip["LineStrips2D:strips"][0]) == len(front)


def _with_values(t: Any) -> Any:
    if t.values is not None:
        t.values = [t.user_attrs["tune"]["pd"], t.user_attrs["tune"]["fa"]]
    return t


def test_parameters_on_their_search_range(study_rrd: Path) -> None:
    """``study/params_scaled`` holds every parameter within 0 … 1: linear for k_sigma, in log for
    a log-searched one, a choice by its index; the raw values stay in ``study/params``."""
    rows, static = _rows(study_rrd)
    done = [i for i, p in enumerate(POINTS) if p is not None]
    scaled = {e.rsplit("/", 1)[1]: [r["Scalars:scalars"][0] for _, r in v]
              for e, v in rows.items() if e.startswith("/study/params_scaled/")}
    assert set(scaled) == {"detection.k_sigma", "tracking.false_tracks_per_1000", "tracking.confirm"}
    for name, values in scaled.items():
        assert len(values) == len(done) and all(0.0 <= v <= 1.0 for v in values), name
    assert scaled["detection.k_sigma"] == pytest.approx([(K_SIGMA[i] - 3.0) / 3.0 for i in done])
    assert scaled["tracking.false_tracks_per_1000"] == pytest.approx(
        [math.log(FTP[i] / 0.05) / math.log(20.0 / 0.05) for i in done])
    assert min(scaled["tracking.false_tracks_per_1000"]) == 0.0 and max(scaled["tracking.false_tracks_per_1000"]) == 1.0
    assert scaled["tracking.confirm"] == [float(i % 2) for i in done]
    raw = [r["Scalars:scalars"][0] for _, r in rows["/study/params/detection.k_sigma"]]
    assert raw == [K_SIGMA[i] for i in done]
    names = static["/study/params_scaled/tracking.false_tracks_per_1000"]["SeriesLines:names"]
    assert names == ["tracking.false_tracks_per_1000 [0.05, 20] log"]


def test_one_colour_per_metric_and_parameter(study_rrd: Path) -> None:
    """A metric has the same colour on the tune and the validation clips, a parameter the same
    in raw units and on its range; no two metrics, no two parameters share one."""
    _, static = _rows(study_rrd)

    def color(entity: str) -> int:
        return static[entity]["SeriesLines:colors"][0]

    metrics = ("mota", "idf1", "pd", "fa", "idsw")
    for m in metrics:
        assert color(f"/study/tune/{m}") == color(f"/study/validate/{m}"), m
    assert len({color(f"/study/tune/{m}") for m in metrics}) == len(metrics)
    params = ("detection.k_sigma", "tracking.false_tracks_per_1000", "tracking.confirm")
    for p in params:
        assert color(f"/study/params/{p}") == color(f"/study/params_scaled/{p}"), p
    assert len({color(f"/study/params/{p}") for p in params}) == len(params)


def test_default_timeline_is_the_only_sequence_one(tmp_path: Path) -> None:
    """``frame`` when there is one; else the only sequence timeline; several and no ``frame``:
    one line naming them."""
    import rerun as rr

    from wfviz.record.screenshot import pick_timeline

    path = tmp_path / "two.rrd"
    rec = rr.RecordingStream("wfviz_test")
    rec.save(str(path))
    for t in range(3):
        rec.set_time("trial", sequence=t)
        rec.set_time("step", sequence=2 * t)
        rec.log("x", rr.Scalars(float(t)))
    rec.flush()
    rec.disconnect()
    with pytest.raises(ValueError, match=r"has no frame timeline: give --timeline \(its sequence timelines: step, trial\)"):
        pick_timeline(path)
    assert pick_timeline(path, "step") == "step"


@needs_vulkan
def test_screenshot_shows_every_trial_on_labelled_axes(study_rrd: Path, tmp_path: Path) -> None:
    """``wfviz screenshot --timeline trial study.rrd`` (and without ``--timeline``) exits 0; the
    picture shows, in the plane, one dot per completed trial (the defaults and the best under
    their own larger marks), the legend's marks and the two axes as long lines."""
    import cv2

    from wfviz.tune.palette import AXIS_COLOR, BEST_COLOR, DEFAULTS_COLOR, TRIAL_COLOR

    completed = sum(p is not None for p in POINTS)
    for name, args in (("t.png", ["--timeline", "trial"]), ("d.png", [])):
        png = tmp_path / name
        proc = wfviz("screenshot", str(study_rrd), *args, "-o", str(png), "--width", "1600", "--height", "1000",
                     timeout=180)
        assert proc.returncode == 0, proc.stderr
        bgr = cv2.imread(str(png))
        plane = bgr[40: int(0.75 * bgr.shape[0]), bgr.shape[1] // 2:]  # the right column's upper view
        hsv = cv2.cvtColor(plane, cv2.COLOR_BGR2HSV).astype(np.int32)

        def blobs(color: tuple[int, int, int], min_area: int, hsv: np.ndarray = hsv) -> int:
            """Round patches of ``color``'s hue (the marks are shaded; a label's letters, in its
            mark's colour, are thinner: at most 40 px, a 4-point dot about 55)."""
            h, sat, _ = cv2.cvtColor(np.uint8([[color[::-1]]]), cv2.COLOR_BGR2HSV)[0, 0].astype(int)
            dh = np.abs(hsv[..., 0] - h)
            mask = (np.minimum(dh, 180 - dh) <= 8) & (hsv[..., 1] >= 0.6 * sat) & (hsv[..., 2] >= 90)
            _, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
            return sum(1 for s in stats[1:] if s[cv2.CC_STAT_AREA] >= min_area
                       and s[cv2.CC_STAT_AREA] >= 0.65 * s[cv2.CC_STAT_WIDTH] * s[cv2.CC_STAT_HEIGHT]
                       and 0.7 <= s[cv2.CC_STAT_WIDTH] / s[cv2.CC_STAT_HEIGHT] <= 1.4)

        # the legend's marks: one each; the defaults' and the best's marks hide their trials' dots
        assert blobs(TRIAL_COLOR, 45) == completed - 2 + 1, f"{name}: a dot per trial"
        assert blobs(DEFAULTS_COLOR, 80) == 2 and blobs(BEST_COLOR, 80) == 2, name
        rgb = cv2.cvtColor(plane, cv2.COLOR_BGR2RGB).astype(np.int32)
        axis = np.abs(rgb - np.array(AXIS_COLOR)).max(axis=2) <= 25
        assert axis.sum(axis=1).max() > 0.3 * plane.shape[1], f"{name}: no x axis"
        assert axis.sum(axis=0).max() > 0.3 * plane.shape[0], f"{name}: no y axis"
