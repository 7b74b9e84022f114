"""Target chains over registered frames (Gao Jianwei et al. 2012, §3.2-3.3).

Coordinates: chains live in the *reference frame* (the first frame processed), where the
stars stand still and a target moves uniformly; every point also keeps its image position
(u, v) in its own frame, which is what the tracker reports.

Per frame k, with the candidate points C_k-2, C_k-1, C_k (unpaired points that passed the
candidate filters), :meth:`ChainManager.step` does, in order:

1. **Triples** (a, b, c) from C_k-2 x C_k-1 x C_k with |d(a, b) - d(b, c)| <= ``v`` (the
   paper's test), both steps between ``min_speed`` and ``max_speed`` px and a turn at b of at
   most ``max_turn`` degrees (additions: the paper's test alone accepts a static point, e.g. a
   star that flickers, and zigzags).
2. **Run extension**: a triple whose a or b belongs to a Run chain adds c to it (if c lies
   within ``gate`` px of the chain's Kalman prediction).
3. **Rejoining**: a triple of free points whose c is within ``dis`` px of the prediction of a
   Run chain that has no point in frame k, heading within ``theta`` degrees of the chain's
   motion, is appended to it (a, b replace the chain's predicted points at k-2, k-1).
4. **Re-detection** of Run chains still without a point: a free candidate within ``gate`` px
   of the prediction, else the caller's re-segmentation around the prediction (a local, lower
   threshold), else the prediction stands in.
5. **New extension**: a triple whose a or b belongs to a New chain adds c (and b if free).
6. **New chains** from the remaining triples of free points.
7. **Kalman**: Run chains are updated with their detections (predictions leave the state).
8. **Promotion**: a New chain longer than ``length`` (N = 4) points becomes a Run chain; its
   filter starts at the chain's first centroid and is updated with the following ones.
   *Backtracking* (an addition, ``backtrack`` frames, 0 = off): the chain's straight-line fit
   is followed back before its first point; in each earlier frame a free candidate within
   ``gate`` px, else a re-segmentation, extends the chain backwards (two empty frames in a
   row stop it). The paper counts p_d on the stored chains, and a target is often found
   before its first triple passes the v test or while it touches a star.
9. **Out**: a Run chain whose next prediction falls outside the image goes to Out;
   one coasting on predictions for ``max_misses`` frames is dropped (lost).
10. New chains that can no longer be extended (no point in k-1 or k) are dropped.

Steps 2-4 run before 5-6 (in the paper, re-detection is step (3), after the New lists):
a Run chain's prediction window is served before noise chains can take its point.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from wfviz.trackers.starfield.config import ChainConfig, StarKalmanConfig, StarTrackingConfig
from wfviz.tracking import kalman
from wfviz.tracking import EventKind, TrackEvent

DETECTED, REDETECTED, PREDICTED = "detected", "redetected", "predicted"
NEW, RUN, OUT, LOST = "new", "run", "out", "lost"
FREE, STAR_LATER = -1, -2  # candidate owners that are no chain: free; paired with the next frame


@dataclass
class ChainPoint:
    """A chain's point in one frame: reference-frame (x, y), image (u, v), how it was found."""

    frame: int
    x: float
    y: float
    u: float
    v: float
    kind: str  # detected (segmentation), redetected (local re-segmentation), predicted


@dataclass
class Chain:
    """A target chain; ``status`` is its list: new, run, out (left the field) or lost."""

    chain_id: int
    points: list[ChainPoint]
    status: str = NEW
    x: np.ndarray | None = None  # Kalman state (x, y, vx, vy), reference frame
    P: np.ndarray | None = None
    misses: int = 0  # consecutive predicted points
    promoted_at: int | None = None

    @property
    def last(self) -> ChainPoint:
        return self.points[-1]

    def at(self, frame: int) -> ChainPoint | None:
        """The chain's point in ``frame``."""
        for p in reversed(self.points):
            if p.frame == frame:
                return p
            if p.frame < frame:
                return None
        return None

    @property
    def hits(self) -> int:
        return sum(p.kind != PREDICTED for p in self.points)


@dataclass
class Candidates:
    """One frame's candidate points: reference-frame ``xy``, image ``uv``, ``owner`` chain id
    (``FREE``, or ``STAR_LATER`` once paired with the next frame) and ``index`` into that
    frame's segmented points."""

    frame: int
    xy: np.ndarray
    uv: np.ndarray
    index: np.ndarray
    owner: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.owner is None:
            self.owner = np.full(len(self.xy), FREE, dtype=np.int64)


