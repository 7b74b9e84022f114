"""The GEWC wide-field tracker: mask, horizon, suppression, start points, GEWC + Kalman."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wfviz.io.frames import Frame
from wfviz.stages.centroid import measure_many
from wfviz.stages.clutter import StaticClutter
from wfviz.stages.detection import Detections
from wfviz.stages.front_end import FrontEnd, PreparedSource
from wfviz.stages.imaging_circle import ImagingCircle
from wfviz.stages.noise import NoiseEstimate
from wfviz.stages.registration import CameraState
from wfviz.trackers.base import FrontEndTrackResult, StageTimer, min_side
from wfviz.trackers.gewc.config import GEWCConfig
from wfviz.tracking import Measurements, Prediction, TrackManager, gate_boxes
from wfviz.tracking.association import Association
from wfviz.tracking.clutter_map import ClutterMap, ClutterView
from wfviz.tracking.confirmation import DetectionDensity, gate_threshold, multiframe_only
from wfviz.tracking.subthreshold import ReadNull, read_at


@dataclass(frozen=True)
class Measurement:
    """A track's GEWC (or intensity) measurement in this frame."""

    track_id: int
    x: float
    y: float
    weights: np.ndarray
    detection: int


@dataclass(frozen=True, kw_only=True)
class GEWCResult(FrontEndTrackResult):
    """Every stage's output for one frame (the common fields and the front end's result
    ``front`` come from FrontEndTrackResult; the tracks were moved by ``front.camera.shift``
    when the camera motion is compensated)."""

    measurements: tuple[Measurement, ...]
    clutter: np.ndarray | None = None  # per detection: 1 static clutter, 0 not, NaN undecided
    #: the clutter map at this frame (:meth:`wfviz.tracking.clutter_map.ClutterView.prior` gives
    #: its static-clutter prior per cell of the image; None: no map)
    clutter_map: ClutterView | None = None


#: px: a hit only the multi-frame stage found is taken this close to a prediction only
HEAD_RADIUS = 2.0


