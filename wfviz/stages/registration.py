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

When fewer than ``min_corners`` corners agree (featureless sky and cloud, a fast re-pointing),
a global fallback measures the shift: phase correlation (OpenCV, Hanning window) of the key
frame and this frame. It is used when its peak (``response``, the share of the frames'
normalised cross-power at the peak) reaches ``RESPONSE_LEVEL`` / sqrt(pixels), twice the
peaks two frames of independent noise give, and when both halves of the frame, left and
right or top and bottom, measure the same shift on their own, within ``AGREE_PX`` px or
``AGREE_SHARE`` of its length: a target lies in one half, the camera moves both. The frames
are first cleared of compact objects (a grey opening, then closing, of ``FLATTEN`` px: a
target the camera follows over featureless cloud would otherwise be all the correlation
sees); when that leaves too little (ground whose structure is its bright spots) the frames
are correlated as they are, under the same test. A new key frame is then taken here once
the camera moves, so that the flow can take over again.

Until the offset has once exceeded ``still`` px the camera counts as *still* (the estimate of
a still camera wanders by a few hundredths of a pixel); stages that treat the two cases
differently read ``moving``. When neither the flow nor the fallback measures the shift it is
*unknown* and the last offset is kept (``reliable`` False, ``method`` "none": the tracker then
moves nothing, does not count scene positions across the frame as motion once the camera
moves, and the recording shows the shift as unknown, never as still). The key frame is kept
through up to ``KEEP_KEY`` such frames, so the next frame measured from it carries their motion
too (a blurred frame in a fast re-pointing loses nothing; on a real sky clip the tracks
otherwise stayed behind by the 17 px of the one frame not measured); after more, the motion
since the key frame is given up and a new key frame is taken. ``confidence`` and
``residual`` say how well it was measured (the flow: the share of the key frame's corners
that agreed and their flows' spread; the fallback: the peak's response and the halves'
disagreement).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


FLOW_WINDOW = 15  # px, side of the Lucas-Kanade window (at the flow's downsampled scale)
FLOW_LEVELS = 3   # pyramid levels above the base
FLATTEN = 9       # px (at the flow's scale), side of the opening and closing before the fallback
RESPONSE_LEVEL = 42.0  # the fallback's peak must reach this / sqrt(pixels correlated)
AGREE_PX, AGREE_SHARE = 1.0, 0.25  # the halves agree within max(AGREE_PX, AGREE_SHARE · |shift|)
REFINE_CORNERS = 3  # corners that refine the fallback's shift
KEEP_KEY = 3  # frames of unknown motion after which the key frame is given up


@dataclass(frozen=True)
class CameraState:
    """``offset``: a scene point of the first frame appears at ``xy + offset`` now; ``shift``:
    the change of offset since the previous frame; ``moving``: the camera has moved more than
    ``still`` px since the first frame; ``corners``: corners that agreed on this frame's flow;
    ``reliable``: the shift was measured (when not, ``shift`` is 0 and the motion is unknown);
    ``method``: how: "flow" (corners), "phase" (the phase-correlation fallback) or "none"
    (unknown); ``confidence`` in [0, 1]: with the flow the share of the key frame's corners that
    agreed (1 on the first frame, which sets the origin), with the fallback its peak's response,
    0 when unknown; ``residual`` (px): with the flow the RMS distance of the agreeing corners'
    flows from their mean, with the fallback the distance between the whole frame's shift and
    its best half's, NaN when unknown."""

    offset: tuple[float, float]
    shift: tuple[float, float]
    moving: bool
    corners: int
    reliable: bool
    confidence: float = 1.0
    residual: float = 0.0
    method: str = "flow"

    @property
    def error(self) -> float:
        """Standard error of this frame's shift (px): the agreeing corners' spread over the root of
        their number (the flow), the frame's halves' disagreement (phase correlation), 0 on the
        first frame, NaN when not measured."""
        if not self.reliable:
            return float("nan")
        if self.method == "phase":
            return float(self.residual)
        return float(self.residual) / float(np.sqrt(max(self.corners, 1)))

    @property
    def lost(self) -> bool:
        """The camera has moved and this frame's motion is unknown: what is seen now cannot be
        placed in the scene (compared with the past, or learnt as the scene)."""
        return self.moving and not self.reliable


