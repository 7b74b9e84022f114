"""The cause of every truth point of a frame (:class:`~wfviz.explain.types.Cause`), read from
what the stages and the track rules report in the tracker's :class:`~wfviz.trackers.base.FrameResult`
(docs/debugging.md, "How a cause is decided").

A visible point is followed down the pipeline and takes the cause of the first stage it does
not pass: matched by the scorer; inside the imaging circle; inside the searched region; a
detection within the gate; its confirmed track not lost; a track on it; that track confirmed.
Every test reads a value a stage or a rule reported (the search region, the noise level and σ,
the change map, the flagged defects, the detections' labels, the manager's detection-to-track
assignment, the rule's :class:`~wfviz.tracking.decision.Verdicts`), never the tracker's state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Mapping
from typing import Any

import numpy as np

from wfviz.evaluate import Box, matchable
from wfviz.explain.types import Cause, TruthExplanation
from wfviz.stages.detection import Detections
from wfviz.stages.front_end import FrontEndResult
from wfviz.stages.horizon import horizon_confident, search_limit
from wfviz.trackers.base import FrameResult
from wfviz.tracking import Check, Decision, EventKind

Point = tuple[int, float, float]


@dataclass(frozen=True)
class PointSignificance:
    """A truth point's own significance in σ of the local noise (NaN: unknown): the residual's
    and the change's, each the largest over the 3 × 3 pixels around the point (a point target's
    peak may fall on a neighbour), and ``threshold``, the level a detection needed there."""

    residual: float
    change: float
    threshold: float

    @property
    def value(self) -> float:
        """The larger of the two (a detection's significance, :func:`wfviz.stages.detection.detect`)."""
        vals = [v for v in (self.residual, self.change) if not math.isnan(v)]
        return max(vals) if vals else math.nan


def _window(shape: tuple[int, ...], r: int, c: int) -> tuple[slice, slice]:
    """The 3 × 3 pixels around (r, c), clipped to ``shape``."""
    return slice(max(r - 1, 0), min(r + 2, shape[0])), slice(max(c - 1, 0), min(c + 2, shape[1]))


def point_significance(front: FrontEndResult, r: int, c: int, k_sigma: float) -> PointSignificance:
    """:class:`PointSignificance` at pixel (row ``r``, column ``c``) of a frame through the shared
    front end; ``k_sigma``: the frame's detection threshold (σ), where no local map lowers it."""
    noise, win = front.noise, _window(front.suppressed.shape, r, c)
    if noise is None:
        return PointSignificance(math.nan, math.nan, math.nan)
    level, sigma = noise.level[win].astype(np.float64), np.maximum(noise.sigma[win].astype(np.float64), 1e-12)
    z = (front.suppressed[win].astype(np.float64) - level) / sigma
    k = k_sigma
    dets = front.detections
    if dets.threshold_map is not None:  # the level at this pixel (lower in a confirmed gate)
        k = float(((dets.threshold_map[r, c] - noise.level[r, c]) / max(float(noise.sigma[r, c]), 1e-12)))
    change = math.nan
    if front.change is not None:
        ch = front.change[win]
        change = float(np.nanmax(ch)) if np.isfinite(ch).any() else math.nan
    return PointSignificance(float(z.max()), change, k)


def held_by(decision: Decision | None) -> Check | None:
    """The confirmation test that held a tentative track back in ``decision`` (its
    :attr:`~wfviz.tracking.decision.Decision.test`; None: none did, or no decision)."""
    if decision is None or not decision.test:
        return None
    return next((c for c in decision.checks if c.name == decision.test and not c.deletes), None)


class TruthCauses:
    """Causes of the truth points frame after frame (:meth:`explain`); it remembers which
    confirmed track last matched each target and the tracks' deletions, so that a target whose
    track was lost says so (:attr:`~wfviz.explain.types.Cause.LOST`).

    ``tracker``: its name (said in a detail when it has no such stage); ``config``: its
    configuration (``detection.k_sigma``, ``min_area``, ``max_area``, ``max_detections`` and
    ``horizon.margin`` are read when present); ``gate``: the scorer's match distance (px)."""

    def __init__(self, tracker: str, config: Any, gate: float) -> None:
        self.tracker, self.gate = tracker, gate
        det = getattr(config, "detection", None)
        hor = getattr(config, "horizon", None)
        self.k_sigma = float(getattr(det, "k_sigma", math.nan))
        self.min_area = int(getattr(det, "min_area", 1))
        self.max_area = int(getattr(det, "max_area", 1 << 30))
        self.max_detections = int(getattr(det, "max_detections", 1 << 30))
        self.margin = float(getattr(hor, "margin", 0.0))
        self._owner: dict[int, tuple[int, int]] = {}     # target -> (track that matched it, last frame)
        self._deleted: dict[int, tuple[int, str]] = {}   # track -> (frame, the deletion's message)
        self._boxes: Mapping[int, Box] = {}
        self._track_xy = np.zeros((0, 2))  # this frame's track positions (rows as result.tracks)
        self._preds: dict[int, tuple[float, float, float, float]] = {}  # track -> (x, y, half w, half h)

    def near(self, target: Point, xy: np.ndarray) -> np.ndarray:
        """Which points ``xy`` (N, 2) lie "within the gate" of ``target``: the scorer's rule
        (:func:`wfviz.evaluate.matchable`, with the target's box when the truth has one)."""
        return matchable(target, xy, self.gate, self._boxes.get(target[0]))

    def explain(self, result: FrameResult, shown: list[Point], hidden: list[Point],
                matches: tuple[tuple[int, int, float], ...],
                boxes: Mapping[int, Box] | None = None) -> tuple[TruthExplanation, ...]:
        """The cause of every point of ``shown`` (visible) and ``hidden`` truth in ``result``'s
        frame; ``matches``: the scorer's (track_id, target_id, distance) of the frame; ``boxes``:
        the targets' {target_id: (w, h)} when the truth has them ("within the gate" is then the
        scorer's rule: within the gate of the centre or inside the box)."""
        self._boxes = boxes or {}
        f = result.index
        owners = {track for track, _ in self._owner.values()}
        for e in result.events:  # only the deletions a lost target will name (not every tentative track's)
            if e.kind == EventKind.DELETED and e.track_id in owners:
                self._deleted[e.track_id] = (f, e.message)
        matched = {target: track for track, target, _ in matches}
        front: FrontEndResult | None = getattr(result, "front", None)
        dets = result.detections
        self._track_xy = np.array([(t.x, t.y) for t in result.tracks], dtype=np.float64).reshape(-1, 2)
        self._preds = {p.track_id: (p.x, p.y, p.half_w, p.half_h) for p in result.predictions}
        out = [self._one(result, front, dets, tid, x, y, matched) for tid, x, y in shown]
        for tid, track in matched.items():
            self._owner[tid] = (track, f)
        out += [TruthExplanation(f, tid, x, y, Cause.HIDDEN, "marked not visible in the truth") for tid, x, y in hidden]
        return tuple(out)

    # -- one point ------------------------------------------------------------------------
    def _one(self, result: FrameResult, front: FrontEndResult | None, dets: Detections, tid: int, x: float,
             y: float, matched: dict[int, int]) -> TruthExplanation:
        f = result.index
        d = np.hypot(dets.xy[:, 0] - x, dets.xy[:, 1] - y) if len(dets) else np.zeros(0)
        det_dist = float(d.min()) if d.size else math.nan
        r, c = int(round(y)), int(round(x))
        shape = front.valid.shape if front is not None else dets.labels.shape
        inside = 0 <= r < shape[0] and 0 <= c < shape[1]
        sig = (point_significance(front, r, c, self.k_sigma) if front is not None and inside
               else PointSignificance(math.nan, math.nan, math.nan))

        def say(cause: Cause, detail: str = "", track: int | None = None, held: Check | None = None) -> TruthExplanation:
            test = ("", math.nan, math.nan) if held is None else (held.name, held.value, held.level)
            return TruthExplanation(f, tid, x, y, cause, detail, sig.value, sig.residual, sig.change, sig.threshold,
                                    det_dist, track, *test, *self._offset(track, x, y))

        if tid in matched:
            return say(Cause.MATCHED, "", matched[tid])
        if not inside:
            return say(Cause.OUTSIDE_CIRCLE, "outside the frame")
        if front is not None and not front.valid[r, c]:
            return say(Cause.OUTSIDE_CIRCLE, "outside the imaging circle (or the frame's border)")
        near = self.near((tid, x, y), dets.xy) if len(dets) else np.zeros(0, dtype=bool)
        if front is not None and not front.region[r, c] and not near.any():
            return say(Cause.OUTSIDE_REGION, self._region_detail(result, front, x, y))
        if not near.any():
            return say(Cause.NOT_DETECTED, self._undetected(result, front, dets, sig, r, c, x, y))
        lost = self._lost(result, tid, x, y, dets, near)
        if lost is not None:
            return say(Cause.LOST, *lost)
        live = result.tracks
        tracks = [t for t, ok in zip(live, self.near((tid, x, y), self._track_xy).tolist()) if ok]
        tentative = sorted((t for t in tracks if not t.confirmed), key=lambda t: math.hypot(t.x - x, t.y - y))
        if tentative:
            t = tentative[0]
            v = result.verdicts
            if v is None:
                return say(Cause.NOT_CONFIRMED, f"tentative track {t.track_id} ({t.hits} hits); tracker "
                           f"'{self.tracker}' reports no confirmation tests", t.track_id)
            dec = v.decision(t.track_id)
            held = held_by(dec)
            if t.hits < v.min_hits:
                by = f"; held back by {held}" if held is not None else ""
                return say(Cause.LATENCY, f"tentative track {t.track_id}: {t.hits} hits < {v.min_hits}, the "
                           f"fewest any track is confirmed in ({v.rule}){by}", t.track_id, held)
            why = dec.reason if dec is not None and dec.reason else "tentative"
            return say(Cause.NOT_CONFIRMED, f"track {t.track_id} ({t.hits} hits) held back by {why}", t.track_id,
                       held)
        if tracks:  # a confirmed track within the gate that the scorer gave another target
            t = min(tracks, key=lambda t: math.hypot(t.x - x, t.y - y))
            other = [g for g, k in matched.items() if k == t.track_id]
            whom = f"target {other[0]}" if other else "a hidden target"
            return say(Cause.NOT_ASSOCIATED, f"confirmed track {t.track_id} within the gate is matched to {whom}",
                       t.track_id)
        j = int(np.argmin(np.where(near, d, np.inf)))
        return say(Cause.NOT_ASSOCIATED, *self._unassociated(result, dets, j, x, y))

    def _offset(self, track: int | None, x: float, y: float) -> tuple[float, float]:
        """(px, share of the gate's half sizes) from ``track``'s prediction of this frame to (x, y);
        NaN when there is no such prediction."""
        p = self._preds.get(track) if track is not None else None
        if p is None:
            return math.nan, math.nan
        dx, dy = x - p[0], y - p[1]
        return math.hypot(dx, dy), max(abs(dx) / max(p[2], 1e-9), abs(dy) / max(p[3], 1e-9))

    def _region_detail(self, result: FrameResult, front: FrontEndResult, x: float, y: float) -> str:
        """Why (x, y) inside the imaging circle lies outside the searched region."""
        h = front.horizon
        c = int(round(x))
        if horizon_confident(h) and h is not None:
            line = float(h.rows[c]) if np.isfinite(h.rows[c]) else math.nan
            limit = float(search_limit(h, self.margin)[c])
            if not math.isnan(line) and y >= line:
                return f"below the horizon ({y - line:.1f} px below the line at row {line:.1f})"
            if np.isfinite(limit) and y >= limit:
                return (f"within the horizon margin ({line - y:.1f} px above the line, horizon.margin "
                        f"{self.margin:g} px)" if not math.isnan(line) else
                        f"within the horizon margin of a neighbouring column (horizon.margin {self.margin:g} px)")
        if getattr(result, "searched", ()):
            return "outside the search windows (this frame was searched in the tracks' windows only)"
        return "outside the searched region (masked)"

    def _undetected(self, result: FrameResult, front: FrontEndResult | None, dets: Detections,
                    sig: PointSignificance, r: int, c: int, x: float, y: float) -> str:
        """Which stage removed a point with no detection within the gate."""
        if front is None:
            return (f"no detection within {self.gate:g} px; tracker '{self.tracker}' reports no "
                    f"per-pixel significance")
        bad = front.bad_pixels
        if len(bad):
            hit = np.nonzero((np.abs(bad[:, 0] - r) <= 1) & (np.abs(bad[:, 1] - c) <= 1))[0]
            if hit.size:
                br, bc = (int(v) for v in bad[hit[0]])
                return f"replaced as a sensor defect (flagged pixel at x={bc}, y={br})"
        if math.isnan(sig.value):  # no noise estimate: the residual against the threshold in DN
            thr = (float(dets.threshold_map[r, c]) if dets.threshold_map is not None else float(dets.threshold))
            peak = float(front.suppressed[_window(front.suppressed.shape, r, c)].max())
            if peak <= thr:
                return f"below threshold: residual {peak:.4g} <= {thr:.4g} (detect)"
        elif sig.value <= sig.threshold:
            parts = f"residual {sig.residual:.1f} σ" + ("" if math.isnan(sig.change) else f", change {sig.change:.1f} σ")
            return f"below threshold: {sig.value:.1f} σ <= {sig.threshold:.1f} σ ({parts}; detect)"
        labels = dets.labels[_window(dets.labels.shape, r, c)]
        comp = labels[labels > 0]
        if comp.size == 0:
            return "above threshold but not labelled (outside the searched pixels)"
        label = int(np.bincount(comp).argmax())
        kept = np.nonzero(dets.component == label)[0]
        if kept.size:
            k = int(kept[0])
            dist = math.hypot(dets.xy[k, 0] - x, dets.xy[k, 1] - y)
            return (f"merged with a neighbour: its component ({int(dets.area[k])} px) has its centroid "
                    f"{dist:.1f} px away (detect, merge_gap)")
        area = int((dets.labels == label).sum())
        if area < self.min_area or area > self.max_area:
            return f"its component of {area} px is outside detection.min_area..max_area ({self.min_area}..{self.max_area})"
        return f"dropped: more than detection.max_detections ({self.max_detections}) components were brighter"

    def _lost(self, result: FrameResult, tid: int, x: float, y: float, dets: Detections,
              near: np.ndarray) -> tuple[str, int] | None:
        """(detail, track) when the confirmed track that last matched target ``tid`` is off it or
        deleted (None: it never had one); ``near``: the detections within the gate of the point.
        A live track off it says why it did not take the point's detection (:meth:`_off_why`)."""
        owner = self._owner.get(tid)
        if owner is None:
            return None
        track, since = owner
        live = {t.track_id: t for t in result.tracks}
        t = live.get(track)
        if t is not None and t.confirmed:
            dist = math.hypot(t.x - x, t.y - y)
            if self.near((tid, x, y), np.array([[t.x, t.y]]))[0]:
                return None  # on it, but the scorer gave it another target (not_associated)
            why = self._off_why(result, track, dets, near, x, y)
            return f"its track {track} (matched until frame {since}) is {dist:.1f} px off it{why}", track
        if t is None and track in self._deleted:
            when, message = self._deleted[track]
            return f"its track {track} (matched until frame {since}) ended at frame {when}: {message}", track
        return f"its track {track} (matched until frame {since}) is gone", track

    @staticmethod
    def _off_why(result: FrameResult, track: int, dets: Detections, near: np.ndarray, x: float, y: float) -> str:
        """Why confirmed ``track`` did not take the detection nearest the point (x, y) among
        ``near``: where it was predicted against its gate, the camera's shift it was moved by,
        and what it took instead ("" when the tracker reports no prediction for it)."""
        pred = next((p for p in result.predictions if p.track_id == track), None)
        if pred is None:
            return ""
        parts = [f"predicted {math.hypot(pred.x - x, pred.y - y):.1f} px from it "
                 f"(gate ±{pred.half_w:.1f} × {pred.half_h:.1f} px)"]
        cam = result.front.camera if result.front is not None else None
        if cam is not None and cam.moving:
            how = (f"{cam.method}, {cam.corners} corners" if cam.reliable else "unknown: not moved")
            parts.append(f"camera shift ({cam.shift[0]:+.1f}, {cam.shift[1]:+.1f}) px ({how})")
        idx = np.flatnonzero(near)
        j = int(idx[np.argmin(np.hypot(dets.xy[idx, 0] - x, dets.xy[idx, 1] - y))])
        dx, dy = dets.xy[j]
        d = math.hypot(dx - x, dy - y)
        owners = result.detection_tracks
        taker = int(owners[j]) if owners is not None and len(owners) == len(dets) else None
        if abs(dx - pred.x) > pred.half_w or abs(dy - pred.y) > pred.half_h:
            parts.append(f"the detection {d:.1f} px from it lay outside that gate")
        elif taker is not None and taker >= 0 and taker != track:
            parts.append(f"the detection {d:.1f} px from it went to track {taker}")
        if owners is not None and len(owners) == len(dets):
            took = np.flatnonzero(owners == track)
            if len(took):
                k = int(took[0])
                parts.append(f"it took a detection {math.hypot(dets.xy[k, 0] - x, dets.xy[k, 1] - y):.1f} px from it")
            else:
                parts.append("it took no detection")
        return ": " + "; ".join(parts)

    def _unassociated(self, result: FrameResult, dets: Detections, j: int, x: float, y: float) -> tuple[str, int | None]:
        """Why detection ``j`` (within the gate of (x, y)) is on no track near the point."""
        dist = math.hypot(dets.xy[j, 0] - x, dets.xy[j, 1] - y)
        owners = result.detection_tracks
        if owners is None or len(owners) != len(dets):
            return (f"a detection {dist:.1f} px away; tracker '{self.tracker}' reports no detection-to-track "
                    f"assignment"), None
        k = int(owners[j])
        if k >= 0:
            t = next((t for t in result.tracks if t.track_id == k), None)
            where = (f", reported {math.hypot(t.x - x, t.y - y):.1f} px from the point" if t is not None
                     else ", and ended this frame")
            return f"its detection ({dist:.1f} px away) was taken by track {k}{where}", k
        dx, dy = dets.xy[j]
        for p in result.predictions:
            if p.confirmed and abs(dx - p.x) <= p.half_w and abs(dy - p.y) <= p.half_h:
                return (f"its detection ({dist:.1f} px away) lies in the gate of confirmed track {p.track_id}, "
                        f"where no track starts"), p.track_id
        return f"its detection ({dist:.1f} px away) started no track on this frame (window search)", None
