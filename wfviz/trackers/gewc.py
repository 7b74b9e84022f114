"""The GEWC wide-field tracker: mask, horizon, suppression, start points, GEWC + Kalman."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.background import TemporalBackground, change as scene_change, suppress_background
from wfviz.centroid import measure_many
from wfviz.clutter import Novelty, StaticClutter
from wfviz.config import GEWCConfig
from wfviz.defects import BadPixels
from wfviz.detection import Detections, detect, sample_at, score_detections
from wfviz.frames import Frame
from wfviz.horizon import Horizon, HorizonTracker, search_zones
from wfviz.imaging_circle import ImagingCircle, ImagingMask
from wfviz.noise import NoiseEstimate, NoiseModel
from wfviz.registration import CameraMotion, CameraState
from wfviz.track_score import DetectionDensity
from wfviz.trackers.base import FrameResult, StageTimer
from wfviz.tracking import TrackManager


@dataclass(frozen=True)
class Measurement:
    """A track's GEWC (or intensity) measurement in this frame."""

    track_id: int
    x: float
    y: float
    weights: np.ndarray
    detection: int


@dataclass(frozen=True)
class GEWCResult(FrameResult):
    """Every stage's output for one frame (the common fields come from FrameResult)."""

    circle: ImagingCircle | None
    mask: np.ndarray
    mask_changed: bool
    horizon: Horizon | None
    horizon_updated: bool
    suppressed: np.ndarray
    measurements: tuple[Measurement, ...]
    innovations: dict[int, np.ndarray]
    bad_pixels: np.ndarray
    bad_pixels_changed: bool
    camera_shift: tuple[float, float] | None  # (dx, dy) the tracks were moved by (None: not compensated)
    clutter: np.ndarray | None = None  # per detection: 1 static clutter, 0 not, NaN undecided
    noise: NoiseEstimate | None = None  # detection.mode = "cfar"
    camera: CameraState | None = None