@dataclass(frozen=True)
class Found:
    """A re-segmentation's answer: the predicted image position, the point found (image and
    reference frame) or None, the window searched (x0, y0, w, h) and its threshold."""

    pred_uv: tuple[float, float]
    uv: tuple[float, float] | None
    xy: tuple[float, float] | None
    window: tuple[int, int, int, int] | None
    threshold: float


@dataclass(frozen=True)
class Redetection:
    """What the re-detection of a Run chain did in ``frame`` (for the recording); ``how``:
    candidate (a free candidate in the gate), resegment, predicted, backtrack."""

    chain_id: int
    frame: int
    how: str
    found: Found


# re-segmentation callback: (chain, frame, predicted reference-frame position) -> Found, or
# None when that frame can no longer be searched
Resegmenter = Callable[["Chain", int, np.ndarray], "Found | None"]


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between vectors a and b (rows)."""
    na, nb = np.hypot(a[..., 0], a[..., 1]), np.hypot(b[..., 0], b[..., 1])
    c = (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]) / np.maximum(na * nb, 1e-12)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


class ChainManager:
    """New / Run / Out chain lists with CV Kalman filters on the Run chains.

    Not :class:`wfviz.tracking.TrackManager`: the paper (Gao Jianwei et al. 2012) starts a track
    as a New chain of three candidates moving at a plausible speed in a straight line (no gate
    around a prediction yet), promotes it to a Run chain, which then takes the candidate nearest
    its Kalman prediction, and re-segments locally when none is there; the lifecycle is the
    chains' states, not gated hits and misses. It shares the Kalman filter
    (:mod:`wfviz.tracking.kalman`) and the event kinds (:class:`wfviz.tracking.EventKind`)."""

    def __init__(self, ccfg: ChainConfig, kcfg: StarKalmanConfig, tcfg: StarTrackingConfig) -> None:
        self.cfg, self.kcfg, self.tcfg = ccfg, kcfg, tcfg
        self.model = kalman.CVModel.make(kcfg.q, kcfg.r)
        self.P0 = kalman.initial_covariance(kcfg.r, kcfg.initial_velocity_std)
        self.new: list[Chain] = []
        self.run: list[Chain] = []
        self.out: list[Chain] = []
        self.lost: list[Chain] = []
        # candidates of the frames a promotion can backtrack into (a chain's first point is at
        # least ``length`` frames old when it is promoted)
        self.past: deque[Candidates] = deque(maxlen=ccfg.length + ccfg.backtrack + 1)
        self.dropped: dict[int, Chain] = {}  # New chains dropped while their points are in ``past``
        self._next_id = 1
        self._events: list[TrackEvent] = []
        self._redets: list[Redetection] = []
        self._frame = 0

    @property
    def history(self) -> list[Candidates]:
        """The last three frames' candidates (C_k-2, C_k-1, C_k)."""
        return list(self.past)[-3:]

    def chains(self) -> list[Chain]:
        """Every chain that reached Run (Run, Out, lost), with all its points."""
        return sorted(self.run + self.out + self.lost, key=lambda c: c.chain_id)

    def _event(self, kind: EventKind, chain: Chain, message: str) -> None:
        self._events.append(TrackEvent(self._frame, kind, chain.chain_id, f"track {chain.chain_id} {message}"))

    @staticmethod
    def _point(cands: Candidates, i: int, kind: str = DETECTED) -> ChainPoint:
        return ChainPoint(cands.frame, float(cands.xy[i, 0]), float(cands.xy[i, 1]),
                          float(cands.uv[i, 0]), float(cands.uv[i, 1]), kind)

    def _triples(self) -> np.ndarray:
        """(T, 3) candidate indices (a, b, c) into C_k-2, C_k-1, C_k passing the tests, best
        (smallest |d1 - d2| / v + turn / max_turn) first. Points of k-2 and k-1 found to be
        stars since (``STAR_LATER``) take no part."""
        hist = self.history
        if len(hist) < 3 or hist[0].frame != hist[2].frame - 2:
            return np.zeros((0, 3), np.int64)
        A, B, C = hist
        ia_ok = np.nonzero(A.owner != STAR_LATER)[0]
        ib_ok = np.nonzero(B.owner != STAR_LATER)[0]
        if not (len(ia_ok) and len(ib_ok) and len(C.xy)):
            return np.zeros((0, 3), np.int64)
        cfg = self.cfg
        na = cKDTree(A.xy[ia_ok]).query_ball_point(B.xy[ib_ok], cfg.max_speed)
        nc = cKDTree(C.xy).query_ball_point(B.xy[ib_ok], cfg.max_speed)
        rows = []
        for b, la, lc in zip(ib_ok, na, nc):
            if not la or not lc:
                continue
            ia, ic = ia_ok[np.array(la)], np.array(lc)
            ia, ic = np.repeat(ia, len(ic)), np.tile(ic, len(ia))
            s1 = B.xy[b] - A.xy[ia]
            s2 = C.xy[ic] - B.xy[b]
            d1, d2 = np.hypot(*s1.T), np.hypot(*s2.T)
            turn = _angle(s1, s2)
            ok = ((d1 >= cfg.min_speed) & (d2 >= cfg.min_speed) & (np.abs(d1 - d2) <= cfg.v)
                  & (turn <= cfg.max_turn))
            if ok.any():
                score = np.abs(d1 - d2)[ok] / max(cfg.v, 1e-9) + turn[ok] / max(cfg.max_turn, 1e-9)
                rows.append(np.column_stack([ia[ok], np.full(ok.sum(), b), ic[ok], score]))
        if not rows:
            return np.zeros((0, 3), np.int64)
        t = np.vstack(rows)
        return t[np.argsort(t[:, 3], kind="stable"), :3].astype(np.int64)

    def predict(self) -> None:
        """Advance every Run chain's filter by one frame (its state becomes the prediction)."""
        if self.run:
            x, P = kalman.predict(np.stack([c.x for c in self.run]), np.stack([c.P for c in self.run]),
                                  self.model)
            for c, xi, Pi in zip(self.run, x, P):
                c.x, c.P = xi, Pi

    def _nearest_free(self, cands: Candidates, xy: np.ndarray, radius: float,
                      dropped: bool = False) -> int | None:
        """Index of the free candidate (or, with ``dropped``, one of a dropped New chain)
        nearest ``xy`` within ``radius`` px, or None."""
        ok = cands.owner == FREE
        if dropped and self.dropped:
            ok |= np.isin(cands.owner, list(self.dropped))
        free = np.nonzero(ok)[0]
        if not len(free):
            return None
        d = np.hypot(*(cands.xy[free] - xy).T)
        j = int(np.argmin(d))
        return int(free[j]) if d[j] <= radius else None

    # -- the frame step -------------------------------------------------------------------
    def step(self, cands: Candidates, shape: tuple[int, int], to_image: Callable[[np.ndarray], np.ndarray],
             resegment: Resegmenter | None) -> tuple[list[TrackEvent], list[Redetection]]:
        """Process frame ``cands.frame`` (steps 1-10 of the module docstring); call
        :meth:`predict` first (the Run chains' states are then this frame's predictions).
        ``to_image`` maps (N, 2) reference-frame points to this frame's image. Returns the
        events and the re-detections."""
        k = self._frame = cands.frame
        self._events, self._redets = [], []
        cfg = self.cfg
        if self.past and self.past[-1].frame != k - 1:
            self.past.clear()  # a gap (unregistered frame): triples cannot span it
        self.past.append(cands)
        triples = self._triples()
        chains = {c.chain_id: c for c in self.new + self.run}
        A, B = (self.history[0], self.history[1]) if len(triples) else (None, None)
        C = cands
        has_k = {c.chain_id for c in self.run if c.last.frame == k}

        def owner(cs: Candidates, i: int) -> Chain | None:
            return chains.get(int(cs.owner[i]))

        def take(chain: Chain, cs: Candidates, i: int) -> None:
            chain.points.append(self._point(cs, i))
            cs.owner[i] = chain.chain_id

        def member(a: int, b: int, status: str) -> Chain | None:
            """The chain of ``status`` holding b, else a (when b is free); None otherwise."""
            ob, oa = owner(B, b), owner(A, a)
            if ob is not None:
                return ob if ob.status == status else None
            return oa if oa is not None and oa.status == status else None

        # 2. Run extension
        for a, b, c in triples:
            ch = member(a, b, RUN)
            if C.owner[c] != FREE or ch is None or ch.chain_id in has_k:
                continue
            if math.hypot(*(C.xy[c] - ch.x[:2])) <= cfg.gate:
                take(ch, C, c)
                has_k.add(ch.chain_id)
        # 3. rejoining
        for a, b, c in triples:
            if C.owner[c] != FREE or A.owner[a] != FREE or B.owner[b] != FREE:
                continue
            for ch in self.run:
                if (ch.chain_id in has_k or math.hypot(*(C.xy[c] - ch.x[:2])) >= cfg.dis
                        or _angle(C.xy[c] - B.xy[b], ch.x[2:]) > cfg.theta):
                    continue
                for cs, i in ((A, a), (B, b)):
                    old = ch.at(cs.frame)
                    if old is not None and old.kind == PREDICTED:
                        ch.points[ch.points.index(old)] = self._point(cs, i)
                        cs.owner[i] = ch.chain_id
                take(ch, C, c)
                has_k.add(ch.chain_id)
                self._event(EventKind.REJOINED, ch, f"rejoined by a new three-frame chain within {cfg.dis:g} px "
                                            f"and {cfg.theta:g} deg of its prediction")
                break
        # 4. re-detection
        for ch in self.run:
            if ch.chain_id not in has_k:
                self._redetect(ch, C, to_image, resegment)
                has_k.add(ch.chain_id)
        # 5. New extension
        got: set[int] = set()
        for a, b, c in triples:
            ch = member(a, b, NEW)
            if C.owner[c] != FREE or ch is None or ch.chain_id in got:
                continue
            if B.owner[b] == FREE:  # a ends the chain, b is free: b joins too
                if ch.last.frame != A.frame:
                    continue
                take(ch, B, b)
            take(ch, C, c)
            got.add(ch.chain_id)
        # 6. new chains
        for a, b, c in triples:
            if C.owner[c] != FREE or A.owner[a] != FREE or B.owner[b] != FREE:
                continue
            ch = Chain(self._next_id, [])
            self._next_id += 1
            for cs, i in ((A, a), (B, b), (C, c)):
                take(ch, cs, i)
            self.new.append(ch)
            self._event(EventKind.BORN, ch, f"New chain from a three-frame triple ending at "
                                    f"({C.uv[c, 0]:.1f}, {C.uv[c, 1]:.1f})")
        # 7. Kalman update of the Run chains detected in this frame
        meas = [c for c in self.run if c.last.kind != PREDICTED]
        if meas:
            z = np.array([[c.last.x, c.last.y] for c in meas])
            x, P, _ = kalman.update(np.stack([c.x for c in meas]), np.stack([c.P for c in meas]), z, self.model)
            for c, xi, Pi in zip(meas, x, P):
                c.x, c.P, c.misses = xi, Pi, 0
        for c in self.run:
            if c.last.kind == PREDICTED:
                c.misses += 1
        # 8. promotion; 10. New chains that cannot grow any more
        keep = []
        for ch in self.new:
            if len(ch.points) > cfg.length:
                self._promote(ch, resegment)
            elif ch.last.frame >= k - 1:
                keep.append(ch)
            else:
                ch.status = LOST
                self.dropped[ch.chain_id] = ch
                self._event(EventKind.DELETED, ch, f"New chain dropped after {len(ch.points)} points")
        self.new = keep
        oldest = self.past[0].frame
        self.dropped = {i: c for i, c in self.dropped.items() if c.last.frame >= oldest}
        # 9. Out / lost
        h, w = shape
        still = []
        for ch in self.run:
            nxt = to_image((self.model.F @ ch.x)[None, :2])[0]
            if not (0.0 <= nxt[0] <= w - 1 and 0.0 <= nxt[1] <= h - 1):
                ch.status = OUT
                self.out.append(ch)
                self._event(EventKind.EXITED, ch, f"left the field: next prediction ({nxt[0]:.1f}, {nxt[1]:.1f}) is "
                                          f"outside the image; moved to Out after {ch.hits} detections")
            elif ch.misses >= self.tcfg.max_misses:
                ch.status = LOST
                self.lost.append(ch)
                self._event(EventKind.DELETED, ch, f"deleted after {ch.misses} consecutive predictions")
            else:
                still.append(ch)
        self.run = still
        return self._events, self._redets

    def _redetect(self, ch: Chain, C: Candidates, to_image: Callable[[np.ndarray], np.ndarray],
                  resegment: Resegmenter | None) -> None:
        """Step 4 for one Run chain: a free candidate in the gate, a re-segmentation, or the
        prediction."""
        k, pred = C.frame, ch.x[:2]
        j = self._nearest_free(C, pred, self.cfg.gate)
        if j is not None:
            ch.points.append(self._point(C, j))
            C.owner[j] = ch.chain_id
            pu, pv = to_image(pred[None])[0]
            self._redets.append(Redetection(ch.chain_id, k, "candidate", Found(
                (float(pu), float(pv)), (float(C.uv[j, 0]), float(C.uv[j, 1])),
                (float(C.xy[j, 0]), float(C.xy[j, 1])), None, math.nan)))
            return
        f = resegment(ch, k, pred) if resegment is not None else None
        if f is None:
            pu, pv = to_image(pred[None])[0]
            f = Found((float(pu), float(pv)), None, None, None, math.nan)
        if f.uv is not None:
            ch.points.append(ChainPoint(k, f.xy[0], f.xy[1], f.uv[0], f.uv[1], REDETECTED))
            self._event(EventKind.REDETECTED, ch, f"re-detected by local re-segmentation at ({f.uv[0]:.1f}, "
                                          f"{f.uv[1]:.1f}), threshold {f.threshold:.1f}")
        else:
            ch.points.append(ChainPoint(k, float(pred[0]), float(pred[1]), f.pred_uv[0], f.pred_uv[1], PREDICTED))
        self._redets.append(Redetection(ch.chain_id, k, "resegment" if f.uv is not None else "predicted", f))

    def _promote(self, ch: Chain, resegment: Resegmenter | None) -> None:
        """New -> Run: backtrack, then a filter from the chain's first centroid updated with
        the following ones."""
        added = self._backtrack(ch, resegment)
        p0 = ch.points[0]
        x = np.array([[p0.x, p0.y, 0.0, 0.0]])
        P = self.P0[None].copy()
        f = p0.frame
        for p in ch.points[1:]:
            for _ in range(p.frame - f):
                x, P = kalman.predict(x, P, self.model)
            x, P, _ = kalman.update(x, P, np.array([[p.x, p.y]]), self.model)
            f = p.frame
        ch.x, ch.P = x[0], P[0]
        ch.status, ch.promoted_at, ch.misses = RUN, self._frame, 0
        self.run.append(ch)
        back = f", {added} earlier point(s) found by backtracking" if added else ""
        self._event(EventKind.PROMOTED, ch, f"promoted New -> Run after {len(ch.points) - added} points "
                                    f"(length > {self.cfg.length}){back}: Kalman filter started")

    def _backtrack(self, ch: Chain, resegment: Resegmenter | None) -> int:
        """Extend ``ch`` before its first point along its least-squares line (see step 8)."""
        if self.cfg.backtrack <= 0:
            return 0
        t = np.array([p.frame for p in ch.points], dtype=np.float64)
        xy = np.array([[p.x, p.y] for p in ch.points])
        A = np.column_stack([np.ones_like(t), t - t[0]])
        coef, *_ = np.linalg.lstsq(A, xy, rcond=None)  # (2, 2): position at t[0], velocity
        past = {c.frame: c for c in self.past}
        added, empty = 0, 0
        for f in range(int(t[0]) - 1, int(t[0]) - 1 - self.cfg.backtrack, -1):
            pred = coef[0] + coef[1] * (f - t[0])
            cands = past.get(f)
            j = self._nearest_free(cands, pred, self.cfg.gate, dropped=True) if cands is not None else None
            if j is not None and int(cands.owner[j]) in self.dropped:  # the target's earlier New chain
                old = self.dropped.pop(int(cands.owner[j]))
                earlier = [p for p in old.points if p.frame <= f]
                ch.points[:0] = earlier
                for cs in self.past:
                    cs.owner[cs.owner == old.chain_id] = ch.chain_id
                self._event(EventKind.ABSORBED, ch, f"took over the {len(earlier)} point(s) of dropped New chain "
                                            f"{old.chain_id} (frames {earlier[0].frame}-{earlier[-1].frame})")
                return added + len(earlier)
            if j is not None:
                ch.points.insert(0, self._point(cands, j))
                cands.owner[j] = ch.chain_id
            else:
                found = resegment(ch, f, pred) if resegment is not None else None
                if found is None or found.uv is None:
                    empty += 1
                    if empty == 2:
                        break
                    continue
                ch.points.insert(0, ChainPoint(f, found.xy[0], found.xy[1], found.uv[0], found.uv[1], REDETECTED))
                self._redets.append(Redetection(ch.chain_id, f, "backtrack", found))
            added += 1
            empty = 0
        return added
