"""The star-field tracker (``--tracker starfield``): dim moving targets among stars in
telescope frames whose background jitters (Gao Jianwei et al. 2012).

Per frame: segmentation into star points (:mod:`wfviz.trackers.starfield.segmentation`), pairing with
the previous frame's points and registration (:mod:`wfviz.trackers.starfield.registration`), candidate
filtering (unpaired points that are not known stars, sensor defects or at the border), target
chains with Kalman filters (:mod:`wfviz.trackers.starfield.chains`). Chains live in the reference
frame (the first frame processed); tracks are reported in each frame's image coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from wfviz.io.frames import Frame
from wfviz.stages.detection import Detections
from wfviz.trackers.base import FrameResult, StageTimer, min_side
from wfviz.trackers.starfield.chains import (NEW, OUT, PREDICTED, RUN, STAR_LATER, Candidates, Chain, ChainManager,
                                    Found, Redetection)
from wfviz.trackers.starfield.config import StarfieldConfig
from wfviz.trackers.starfield.registration import Registration, apply, register
from wfviz.trackers.starfield.segmentation import Segmentation, noise_at, resegment, segment
from wfviz.tracking import Prediction, TrackState

# why an unpaired point is or is not a candidate
CANDIDATE, KNOWN_STAR, DEFECT, BORDER, NOT_REGISTERED = 0, 1, 2, 3, 4
CANDIDATE_STATUS = ("candidate", "known star", "sensor defect", "border", "not registered")


@dataclass(frozen=True)
class ChainView:
    """A chain as drawn this frame: its list (new, run, out), its last points in this frame's
    image coordinates and how each was found (detected, redetected, predicted)."""

    chain_id: int
    status: str
    xy: np.ndarray
    kinds: tuple[str, ...]


@dataclass(frozen=True, kw_only=True)
class StarfieldResult(FrameResult):
    """Every stage's output for one frame (the common fields come from FrameResult;
    ``detections`` are the candidates, ``stars`` every segmented point).

    ``paired``: per point of ``stars``, paired with the previous frame; ``pair_segments``
    (K, 2, 2): each pair's image position in the previous frame and in this one (the jitter);
    ``unpaired`` / ``unpaired_status``: indices of the unpaired points and why each is or is
    not a candidate (``CANDIDATE_STATUS``); ``to_reference``: 2x3 affine from this frame to
    the reference frame; ``redetections``: what the re-detection of each Run chain did (and
    what backtracking found in earlier frames); ``predicted``: ids of tracks whose reported
    position is a prediction; ``chain_points``: (chain id, frame, u, v, kind) of Run and Out
    chains' points added or changed this frame (all of a chain's points when it is promoted),
    from which :func:`wfviz.trackers.starfield.metrics.paper_scores` counts the paper's p_d;
    ``residual``: the smoothed background-subtracted frame (the detection map) with its robust
    std ``noise_sigma``; ``defects``: flagged sensor positions (x, y).
    """

    stars: Detections
    paired: np.ndarray
    registration: Registration
    pair_segments: np.ndarray
    unpaired: np.ndarray
    unpaired_status: np.ndarray
    to_reference: np.ndarray
    chains: tuple[ChainView, ...]
    redetections: tuple[Redetection, ...]
    predicted: frozenset[int]
    chain_points: tuple[tuple[int, int, float, float, str], ...]
    residual: np.ndarray
    noise_sigma: float
    defects: np.ndarray


@dataclass(frozen=True)
class _Stored:
    """A past frame kept for re-segmentation: its residual, the detection map's noise (median,
    and per pixel when estimated locally), its image -> reference map (3x3)."""

    residual: np.ndarray
    sigma: float
    sigma_map: np.ndarray | None
    to_ref: np.ndarray


def _h(m: np.ndarray) -> np.ndarray:
    """2x3 affine -> 3x3."""
    return np.vstack([m, [0.0, 0.0, 1.0]])


def _subset(d: Detections, idx: np.ndarray) -> Detections:
    return Detections(d.xy[idx], d.area[idx], d.peak[idx], d.flux[idx], d.bbox[idx], d.component[idx],
                      d.labels, d.threshold)


class StarfieldTracker:
    """Streams frames through the star-field pipeline; ``step`` returns a :class:`StarfieldResult`."""

    name = "starfield"

    def __init__(self, config: StarfieldConfig | None = None) -> None:
        self.config = config or StarfieldConfig()
        c = self.config
        self.manager = ChainManager(c.chains, c.kalman, c.tracking)
        self._prev: tuple[Detections, np.ndarray] | None = None  # previous points, their to-reference map
        self._prev_optical = np.zeros(0, np.int64)  # previous points that are not sharp (registration input)
        self._to_ref = np.eye(3)  # this frame's image -> reference frame
        self._catalogue = np.zeros((0, 2))  # known stars, reference frame, and their flux
        self._catalogue_flux = np.zeros(0)
        self._catalogue_tree: cKDTree | None = None
        self._static_uv = np.zeros((0, 2))  # previous frame's unpaired points (image) ...
        self._static_n = np.zeros(0, np.int64)  # ... and for how many frames each stood still
        self._defects = np.zeros((0, 2))
        # past frames for re-segmentation (star-free differences, backtracking)
        self._stored: dict[int, _Stored] = {}
        self._keep = c.chains.length + c.chains.backtrack + c.resegment.references + 2

    # -- candidates --------------------------------------------------------------------------
    def _update_catalogue(self, ref_xy: np.ndarray, flux: np.ndarray) -> None:
        """Merge this frame's paired stars (reference frame, flux) into the catalogue."""
        r = self.config.candidates.star_radius
        if self._catalogue_tree is not None and len(ref_xy):
            d, j = self._catalogue_tree.query(ref_xy, distance_upper_bound=r)
            hit = np.isfinite(d)
            self._catalogue[j[hit]] = ref_xy[hit]  # follow slow drift of the chained registration
            self._catalogue_flux[j[hit]] = flux[hit]
            ref_xy, flux = ref_xy[~hit], flux[~hit]
        if len(ref_xy):
            self._catalogue = np.vstack([self._catalogue, ref_xy])
            self._catalogue_flux = np.concatenate([self._catalogue_flux, flux])
        self._catalogue_tree = cKDTree(self._catalogue) if len(self._catalogue) else None

    def _star_flux(self, ref_xy: np.ndarray) -> np.ndarray:
        """Flux of the known star within ``candidates.star_radius`` of each point (0: none)."""
        out = np.zeros(len(ref_xy))
        if self._catalogue_tree is not None and len(ref_xy):
            d, j = self._catalogue_tree.query(ref_xy, distance_upper_bound=self.config.candidates.star_radius)
            hit = np.isfinite(d)
            out[hit] = np.maximum(self._catalogue_flux[j[hit]], 1e-9)
        return out

    def _near_star(self, ref_xy: np.ndarray) -> np.ndarray:
        return self._star_flux(ref_xy) > 0

    def _near_defect(self, uv: np.ndarray) -> np.ndarray:
        if not len(self._defects) or not len(uv):
            return np.zeros(len(uv), dtype=bool)
        d, _ = cKDTree(self._defects).query(uv, distance_upper_bound=self.config.candidates.defect_radius)
        return np.isfinite(d)

    def _classify(self, uv: np.ndarray, ref: np.ndarray, shape: tuple[int, int], defects: bool) -> np.ndarray:
        """Status code of each unpaired point (image ``uv``, reference ``ref``); ``defects``:
        update the sensor-defect evidence with these points (once per frame)."""
        cc = self.config.candidates
        status = np.full(len(uv), CANDIDATE, np.int64)
        if defects:  # unpaired points that stand still on the sensor for defect_frames frames
            n = np.ones(len(uv), np.int64)
            if len(self._static_uv) and len(uv):
                d, j = cKDTree(self._static_uv).query(uv, distance_upper_bound=cc.defect_radius)
                hit = np.isfinite(d)
                n[hit] = self._static_n[j[hit]] + 1
            self._static_uv, self._static_n = uv.copy(), n
            new = uv[n >= cc.defect_frames]
            new = new[~self._near_defect(new)]
            if len(new):
                self._defects = np.vstack([self._defects, new])
        status[self._near_defect(uv)] = DEFECT
        status[self._near_star(ref) & (status == CANDIDATE)] = KNOWN_STAR
        h, w = shape
        b = cc.border
        edge = (uv[:, 0] < b) | (uv[:, 1] < b) | (uv[:, 0] > w - 1 - b) | (uv[:, 1] > h - 1 - b)
        status[edge & (status == CANDIDATE)] = BORDER
        return status

    def _candidates(self, frame: int, pts: Detections, idx: np.ndarray, to_ref: np.ndarray,
                    shape: tuple[int, int], defects: bool = True, sharp: np.ndarray | None = None
                    ) -> tuple[Candidates, np.ndarray]:
        uv = pts.xy[idx]
        ref = apply(to_ref, uv)
        status = self._classify(uv, ref, shape, defects)
        if sharp is not None:  # single-pixel events (segmentation.sharpness) are sensor defects
            status[sharp & (status == CANDIDATE)] = DEFECT
        keep = status == CANDIDATE
        return Candidates(frame, ref[keep], uv[keep], idx[keep]), status

    # -- re-segmentation -----------------------------------------------------------------------
    def _resegment(self, chain: Chain, frame: int, pred: np.ndarray) -> Found | None:
        """Re-segment stored frame ``frame`` around the chain's reference-frame position
        ``pred``, on the difference with up to ``resegment.references`` stored frames in
        which the chain was at least ``resegment.min_offset`` px away (None: frame not kept)."""
        rc = self.config.resegment
        st = self._stored.get(frame)
        if st is None:
            return None
        pu, pv = apply(np.linalg.inv(st.to_ref)[:2], pred[None])[0]
        if not rc.enabled:
            return Found((float(pu), float(pv)), None, None, None, math.nan)
        refs = []
        for f in sorted(self._stored, key=lambda f: abs(f - frame)):
            if len(refs) >= rc.references:
                break
            p = chain.at(f)
            if f == frame or p is None or math.hypot(p.x - pred[0], p.y - pred[1]) < rc.min_offset:
                continue
            other = self._stored[f]
            refs.append((other.residual, (np.linalg.inv(other.to_ref) @ st.to_ref)[:2]))
        r = resegment(st.residual, noise_at(st.sigma_map, st.sigma, pu, pv), pu, pv, rc.window, rc.k_sigma, rc.radius, refs,
                      self.config.segmentation.smooth_sigma)
        window = (r.x0, r.y0, r.w, r.h)
        if r.found is not None:
            uv = np.array([r.found[:2]])
            xy = apply(st.to_ref[:2], uv)
            # A star there hides the target, unless the stars were differenced away and the peak
            # clears the threshold by more than what that star leaves in the difference.
            star = self._star_flux(xy)[0]
            hidden = star > 0 and not (refs and r.found[4] > r.threshold + rc.star_leak * star)
            if not (hidden or self._near_defect(uv)[0]):
                return Found((float(pu), float(pv)), (float(uv[0, 0]), float(uv[0, 1])),
                             (float(xy[0, 0]), float(xy[0, 1])), window, r.threshold)
        return Found((float(pu), float(pv)), None, None, window, r.threshold)

    # -- the frame step -----------------------------------------------------------------------
    def min_frame_side(self) -> int:
        """Smallest frame side accepted (no suppression or horizon windows to fit)."""
        return min_side()

    def step(self, frame: Frame) -> StarfieldResult:
        """Run every stage on one frame."""
        c = self.config
        timer = StageTimer(("segment", "register", "candidates", "chains", "resegment"))
        lap = timer.lap
        k, shape = frame.index, frame.image.shape[:2]
        seg = segment(frame.image, c.segmentation)
        pts = seg.points
        lap("segment")
        prev = self._prev
        sharp = seg.sharp if seg.sharp is not None else np.zeros(len(pts), dtype=bool)
        optical = np.nonzero(~sharp)[0]  # single-pixel sensor events stand still: no registration input
        if prev is None:
            reg = replace(register(np.zeros((0, 2)), np.zeros(0), pts.xy[optical], pts.flux[optical], shape,
                                   c.registration), note="first frame")
        else:
            po = self._prev_optical
            reg = register(prev[0].xy[po], prev[0].flux[po], pts.xy[optical], pts.flux[optical], shape,
                           c.registration)
            if len(reg.pairs):  # indices back into all points
                reg = replace(reg, pairs=np.column_stack([po[reg.pairs[:, 0]], optical[reg.pairs[:, 1]]]))
            if reg.ok:  # chain the motion: this frame -> previous frame -> reference frame
                self._to_ref = prev[1] @ np.linalg.inv(_h(reg.matrix))
        to_ref, to_img = self._to_ref[:2], np.linalg.inv(self._to_ref)[:2]
        paired = np.zeros(len(pts), dtype=bool)
        paired[reg.pairs[:, 1]] = True
        segments = (np.stack([prev[0].xy[reg.pairs[:, 0]], pts.xy[reg.pairs[:, 1]]], axis=1)
                    if prev is not None and len(reg.pairs) else np.zeros((0, 2, 2)))
        lap("register")
        self._update_catalogue(apply(to_ref, pts.xy[paired]), pts.flux[paired])
        unpaired = np.nonzero(~paired)[0]
        m = self.manager
        if prev is not None and reg.ok:
            if m.past and m.past[-1].frame == k - 1:  # a previous candidate paired now: a flickering star
                last = m.past[-1]
                last.owner[np.isin(last.index, reg.pairs[:, 0]) & (last.owner < 0)] = STAR_LATER
            else:  # first registered pair: the previous frame's points unpaired with this one
                idx0 = np.setdiff1d(np.arange(len(prev[0])), reg.pairs[:, 0])
                m.past.append(self._candidates(k - 1, prev[0], idx0, prev[1][:2], shape, defects=False)[0])
            cands, status = self._candidates(k, pts, unpaired, to_ref, shape, sharp=sharp[unpaired])
        else:
            cands = Candidates(k, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64))
            status = np.full(len(unpaired), NOT_REGISTERED, np.int64)
        self._stored[k] = _Stored(seg.residual, seg.sigma, seg.sigma_map, self._to_ref.copy())
        for f in [f for f in self._stored if f <= k - self._keep]:
            del self._stored[f]
        lap("candidates")
        def reseg(chain: Chain, f: int, pred: np.ndarray) -> Found | None:
            with timer.inner("resegment"):
                return self._resegment(chain, f, pred)

        m.predict()
        preds = self._predictions(k, to_img)
        events, redets = [], []
        if prev is not None:
            events, redets = m.step(cands, shape, lambda p: apply(to_img, p), reseg)
        lap("chains")
        self._prev = (pts, self._to_ref.copy())
        self._prev_optical = optical
        return self._result(frame, seg, reg, paired, segments, unpaired, status, to_ref, to_img, preds,
                            events, redets, timer)

    def _predictions(self, frame: int, to_img: np.ndarray) -> list[Prediction]:
        """This frame's predictions: Run chains (Kalman, gate = chains.gate) and New chains
        (their last step extrapolated, gate = chains.v)."""
        c = self.config.chains
        out = []
        for ch in self.manager.run:
            u, v = apply(to_img, ch.x[None, :2])[0]
            out.append(Prediction(ch.chain_id, float(u), float(v), c.gate, c.gate, True, False,
                                  float(np.trace(ch.P))))
        g = max(c.v, 1.0)
        for ch in self.manager.new:
            p0, p1 = ch.points[-2], ch.points[-1]
            s = (frame - p1.frame) / max(p1.frame - p0.frame, 1)
            u, v = apply(to_img, np.array([[p1.x + s * (p1.x - p0.x), p1.y + s * (p1.y - p0.y)]]))[0]
            out.append(Prediction(ch.chain_id, float(u), float(v), g, g, False, False, math.nan))
        return out

    def _result(self, frame: Frame, seg: Segmentation, reg: Registration, paired: np.ndarray,
                segments: np.ndarray, unpaired: np.ndarray, status: np.ndarray, to_ref: np.ndarray,
                to_img: np.ndarray, preds: list[Prediction], events: list, redets: list,
                timer: StageTimer) -> StarfieldResult:
        m, k = self.manager, frame.index
        lin = to_img[:, :2]
        tracks: list[TrackState] = []
        predicted: set[int] = set()
        chain_points: list[tuple[int, int, float, float, str]] = []
        for ch in m.run + [ch for ch in m.out if ch.last.frame == k]:  # incl. those that exit now
            p = ch.last
            vx, vy = lin @ ch.x[2:]
            tracks.append(TrackState(ch.chain_id, p.u, p.v, float(vx), float(vy), True, False, ch.hits, ch.misses))
            if p.kind == PREDICTED:
                predicted.add(ch.chain_id)
            recent = ch.points if ch.promoted_at == k else ch.points[-3:]
            chain_points.extend((ch.chain_id, q.frame, q.u, q.v, q.kind) for q in recent)
        for ch in m.new:
            p, q = ch.points[-1], ch.points[-2]
            u, v = (p.u, p.v) if p.frame == k else apply(to_img, np.array([[p.x, p.y]]))[0]
            vx, vy = lin @ np.array([p.x - q.x, p.y - q.y])
            tracks.append(TrackState(ch.chain_id, float(u), float(v), float(vx), float(vy), False, False,
                                     len(ch.points), 0))
        n_trail = self.config.tracking.trail_length
        views = []
        for name, lst in ((NEW, m.new), (RUN, m.run), (OUT, m.out)):
            for ch in lst:
                pts = ch.points[-n_trail:]
                xy = apply(to_img, np.array([[q.x, q.y] for q in pts]))
                views.append(ChainView(ch.chain_id, name, xy, tuple(q.kind for q in pts)))
        timings = timer.done()
        return StarfieldResult(
            index=k, time=frame.time, tracks=tuple(tracks), predictions=tuple(preds),
            detections=_subset(seg.points, unpaired[status == CANDIDATE]), events=tuple(events),
            timings=timings, stars=seg.points, paired=paired, registration=reg, pair_segments=segments,
            unpaired=unpaired, unpaired_status=status, to_reference=to_ref.copy(), chains=tuple(views),
            redetections=tuple(redets), predicted=frozenset(predicted), chain_points=tuple(chain_points),
            residual=seg.smoothed, noise_sigma=seg.sigma, defects=self._defects.copy())
