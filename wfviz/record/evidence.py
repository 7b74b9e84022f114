"""Why a track was born, held back or lost, as recording entities (see docs/recording.md): the
explanation of each frame (a cause per truth point, the misses and the false tracks, from
:mod:`wfviz.explain`), each track's confirmation and deletion tests against their levels (from
the track manager's :class:`~wfviz.tracking.decision.Verdicts`), the overlays' class tables
(annotation contexts: labels on hover) and the legend drawn beside the camera view."""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
import rerun as rr

from wfviz.record.colors import target_color, track_color
from wfviz.explain.types import MISSES, Cause, FalseCause, FrameExplanation
from wfviz.tracking.decision import Verdicts
from wfviz.tracking.tracks import TrackState

Color = tuple[int, ...]


class Recorder(Protocol):
    """What the evidence logs through (:class:`wfviz.record.recorder.Recorder`)."""

    rec: Any

    def text(self, message: str, level: str = "INFO", path: str = "log") -> None: ...

    def scalar(self, path: str, value: float) -> None: ...

    def name_series(self, path: str, name: str | list[str], color: Color | list[Color] | None = None,
                    width: float | list[float] | None = None) -> None: ...

#: wfviz compare's marks (:mod:`wfviz.record.compare`), reused by a single recording's explanation
MISSED_COLOR: Color = (255, 40, 40)
FALSE_TRACK_COLOR: Color = (255, 160, 0)
MARK_RADIUS = 6.0
MISS_RADIUS = 8.0  # px: a miss, larger than the other marks and far larger than a defect's dot (2 px)
CAUSE_RADIUS = 4.5  # px: a ring inside the marks, around the detection and the truth point

#: 2-D draw order of the camera overlays (higher on top; Rerun's defaults: images -10,
#: segmentation images 0, boxes 10, lines 20, points 30)
DRAW_SEARCH_REGION = 0.5
DRAW_BAD_PIXELS = 24.0
DRAW_MARKS = 25.0
DRAW_MISSES = 25.5  # over the other marks and the defects, under the cause rings and the tracks
DRAW_CAUSES = 26.0
DRAW_CLUTTER = 28.0
DRAW_DETECTIONS = 30.0
DRAW_TRACKS = 31.0  # predictions and measurements
DRAW_TRUTH = 32.0  # small, over the prediction and the detection that should sit on it

#: a cause's class id (its place in :class:`Cause`, from 1), label (on hover), short label (the
#: legend's) and colour
CAUSE_STYLE: dict[Cause, tuple[int, str, str, Color]] = {
    Cause.MATCHED: (1, "matched", "matched", (60, 210, 90)),
    Cause.HIDDEN: (2, "hidden (don't care)", "hidden", (140, 140, 140)),
    Cause.OUTSIDE_CIRCLE: (3, "outside the imaging circle", "outside circle", (200, 60, 255)),
    Cause.OUTSIDE_REGION: (4, "outside the searched region", "outside region", (80, 120, 255)),
    Cause.NOT_DETECTED: (5, "not detected", "not detected", (255, 40, 40)),
    Cause.NOT_ASSOCIATED: (6, "detected, not associated", "not associated", (255, 120, 0)),
    Cause.LATENCY: (7, "latency (its track is too young)", "latency", (120, 220, 255)),
    Cause.NOT_CONFIRMED: (8, "not confirmed (held back by a test)", "not confirmed", (255, 90, 200)),
    Cause.LOST: (9, "lost (its track is off it or deleted)", "lost", (180, 30, 30)),
}
FALSE_LABELS: dict[FalseCause, tuple[int, str]] = {
    FalseCause.STATIC_IN_SCENE: (1, "false track: static in the scene"),
    FalseCause.CAMERA_MOTION: (2, "false track: camera motion"),
    FalseCause.STRUCTURE: (3, "false track: structure"),
    FalseCause.DEFECT: (4, "false track: sensor defect"),
    FalseCause.DUPLICATE: (5, "false track: duplicate"),
    FalseCause.OFF_TARGET: (6, "false track: off target"),
    FalseCause.UNKNOWN: (7, "false track: unknown"),
    FalseCause.HOPPING: (8, "false track: hopping between spots"),
}
#: a test held back a tentative track this many consecutive frames: one log line
HELD_FRAMES = 25
#: significance, change and threshold of a truth point (explain/T<id>/<part>)
EXPLAIN_PARTS = ("significance", "change", "threshold")


def class_context(classes: Sequence[tuple[int, str, Color]]) -> rr.AnnotationContext:
    """An annotation context of (class id, label, colour) rows."""
    return rr.AnnotationContext([rr.ClassDescription(info=rr.AnnotationInfo(id=i, label=label, color=color))
                                 for i, label, color in classes])


def cause_classes() -> list[tuple[int, str, Color]]:
    """The classes of ``camera/causes``: one per :class:`Cause`."""
    return [(i, label, color) for i, label, _, color in (CAUSE_STYLE[c] for c in Cause)]


