"""Where the runs of ``wfviz compare`` disagree, frame by frame.

With truth, each run's confirmed tracks are matched to the visible targets as the scores match
them (:func:`wfviz.evaluate.frame_errors`: optimal assignment within the gate or inside the
target's box when the truth has one, tracks on hidden targets left out). A frame disagrees where

- ``missed``: a target is matched by some runs and missed by the others;
- ``false_track``: a false track (a confirmed track matched to no target) that not every run
  has (false tracks of different runs within the gate of each other are the same one);
- ``switch``: a target matched by another track than the one that last matched it, in some run
  but not in every run.

Without truth, ``unmatched``: a confirmed track that not every run has within the gate.
Each disagreement has a key that stays the same while it lasts, so that its start and end can
be told (:attr:`FrameComparison.began`, :attr:`FrameComparison.ended`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from wfviz.evaluate import Box, Point, _assign, _drop_hidden

KINDS = ("missed", "false_track", "switch", "unmatched")


@dataclass(frozen=True)
class Mark:
    """One disagreement on one frame: its kind, where (x, y), its key, a line naming the
    runs, and the runs that have it (for ``missed``: the runs that missed)."""

    kind: str
    x: float
    y: float
    key: tuple
    text: str
    runs: tuple[str, ...]


@dataclass(frozen=True)
class RunFrame:
    """One run on one frame: Pd (matched / visible targets; NaN without truth or target), false
    tracks, mean centroid error of its matches (px; NaN: none) and confirmed tracks."""

    pd: float
    false_tracks: float
    cle: float
    tracks: int


@dataclass(frozen=True)
class FrameComparison:
    """A frame's disagreements (``marks``), those that began and those that ended on it, and
    every run's :class:`RunFrame`."""

    frame: int
    marks: tuple[Mark, ...]
    began: tuple[Mark, ...]
    ended: tuple[Mark, ...]
    runs: tuple[RunFrame, ...]


def _names(labels: Sequence[str]) -> str:
    return ", ".join(labels)


def clusters(points: Sequence[Sequence[Point]], gate: float) -> list[list[tuple[int, Point]]]:
    """Points of several runs grouped into clusters of at most one point per run: each run's
    points are assigned (optimally, within ``gate`` px of the cluster's mean) to the clusters of
    the runs before it; the rest start clusters of their own. Members are (run, point)."""
    groups: list[list[tuple[int, Point]]] = []
    for r, pts in enumerate(points):
        centres = [(0, float(np.mean([p[1] for _, p in g])), float(np.mean([p[2] for _, p in g]))) for g in groups]
        pairs = _assign(centres, list(pts), gate)
        taken = set()
        for i, j, _ in pairs:
            groups[i].append((r, pts[j]))
            taken.add(j)
        groups += [[(r, p)] for j, p in enumerate(pts) if j not in taken]
    return groups


class Disagreements:
    """Compares the runs frame by frame (see the module's docstring); :meth:`update` once a
    frame, in order."""

    def __init__(self, labels: Sequence[str], gate: float = 3.0) -> None:
        self.labels = tuple(labels)
        self.gate = gate
        self._last: list[dict[int, int]] = [{} for _ in self.labels]  # per run: target -> track last matched
        self._active: dict[tuple, Mark] = {}

    def update(self, frame: int, points: Sequence[Sequence[Point]], shown: Sequence[Point] | None = None,
               hidden: Sequence[Point] = (), boxes: Mapping[int, Box] | None = None) -> FrameComparison:
        """``points``: every run's confirmed (track_id, x, y); ``shown``/``hidden``: the visible
        and don't-care targets of the frame (None: no truth); ``boxes``: their {target_id: (w, h)}."""
        if shown is None:
            marks, runs = self._without_truth(points)
        else:
            marks, runs = self._with_truth(points, shown, hidden, boxes)
        now = {m.key: m for m in marks}
        began = tuple(m for m in marks if m.key not in self._active)
        ended = tuple(m for k, m in self._active.items() if k not in now and m.kind != "switch")
        self._active = now
        return FrameComparison(frame, tuple(marks), began, ended, tuple(runs))

    def _with_truth(self, points: Sequence[Sequence[Point]], shown: Sequence[Point], hidden: Sequence[Point],
                    boxes: Mapping[int, Box] | None = None) -> tuple[list[Mark], list[RunFrame]]:
        n, g = len(self.labels), self.gate
        matched: list[dict[int, int]] = []
        false: list[list[Point]] = []
        runs = []
        switched: dict[int, list[tuple[int, int, int]]] = {}
        for r, pts in enumerate(points):
            kept = _drop_hidden(list(pts), list(shown), list(hidden), g, boxes)
            pairs = _assign(list(shown), kept, g, boxes)
            m = {shown[i][0]: kept[j][0] for i, j, _ in pairs}
            used = {j for _, j, _ in pairs}
            false.append([p for j, p in enumerate(kept) if j not in used])
            matched.append(m)
            for tid, track in m.items():
                before = self._last[r].get(tid)
                if before is not None and before != track:
                    switched.setdefault(tid, []).append((r, before, track))
                self._last[r][tid] = track
            runs.append(RunFrame(len(m) / len(shown) if shown else math.nan, float(len(false[-1])),
                                 float(np.mean([d for *_, d in pairs])) if pairs else math.nan,
                                 len(pts)))
        marks: list[Mark] = []
        for tid, x, y in shown:
            have = [self.labels[r] for r in range(n) if tid in matched[r]]
            if 0 < len(have) < n:
                miss = tuple(self.labels[r] for r in range(n) if tid not in matched[r])
                marks.append(Mark("missed", x, y, ("missed", tid, miss),
                                  f"T{tid} missed by {_names(miss)} (matched by {_names(have)})", miss))
        where = {tid: (x, y) for tid, x, y in shown}
        for tid, sw in switched.items():
            if len(sw) < n:
                for r, before, track in sw:
                    marks.append(Mark("switch", *where[tid], ("switch", tid, self.labels[r], track),
                                      f"T{tid}: identity switch in {self.labels[r]} (track {before} -> {track})",
                                      (self.labels[r],)))
        for c in clusters(false, g):
            if len(c) < n:
                marks.append(self._cluster_mark("false_track", c, "false track"))
        return marks, runs

    def _without_truth(self, points: Sequence[Sequence[Point]]) -> tuple[list[Mark], list[RunFrame]]:
        runs = [RunFrame(math.nan, math.nan, math.nan, len(p)) for p in points]
        return [self._cluster_mark("unmatched", c, "track") for c in clusters(points, self.gate)
                if len(c) < len(self.labels)], runs

    def _cluster_mark(self, kind: str, members: list[tuple[int, Point]], what: str) -> Mark:
        have = tuple(self.labels[r] for r, _ in members)
        lack = tuple(label for label in self.labels if label not in have)
        ids = ", ".join(f"{self.labels[r]} {p[0]}" for r, p in members)
        x = float(np.mean([p[1] for _, p in members]))
        y = float(np.mean([p[2] for _, p in members]))
        text = f"{what} only in {ids}, not in {_names(lack)}"
        return Mark(kind, x, y, (kind, tuple((self.labels[r], p[0]) for r, p in members)), text, have)
