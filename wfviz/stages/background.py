"""Background suppression: 5x5 minimum background prediction, positive residual."""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np


def suppress_background(image: np.ndarray, size: int = 5, method: str = "opening") -> np.ndarray:
    """Residual = image - predicted background, clipped at 0 (same dtype as integer input).

    The background is predicted from a low statistic of the ``size`` x ``size`` neighbourhood:
    ``"opening"`` (erosion then dilation, the white top-hat: flat areas and structures wider
    than the window give 0) or ``"erosion"`` (the literal neighbourhood minimum).
    """
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (size, size))
    img = image if image.dtype in (np.uint8, np.uint16, np.float32) else image.astype(np.float32)
    if method == "opening":
        return cv2.morphologyEx(img, cv2.MORPH_TOPHAT, kernel)
    if method == "erosion":
        return cv2.subtract(img, cv2.erode(img, kernel))
    raise ValueError(f"unknown suppression method {method!r} (use 'opening' or 'erosion')")


class TemporalBackground:
    """What the scene looked like ``lag`` frames ago, for each pixel of this frame (not in the
    paper): the background-suppressed images of the past, camera motion removed, so that
    ``residual - background`` keeps what is new or has moved and drops what stays put (stars,
    lamps, buildings, textured ground, fixed-pattern noise, hot spots).

    A still camera (``moving`` False) keeps a running mean of the residual (the
    first ``memory`` frames equally weighted, then exponentially with weight 1 / ``memory``)
    delayed by ``lag`` frames: fixed-pattern noise averages out of it, and a target moving more
    than its own size in ``lag`` frames is not in it. A moving camera uses the single image
    ``lag`` frames back, moved by the camera's offset with bilinear interpolation (pixels it
    does not cover are NaN, i.e. unknown). Before ``lag`` frames have been
    seen the oldest frame stands in (the lag is as long as the clip so far); on the first frame
    there is no background (None).
    """

    def __init__(self, lag: int = 16, memory: int = 32) -> None:
        self.lag, self.memory = lag, memory
        self._ring: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=lag)
        self._mean: np.ndarray | None = None
        self._count = 0
        self._still = True

    def forget(self) -> None:
        """Drop the past (the camera's motion was lost: the stored images are no longer
        registered to the frames to come); the next frame starts a new history, as the first."""
        self._ring.clear()
        self._mean, self._count = None, 0

    def update(self, residual: np.ndarray, offset: np.ndarray | tuple[float, float],
               moving: bool = False) -> np.ndarray | None:
        """This frame's background (float32, or None on the first frame); then remembers it.
        ``offset``: the camera's (:class:`wfviz.stages.registration.CameraState`); ``moving``: it has
        moved (from then on the moving-camera background is used)."""
        r = np.asarray(residual, dtype=np.float32)
        off = np.asarray(offset, dtype=np.float64)
        ring = self._ring
        if ring and ring[-1][0].shape != r.shape:
            self.forget()
        if moving:
            self._still = False
        background = None
        if ring:
            if self._still:
                if len(ring) == ring.maxlen:  # the frame leaving the delay line joins the mean
                    old = ring[0][0]
                    self._count += 1
                    a = max(1.0 / self._count, 1.0 / self.memory)
                    if self._mean is None:
                        self._mean = old.copy()
                    else:
                        cv2.accumulateWeighted(old, self._mean, a)
                background = self._mean if self._mean is not None else ring[0][0]
            else:
                old, then = ring[0]
                background = _moved(old, off - then)
        ring.append((r.copy() if r is residual else r, off.copy()))
        return background


def gain(residual: np.ndarray, background: np.ndarray, bright: float = 0.95) -> float:
    """The gain ``g`` of ``residual ≈ g · background`` (automatic gain control, a slow drift of
    the sensor's response), fitted by least squares on the pixels where the background is
    brightest (above its ``bright`` quantile; every 4th row and column, which fits it as well),
    so that static structure cancels in :func:`change` however the video's contrast drifts."""
    bs = background[::4, ::4]
    rs = residual[::4, ::4]
    known = np.isfinite(bs)
    b = bs[known]
    if b.size < 16:
        return 1.0
    k = int(bright * (b.size - 1))
    cut = np.partition(b, k)[k]
    top = b >= cut
    bt, rt = b[top].astype(np.float64), rs[known][top].astype(np.float64)
    den = float(np.dot(bt, bt))
    return float(np.dot(rt, bt)) / den if den > 0 else 1.0


def change(residual: np.ndarray, background: np.ndarray, g: float | None = None) -> np.ndarray:
    """``residual - g · background``, float32 (NaN where the background is); ``g``: the gain
    (None: fitted here, :func:`gain`)."""
    r = residual.astype(np.float32, copy=False)
    if g is None:
        g = gain(r, background)
    return cv2.scaleAdd(background, -float(g), r)


def _moved(image: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``image`` moved by ``d`` (x, y) with bilinear interpolation; uncovered pixels are NaN."""
    h, w = image.shape
    m = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
    out = cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=np.nan)
    return out