class GEWCTracker:
    """Streams frames through the GEWC pipeline; ``step`` returns a :class:`GEWCResult`."""

    name = "gewc"
    #: its front end runs on whole frames (no search windows that follow the tracks): what
    #: comes before detection can be prepared once and replayed (``wfviz tune``'s cache)
    searches_whole_frames = True

    def __init__(self, config: GEWCConfig | None = None, source: PreparedSource | None = None) -> None:
        """``source``: where the front end's prepared frames come from (default: its own
        stages; ``wfviz tune`` replays frames it prepared once, ``wfviz compare`` shares one
        preparation among trackers)."""
        self.config = config or GEWCConfig()
        c = self.config
        self.front = FrontEnd(c, source)
        self.clutter = StaticClutter(c.clutter) if c.clutter.enabled else None
        self.manager = TrackManager(c.kalman, c.tracking, c.detection.k_sigma,
                                    clutter_rule=c.clutter if self.clutter is not None else None)
        self.density = DetectionDensity(c.noise.tile)
        t = c.tracking
        self.clutter_map = (ClutterMap(t.clutter_cell, t.clutter_memory)
                            if t.clutter_map and t.confirm == "sprt" else None)
        self.reads = ReadNull() if t.read_misses and t.confirm == "sprt" else None

    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.front.circle

    def min_frame_side(self) -> int:
        """Smallest frame side the suppression and horizon windows fit in."""
        return min_side(self.config.suppression, self.config.horizon)

    def step(self, frame: Frame) -> GEWCResult:
        """Run every stage on one frame, in the order of docs/pipeline.md: prepare, predict (the
        tracks moved with the camera, then advanced), finish (detection with the confirmed
        gates and their thresholds), associate, measure, update."""
        c = self.config
        timer = StageTimer()
        lap = timer.lap
        shape = frame.image.shape
        prepared = self.front.prepare(frame.image, lap)
        preds = self._predict(frame.index, prepared.camera)
        gate_k = (self._gate_thresholds(preds) if c.tracking.gate_false_alarm > 0 and prepared.noise is not None
                  else None)
        k_map = None if gate_k is None else self._threshold_map(preds, gate_k, shape)
        fe = self.front.finish(prepared, lap, k_map=k_map, gates=gate_boxes(preds, shape[:2]))
        dets, suppressed, valid = fe.detections, fe.suppressed, fe.valid
        labels = None if self.clutter is None else self.clutter.update(
            dets.xy, suppressed, fe.offset, dets.peak / np.maximum(dets.thresholds(), 1e-12))
        assoc = self.manager.associate(preds, dets.xy)
        if c.tracking.reacquire > 0:
            assoc = self.manager.reacquire(preds, dets.xy, assoc, self._could_confirm(dets, labels),
                                           c.tracking.reacquire)
        assoc = self._near_heads_only(assoc, preds, dets, gate_k)
        lap("associate")
        meas = self._measure(assoc.pairs, preds, dets, suppressed, fe.noise)
        lap("centroid")
        self.density.update(dets.xy[~assoc.claimed], valid)
        pred_xy = np.array([[p.x, p.y] for p in preds], dtype=np.float64).reshape(-1, 2)
        track_clutter = None
        if self.clutter_map is not None:
            mine = np.zeros(len(preds))
            if fe.camera is not None and fe.camera.lost:  # where what is seen now lies in the scene is unknown
                self.clutter_map.forget_last()
            else:
                counted, mine = self._unexplained(dets, preds, assoc.pairs, fe.offset)
                self.clutter_map.update(dets.xy[counted], fe.region, fe.offset)
            track_clutter = (*self.clutter_map.at(pred_xy, fe.offset), mine)
        reads = null = None
        if self.reads is not None and fe.change is not None:
            reads = np.full(len(preds), np.nan)  # the confirmed tracks without a hit read (wfviz.tracking.rules)
            missed = np.array([p.confirmed and i not in assoc.pairs for i, p in enumerate(preds)], dtype=bool)
            if missed.any():
                reads[missed] = read_at(fe.change, pred_xy[missed], mask=fe.region)
                null = self.reads.snapshot()  # this frame's reads are not in it
            self.reads.update(fe.change, fe.region)
        events = self.manager.update(
            assoc, Measurements(dets.xy, dets.significance, dets.blobness, dets.change, labels,
                                self.density.at(dets.xy), dets.linearity, dets.max_linearity,
                                size=dets.bbox[:, 2:4]),
            positions={i: (m.x, m.y) for i, m in meas.items()}, track_density=self.density.at(pred_xy),
            gate_k=gate_k, frame_shape=fe.image.shape, track_clutter=track_clutter, track_read=reads,
            read_null=null)
        lap("kalman")
        timings = timer.done()
        return GEWCResult(
            index=frame.index, time=frame.time, tracks=tuple(self.manager.states()),
            predictions=tuple(preds), detections=dets, events=tuple(events), timings=timings, front=fe,
            verdicts=self.manager.verdicts, detection_tracks=self.manager.detection_tracks,
            innovations=self.manager.innovations(), thresholds=self.manager.thresholds,
            measurements=tuple(meas.values()), clutter=labels,
            clutter_map=None if self.clutter_map is None else self.clutter_map.snapshot())

    def _unexplained(self, dets: Detections, preds: list[Prediction], pairs: dict[int, int],
                     offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The detections the clutter map counts: persistent (:meth:`ClutterMap.persistent`) and explained by
        no confirmed track (neither taken by one nor in its gate); and how many of them lie in
        each track's gate (a tentative track's own hits and its target's other parts, which must
        not teach the map that its place is clutter)."""
        assert self.clutter_map is not None
        keep = self.clutter_map.persistent(dets.xy, offset)
        confirmed = self.manager.tracks.confirmed
        keep[[j for i, j in pairs.items() if confirmed[i]]] = False
        mine = np.zeros(len(preds))
        if preds and keep.any():
            g = np.array([[p.x, p.y, p.half_w, p.half_h] for p in preds])
            d = np.abs(dets.xy[keep, None, :] - g[None, :, :2])
            inside = (d[..., 0] <= g[:, 2]) & (d[..., 1] <= g[:, 3])
            rows = np.nonzero(keep)[0]
            keep[rows[(inside & confirmed[None, :]).any(axis=1)]] = False
            mine = (inside & keep[rows, None]).sum(axis=0).astype(np.float64)
        return keep, mine

    def _predict(self, index: int, camera: CameraState | None) -> list[Prediction]:
        """The tracks moved by the camera's shift of this frame (``camera``; None: not
        compensated; unknown on a moving camera: no motion test across this frame), then
        advanced to frame ``index``: the predictions are in this frame's image."""
        if camera is not None:
            self.manager.follow_camera(camera.shift, camera.error, camera.lost)
        return self.manager.predict(index)

    def _gate_thresholds(self, preds: list) -> np.ndarray | None:
        """Per prediction, the threshold (σ) its gate is searched at: lower for confirmed tracks
        not in meeting mode (:func:`wfviz.tracking.confirmation.gate_threshold`, ``tracking.gate_false_alarm``),
        ``detection.k_sigma`` for the others; None when no gate looks deeper."""
        c = self.config
        if c.tracking.confirm != "sprt":
            return None
        deep = np.array([p.confirmed and not p.meeting for p in preds], dtype=bool)
        if not deep.any():
            return None
        k = np.full(len(preds), c.detection.k_sigma)
        half = np.array([[p.half_w, p.half_h] for p in preds])[deep]
        k[deep] = gate_threshold(half, c.tracking.gate_false_alarm, c.detection.k_sigma)
        return k

    def _threshold_map(self, preds: list, k: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Detection threshold (σ) of every pixel: the lowest of the gates covering it
        (:meth:`_gate_thresholds`), ``detection.k_sigma`` outside them."""
        out = np.full(shape[:2], self.config.detection.k_sigma, dtype=np.float32)
        h, w = shape[:2]
        for p, kg in zip(preds, k.tolist()):
            if kg >= self.config.detection.k_sigma:
                continue
            x0, x1 = int(np.ceil(p.x - p.half_w)), int(np.floor(p.x + p.half_w)) + 1
            y0, y1 = int(np.ceil(p.y - p.half_h)), int(np.floor(p.y + p.half_h)) + 1
            if x1 > 0 and y1 > 0 and x0 < w and y0 < h:
                sub = out[max(y0, 0):y1, max(x0, 0):x1]
                np.minimum(sub, np.float32(kg), out=sub)
        return out

    def _could_confirm(self, dets: Detections, labels: np.ndarray | None) -> np.ndarray:
        """Detections that pass the confirmation tests in use one by one (new in the scene for
        the sequential test; significance, blobness, not static clutter for the paper's rule
        with its options; not line-like): the ones a lost track may re-acquire."""
        t = self.config.tracking
        ok = np.ones(len(dets), dtype=bool)
        if t.confirm == "sprt" and dets.change is not None:  # new at its place in the scene
            ok &= np.nan_to_num(dets.change, nan=np.inf) > self.config.detection.k_sigma
        if dets.significance is not None and t.confirm_significance > 0:
            ok &= dets.significance >= t.confirm_significance
        if dets.blobness is not None:
            ok &= dets.blobness >= t.confirm_blobness
        if labels is not None:
            ok &= labels != 1
        return ok & ~dets.line_like()

    def _near_heads_only(self, assoc: Association, preds: list[Prediction], dets: Detections,
                         gate_k: np.ndarray | None) -> Association:
        """``assoc`` without the pairs of a detection only the multi-frame stage found (its own
        significance below the track's threshold) lying more than :data:`HEAD_RADIUS` px from
        the track's prediction: a path head marks where a dim target is to about a pixel, and a
        track that lost its target must not be fed by the noise heads about it."""
        if dets.multiframe is None or dets.significance is None or not assoc.pairs:
            return assoc
        rows = np.array(list(assoc.pairs), dtype=np.int64)
        cols = np.array([assoc.pairs[i] for i in rows], dtype=np.int64)
        k = np.full(len(rows), self.config.detection.k_sigma)
        if gate_k is not None:
            k = np.minimum(np.asarray(gate_k, dtype=np.float64)[rows], k)
        at = np.array([[preds[i].x, preds[i].y] for i in rows])
        far = np.hypot(*(dets.xy[cols] - at).T) > HEAD_RADIUS
        drop = far & multiframe_only(dets.significance[cols], k)
        if not drop.any():
            return assoc
        return assoc.with_pairs({int(i): int(j) for i, j, d in zip(rows, cols, drop) if not d})

    def _measure(self, pairs: dict[int, int], preds: list, dets: Detections,
                 suppressed: np.ndarray, noise: NoiseEstimate | None = None) -> dict[int, Measurement]:
        """GEWC centroid of each assigned detection inside its track's window (of the residual
        above the threshold, or above the local level with the noise estimate: a detection
        found in the change image alone may lie below the threshold)."""
        cc = self.config.centroid
        if not pairs:
            return {}
        tracks = list(pairs)
        di = np.array([pairs[t] for t in tracks], dtype=np.int64)
        sizes = np.maximum(cc.window, dets.bbox[di, 2:4].max(axis=1) + 4)
        results = measure_many(
            suppressed, dets.labels, dets.component[di], dets.xy[di], sizes,
            noise.level if noise is not None else
            dets.threshold if dets.threshold_map is None else dets.threshold_map,
            cc.method, cc.gradient_bins, cc.iterations)
        return {ti: Measurement(preds[ti].track_id, r.x, r.y, r.weights, int(d))
                for ti, d, r in zip(tracks, di, results) if r is not None}