class CameraMotion:
    """Streams frames; :meth:`update` returns the :class:`CameraState` of each."""

    def __init__(self, max_side: int = 400, corners: int = 150, still: float = 1.5,
                 rekey: float = 16.0, min_corners: int = 8, fb_error: float = 0.5) -> None:
        self.max_side, self.n_corners, self.still, self.rekey = max_side, corners, still, rekey
        self.min_corners, self.fb_error = min_corners, fb_error
        self._key: np.ndarray | None = None
        self._key_pts: np.ndarray | None = None
        self._key_float: np.ndarray | None = None
        self._key_flat: np.ndarray | None = None
        self._key_offset = np.zeros(2)
        self._scale = 1
        self._range: tuple[float, float] | None = None
        self.offset = np.zeros(2)
        self.moving = False
        self._unknown = 0  # consecutive frames of unknown motion

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

    def _reduced(self, image: np.ndarray) -> np.ndarray:
        """float32, downsampled copy (the flow's scale) for the fallback: no clipping to 8 bits."""
        f = image.astype(np.float32, copy=False)
        s = self._scale
        return cv2.resize(f, (image.shape[1] // s, image.shape[0] // s), interpolation=cv2.INTER_AREA) if s > 1 else f

    def _set_key(self, g: np.ndarray, image: np.ndarray) -> None:
        self._key = g
        self._key_pts = cv2.goodFeaturesToTrack(g, self.n_corners, 0.01, 7, blockSize=7)
        self._key_offset = self.offset.copy()
        self._key_float = self._reduced(image).copy()  # the caller may reuse the frame's buffer
        self._key_flat = None

    def update(self, image: np.ndarray) -> CameraState:
        """Measure this frame's offset (see the module docstring)."""
        before = self.offset.copy()
        if self._key is not None and self._key.shape != (image.shape[0] // self._scale,
                                                         image.shape[1] // self._scale):
            self._key, self._range = None, None  # new frame size: start again
        if self._key is None:
            self._set_key(self._grey(image), image)
            return self._state(before, 0, True, 1.0, 0.0)
        g = self._grey(image)
        state = self._measure(g, image, before)
        self._unknown = 0 if state.reliable else self._unknown + 1
        if self.moving and self._unknown > KEEP_KEY:  # the key frame is out of reach: start again here
            self._set_key(g, image)
            self._unknown = 0
        return state

    def _measure(self, g: np.ndarray, image: np.ndarray, before: np.ndarray) -> CameraState:
        """This frame's state from the key frame (module docstring)."""
        agreed = 0
        if self._key is not None and self._key_pts is not None and len(self._key_pts) >= self.min_corners:
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
                        self._set_key(g, image)
                    return self._state(before, agreed, True, confidence, residual)
        phase = self._fallback(g, self._reduced(image))
        if phase is not None:
            shift, response, residual, refined = phase
            self.offset = self._key_offset + shift
            if not self.moving and np.hypot(*self.offset) > self.still:
                self.moving = True
            if self.moving:
                self._set_key(g, image)
            return self._state(before, max(agreed, refined), True, response, residual, "phase")
        return self._state(before, agreed, False, 0.0, float("nan"), "none")

    def _fallback(self, g: np.ndarray, now: np.ndarray) -> tuple[np.ndarray, float, float, int] | None:
        """The phase-correlation shift (px, full scale) of this frame (``g`` for the flow, ``now``
        for the correlation) from the key frame, its response, the halves' disagreement (px) and
        the corners that refined it, or None when not measured (module docstring): first on the
        frames cleared of compact objects, then on the frames as they are."""
        if self._key_float is None or self._key is None:
            return None
        if self._key_flat is None:
            self._key_flat = _flatten(self._key_float)
        for a, b, halves in ((self._key_flat, _flatten(now), 1), (self._key_float, now, 2)):
            found = _agreed_shift(a, b, halves)
            if found is not None:
                shift, response, apart = found
                shift, refined = self._refine(g, shift)
                return shift * self._scale, response, apart * self._scale, refined
        return None

    def _refine(self, g: np.ndarray, shift: np.ndarray) -> tuple[np.ndarray, int]:
        """``shift`` (px, flow scale) refined by the key frame's corners followed from it (at
        least ``REFINE_CORNERS`` within 1 px of it and of their median, forward–backward
        checked): the correlation's peak is biased by up to a few tenths of a pixel, the flow
        is not. Unchanged (and 0 corners) when too few agree."""
        pts, key = self._key_pts, self._key
        if pts is None or key is None or len(pts) < REFINE_CORNERS:
            return shift, 0
        win = (FLOW_WINDOW, FLOW_WINDOW)
        guess = (pts + shift.astype(np.float32)).astype(np.float32)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(key, g, pts, guess.copy(), winSize=win, maxLevel=1,
                                             flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        p0, st2, _ = cv2.calcOpticalFlowPyrLK(g, key, p1, pts.copy(), winSize=win, maxLevel=1,
                                              flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        back = np.hypot(*(p0 - pts)[:, 0].T)
        ok = (st[:, 0] == 1) & (st2[:, 0] == 1) & (back < self.fb_error)
        d = (p1 - pts)[:, 0][ok].astype(np.float64)
        d = d[np.hypot(*(d - shift).T) < 1.0]
        if len(d) < REFINE_CORNERS:
            return shift, 0
        d = d[np.hypot(*(d - np.median(d, axis=0)).T) < 1.0]
        return (d.mean(axis=0), len(d)) if len(d) >= REFINE_CORNERS else (shift, 0)

    def _state(self, before: np.ndarray, corners: int, reliable: bool, confidence: float,
               residual: float, method: str = "flow") -> CameraState:
        shift = self.offset - before
        return CameraState((float(self.offset[0]), float(self.offset[1])),
                           (float(shift[0]), float(shift[1])), self.moving, corners, reliable, confidence, residual,
                           method)


def _flatten(g: np.ndarray) -> np.ndarray:
    """``g`` (8-bit) without compact bright and dark objects (grey opening, then closing, of
    :data:`FLATTEN` px), as float32 for the correlation."""
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (FLATTEN, FLATTEN))
    return cv2.morphologyEx(cv2.morphologyEx(g, cv2.MORPH_OPEN, k), cv2.MORPH_CLOSE, k).astype(np.float32)


def _agreed_shift(a: np.ndarray, b: np.ndarray, halves: int) -> tuple[np.ndarray, float, float] | None:
    """Shift of ``b`` from ``a`` by phase correlation, its response and the distance (px) of
    the agreeing halves' shifts from it, when the response reaches the level and ``halves`` (1
    or 2) halves of the frame agree, 2: left and right or top and bottom (module docstring);
    else None."""
    if float(a.std()) < 1e-3 or float(b.std()) < 1e-3:
        return None  # nothing to correlate
    full, response = _correlate(a, b)
    if response < RESPONSE_LEVEL / np.sqrt(a.size):
        return None
    h, w = a.shape
    tol = max(AGREE_PX, AGREE_SHARE * float(np.hypot(*full)))
    best: float | None = None
    for pair in (((slice(None), slice(0, w // 2)), (slice(None), slice(w // 2, None))),
                 ((slice(0, h // 2), slice(None)), (slice(h // 2, None), slice(None)))):
        apart = sorted(float(np.hypot(*(_correlate(a[r, c], b[r, c])[0] - full))) for r, c in pair)[halves - 1]
        if apart <= tol and (best is None or apart < best):
            best = apart
    return None if best is None else (full, response, best)


def _correlate(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Shift of ``b`` from ``a`` (px) by phase correlation with a Hanning window, and its
    response. The means are removed first: the window times a common mean is a pattern both
    frames share at zero shift."""
    h, w = a.shape
    (dx, dy), response = cv2.phaseCorrelate(a - np.float32(a.mean()), b - np.float32(b.mean()),
                                            cv2.createHanningWindow((w, h), cv2.CV_32F))
    return np.array([dx, dy]), float(response)
