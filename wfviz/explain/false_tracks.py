"""The cause of every confirmed track point that matches no truth
(:class:`~wfviz.explain.types.FalseCause`), decided by the first of these rules that holds
(docs/debugging.md, "False tracks"):

1. ``duplicate``: within ``DUPLICATE_GATES`` gates of a visible target another track matches;
2. ``off_target``: the track matched a target before (it drifted off, or the target left it);
3. ``defect``: within 1 px of a pixel flagged as a sensor defect;
4. ``camera_motion``: it moves (``MIN_SPEED`` px/frame at least) and so do ``COMMON_TRACKS`` - 1
   other tracks matching no truth (tentative ones with ``MIN_HITS`` hits included) with a velocity
   within ``COMMON_VELOCITY`` px/frame of its own, and the camera's motion was not measured (not
   compensated, or lost) on some frame of its life: the scene moved with the camera (tracks
   moving alike under a measured camera are drifting clutter: ``unknown``, said in the detail);
5. ``static_in_scene``: over its last ``STATIC_FRAMES`` frames (``STATIC_MIN`` at least) its
   positions in the scene (camera motion removed) stay within ``STATIC_SPREAD`` px of their median;
6. ``hopping``: its hits in the scene (its last ``HOP_HITS``, ``STATIC_MIN`` at least, with a
   missed frame among them) progress ``HOP_PROGRESS`` px at least, but between hits of
   consecutive frames less than ``HOP_SHARE`` of what their velocity predicts
   (:func:`wfviz.tracking.confirmation.consecutive_progress`): it made its way in jumps across
   its misses, from one static spot to the next its grown gate caught;
7. ``structure``: on the sky–ground line (within ``HORIZON_RANGE`` px), or its detection is
   elongated (``ELONGATION`` times longer than wide and ``LINE_LENGTH`` px long), extended
   (``EXTENDED_AREA`` px or more) or a ridge (blobness below ``RIDGE_BLOBNESS``), or it slides
   along a line: the components of its last hits (``STATIC_MIN`` at least) are, in the median,
   ``SLIDE_ELONGATION`` times longer along its way in the scene than across it
   (:func:`wfviz.tracking.confirmation.slide`), and that way is ``MIN_SPEED`` px a frame at least;
8. ``unknown``; but a track that had a cause other than ``unknown`` on an earlier frame of its
   life keeps it (said in the detail: "since frame N"): it is still the same spot, chain or
   line, on a frame where its own evidence (a compact hit on its line, a few consecutive hits
   on its last spot) does not show it.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from wfviz.evaluate import FrameErrors
from wfviz.explain.types import FalseCause, FalseExplanation
from wfviz.stages.front_end import FrontEndResult
from wfviz.stages.horizon import horizon_confident
from wfviz.trackers.base import FrameResult
from wfviz.tracking import TrackState
from wfviz.tracking.confirmation import motion, slide

Point = tuple[int, float, float]

DUPLICATE_GATES = 3.0
COMMON_TRACKS = 3
COMMON_VELOCITY = 0.5
MIN_SPEED = 0.3
MIN_HITS = 3
STATIC_FRAMES = 10
STATIC_MIN = 5
STATIC_SPREAD = 1.0
HORIZON_RANGE = 3.0
ELONGATION = 3.0
LINE_LENGTH = 5
EXTENDED_AREA = 30
RIDGE_BLOBNESS = 0.3
HOP_HITS = 32
HOP_SHARE = 0.5
HOP_PROGRESS = 1.5
SLIDE_ELONGATION = 1.75


class FalseCauses:
    """Causes of the false confirmed track points frame after frame (:meth:`explain`); it keeps
    each live track's last ``STATIC_FRAMES`` scene positions and the target each track matched.
    ``gate``: the scorer's match distance (px)."""

    def __init__(self, gate: float) -> None:
        self.gate = gate
        self._scene: dict[int, deque[tuple[float, float]]] = {}
        self._matched: dict[int, tuple[int, int]] = {}  # track -> (target, last frame)
        self._unmeasured: set[int] = set()  # live tracks that lived through a frame of unmeasured camera motion
        self._hits: dict[int, deque[tuple[int, float, float]]] = {}  # track -> its last hits (frame, scene x, y)
        self._shapes: dict[int, deque[tuple[int, int]]] = {}  # track -> its last hits' components (w, h)
        self._count: dict[int, int] = {}  # track -> its hits at the last frame
        self._named: dict[int, tuple[FalseCause, str, int]] = {}  # track -> its first cause other than unknown

    def explain(self, result: FrameResult, shown: list[Point], errors: FrameErrors) -> tuple[FalseExplanation, ...]:
        """The cause of every false alarm of ``errors`` (the scorer's matching of the frame:
        :func:`wfviz.evaluate.frame_errors`) among the tracks of ``result``."""
        f = result.index
        front: FrontEndResult | None = getattr(result, "front", None)
        self._remember(result, front)
        matches = errors.matches
        taken = {track for track, _, _ in matches}
        ids = set(errors.false_tracks)
        false = [t for t in result.tracks if t.track_id in ids]
        common = self._common_motion(result, false, taken)
        static = self._static(false)
        hops = self._hopping(false)
        out = []
        for t in false:
            cause, detail = self._cause(result, front, t, shown, matches, common, static, hops)
            named = self._named.get(t.track_id)
            if cause is FalseCause.UNKNOWN and named is not None:
                cause, detail = named[0], f"since frame {named[2]}: {named[1]}"
            elif cause is not FalseCause.UNKNOWN and named is None:
                self._named[t.track_id] = (cause, detail, f)
            out.append(FalseExplanation(f, t.track_id, t.x, t.y, cause, detail))
        for track, target, _ in matches:
            self._matched[track] = (target, f)
        return tuple(out)

    def _remember(self, result: FrameResult, front: FrontEndResult | None) -> None:
        """Each live track's scene position (its image position minus the camera's offset), and
        the tracks that lived through a frame whose camera motion was not measured."""
        off = front.offset if front is not None else np.zeros(2)
        ox, oy = float(off[0]), float(off[1])
        cam = front.camera if front is not None else None
        unmeasured = cam is None or not cam.reliable
        if cam is not None and cam.lost:  # scene positions before and after are not comparable
            self._hits.clear()
        live = set()
        dets = result.detections
        for t in result.tracks:
            tid = t.track_id
            live.add(tid)
            self._scene.setdefault(tid, deque(maxlen=STATIC_FRAMES)).append((t.x - ox, t.y - oy))
            if unmeasured:
                self._unmeasured.add(tid)
            if t.hits > self._count.get(tid, 0):  # measured this frame
                self._hits.setdefault(tid, deque(maxlen=HOP_HITS)).append((result.index, t.x - ox, t.y - oy))
                j = _nearest(dets, t.x, t.y)
                if j is not None:
                    self._shapes.setdefault(tid, deque(maxlen=STATIC_FRAMES)).append(
                        (int(dets.bbox[j, 2]), int(dets.bbox[j, 3])))
            self._count[tid] = t.hits
        for store in (self._scene, self._hits, self._shapes, self._count, self._named):
            for tid in [k for k in store if k not in live]:
                del store[tid]
        self._unmeasured &= live

    @staticmethod
    def _common_motion(result: FrameResult, false: list[TrackState], taken: set[int]) -> dict[int, str]:
        """{track: detail} of the false tracks that move alike with other tracks (rule 4): the
        live tracks with ``MIN_HITS`` hits or more that match no truth, tentative ones included."""
        if not false:
            return {}
        others = [t for t in result.tracks if t.hits >= MIN_HITS and t.track_id not in taken]
        if len(others) < COMMON_TRACKS:
            return {}
        v = np.array([[t.vx, t.vy] for t in others])
        f = np.array([[t.vx, t.vy] for t in false])
        alike = (np.hypot(f[:, None, 0] - v[None, :, 0], f[:, None, 1] - v[None, :, 1]) <= COMMON_VELOCITY).sum(axis=1)
        moving = np.hypot(f[:, 0], f[:, 1]) >= MIN_SPEED
        out = {}
        for i in np.nonzero((alike >= COMMON_TRACKS) & moving)[0].tolist():  # itself among the alike
            t = false[i]
            out[t.track_id] = (f"moves at ({t.vx:.2f}, {t.vy:.2f}) px/frame with {int(alike[i]) - 1} other "
                               f"unmatched tracks alike: the scene moved")
        return out

    def _static(self, false: list[TrackState]) -> dict[int, tuple[float, int]]:
        """{track: (spread, positions)} of the false tracks with ``STATIC_MIN`` scene positions or
        more: the farthest of their last positions from their median (rule 5), in one pass."""
        rows = [(t.track_id, self._scene[t.track_id]) for t in false
                if len(self._scene.get(t.track_id, ())) >= STATIC_MIN]
        if not rows:
            return {}
        a = np.full((len(rows), STATIC_FRAMES, 2), np.nan)
        for k, (_, q) in enumerate(rows):
            a[k, :len(q)] = q
        d = a - np.nanmedian(a, axis=1)[:, None, :]
        spread = np.nanmax(np.hypot(d[..., 0], d[..., 1]), axis=1)
        return {tid: (float(v), len(q)) for (tid, q), v in zip(rows, spread.tolist())}

    def _hopping(self, false: list[TrackState]) -> dict[int, str]:
        """{track: detail} of the false tracks whose hits hop (rule 6), in one pass; and the way
        of every false track with enough hits (for rule 7's sliding), kept in ``self._way``."""
        self._way: dict[int, np.ndarray] = {}
        rows = [(t.track_id, self._hits[t.track_id]) for t in false
                if len(self._hits.get(t.track_id, ())) >= STATIC_MIN]
        if not rows:
            return {}
        n = len(rows)
        t = np.zeros((n, HOP_HITS))
        xy = np.zeros((n, HOP_HITS, 2))
        ok = np.zeros((n, HOP_HITS), dtype=bool)
        for k, (_, q) in enumerate(rows):
            a = np.asarray(q, dtype=np.float64)
            t[k, :len(a)], xy[k, :len(a)], ok[k, :len(a)] = a[:, 0], a[:, 1:], True
        mo = motion(t, xy, ok, STATIC_SPREAD)
        speed = np.hypot(mo.velocity[:, 0], mo.velocity[:, 1])
        span = np.where(ok, t, -np.inf).max(axis=1) - np.where(ok, t, np.inf).min(axis=1)
        share = mo.consecutive if mo.consecutive is not None else np.full(n, np.nan)
        hop = (speed * span >= HOP_PROGRESS) & (share < HOP_SHARE)
        out = {}
        for k, (tid, q) in enumerate(rows):
            self._way[tid] = mo.velocity[k]
            if hop[k]:
                out[tid] = (f"hops between spots: its {len(q)} hits progress {speed[k] * span[k]:.1f} px in the scene "
                            f"({speed[k]:.2f} px/frame), but between hits of consecutive frames only "
                            f"{100 * share[k]:.0f} % of that pace (< {100 * HOP_SHARE:.0f} %): the rest in jumps "
                            f"across its misses")
        return out

    def _sliding(self, t: TrackState) -> str:
        """Why the track slides along a line (rule 7), or ""."""
        way = self._way.get(t.track_id)
        shapes = self._shapes.get(t.track_id, ())
        if way is None or len(shapes) < STATIC_MIN:
            return ""
        speed = float(np.hypot(*way))
        if speed < MIN_SPEED:
            return ""
        wh = np.asarray(shapes, dtype=np.float64)[None]
        ratio = float(slide(wh, np.ones(wh.shape[:2], dtype=bool), way[None])[0])
        if not ratio >= SLIDE_ELONGATION:
            return ""
        return (f"slides along a line: its last {len(shapes)} hits' components are {ratio:.1f} times longer along "
                f"its way ({speed:.2f} px/frame in the scene) than across it")

    def _cause(self, result: FrameResult, front: FrontEndResult | None, t: TrackState, shown: list[Point],
               matches: tuple[tuple[int, int, float], ...], common: dict[int, str],
               static: dict[int, tuple[float, int]], hops: dict[int, str]) -> tuple[FalseCause, str]:
        for track, target, _ in matches:
            p = next(((x, y) for i, x, y in shown if i == target), None)
            if p is not None and math.hypot(t.x - p[0], t.y - p[1]) <= DUPLICATE_GATES * self.gate:
                return FalseCause.DUPLICATE, (f"{math.hypot(t.x - p[0], t.y - p[1]):.1f} px from target {target}, "
                                              f"which track {track} matches")
        if t.track_id in self._matched:
            target, last = self._matched[t.track_id]
            p = next(((x, y) for i, x, y in shown if i == target), None)
            where = f", now {math.hypot(t.x - p[0], t.y - p[1]):.1f} px from it" if p is not None else ""
            return FalseCause.OFF_TARGET, f"matched target {target} until frame {last}{where}"
        if front is not None and len(front.bad_pixels):
            bad = front.bad_pixels
            r, c = int(round(t.y)), int(round(t.x))
            if ((np.abs(bad[:, 0] - r) <= 1) & (np.abs(bad[:, 1] - c) <= 1)).any():
                return FalseCause.DEFECT, "within 1 px of a pixel flagged as a sensor defect"
        if t.track_id in common and t.track_id in self._unmeasured:
            cam = front.camera if front is not None else None
            state = ("camera motion not compensated" if cam is None else
                     f"camera motion {'measured now' if cam.reliable else 'lost'}, {cam.corners} corners agreed; "
                     f"not measured on some frame of the track")
            return FalseCause.CAMERA_MOTION, f"{common[t.track_id]} ({state})"
        spread, n = static.get(t.track_id, (math.inf, 0))
        if spread <= STATIC_SPREAD:
            return FalseCause.STATIC_IN_SCENE, (f"fixed in the scene: within {spread:.2f} px of one point over "
                                                f"its last {n} frames (camera motion removed)")
        if t.track_id in hops:
            return FalseCause.HOPPING, hops[t.track_id]
        structure = _structure(result, front, t) or self._sliding(t)
        if structure:
            return FalseCause.STRUCTURE, structure
        if t.track_id in common:  # the camera's motion was measured all along: the scene itself moves
            return FalseCause.UNKNOWN, (f"{common[t.track_id].replace(': the scene moved', '')}, with the camera's "
                                        f"motion measured (drifting clutter: clouds, smoke?)")
        return FalseCause.UNKNOWN, ""


