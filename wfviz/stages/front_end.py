"""The stages every detection-based tracker shares (GEWC and fusion): defects, imaging circle,
sky–ground line, camera motion, background suppression, local noise, change in the scene and
noise-aware detection.

A frame goes through them in two calls with the tracks' prediction between them
(docs/pipeline.md, "One frame, from reader to recorder"): :meth:`FrontEnd.prepare` runs the
stages before detection (a :class:`PreparedFrame`, which holds the camera's motion the tracks
are moved by), the tracker predicts its tracks, and :meth:`FrontEnd.finish` detects with the
predictions' gates and thresholds (a :class:`FrontEndResult`). Nothing is called back.

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

Stages 1–7 are a :class:`Preparer`'s. A front end prepares its frames with its own, or takes
them from another :class:`PreparedSource` (``wfviz tune`` replays frames prepared once,
``wfviz compare`` shares one preparation among trackers).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields, replace
from typing import Protocol

import cv2
import numpy as np

from wfviz.config import (CircleConfig, DefectsConfig, DetectionConfig, HorizonConfig, NoiseConfig,
                          SuppressionConfig, TrackingConfig)
from wfviz.stages.background import TemporalBackground, change as scene_change, gain, suppress_background
from wfviz.stages.defects import BadPixels
from wfviz.stages.detection import Detections, detect, sample_at, score_detections
from wfviz.stages.horizon import Horizon, HorizonTracker, search_zones
from wfviz.stages.imaging_circle import ImagingCircle, ImagingMask
from wfviz.stages.multiframe import MotionIntegrator
from wfviz.stages.noise import NoiseEstimate, NoiseModel, TailCalibration
from wfviz.stages.registration import CameraMotion, CameraState

#: a box of the frame: (rows, columns)
Box = tuple[slice, slice]
#: frames the multi-frame score integrates after it (re)starts before it is used
WARM_UP = 4
#: frames between the multi-frame score's full standardisations (its drift is followed in between)
CALIBRATE = 8


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


@dataclass(frozen=True, kw_only=True)
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
    multiframe: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True)
class FrontEndResult(PreparedFrame):
    """One frame through the shared stages: a :class:`PreparedFrame` (``region`` here with the
    tracker's windows and gates) and this frame's ``detections``, with significance and change.

    ``image``: the frame with defects replaced (``raw``: as read); ``mask``: outside the imaging
    area (``valid``: inside); ``circle``: the imaging circle; ``horizon``: the sky–ground line
    (``horizon_updated``: re-estimated on this frame); ``region``: where detections are
    searched; ``zones``: the parts of it with their own noise statistics (None: one);
    ``camera``: the camera's motion (None: not compensated); ``offset``: the camera's (scene
    point s is at s + offset); ``suppressed``: the background-suppressed residual; ``noise``:
    its local level and σ (None outside "cfar" detection); ``change``: the change significance
    of every pixel (None on the first frame); ``bad_pixels``: the flagged defects (row, col);
    ``multiframe``: the multi-frame significance of every pixel (:mod:`wfviz.stages.multiframe`;
    None: not computed).
    """

    detections: Detections

    @classmethod
    def of(cls, prepared: PreparedFrame, *, region: np.ndarray, detections: Detections,
           bad_pixels: np.ndarray, bad_pixels_changed: bool) -> FrontEndResult:
        """``prepared`` with its detections (and the region and flagged defects they were found
        with)."""
        kept = {f.name: getattr(prepared, f.name) for f in fields(PreparedFrame)}
        return cls(**{**kept, "region": region, "bad_pixels": bad_pixels,
                      "bad_pixels_changed": bad_pixels_changed}, detections=detections)


class PreparedSource(Protocol):
    """Where a front end's prepared frames come from: its own :class:`Preparer`, or frames
    prepared elsewhere (replayed, shared)."""

    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle as of the last frame handed out."""
        ...

    def prepare(self, raw: np.ndarray, lap: Callable[[str], None], whole: bool = True,
                update_horizon: bool = True) -> PreparedFrame:
        """The next frame through the stages before detection (:meth:`Preparer.prepare`)."""
        ...


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


class Preparer:
    """The stages before detection (1–7 of the module docstring) with their state: streams
    frames through :meth:`prepare`. ``config``: a :class:`FrontEndConfig`."""

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
        self.multi = MotionIntegrator(c.detection.multi_memory, c.detection.multi_clip) \
            if cfar and c.detection.multi_memory > 0 else None
        self.multi_noise = NoiseModel(c.noise.tile, c.noise.smoothing) if self.multi is not None else None
        self.multi_tail = TailCalibration(c.noise.tile, refresh=c.noise.every) if self.multi is not None else None
        # level, 1 / (sigma x tail factor), and the region's mean and spread then
        self._multi: tuple[np.ndarray, np.ndarray, float, float] | None = None

    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.imaging.circle

    @property
    def region(self) -> np.ndarray | None:
        """The last frame's search region (None before the first frame)."""
        return self._region

    @property
    def zones(self) -> list[np.ndarray] | None:
        """The parts of :attr:`region` with their own noise statistics (None: one)."""
        return self._zones

    def prepare(self, raw: np.ndarray, lap: Callable[[str], None], whole: bool = True,
                update_horizon: bool = True) -> PreparedFrame:
        """Stages 1–7 on the next frame; ``lap(stage)`` is called as each stage ends (timing).
        ``whole``: the frame is searched whole (no windows: the noise statistics may be
        re-estimated). ``update_horizon``: the horizon may be re-estimated on this frame (when
        due)."""
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
        noise = change = multiframe = None
        self._frame += 1
        moved = camera is not None and float(np.hypot(*camera.shift)) > c.noise.tile / 4
        due = moved or mask_changed or horizon_updated or (self._frame - 1) % c.noise.every == 0
        bad_changed = False
        if self.noise is not None:
            if (whole and due) or self._noise is None:
                est = self.noise.update(suppressed, self._region, self._zones, image=img, reset=moved)
                g = self.tail.update(est.significance(suppressed), self._region, overall=c.noise.residual_floor_overall)
                self._noise = replace(est, sigma=est.sigma * g)
            noise = self._noise
            lap("noise")
            change = self._change(raw, img, suppressed, camera, whole and due)
            if change is not None and len(self.bad.flagged):
                change = _unknown_at(change, self.bad.flagged)
            lap("change")
            multiframe = self._multiframe(change, camera, whole and due)
            lap("multiframe")
            # a hot pixel's spike exceeds defects.k_sigma of the typical local noise
            bad_changed = self.bad.update(raw, noise.typical_threshold(c.defects.k_sigma))
            lap("defects")
        return PreparedFrame(image=img, raw=raw, mask=mask, mask_changed=mask_changed, valid=valid,
                             circle=self.circle, horizon=horizon, horizon_updated=horizon_updated,
                             region=self._region, zones=self._zones, camera=camera,
                             offset=self._offset.copy(), suppressed=suppressed, noise=noise, change=change,
                             multiframe=multiframe, bad_pixels=self.bad.flagged, bad_pixels_changed=bad_changed)

    def flag_defects(self, raw: np.ndarray, threshold: float) -> tuple[np.ndarray, bool]:
        """The defect stage's evidence of this frame at the detection's ``threshold`` (global or
        box detection): the flagged pixels, and whether they changed."""
        changed = self.bad.update(raw, threshold)
        return self.bad.flagged, changed

    def renoise(self, suppressed: np.ndarray, image: np.ndarray) -> NoiseEstimate | None:
        """The noise statistics re-estimated over the whole search region of this frame's
        ``suppressed`` residual (after a window search; None outside "cfar" detection)."""
        if self.noise is None:
            return None
        est = self.noise.update(suppressed, self._region, self._zones, image=image)
        g = self.tail.update(est.significance(suppressed), self._region,
                             overall=self.config.noise.residual_floor_overall)
        self._noise = replace(est, sigma=est.sigma * g)
        return self._noise

    def _multiframe(self, change: np.ndarray | None, camera: CameraState | None,
                    learn_spread: bool) -> np.ndarray | None:
        """The multi-frame significance of every pixel: the score of the best path of the change
        significance ending there (:class:`wfviz.stages.multiframe.MotionIntegrator`),
        standardised like a significance (local level and σ, tail calibration) about every
        :data:`CALIBRATE` frames (on the frames ``learn_spread``, where the noise statistics are
        re-estimated, in the first ``noise.every`` of every :data:`CALIBRATE`) and on every frame
        while its memory fills, the search region's
        mean and spread followed in between (float32). None when there is no change image, and
        for the first :data:`WARM_UP` frames after the integration (re)starts."""
        if self.multi is None:
            return None
        if change is None:
            self.multi.forget()
            return None
        a = self.multi.update(change, camera.shift if camera is not None else (0.0, 0.0))
        region = self._region
        assert region is not None
        sub = np.ascontiguousarray(a[::4, ::4])  # the drift: a sample is enough
        m, sd = cv2.meanStdDev(sub, mask=np.ascontiguousarray(region[::4, ::4]).view(np.uint8))
        mean, std = float(m[0, 0]), float(sd[0, 0])
        # its distribution settles over a few memories (1 / (1 - λ) frames each): standardised every frame till then
        young = self.multi.frames <= 3.0 / max(1.0 - self.multi.memory, 1e-3)
        if young or self._multi is None or (learn_spread and self.multi.frames % CALIBRATE < self.config.noise.every):
            assert self.multi_noise is not None and self.multi_tail is not None
            est = self.multi_noise.update(np.where(region, a, 0.0), region, None, image=a, reset=True)
            factor = self.multi_tail.update(est.significance(a), region, overall=self.config.noise.change_floor_overall)
            self._multi = (est.level, np.asarray(cv2.divide(1.0, cv2.multiply(est.sigma, factor))), mean, std)
        if self.multi.frames < WARM_UP:
            return None
        level, scale, mean0, std0 = self._multi
        z = cv2.subtract(a, level)
        z -= np.float32(mean - mean0)
        return cv2.multiply(z, scale, scale=std0 / max(std, 1e-6))

    def _change(self, raw: np.ndarray, img: np.ndarray, suppressed: np.ndarray,
                camera: CameraState | None, learn_spread: bool) -> np.ndarray | None:
        """Change significance of every pixel (:class:`wfviz.stages.background.TemporalBackground`):
        the raw frame's residual (defects not yet replaced, so that a pixel flagged during the
        clip does not look like a change), smoothed by a Gaussian of 1 px (a sharp spot's
        sampled peak depends on where it falls between pixels), against the scene's past, in
        units of the change's own spread and from 0 (static structure is unchanged whatever the
        change image's typical level). ``learn_spread``: re-estimate that spread (else the last
        one). None when there is no past to compare with: the first frame, and a frame whose
        camera motion is unknown after the camera has moved (the past is then forgotten)."""
        c = self.config
        if camera is not None and camera.lost:
            # the camera's motion is unknown: nothing here can be compared with the scene's past,
            # and the past stored so far will not be registered to the frames to come
            self.temporal.forget()
            return None
        raw_residual = suppress_background(raw, c.suppression.size, c.suppression.method) if raw is not img \
            else suppressed
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
            factor = self.change_tail.update(z, known, overall=c.noise.change_floor_overall)
            self._change_scale = cv2.divide(1.0, cv2.multiply(self._spread.sigma, factor))
            return cv2.divide(z, factor)
        return cv2.multiply(change, self._change_scale)


class FrontEnd:
    """The shared stages of one tracker (module docstring): :meth:`prepare`, then :meth:`finish`
    (and :meth:`redetect`). ``config`` needs the sections ``defects``, ``circle``, ``horizon``,
    ``suppression``, ``noise``, ``detection`` and ``tracking`` (for ``compensate_motion`` and
    the shape test): :class:`FrontEndConfig`. ``source``: where the prepared frames come from
    (default: this front end's own :class:`Preparer`); only a front end whose preparation does
    not depend on the tracks (:meth:`independent_of_tracks`) takes another."""

    def __init__(self, config: FrontEndConfig, source: PreparedSource | None = None) -> None:
        c = self.config = config
        if source is not None and not self.independent_of_tracks(c):
            raise ValueError("a front end whose detection threshold feeds the defect stage (detection.mode "
                             "other than \"cfar\") prepares its own frames")
        #: the own stages before detection (None: the frames come from ``source``)
        self.preparer: Preparer | None = None
        if source is None:
            source = self.preparer = Preparer(c)
        self.source: PreparedSource = source
        self._significance = c.detection.mode != "cfar" and (
            c.detection.significance or c.tracking.confirm_significance > 0)

    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.source.circle

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
        """The stages before detection on the next frame, from :attr:`source`
        (:meth:`Preparer.prepare`). In "cfar" mode nothing in it depends on the tracks when
        the frame is searched whole, so it can be computed once and replayed."""
        return self.source.prepare(raw, lap, whole, update_horizon)

    def finish(self, p: PreparedFrame, lap: Callable[[str], None], windows: np.ndarray | None = None,
               k_map: np.ndarray | None = None, gates: Sequence[Box] = ()) -> FrontEndResult:
        """Detection on a frame from :meth:`prepare`; ``lap("detect")`` as it ends.
        ``windows`` (a mask): detect only there, with the noise statistics of the last frame
        searched whole (a tracker's search windows; with a global or box threshold, this
        frame's threshold over the whole search region). ``k_map``: the detection threshold of
        every pixel in σ (None: ``detection.k_sigma``; used with a noise estimate only; see
        :func:`wfviz.stages.detection.detect`). ``gates``: boxes searched besides the search
        region (confirmed tracks' gates, which may reach below the horizon; ignored when
        ``detection.gates_cross_horizon`` is off)."""
        c = self.config
        noise, valid = p.noise, p.valid
        region = p.region if windows is None else p.region & windows
        kmap = k_map if noise is not None else None
        boxes = gates if c.detection.gates_cross_horizon else ()
        full = _with_boxes(p.region, boxes, valid)  # the search region and confirmed gates
        region = _with_boxes(region, boxes, valid, windows)
        if windows is not None and c.detection.mode != "cfar":
            # a global or box threshold is a statistic of the whole search region, not of the
            # windows (whose own statistics a bright target inflates): detect there, keep the
            # candidates inside the windows
            dets = detect(p.suppressed, full, c.detection, p.zones, noise, p.change, kmap, p.multiframe)
            dets = dets.subset(sample_at(windows, dets.xy))
        else:
            dets = detect(p.suppressed, region, c.detection, p.zones, noise, p.change, kmap, p.multiframe)
        dets = score_detections(dets, p.image, full, c.detection, self._significance,
                                c.tracking.confirm_blobness > 0, p.suppressed)
        bad_pixels, bad_changed = p.bad_pixels, p.bad_pixels_changed
        if not self.independent_of_tracks(c):  # the defect stage takes the detection's threshold
            bad_pixels, bad_changed = self._own_stages("finish").flag_defects(p.raw, dets.threshold)
        lap("detect")
        return FrontEndResult.of(p, region=region, detections=dets, bad_pixels=bad_pixels,
                                 bad_pixels_changed=bad_changed)

    def redetect(self, result: FrontEndResult, lap: Callable[[str], None],
                 gates: Sequence[Box] = ()) -> FrontEndResult:
        """``result`` (a frame searched in windows only) detected again over the whole search
        region (and ``gates``, as in :meth:`finish`), with this frame's own noise statistics
        (the other stages are not repeated)."""
        c = self.config
        stages = self._own_stages("redetect")
        noise = result.noise
        if stages.noise is not None:
            noise = stages.renoise(result.suppressed, result.image)
            lap("noise")
        boxes = gates if c.detection.gates_cross_horizon else ()
        region = _with_boxes(stages.region, boxes, result.valid)
        dets = detect(result.suppressed, region, c.detection, stages.zones, noise, result.change,
                      multi=result.multiframe)
        dets = score_detections(dets, result.image, region, c.detection, self._significance,
                                c.tracking.confirm_blobness > 0, result.suppressed)
        lap("detect")
        return replace(result, region=region, noise=noise, detections=dets)

    def _own_stages(self, what: str) -> Preparer:
        """This front end's own :class:`Preparer` (``what`` needs it)."""
        if self.preparer is None:
            raise ValueError(f"FrontEnd.{what}: a front end with prepared frames from elsewhere has no stages of its own")
        return self.preparer


def _with_boxes(region: np.ndarray, boxes: Sequence[Box], valid: np.ndarray,
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