def cause_legend() -> list[tuple[str, Color]]:
    """The legend's rows of the causes (short labels)."""
    return [("cause (ring):", (200, 200, 200))] + [(short, color) for _, _, short, color in
                                                   (CAUSE_STYLE[c] for c in Cause)]


def false_classes() -> list[tuple[int, str, Color]]:
    """The classes of ``camera/false_tracks``: one per :class:`FalseCause`, all in the compare mark's colour."""
    return [(i, label, FALSE_TRACK_COLOR) for i, label in (FALSE_LABELS[c] for c in FalseCause)]


def test_slug(name: str) -> str:
    """A test's name as an entity path part: "motion: T²" -> "motion_t2"."""
    return re.sub(r"[^a-z0-9]+", "_", name.replace("²", "2").lower()).strip("_") or "test"


class TestLog:
    """Each track's confirmation and deletion tests, per frame, against their levels:
    ``tests/<track_id>/<test>``, two series (the statistic, its level) in one entity (a chunk
    each: a real clip has dozens of tentative tracks old enough). Every test of the confirmed
    tracks; of the tentative ones with at least ``verdicts.min_hits`` hits (younger ones cannot
    have been confirmed yet: not logged, which keeps hundreds of young tracks a frame out of the
    recording), the confirmation tests that have held them back, from the first frame each did
    (a test that always held does not explain, a deletion is the log's event line); a log line
    when one test has held a tentative track back :data:`HELD_FRAMES` frames in a row.
    Series of confirmed tracks are named ``track N`` and ``track N level`` (static ``SeriesLines``,
    in the track's colour); the others are not (a static entity each)."""

    __test__ = False  # not a pytest class

    def __init__(self, recorder: Recorder) -> None:
        self.recorder = recorder
        self.slugs: dict[str, str] = {}  # test name -> path part, in the order first seen
        self.logged: set[int] = set()  # tracks with series
        self.named: set[int] = set()  # tracks whose series are named
        self.failing: dict[int, set[str]] = {}  # tentative track -> tests that have held it back
        self.held: dict[int, tuple[str, int]] = {}  # tentative track -> (test holding it back, frames)

    def log(self, verdicts: Verdicts, tracks: Sequence[TrackState]) -> None:
        """This frame's tests of the tracks shown (see the class docstring)."""
        d = verdicts.decisions
        stats = d.statistics
        ids = verdicts.ids
        if not stats or not len(ids):
            return
        confirmed = verdicts.confirmed | d.confirm
        ended = d.delete | verdicts.gone
        if confirmed.all():
            rows = np.arange(len(ids))
        else:  # one pass over the tracks: hundreds of young ones are common
            need = verdicts.min_hits
            shown = {t.track_id for t in tracks if t.hits >= need} | self.logged
            conf = confirmed.tolist()
            rows = np.array([r for r, i in enumerate(ids.tolist()) if conf[r] or i in shown], dtype=np.int64)
        if not len(rows):
            return
        rec = self.recorder
        put = rec.columns.pair
        frame, time = rec.now
        slugs = [self.slugs.get(s.name) or self.slugs.setdefault(s.name, test_slug(s.name)) for s in stats]
        values = [s.value[rows].tolist() for s in stats]
        levels = [np.broadcast_to(np.asarray(s.level, dtype=np.float64), ids.shape)[rows].tolist() for s in stats]
        holds = [s.holds[rows].tolist() for s in stats]
        confirming = [j for j, s in enumerate(stats) if not s.deletes]
        every = range(len(stats))
        row_ids = ids[rows].tolist()
        for k, tid in enumerate(row_ids):
            if confirmed[rows[k]]:
                if tid not in self.named:
                    self._name(tid, slugs)
                chosen: Sequence[int] = every
            else:  # the confirmation tests that have held it back (from the first frame each did)
                failing = self.failing.setdefault(tid, set())
                failing.update(slugs[j] for j in confirming if not holds[j][k] and not math.isnan(values[j][k]))
                chosen = [j for j in confirming if slugs[j] in failing]
            self.logged.add(tid)
            base = f"tests/{tid}/"
            for j in chosen:
                level = levels[j][k]
                put(base + slugs[j], frame, time, values[j][k], level if math.isfinite(level) else math.nan)
        self._held_back(verdicts, rows, row_ids, confirmed, ended)
        for k, tid in enumerate(row_ids):
            if ended[rows[k]]:
                self.logged.discard(tid)
                self.failing.pop(tid, None)

    def _held_back(self, verdicts: Verdicts, rows: np.ndarray, row_ids: list[int], confirmed: np.ndarray,
                   ended: np.ndarray) -> None:
        """Count the frames each tentative track shown is held back by one test (the first
        confirmation test that does not hold, as :class:`~wfviz.tracking.decision.Decision`
        names it); one INFO line when a count reaches :data:`HELD_FRAMES`."""
        stats = verdicts.decisions.statistics
        held: dict[int, tuple[str, int]] = {}
        for k, tid in enumerate(row_ids):
            r = int(rows[k])
            if confirmed[r] or ended[r]:
                continue
            s = next((s for s in stats if not s.deletes and not s.holds[r] and not math.isnan(s.value[r])), None)
            if s is None:
                continue
            test, n = self.held.get(tid, ("", 0))
            n = n + 1 if test == s.name else 1
            held[tid] = (s.name, n)
            if n == HELD_FRAMES:
                self.recorder.text(f"track {tid} held back {HELD_FRAMES} frames by {s.check(r)}", "INFO")
        self.held = held

    def _name(self, tid: int, slugs: list[str]) -> None:
        """Name a confirmed track's series (its value and level per test)."""
    
        self.named.add(tid)
        color = track_color(tid)
        for slug in slugs:
            self.recorder.name_series(f"tests/{tid}/{slug}", [f"track {tid}", f"track {tid} level"], [color, color],
                                      [2.0, 1.0])

    def views(self) -> list[tuple[str, str]]:
        """(test name, path part) of every test seen, in order."""
        return list(self.slugs.items())


