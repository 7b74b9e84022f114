"""Feature-fusion Kalman tracker (Zheng Jia, Li Jiangyong and Chen Gang): global multi-target
detection, per-target features (centre of the bounding rectangle, area, grey sum) fused into one
matching cost, constant-velocity Kalman search windows, and global re-detection whenever a
confirmed track's window holds no candidate.

Per frame (:meth:`FusionTracker.step`; the order of docs/pipeline.md):

1. Kalman prediction of every track (``TrackManager.predict``), before the camera shift is
   known: the gate is the search window, in the previous frame's image.
2. ``defects``, ``mask``, ``horizon`` (global frames only), ``camera``, ``suppress``, ``noise``,
   ``change``: the front end's stages before detection (``FrontEnd.prepare``); the tracks'
   states (not the predictions) are then moved by the camera's shift.
3. ``detect``: inside the windows only (with the noise statistics of the last global
   detection), or global detection on the whole frame on the first frame, while no track is
   confirmed, every ``fusion.detect_every`` frames, and whenever a confirmed track's window
   holds no candidate (``FrontEnd.redetect``: the window search is then replaced by the global
   candidates). Connected components, features.
4. ``associate``: optimal assignment minimising the fused cost (confirmed tracks first, no
   candidate used twice); a confirmed track whose window is empty may *recover* the best
   candidate of the global detection within ``fusion.recover_radius``.
5. ``kalman``: updates, hits and misses, births from unused global detections.

Features and the fused cost (docs/pipeline.md, "The feature-fusion tracker"): the centre c is
the centre of the component's bounding rectangle (axis-aligned by default), the area a its
pixel count, the grey sum g the sum of its background-suppressed residual. With the track's
predicted centre, window half sizes (w, h) and last matched area and grey sum,

    cost = α·‖(Δx / w, Δy / h)‖ + β·|a_t − a| / max(a_t, a) + γ·|g_t − g| / max(g_t, g)

(``fusion.cost = "sum"``), or ``|Φ_t − Φ(j)|`` of the scalar fused feature
Φ = α·ĉ + β·a / a₀ + γ·g / g₀ (``"scalar"``; ĉ the position normalised by the frame, a₀ and g₀
the means of the track's matched areas and grey sums). Φ is logged per track in both modes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from wfviz.io.frames import Frame
from wfviz.stages.detection import Detections
from wfviz.stages.front_end import FrontEnd
from wfviz.stages.imaging_circle import ImagingCircle
from wfviz.trackers.base import FrontEndTrackResult, StageTimer, min_side
from wfviz.trackers.fusion.config import FusionConfig
from wfviz.trackers.fusion.features import (Features, box_corners, fused_cost, min_area_rects,
                                           scalar_phi)
from wfviz.tracking import (EventKind, Measurements, Prediction, TrackEvent, TrackManager, assign_confirmed_first,
                            gate_boxes)
from wfviz.tracking.confirmation import DetectionDensity

_BIG = 1e9
DENSE_CROPS = 64  # more search crops than this: one full-frame crop is faster


@dataclass(frozen=True)
class Match:
    """A track continued by a candidate: fused cost, scalar Φ, recovered by global detection."""

    track_id: int
    detection: int
    x: float
    y: float
    cost: float
    phi: float
    recovered: bool


@dataclass(frozen=True, kw_only=True)
class FusionResult(FrontEndTrackResult):
    """Every stage's output for one frame (the common fields and the front end's result
    ``front`` come from FrontEndTrackResult).

    ``detections`` are the frame's candidates: all components of the global detection on
    global frames, the components found inside the search windows otherwise (their ``xy`` is
    ``features.centre``; ``front.detections`` has the components' own centroids).
    ``front.suppressed`` is the whole frame's residual on every frame.
    """

    features: Features
    matches: tuple[Match, ...]
    assigned: np.ndarray  # (N,) track id of each candidate, -1 when unused
    global_detection: bool
    global_reason: str  # "" when only the windows were searched
    searched: tuple[tuple[int, int, int, int], ...]  # (x0, y0, x1, y1) crops searched
    lost: tuple[Prediction, ...]  # confirmed tracks whose window held no candidate
    recover_radius: float


@dataclass
class _Ref:
    """A track's reference features: last matched area and grey sum (the fused cost), their
    means over the track's matches (the scales a₀, g₀ of the scalar Φ), and whether its last
    frame was a match inside its own window (only then may it recover)."""

    area: float
    grey: float
    area0: float
    grey0: float
    n: int = 1
    phi: float = float("nan")
    in_window: bool = True

    def add(self, area: float, grey: float, phi: float, in_window: bool) -> None:
        self.n += 1
        self.area0 += (area - self.area0) / self.n
        self.grey0 += (grey - self.grey0) / self.n
        self.area, self.grey, self.phi, self.in_window = area, grey, phi, in_window


class FusionTracker:
    """Streams frames through the feature-fusion pipeline; ``step`` returns a :class:`FusionResult`."""

    name = "fusion"

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        c = self.config
        self.front = FrontEnd(c)
        self.manager = TrackManager(c.kalman, c.tracking, c.detection.k_sigma)
        self.density = DetectionDensity(c.noise.tile)
        self._refs: dict[int, _Ref] = {}
        self._steps = 0

    # -- helpers --------------------------------------------------------------------------
    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.front.circle

    def _crops(self, preds: list[Prediction], shape: tuple[int, int]
               ) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
        """Search crops: each window grown by ``fusion.pad``; overlapping ones are searched as
        one crop (their union box). When the crops would cover more than a quarter of the
        frame or number more than ``DENSE_CROPS``, one full-frame crop is cheaper.

        Returns [((x0, y0, x1, y1) half-open, prediction indices), ...]."""
        h, w = shape
        if not preds:
            return []
        pad = self.config.fusion.pad
        c = np.array([[p.x, p.y] for p in preds])
        hs = np.array([[p.half_w, p.half_h] for p in preds])
        lo = np.floor(c - hs).astype(np.int64) - pad
        hi = np.ceil(c + hs).astype(np.int64) + pad + 1
        lo = np.maximum(lo, 0)
        hi = np.minimum(hi, [w, h])
        ok = (hi > lo).all(axis=1)
        idx = np.nonzero(ok)[0]
        if idx.size == 0:
            return []
        lo, hi = lo[idx], hi[idx]
        area = np.prod(hi - lo, axis=1).sum()
        if idx.size > DENSE_CROPS or area > 0.25 * h * w:
            return [((0, 0, w, h), idx)]
        overlap = ((lo[:, None, :] < hi[None, :, :]) & (lo[None, :, :] < hi[:, None, :])).all(axis=2)
        comp = np.arange(idx.size)
        while True:  # each crop takes the smallest index of its overlap cluster
            new = np.where(overlap, comp[None, :], idx.size).min(axis=1)
            if np.array_equal(new, comp):
                break
            comp = new
        out = []
        for k in np.unique(comp):
            m = np.nonzero(comp == k)[0]
            x0, y0 = lo[m].min(axis=0)
            x1, y1 = hi[m].max(axis=0)
            out.append(((int(x0), int(y0), int(x1), int(y1)), idx[m]))
        return out

    def _window_mask(self, preds: list[Prediction], search: list[int], shape: tuple[int, int]
                     ) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
        """The pixels of the search crops of the tracks ``search`` (and the crops)."""
        mask = np.zeros(shape, dtype=bool)
        crops = [box for box, _ in self._crops([preds[i] for i in search], shape)]
        for x0, y0, x1, y1 in crops:
            mask[y0:y1, x0:x1] = True
        return mask, crops

    def _features(self, dets: Detections, img: np.ndarray) -> tuple[Detections, Features]:
        """The fused features of each candidate (centre, area, grey sum, rectangle); the
        detections' positions become the feature centres."""
        c = self.config
        if not len(dets):
            return dets, Features(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 4, 2)))
        b = dets.bbox.astype(np.float64)
        rects = box_corners(b)
        if c.features.centre == "min_area_rect":
            centre, rects = min_area_rects(dets.labels, dets.component)
        elif c.features.centre == "centroid":
            centre = dets.xy.astype(np.float64)
        else:
            centre = np.column_stack([b[:, 0] + (b[:, 2] - 1) / 2.0, b[:, 1] + (b[:, 3] - 1) / 2.0])
        if c.features.grey == "raw":
            idx = np.flatnonzero(dets.labels)
            sums = np.bincount(dets.labels.ravel()[idx], weights=img.ravel()[idx].astype(np.float64),
                               minlength=int(dets.component.max()) + 1)
            grey = sums[dets.component]
        else:
            grey = dets.flux.astype(np.float64)
        feats = Features(centre, dets.area, grey, rects)
        return replace(dets, xy=feats.centre), feats

    # -- per frame ------------------------------------------------------------------------
    def min_frame_side(self) -> int:
        """Smallest frame side the suppression and horizon windows fit in."""
        return min_side(self.config.suppression, self.config.horizon)

    def step(self, frame: Frame) -> FusionResult:
        """Run every stage on one frame, in the order of docs/pipeline.md: predict, prepare, the
        tracks and their predictions moved with the camera (the windows and gates are in this
        frame's image), finish (detection in the windows or the
        whole frame, with the confirmed gates), associate (with global re-detection), update."""
        fc = self.config.fusion
        timer = StageTimer(("defects", "mask", "horizon", "camera", "suppress", "noise", "change",
                            "detect", "associate", "kalman"))
        lap = timer.lap
        shape = frame.image.shape
        mgr = self.manager
        preds = mgr.predict(frame.index)
        pred_xy = np.array([[p.x, p.y] for p in preds], dtype=np.float64).reshape(-1, 2)
        half = np.array([[p.half_w, p.half_h] for p in preds], dtype=np.float64).reshape(-1, 2)
        confirmed = np.array([p.confirmed for p in preds], dtype=bool)
        active = np.array([not p.meeting for p in preds], dtype=bool)  # meeting tracks take nothing
        gates = gate_boxes(preds, shape[:2])  # confirmed gates, below the horizon too
        lap("associate")

        reason = ""
        if self._steps == 0:
            reason = "first frame"
        elif not confirmed.any():
            reason = "no confirmed track"
        elif fc.detect_every > 0 and self._steps % fc.detect_every == 0:
            reason = f"periodic, every {fc.detect_every} frames"
        self._steps += 1

        searched: list = []
        pairs: dict[int, int] = {}
        lost: list[int] = []
        # a window frame is prepared for its windows: the noise statistics and the horizon stay
        prepared = self.front.prepare(frame.image, lap, whole=bool(reason), update_horizon=bool(reason))
        if prepared.camera is not None:  # the tracks and their predictions move with the camera
            camera = prepared.camera
            mgr.follow_camera(camera.shift, camera.error, camera.lost)
            if camera.shift != (0.0, 0.0):
                preds = [replace(p, x=p.x + camera.shift[0], y=p.y + camera.shift[1]) for p in preds]
                pred_xy = pred_xy + np.asarray(camera.shift)
                gates = gate_boxes(preds, shape[:2])
        if not reason:
            search = [i for i in range(len(preds)) if active[i]]
            windows, searched = self._window_mask(preds, search, shape)
            fe = self.front.finish(prepared, lap, windows=windows, gates=gates)
            dets, feats = self._features(fe.detections, fe.image)
            pairs, cost = self._associate(preds, pred_xy, half, confirmed, active, feats, shape)
            lost = [i for i in range(len(preds)) if confirmed[i] and active[i] and i not in pairs]
            lap("associate")
            if lost:
                ids = ", ".join(str(preds[i].track_id) for i in lost)
                reason = f"track{'s' if len(lost) > 1 else ''} {ids}: no candidate in the search window"
        else:
            fe = self.front.finish(prepared, lap, gates=gates)
        is_global = bool(reason)
        events_pre: list[TrackEvent] = []
        recovered: dict[int, int] = {}
        recover_cost: dict[int, float] = {}
        if is_global:
            for i in lost:
                events_pre.append(TrackEvent(frame.index, EventKind.WINDOW_LOST, preds[i].track_id,
                                             f"track {preds[i].track_id}: no candidate in its search "
                                             f"window, global detection reruns"))
            if lost:  # the windows were searched: detect in the whole frame, this frame's statistics
                fe = self.front.redetect(fe, lap, gates=gates)
            searched = []
            dets, feats = self._features(fe.detections, fe.image)
            pairs, cost = self._associate(preds, pred_xy, half, confirmed, active, feats, shape)
            lost = [i for i in range(len(preds)) if confirmed[i] and active[i] and i not in pairs]
            recovered, recover_cost = self._recover(preds, pred_xy, lost, pairs, feats, confirmed, half, shape)
            lap("associate")
        matches, meas = self._matches(preds, pairs, recovered, recover_cost, cost, feats, shape)
        taken = {**pairs, **recovered}
        assoc = mgr.gate(preds, feats.centre).with_pairs(taken)
        if is_global and len(dets):
            self.density.update(feats.centre[~assoc.claimed], fe.valid)
        born_idx = mgr.initiate(assoc, start=None if is_global else False)
        velocities = {i: mgr.velocity(i) for i in recovered}
        self._restart(preds, recovered, velocities, feats)  # before the update: no jump to score
        events = events_pre + mgr.update(
            assoc, Measurements(feats.centre, dets.significance, dets.blobness, dets.change,
                                density=self.density.at(feats.centre), size=dets.bbox[:, 2:4]),
            positions=meas, track_density=self.density.at(pred_xy), start=None if is_global else False,
            frame_shape=shape)
        events += [TrackEvent(frame.index, EventKind.RECOVERED, preds[i].track_id,
                              f"track {preds[i].track_id} recovered by global detection at "
                              f"({feats.centre[j, 0]:.1f}, {feats.centre[j, 1]:.1f}), "
                              f"{math.hypot(*(feats.centre[j] - pred_xy[i])):.1f} px from its prediction")
                   for i, j in recovered.items()]
        self._update_refs(events, born_idx, feats, matches)
        lap("kalman")
        assigned = np.full(len(dets), -1, dtype=np.int64)
        for m in matches:
            assigned[m.detection] = m.track_id
        timings = timer.done()
        return FusionResult(
            index=frame.index, time=frame.time, tracks=tuple(mgr.states()),
            predictions=tuple(preds), detections=dets, events=tuple(events), timings=timings, front=fe,
            verdicts=mgr.verdicts, detection_tracks=mgr.detection_tracks,
            innovations=mgr.innovations(), thresholds=mgr.thresholds,
            features=feats, matches=tuple(matches), assigned=assigned, global_detection=is_global,
            global_reason=reason, searched=tuple(searched),
            lost=tuple(preds[i] for i in lost if i not in recovered), recover_radius=fc.recover_radius)

    # -- association ----------------------------------------------------------------------
    def _ref_arrays(self, preds: list[Prediction]) -> tuple[np.ndarray, ...]:
        refs = [self._refs.get(p.track_id) for p in preds]
        get = (lambda attr: np.array([getattr(r, attr) if r else np.nan for r in refs], dtype=np.float64))  # noqa: E731
        return get("area"), get("grey"), get("area0"), get("grey0")

    def _cost(self, preds: list[Prediction], pred_xy: np.ndarray, half: np.ndarray, feats: Features,
              shape: tuple[int, int]) -> np.ndarray:
        """(T, N) fused matching cost of the configured kind."""
        fc = self.config.fusion
        area, grey, area0, grey0 = self._ref_arrays(preds)
        if fc.cost == "scalar":
            phi_t = scalar_phi(pred_xy, area, grey, area0, grey0, shape, fc.alpha, fc.beta, fc.gamma)
            phi_c = scalar_phi(feats.centre[None, :, :], feats.area[None, :].astype(np.float64),
                               feats.grey[None, :], area0[:, None], grey0[:, None], shape,
                               fc.alpha, fc.beta, fc.gamma)
            cost = np.abs(phi_t[:, None] - phi_c)
        else:
            cost = fused_cost(pred_xy, half, area, grey, feats.centre, feats.area, feats.grey,
                              fc.alpha, fc.beta, fc.gamma)
        return np.where(np.isfinite(cost), cost, _BIG)

    def _associate(self, preds: list[Prediction], pred_xy: np.ndarray, half: np.ndarray,
                   confirmed: np.ndarray, active: np.ndarray, feats: Features,
                   shape: tuple[int, int]) -> tuple[dict[int, int], np.ndarray]:
        """{prediction index: candidate index} by minimal fused cost inside the windows."""
        if not preds or not len(feats):
            return {}, np.zeros((len(preds), len(feats)))
        cost = self._cost(preds, pred_xy, half, feats, shape)
        diff = np.abs(feats.centre[None, :, :] - pred_xy[:, None, :])
        ok = (diff <= half[:, None, :]).all(axis=2) & active[:, None] & (cost <= self.config.fusion.max_cost)
        return assign_confirmed_first(cost, ok, confirmed), cost

    def _recover(self, preds: list[Prediction], pred_xy: np.ndarray, lost: list[int],
                 pairs: dict[int, int], feats: Features, confirmed: np.ndarray, half: np.ndarray,
                 shape: tuple[int, int]) -> tuple[dict[int, int], dict[int, float]]:
        """Lost confirmed tracks take the best unused global candidate within the recovery
        radius (centre term normalised by the radius), outside other confirmed windows."""
        # a target that *left* its window: the track was measured inside it on the last frame
        # (repeated recoveries would keep a track on clutter alive indefinitely)
        lost = [i for i in lost if (ref := self._refs.get(preds[i].track_id)) is not None and ref.in_window]
        if not lost or not len(feats):
            return {}, {}
        fc = self.config.fusion
        r = fc.recover_radius
        sub = [preds[i] for i in lost]
        cost = self._cost(sub, pred_xy[lost], np.full((len(lost), 2), r), feats, shape)
        dist = np.hypot(*(feats.centre[None, :, :] - pred_xy[lost][:, None, :]).transpose(2, 0, 1))
        used = np.zeros(len(feats), dtype=bool)
        used[list(pairs.values())] = True
        others = [i for i in range(len(preds)) if confirmed[i] and i not in lost]
        if others:
            d = np.abs(feats.centre[None, :, :] - pred_xy[others][:, None, :])
            used |= (d <= half[others][:, None, :]).all(axis=2).any(axis=0)
        ok = (dist <= r) & ~used[None, :] & (cost <= fc.recover_max_cost)
        got = assign_confirmed_first(cost, ok, np.ones(len(lost), dtype=bool))
        return {lost[k]: j for k, j in got.items()}, {lost[k]: float(cost[k, j]) for k, j in got.items()}

    def _matches(self, preds: list[Prediction], pairs: dict[int, int], recovered: dict[int, int],
                 recover_cost: dict[int, float], cost: np.ndarray, feats: Features,
                 shape: tuple[int, int]
                 ) -> tuple[list[Match], dict[int, tuple[float, float]]]:
        fc = self.config.fusion
        out, meas = [], {}
        for i, j in list(pairs.items()) + list(recovered.items()):
            p = preds[i]
            ref = self._refs.get(p.track_id)
            a0, g0 = (ref.area0, ref.grey0) if ref else (float(feats.area[j]), float(feats.grey[j]))
            phi = float(scalar_phi(feats.centre[j], float(feats.area[j]), float(feats.grey[j]), a0, g0,
                                   shape, fc.alpha, fc.beta, fc.gamma))
            cst = float(cost[i, j]) if i in pairs else recover_cost[i]  # recovery: centre term / radius
            x, y = float(feats.centre[j, 0]), float(feats.centre[j, 1])
            out.append(Match(p.track_id, j, x, y, cst, phi, i in recovered))
            meas[i] = (x, y)
        return out, meas

    # -- bookkeeping ----------------------------------------------------------------------
    def _restart(self, preds: list[Prediction], recovered: dict[int, int], velocities: dict,
                 feats: Features) -> None:
        """A recovered track restarts its filter at the new position (velocity kept, P = P₀):
        the old state would pull its next window back towards where the target was lost."""
        if not recovered:
            return
        for i, j in recovered.items():
            self.manager.restart(preds[i].track_id, np.array(
                [feats.centre[j, 0], feats.centre[j, 1], *velocities[i]], dtype=np.float64))

    def _update_refs(self, events: list[TrackEvent], born_idx: np.ndarray, feats: Features,
                     matches: list[Match]) -> None:
        matched = {m.track_id for m in matches}
        for tid, ref in self._refs.items():
            if tid not in matched:
                ref.in_window = False
        for m in matches:
            ref = self._refs.get(m.track_id)
            a, g = float(feats.area[m.detection]), float(feats.grey[m.detection])
            if ref is None:
                self._refs[m.track_id] = _Ref(a, g, a, g, 1, m.phi, not m.recovered)
            else:
                ref.add(a, g, m.phi, not m.recovered)
        born = [e.track_id for e in events if e.kind == EventKind.BORN]
        for tid, j in zip(born, born_idx):
            a, g = float(feats.area[j]), float(feats.grey[j])
            self._refs[tid] = _Ref(a, g, a, g)
        live = set(self.manager.track_ids)
        for tid in list(self._refs):
            if tid not in live:
                del self._refs[tid]