def _structure(result: FrameResult, front: FrontEndResult | None, t: TrackState) -> str:
    """Why the track's place is structure (rule 6), or ""."""
    if front is not None and horizon_confident(front.horizon) and front.horizon is not None:
        rows = front.horizon.rows
        c = min(max(int(round(t.x)), 0), len(rows) - 1)
        if np.isfinite(rows[c]) and abs(t.y - rows[c]) <= HORIZON_RANGE:
            return f"on the sky–ground line ({t.y - rows[c]:+.1f} px from it)"
    dets = result.detections
    j = _nearest(dets, t.x, t.y)
    if j is None:
        return ""
    w, h, area = int(dets.bbox[j, 2]), int(dets.bbox[j, 3]), int(dets.area[j])
    if max(w, h) >= ELONGATION * min(w, h) and max(w, h) >= LINE_LENGTH:
        return f"on an elongated component ({w}×{h} px): an edge or a line"
    if area >= EXTENDED_AREA:
        return f"on an extended component ({area} px)"
    blob: Any = dets.blobness
    if blob is not None and blob[j] < RIDGE_BLOBNESS:
        return f"on a ridge (blobness {blob[j]:.2f} < {RIDGE_BLOBNESS})"
    return ""


def _nearest(dets: Any, x: float, y: float) -> int | None:
    """The detection within 2 px of (x, y) nearest to it, or None."""
    if not len(dets):
        return None
    d = np.hypot(dets.xy[:, 0] - x, dets.xy[:, 1] - y)
    j = int(np.argmin(d))
    return j if d[j] <= 2.0 else None