class GEWCTracker:
    """Streams frames through the GEWC pipeline; ``step`` returns a :class:`GEWCResult`."""

    name = "gewc"

    def __init__(self, config: GEWCConfig | None = None) -> None:
        self.config = config or GEWCConfig()
        c = self.config
        self._significance = c.detection.mode != "cfar" and (c.detection.significance
                                                             or c.tracking.confirm_significance > 0)
        self.manager = TrackManager(c.kalman, c.tracking, c.detection.k_sigma)
        self.horizon = HorizonTracker(c.horizon)
        self.bad = BadPixels(c.defects)
        self.motion = CameraMotion() if c.tracking.compensate_motion != "off" else None
        self.noise = NoiseModel(c.noise.tile, c.noise.smoothing) if c.detection.mode == "cfar" else None
        self.density = DetectionDensity(c.noise.tile)
        self.temporal = TemporalBackground()
        self.change_noise = NoiseModel(c.noise.tile, c.noise.smoothing)
        self.imaging = ImagingMask(c.circle)
        self.clutter = StaticClutter(c.clutter) if c.clutter.enabled else None
        if self.clutter is not None:
            self.manager.clutter_rule = c.clutter
        self._offset = np.zeros(2)  # accumulated camera shift (scene -> image)
        self._region: np.ndarray | None = None
        self._valid: np.ndarray | None = None
        self._zones: list[np.ndarray] | None = None

    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.imaging.circle

    def step(self, frame: Frame) -> GEWCResult:
        """Run every stage on one frame."""
        c = self.config
        img = frame.image
        timer = StageTimer()
        lap = timer.lap
        raw, img = img, self.bad.clean(img)
        lap("defects")
        mask, mask_changed = self.imaging.update(img)
        if mask_changed or self._valid is None:
            self._valid = ~mask
        valid = self._valid
        lap("mask")
        horizon, horizon_updated = self.horizon.update(img, valid)
        if horizon_updated or mask_changed or self._region is None:
            self._region, self._zones = search_zones(valid, horizon, c.horizon.margin,
                                                     c.horizon.exclude_ground, self.circle is not None)
        lap("horizon")
        camera = shift = None
        if self.motion is not None:
            camera = self.motion.update(img)
            shift = camera.shift
            self._offset = np.asarray(camera.offset, dtype=np.float64)
            self.manager.shift(*shift)
        lap("camera")
        suppressed = suppress_background(img, c.suppression.size, c.suppression.method)
        lap("suppress")
        noise = change_z = None
        if self.noise is not None:
            moved = shift is not None and float(np.hypot(*shift)) > c.noise.tile / 4
            noise = self.noise.update(suppressed, self._region, self._zones, image=img, reset=moved)
            change_z = self._change(raw, suppressed, img, camera)
            lap("noise")
        dets = detect(suppressed, self._region, c.detection, self._zones, noise, change_z)
        dets = score_detections(dets, img, self._region, c.detection, self._significance,
                                c.tracking.confirm_blobness > 0)
        bad_changed = self.bad.update(raw, suppressed, dets.threshold)
        lap("detect")
        labels = None if self.clutter is None else self.clutter.update(
            dets.xy, suppressed, self._offset,
            dets.peak / np.maximum(dets.thresholds(), 1e-12))
        nov = dets.change if dets.change is not None else np.full(len(dets), np.nan)
        preds = self.manager.predict(frame.index)
        pairs = self.manager.associate(preds, dets.xy)
        if c.tracking.reacquire > 0:
            pairs = self.manager.reacquire(preds, dets.xy, pairs, self._could_confirm(dets, labels),
                                           c.tracking.reacquire)
        lap("associate")
        meas = self._measure(pairs, preds, dets, suppressed, noise)
        lap("centroid")
        claimed = self.manager.claimed(preds, dets.xy)
        used = np.zeros(len(dets), dtype=bool)
        used[list(pairs.values())] = True
        born = ~used & ~claimed
        sig, blob = dets.significance, dets.blobness
        self.density.update(dets.xy[~claimed], valid)
        pred_xy = np.array([[p.x, p.y] for p in preds], dtype=np.float64).reshape(-1, 2)
        self.manager.frame_shape = img.shape
        events = self.manager.update(
            {i: (m.x, m.y) for i, m in meas.items()}, dets.xy[born],
            scores=None if sig is None else {i: float(sig[m.detection]) for i, m in meas.items()},
            birth_scores=None if sig is None else sig[born],
            shapes=None if blob is None else {i: float(blob[m.detection]) for i, m in meas.items()},
            birth_shapes=None if blob is None else blob[born],
            clutter=None if labels is None else self._track_clutter(labels, meas),
            birth_clutter=None if labels is None else labels[born],
            density=self.density.at(pred_xy), birth_density=self.density.at(dets.xy[born]),
            novelty={i: float(nov[m.detection]) for i, m in meas.items()}, birth_novelty=nov[born])
        lap("kalman")
        timings = timer.done()
        return GEWCResult(
            index=frame.index, time=frame.time, tracks=tuple(self.manager.states()),
            predictions=tuple(preds), detections=dets, events=tuple(events), timings=timings,
            circle=self.circle, mask=mask, mask_changed=mask_changed, horizon=horizon,
            horizon_updated=horizon_updated, suppressed=suppressed,
            measurements=tuple(meas.values()), innovations=self.manager.innovations(),
            bad_pixels=self.bad.flagged, bad_pixels_changed=bad_changed, camera_shift=shift,
            clutter=labels, noise=noise, camera=camera,
        )

    def _change(self, raw: np.ndarray, suppressed: np.ndarray, img: np.ndarray,
                camera: CameraState | None) -> np.ndarray | None:
        """Change significance of every pixel (:class:`wfviz.background.TemporalBackground`):
        the raw frame's residual (defects not yet replaced, so that a pixel flagged during the
        clip does not look like a change), smoothed by a Gaussian of 1 px (a sharp spot's sampled
        peak depends on where it falls between pixels), against the scene's past, in units of the
        change's own spread and from 0 (static structure is unchanged whatever the change
        image's typical level)."""
        c = self.config
        raw_residual = suppressed if raw is img else suppress_background(raw, c.suppression.size,
                                                                          c.suppression.method)
        now = cv2.GaussianBlur(raw_residual.astype(np.float32), (0, 0), 1.0)
        background = self.temporal.update(now, self._offset, camera is not None and camera.moving)
        if background is None:
            return None
        change = scene_change(now, background)
        known = self._region & np.isfinite(change)
        spread = self.change_noise.update(np.where(known, change, 0.0), known, None, image=img)
        return change / spread.sigma

    def _could_confirm(self, dets: Detections, labels: np.ndarray | None) -> np.ndarray:
        """Detections that pass the confirmation tests in use one by one (significance,
        blobness, not static clutter): the ones a lost track may re-acquire."""
        t = self.config.tracking
        ok = np.ones(len(dets), dtype=bool)
        if dets.significance is not None and t.confirm_significance > 0:
            ok &= dets.significance >= t.confirm_significance
        if dets.blobness is not None:
            ok &= dets.blobness >= t.confirm_blobness
        if labels is not None:
            ok &= labels != 1
        return ok

    def _track_clutter(self, labels: np.ndarray, meas: dict[int, Measurement]) -> dict[int, float]:
        """Each track's static-clutter label: its measurement's, or (meeting mode, no
        measurement) that of the detection nearest its extrapolated position."""
        mgr = self.manager
        out = {int(i): float(labels[d]) for i, d in enumerate(mgr.nearest.tolist())
               if d >= 0 and mgr.meeting[i]}
        out.update({i: float(labels[m.detection]) for i, m in meas.items()})
        return out

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
