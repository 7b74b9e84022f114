"""Camera motion: the scene's offset in the image since the clip's first frame (not in the paper).

The GEWC paper assumes a staring camera. Narrow views on pan/tilt platforms (the real
sequences) move: the ground slides under a target the camera follows. :class:`CameraMotion`
measures that motion so that the tracker can tell scene motion from image motion, and says
when it cannot (too few features) and when the camera has not moved at all.

Method: Shi–Tomasi corners of a key frame are followed into each new frame by pyramidal
Lucas–Kanade optical flow (OpenCV), kept when the flow back from the new frame returns within
``fb_error`` px of the corner (forward–backward check). The frame's shift from the key frame is
the mean flow of the corners within 1 px of the median flow (targets and clouds that move on
their own are a minority). Flow against a key frame, not frame to frame, keeps the small errors
of a still camera from adding up. A new key frame is taken when the shift exceeds ``rekey`` px
or fewer than half the corners remain.

Until the offset has once exceeded ``still`` px the camera counts as *still* (the estimate of
a still camera wanders by a few hundredths of a pixel); stages that treat the two cases
differently read ``moving``. With fewer than ``min_corners`` corners agreeing, the shift is
*unknown* and the last offset is kept (``reliable`` False: the tracker then moves nothing, and the
recording shows the shift as unknown, never as still). ``confidence`` (the share of the key
frame's corners that agreed) and ``residual`` (their flows' spread) say how well it was measured;
the tracker does not read them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


FLOW_WINDOW = 15  # px, side of the Lucas-Kanade window (at the flow's downsampled scale)
FLOW_LEVELS = 3   # pyramid levels above the base


@dataclass(frozen=True)
class CameraState:
    """``offset``: a scene point of the first frame appears at ``xy + offset`` now; ``shift``:
    the change of offset since the previous frame; ``moving``: the camera has moved more than
    ``still`` px since the first frame; ``corners``: corners that agreed on this frame's flow;
    ``reliable``: the flow was measured (enough corners agreed; when not, ``shift`` is 0 and the
    motion is unknown); ``confidence``: the share of the key frame's corners that agreed, in
    [0, 1] (0 when not reliable; 1 on the first frame, which sets the origin); ``residual``: RMS
    distance (px) of the agreeing corners' flows from their mean (NaN when not reliable)."""

    offset: tuple[float, float]
    shift: tuple[float, float]
    moving: bool
    corners: int
    reliable: bool
    confidence: float = 1.0
    residual: float = 0.0


class CameraMotion:
    """Streams frames; :meth:`update` returns the :class:`CameraState` of each."""

    def __init__(self, max_side: int = 400, corners: int = 150, still: float = 1.5,
                 rekey: float = 16.0, min_corners: int = 8, fb_error: float = 0.5) -> None:
        self.max_side, self.n_corners, self.still, self.rekey = max_side, corners, still, rekey
        self.min_corners, self.fb_error = min_corners, fb_error
        self._key: np.ndarray | None = None
        self._key_pts: np.ndarray | None = None
        self._key_offset = np.zeros(2)
        self._scale = 1
        self._range: tuple[float, float] | None = None
        self.offset = np.zeros(2)
        self.moving = False

    def _grey(self, image: np.ndarray) -> np.ndarray:
        """8-bit, downsampled copy for the flow (grey range fixed by the first frame)."""
        f = image.astype(np.float32, copy=False)
        if self._range is None:
            lo, hi = np.percentile(f[::4, ::4], [0.5, 99.5])
            self._range = (float(lo), float(max(hi, lo + 1e-6)))
            self._scale = max(1, int(np.ceil(max(image.shape) / self.max_side)))
        lo, hi = self._range
        g = cv2.convertScaleAbs(f, alpha=255.0 / (hi - lo), beta=-lo * 255.0 / (hi - lo))
        s = self._scale
        if s > 1:
            g = cv2.resize(g, (image.shape[1] // s, image.shape[0] // s), interpolation=cv2.INTER_AREA)
        return g

    def _set_key(self, g: np.ndarray) -> None:
        self._key = g
        self._key_pts = cv2.goodFeaturesToTrack(g, self.n_corners, 0.01, 7, blockSize=7)
        self._key_offset = self.offset.copy()

    def update(self, image: np.ndarray) -> CameraState:
        """Measure this frame's offset (see the module docstring)."""
        before = self.offset.copy()
        if self._key is not None and self._key.shape != (image.shape[0] // self._scale,
                                                         image.shape[1] // self._scale):
            self._key, self._range = None, None  # new frame size: start again
        if self._key is None:
            self._set_key(self._grey(image))
            return self._state(before, 0, True, 1.0, 0.0)
        g = self._grey(image)
        agreed = 0
        if self._key_pts is not None and len(self._key_pts) >= self.min_corners:
            win = (FLOW_WINDOW, FLOW_WINDOW)
            p1, st, _ = cv2.calcOpticalFlowPyrLK(self._key, g, self._key_pts, None, winSize=win, maxLevel=FLOW_LEVELS)
            p0, st2, _ = cv2.calcOpticalFlowPyrLK(g, self._key, p1, None, winSize=win, maxLevel=FLOW_LEVELS)
            back = np.hypot(*(p0 - self._key_pts)[:, 0].T)
            ok = (st[:, 0] == 1) & (st2[:, 0] == 1) & (back < self.fb_error)
            d = (p1 - self._key_pts)[:, 0][ok].astype(np.float64)
            if len(d) >= self.min_corners:
                med = np.median(d, axis=0)
                inl = np.hypot(*(d - med).T) < 1.0
                agreed = int(inl.sum())
                if agreed >= self.min_corners:
                    mean = d[inl].mean(axis=0)
                    shift = mean * self._scale
                    confidence = min(1.0, agreed / len(self._key_pts))
                    residual = float(np.sqrt(np.mean(np.sum((d[inl] - mean) ** 2, axis=1)))) * self._scale
                    self.offset = self._key_offset + shift
                    if not self.moving and np.hypot(*self.offset) > self.still:
                        self.moving = True
                    if np.hypot(*shift) > self.rekey or agreed < 0.5 * len(self._key_pts):
                        self._set_key(g)
                    return self._state(before, agreed, True, confidence, residual)
        if self.moving:  # lost the key frame's corners: start a new key frame here
            self._set_key(g)
        return self._state(before, agreed, False, 0.0, float("nan"))

    def _state(self, before: np.ndarray, corners: int, reliable: bool, confidence: float,
               residual: float) -> CameraState:
        shift = self.offset - before
        return CameraState((float(self.offset[0]), float(self.offset[1])),
                           (float(shift[0]), float(shift[1])), self.moving, corners, reliable, confidence, residual)
