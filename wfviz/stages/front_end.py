"""The stages every detection-based tracker shares (GEWC and fusion): defects, imaging circle,
sky–ground line, camera motion, background suppression, local noise, change in the scene and
noise-aware detection. Each frame goes through :meth:`FrontEnd.step`; the tracker then
associates, measures and manages tracks.

Order and stages (docs/pipeline.md):

1. ``defects``: flagged hot and dead pixels replaced (:mod:`wfviz.stages.defects`).
2. ``mask``: the imaging circle of a fisheye lens and the frame border (:mod:`wfviz.stages.imaging_circle`).
3. ``horizon``: the sky–ground line, re-estimated every ``horizon.every`` frames
   (:mod:`wfviz.stages.horizon`); the search region and its zones follow from it.
4. ``camera``: the scene's offset in the image (:mod:`wfviz.stages.registration`).
5. ``suppress``: the paper's 5 × 5 background suppression (:mod:`wfviz.stages.background`).
6. ``noise``: the residual's local level and noise σ (:mod:`wfviz.stages.noise`).
7. ``change``: what is new at each place in the scene, in its own noise σ
   (:class:`wfviz.stages.background.TemporalBackground`).
8. ``detect``: components above ``k_sigma`` in either significance (:func:`wfviz.stages.detection.detect`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol

import cv2
import numpy as np

from wfviz.config import (CircleConfig, DefectsConfig, DetectionConfig, HorizonConfig, NoiseConfig,
                          SuppressionConfig, TrackingConfig)
from wfviz.stages.background import TemporalBackground, change as scene_change, gain, suppress_background
from wfviz.stages.defects import BadPixels
from wfviz.stages.detection import Detections, detect, sample_at, score_detections, typical_threshold
from wfviz.stages.horizon import Horizon, HorizonTracker, search_zones
from wfviz.stages.imaging_circle import ImagingCircle, ImagingMask
from wfviz.stages.noise import NoiseEstimate, NoiseModel, TailCalibration
from wfviz.stages.registration import CameraMotion, CameraState


class FrontEndConfig(Protocol):
    """The sections of a tracker's configuration the front end reads (GEWC's and fusion's both
    have them)."""

    defects: DefectsConfig
    circle: CircleConfig
    horizon: HorizonConfig
    suppression: SuppressionConfig
    noise: NoiseConfig
    detection: DetectionConfig
    tracking: TrackingConfig


SPATIAL_OVERALL = False  # the residual's tail calibration holds a floor over the whole frame
#: confirmed tracks' gates (``gates`` of :meth:`FrontEnd.step`) are searched below the horizon
#: too (False: the search region only, for ablations)
GATES_CROSS_HORIZON = True
CHANGE_OVERALL = True   # the change's does


@dataclass(frozen=True)
class PreparedFrame:
    """A frame through the stages before detection (:meth:`FrontEnd.prepare`; the fields are
    described at :class:`FrontEndResult`; ``region`` here without any tracker's windows or
    gates)."""

    image: np.ndarray
    raw: np.ndarray
    mask: np.ndarray
    mask_changed: bool
    valid: np.ndarray
    circle: ImagingCircle | None
    horizon: Horizon | None
    horizon_updated: bool
    region: np.ndarray
    zones: list[np.ndarray] | None
    camera: CameraState | None
    offset: np.ndarray
    suppressed: np.ndarray
    noise: NoiseEstimate | None
    change: np.ndarray | None
    bad_pixels: np.ndarray
    bad_pixels_changed: bool


@dataclass(frozen=True)
class FrontEndResult(PreparedFrame):
    """One frame through the shared stages: a :class:`PreparedFrame` (``region`` here with the
    tracker's windows and gates) and this frame's ``detections``, with significance and change.

    ``image``: the frame with defects replaced (``raw``: as read); ``valid``: inside the imaging
    area; ``region``: where detections are searched; ``zones``: the parts of it with their own
    noise statistics (None: one); ``offset``: the camera's (scene point s is at s + offset);
    ``suppressed``: the background-suppressed residual; ``noise``: its local level and σ (None
    outside "cfar" detection); ``change``: the change significance of every pixel (None on the
    first frame).
    """

    detections: Detections


def _unknown_at(change: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """``change`` with NaN (unknown) in the 3 × 3 neighbourhood of each (row, col) of ``pixels``
    (flagged defects: the change map is built from the raw frame, so a defect's own flicker
    would otherwise be detected as a change)."""
    out = change.copy()
    h, w = out.shape
    d = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)])
    rc = (pixels[:, None, :] + d[None, :, :]).reshape(-1, 2)
    rc = rc[(rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)]
    out[rc[:, 0], rc[:, 1]] = np.nan
    return out


class FrontEnd:
    """Streams frames through the shared stages (module docstring). ``config`` needs the
    sections ``defects``, ``circle``, ``horizon``, ``suppression``, ``noise``, ``detection`` and
    ``tracking`` (for ``compensate_motion`` and the shape test): :class:`FrontEndConfig`."""

    def __init__(self, config: FrontEndConfig) -> None:
        c = self.config = config
        self.bad = BadPixels(c.defects)
        self.imaging = ImagingMask(c.circle)
        self.horizon = HorizonTracker(c.horizon)
        self.motion = CameraMotion() if c.tracking.compensate_motion != "off" else None
        cfar = c.detection.mode == "cfar"
        self.noise = NoiseModel(c.noise.tile, c.noise.smoothing) if cfar else None
        self.temporal = TemporalBackground() if cfar else None
        self.change_noise = NoiseModel(c.noise.tile, c.noise.smoothing) if cfar else None
        self._significance = not cfar and (c.detection.significance or c.tracking.confirm_significance > 0)
        self._valid: np.ndarray | None = None
        self._region: np.ndarray | None = None
        self._zones: list[np.ndarray] | None = None
        self._offset = np.zeros(2)
        self._noise: NoiseEstimate | None = None
        self._spread: NoiseEstimate | None = None
        self.tail = TailCalibration(c.noise.tile, refresh=c.noise.every)         # of the residual's significance
        self.change_tail = TailCalibration(c.noise.tile, refresh=c.noise.every)  # of the change significance
        self._change_scale: np.ndarray | None = None  # 1 / (spread x tail factor) of the change
        self._frame = 0
        self._gain: float | None = None  # of the change (automatic gain control)

    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.imaging.circle

    def step(self, raw: np.ndarray, lap: Callable[[str], None], windows: np.ndarray | None = None,
             update_horizon: bool = True,
             k_map: Callable[[CameraState | None], np.ndarray | None] | None = None,
             gates: Callable[[CameraState | None], list[tuple[slice, slice]]] | None = None) -> FrontEndResult:
        """Every stage on one frame; ``lap(stage)`` is called as each stage ends (timing).
        ``windows`` (a mask): detect only there, with the noise statistics of the last frame
        searched whole (a tracker's search windows; with a global or box threshold, this
        frame's threshold over the whole search region); the temporal background still learns every
        frame. ``update_horizon``: the horizon may be re-estimated on this frame (when due).
        ``k_map(camera)``: called once the camera motion is known, the detection threshold of
        every pixel in σ (None: ``detection.k_sigma``; see :func:`wfviz.stages.detection.detect`).
        ``gates(camera)``: likewise, boxes (row and column slices) searched besides the search
        region (confirmed tracks' gates, which may reach below the horizon).

        The same as :meth:`finish` of :meth:`prepare`: what comes before the detection does not
        depend on the tracks when the frame is searched whole in "cfar" mode
        (:meth:`independent_of_tracks`), so it can be computed once and replayed."""
        return self.finish(self.prepare(raw, lap, windows is None, update_horizon), lap, windows, k_map, gates)

    @staticmethod
    def prepare_key(config: FrontEndConfig) -> tuple:
        """Every configuration value :meth:`prepare` reads: two configurations with the same
        key prepare every frame the same (``wfviz tune``'s front-end cache is keyed by it)."""
        c = config
        return (c.defects, c.circle, c.horizon, c.suppression, c.noise, c.detection.mode,
                c.tracking.compensate_motion)

    @staticmethod
    def independent_of_tracks(config: FrontEndConfig) -> bool:
        """Whether :meth:`prepare` of frames searched whole gives the same whatever the tracks
        with ``config`` (in "cfar" mode; with a global or box threshold the defect stage takes
        the detection's threshold, which the tracks' gates change)."""
        return config.detection.mode == "cfar"

    def prepare(self, raw: np.ndarray, lap: Callable[[str], None], whole: bool = True,
                update_horizon: bool = True) -> PreparedFrame:
        """The stages before detection (:meth:`step`); ``whole``: the frame is searched whole
        (no windows: the noise statistics may be re-estimated)."""
        c = self.config
        img = self.bad.clean(raw)
        lap("defects")
        mask, mask_changed = self.imaging.update(img)
        if mask_changed or self._valid is None:
            self._valid = ~mask
        valid = self._valid
        lap("mask")
        horizon, horizon_updated = (self.horizon.update(img, valid) if update_horizon
                                    else (self.horizon.horizon, False))
        if horizon_updated or mask_changed or self._region is None:
            self._region, self._zones = search_zones(valid, horizon, c.horizon.margin,
                                                     c.horizon.exclude_ground, self.circle is not None)
        lap("horizon")
        camera = None
        if self.motion is not None:
            camera = self.motion.update(img)
            self._offset = np.asarray(camera.offset, dtype=np.float64)
        lap("camera")
        suppressed = suppress_background(img, c.suppression.size, c.suppression.method)
        lap("suppress")
        noise = change = None
        self._frame += 1
        moved = camera is not None and float(np.hypot(*camera.shift)) > c.noise.tile / 4
        due = moved or mask_changed or horizon_updated or (self._frame - 1) % c.noise.every == 0
        bad_changed = False
        if self.noise is not None:
            if (whole and due) or self._noise is None:
                est = self.noise.update(suppressed, self._region, self._zones, image=img, reset=moved)
                g = self.tail.update(est.significance(suppressed), self._region, overall=SPATIAL_OVERALL)
                self._noise = replace(est, sigma=est.sigma * g)
            noise = self._noise
            lap("noise")
            change = self._change(raw, img, suppressed, camera, whole and due)
            if change is not None and len(self.bad.flagged):
                change = _unknown_at(change, self.bad.flagged)
            lap("change")
            # a hot pixel's spike exceeds defects.k_sigma of the typical local noise
            bad_changed = self.bad.update(raw, suppressed, typical_threshold(noise, c.defects.k_sigma))
            lap("defects")
        return PreparedFrame(img, raw, mask, mask_changed, valid, self.circle, horizon, horizon_updated,
                             self._region, self._zones, camera, self._offset.copy(), suppressed, noise,
                             change, self.bad.flagged, bad_changed)

    def finish(self, p: PreparedFrame, lap: Callable[[str], None], windows: np.ndarray | None = None,
               k_map: Callable[[CameraState | None], np.ndarray | None] | None = None,
               gates: Callable[[CameraState | None], list[tuple[slice, slice]]] | None = None) -> FrontEndResult:
        """Detection on a frame from :meth:`prepare` (:meth:`step`)."""
        c = self.config
        noise, camera, valid = p.noise, p.camera, p.valid
        region = p.region if windows is None else p.region & windows
        kmap = k_map(camera) if k_map is not None and noise is not None else None
        boxes = gates(camera) if gates is not None and GATES_CROSS_HORIZON else []
        full = _with_boxes(p.region, boxes, valid)  # the search region and confirmed gates
        region = _with_boxes(region, boxes, valid, windows)
        if windows is not None and c.detection.mode != "cfar":
            # a global or box threshold is a statistic of the whole search region, not of the
            # windows (whose own statistics a bright target inflates): detect there, keep the
            # candidates inside the windows
            dets = detect(p.suppressed, full, c.detection, p.zones, noise, p.change, kmap)
            dets = dets.subset(sample_at(windows, dets.xy))
        else:
            dets = detect(p.suppressed, region, c.detection, p.zones, noise, p.change, kmap)
        dets = score_detections(dets, p.image, full, c.detection, self._significance,
                                c.tracking.confirm_blobness > 0)
        bad_pixels, bad_changed = p.bad_pixels, p.bad_pixels_changed
        if not self.independent_of_tracks(c):  # the defect stage takes the detection's threshold
            bad_changed = self.bad.update(p.raw, p.suppressed, dets.threshold)
            bad_pixels = self.bad.flagged
        lap("detect")
        return FrontEndResult(p.image, p.raw, p.mask, p.mask_changed, valid, p.circle, p.horizon,
                              p.horizon_updated, region, p.zones, camera, p.offset, p.suppressed, noise,
                              p.change, bad_pixels, bad_changed, dets)

    def redetect(self, result: FrontEndResult, lap: Callable[[str], None],
                 gates: Callable[[CameraState | None], list[tuple[slice, slice]]] | None = None) -> FrontEndResult:
        """``result`` (a frame searched in windows only) detected again over the whole search
        region (and ``gates``, as in :meth:`step`), with this frame's own noise statistics (the
        other stages are not repeated)."""
        c = self.config
        noise = result.noise
        if self.noise is not None:
            est = self.noise.update(result.suppressed, self._region, self._zones, image=result.image)
            g = self.tail.update(est.significance(result.suppressed), self._region, overall=SPATIAL_OVERALL)
            noise = self._noise = replace(est, sigma=est.sigma * g)
            lap("noise")
        boxes = gates(result.camera) if gates is not None and GATES_CROSS_HORIZON else []
        region = _with_boxes(self._region, boxes, result.valid)
        dets = detect(result.suppressed, region, c.detection, self._zones, noise, result.change)
        dets = score_detections(dets, result.image, region, c.detection, self._significance,
                                c.tracking.confirm_blobness > 0)
        lap("detect")
        return replace(result, region=region, noise=noise, detections=dets)

    def _change(self, raw: np.ndarray, img: np.ndarray, suppressed: np.ndarray,
                camera: CameraState | None, learn_spread: bool) -> np.ndarray | None:
        """Change significance of every pixel (:class:`wfviz.stages.background.TemporalBackground`):
        the raw frame's residual (defects not yet replaced, so that a pixel flagged during the
        clip does not look like a change), smoothed by a Gaussian of 1 px (a sharp spot's
        sampled peak depends on where it falls between pixels), against the scene's past, in
        units of the change's own spread and from 0 (static structure is unchanged whatever the
        change image's typical level). ``learn_spread``: re-estimate that spread (else the last
        one)."""
        c = self.config
        raw_residual = suppressed if raw is img else suppress_background(raw, c.suppression.size,
                                                                          c.suppression.method)
        now = cv2.GaussianBlur(raw_residual.astype(np.float32), (0, 0), 1.0)
        background = self.temporal.update(now, self._offset, camera is not None and camera.moving)
        if background is None:
            return None
        if learn_spread or self._gain is None:
            self._gain = gain(now, background)
        change = scene_change(now, background, self._gain)
        if learn_spread or self._spread is None:
            known = self._region & np.isfinite(change)
            self._spread = self.change_noise.update(np.where(known, change, 0.0), known, None, image=img)
            z = cv2.divide(change, self._spread.sigma)
            factor = self.change_tail.update(z, known, overall=CHANGE_OVERALL)
            self._change_scale = cv2.divide(1.0, cv2.multiply(self._spread.sigma, factor))
            return cv2.divide(z, factor)
        return cv2.multiply(change, self._change_scale)


def _with_boxes(region: np.ndarray, boxes: list[tuple[slice, slice]], valid: np.ndarray,
                windows: np.ndarray | None = None) -> np.ndarray:
    """``region`` (not modified) plus the ``valid`` pixels of each box (inside ``windows``, when
    given)."""
    if not boxes:
        return region
    out = region.copy()
    for rows, cols in boxes:
        add = valid[rows, cols] if windows is None else valid[rows, cols] & windows[rows, cols]
        out[rows, cols] |= add
    return out