class ExplanationLog:
    """A frame's :class:`FrameExplanation` in the recording: per truth target its significance,
    change and threshold (σ) as series, a marker per truth point coloured by its cause
    (``camera/causes``), the misses and the false tracks marked as ``wfviz compare`` marks them
    (``camera/misses``, ``camera/false_tracks``)."""

    def __init__(self, recorder: Recorder, on_first: Callable[[], None]) -> None:
        self.recorder = recorder
        self.on_first = on_first
        self.targets: set[int] = set()
        self._empty: dict[str, bool] = {}  # entity -> its last batch was empty
        self.started = False

    def log(self, expl: FrameExplanation) -> None:
        """One frame's explanation, at the recorder's current frame."""
        rec = self.recorder
        if not self.started:
            self.started = True
            self._contexts()
            self.on_first()
        for t in expl.truth:
            if t.target_id not in self.targets:
                self._name_target(t.target_id)
            base = f"explain/T{t.target_id}/"
            rec.scalar(base + "significance", t.significance)
            rec.scalar(base + "change", t.change)
            rec.scalar(base + "threshold", t.threshold)
        truth = expl.truth
        xy = np.array([(t.x, t.y) for t in truth], dtype=np.float32).reshape(-1, 2)
        labels = [f"T{t.target_id} {CAUSE_STYLE[t.cause][1]}" + (f": {t.detail}" if t.detail else "") for t in truth]
        self._points("camera/causes", rr.Points2D(
            xy, class_ids=np.array([CAUSE_STYLE[t.cause][0] for t in truth], dtype=np.uint16), labels=labels,
            radii=CAUSE_RADIUS, draw_order=DRAW_CAUSES, show_labels=False), rr.AnyValues(
            cause=[str(t.cause) for t in truth], detail=[t.detail for t in truth],
            significance=[t.significance for t in truth], residual=[t.residual for t in truth],
            change=[t.change for t in truth], threshold=[t.threshold for t in truth],
            det_dist=[t.det_dist for t in truth],
            track=[-1 if t.track_id is None else t.track_id for t in truth]) if truth else None, empty=not truth)
        missed = [k for k, t in enumerate(truth) if t.cause in MISSES]
        self._points("camera/misses", rr.Points2D(
            xy[missed], class_ids=1, labels=[f"T{truth[k].target_id} missed: {labels[k].split(' ', 1)[1]}" for k in missed],
            colors=MISSED_COLOR, radii=MISS_RADIUS, draw_order=DRAW_MISSES, show_labels=False), empty=not missed)
        false = expl.false
        self._points("camera/false_tracks", rr.Points2D(
            np.array([(f.x, f.y) for f in false], dtype=np.float32).reshape(-1, 2),
            class_ids=np.array([FALSE_LABELS[f.cause][0] for f in false], dtype=np.uint16),
            labels=[f"track {f.track_id} {FALSE_LABELS[f.cause][1]}" + (f": {f.detail}" if f.detail else "")
                    for f in false],
            colors=FALSE_TRACK_COLOR, radii=MARK_RADIUS, draw_order=DRAW_MARKS, show_labels=False), empty=not false)

    def _points(self, path: str, points: rr.Points2D, extra: rr.AnyValues | None = None,
                empty: bool = False) -> None:
        """Log ``points`` (with ``extra``), but an empty batch only once in a row (the viewer
        keeps showing the last one: nothing)."""
        if empty and self._empty.get(path, False):
            return
        self._empty[path] = empty
        if extra is None:
            self.recorder.rec.log(path, points)
        else:
            self.recorder.rec.log(path, points, extra)

    def _contexts(self) -> None:
        rec = self.recorder.rec
        rec.log("camera/causes", class_context(cause_classes()), static=True)
        rec.log("camera/misses", class_context([(1, "missed", MISSED_COLOR)]), static=True)
        rec.log("camera/false_tracks", class_context(false_classes()), static=True)

    def _name_target(self, target_id: int) -> None:
        self.targets.add(target_id)
        color = target_color(target_id)
        dim = tuple(int(c * 0.6) for c in color)
        for part, c, w in zip(EXPLAIN_PARTS, (color, dim, (200, 200, 200)), (2.0, 1.5, 1.0)):
            self.recorder.name_series(f"explain/T{target_id}/{part}", f"T{target_id} {part} (σ)", c, w)
