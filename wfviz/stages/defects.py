"""Hot and dead pixels: persistent one-pixel outliers, flagged over time and replaced by their
3x3 median.

Not in the GEWC paper; every IR focal plane has such defects. A hot pixel is a static point
source and would become a confirmed track; a dead pixel leaves a positive top-hat ring around
it, which would too. A pixel is *hot* in a frame when it is a one-pixel detection whose excess
over its 3x3 median is at least ``spike_ratio`` of its background-suppressed residual (a real
target, even a static one, spreads over several pixels, so its 3x3 median is raised and the
ratio stays near 0.5); it is *dead* when it lies more than twice the detection threshold below
its 3x3 median. A pixel seen so in consecutive frames accumulates evidence
``e <- (1 - rate) e + rate`` (otherwise ``e <- (1 - rate) e``) and is flagged once
``e >= flag_level``. Flagged pixels stay flagged while their raw value keeps deviating from
their 3x3 median by more than the detection threshold.
"""

from __future__ import annotations

import cv2
import numpy as np

from wfviz.config import DefectsConfig


_DR, _DC = np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij")


def median3(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, exclude_centre: bool = True) -> np.ndarray:
    """Median of each listed pixel's 3x3 neighbourhood (edge-replicated), optionally without it."""
    h, w = image.shape
    keep = ~((_DR == 0) & (_DC == 0)) if exclude_centre else np.ones_like(_DR, bool)
    rr = np.clip(rows[:, None] + _DR[keep][None, :], 0, h - 1)
    cc = np.clip(cols[:, None] + _DC[keep][None, :], 0, w - 1)
    return np.median(image[rr, cc].astype(np.float64), axis=1)


def _where(mask: np.ndarray) -> np.ndarray:
    """Flat indices of the non-zero pixels of an OpenCV 0/255 mask (via numpy's fast bool path)."""
    return np.flatnonzero(np.bitwise_and(mask, 1, out=mask).view(bool))


class BadPixels:
    """Evidence map of hot and dead pixels; :meth:`clean` replaces flagged pixels in a frame."""

    def __init__(self, cfg: DefectsConfig) -> None:
        self.cfg = cfg
        self.evidence: np.ndarray | None = None
        self.flagged = np.zeros((0, 2), dtype=np.int64)  # (row, col)

    def clean(self, image: np.ndarray) -> np.ndarray:
        """A copy of ``image`` with flagged pixels replaced by their 3x3 median (or ``image``)."""
        if not self.cfg.enabled or len(self.flagged) == 0:
            return image
        r, c = self.flagged[:, 0], self.flagged[:, 1]
        out = image.copy()
        out[r, c] = median3(image, r, c).astype(image.dtype)
        return out

    def update(self, raw: np.ndarray, residual: np.ndarray, threshold: float) -> bool:
        """Add this frame's evidence; True if the set of flagged pixels changed."""
        if not self.cfg.enabled or not np.isfinite(threshold):
            return False
        if self.evidence is None or self.evidence.shape != raw.shape:
            self.evidence = np.zeros(raw.shape, dtype=np.float32)
        src = raw if raw.dtype in (np.uint8, np.uint16, np.float32) else raw.astype(np.float32)
        dev = cv2.subtract(src, cv2.medianBlur(src, 3), dtype=cv2.CV_32F)
        w = raw.shape[1]
        # this frame's hot candidates (spike above the threshold and at least spike_ratio of the
        # residual; few pixels, so the ratio is tested on those only) and dead ones (more than
        # two thresholds below the median)
        cand = _where(cv2.compare(dev, float(threshold), cv2.CMP_GT))
        ratio = np.float32(self.cfg.spike_ratio)
        hot = cand[dev.ravel()[cand] >= ratio * residual.ravel()[cand].astype(np.float32)]
        seen = [hot, _where(cv2.compare(dev, -2.0 * float(threshold), cv2.CMP_LT))]
        if len(self.flagged):  # flagged pixels were cleaned before detection: test them raw
            r, c = self.flagged[:, 0], self.flagged[:, 1]
            still = np.abs(dev[r, c]) > threshold
            seen.append(r[still] * w + c[still])
        ev = self.evidence  # e <- (1 - rate) e (+ rate where seen)
        ev *= np.float32(1.0 - self.cfg.rate)
        ev.ravel()[np.unique(np.concatenate(seen))] += np.float32(self.cfg.rate)
        idx = np.flatnonzero(ev >= self.cfg.flag_level)
        new = np.column_stack([idx // w, idx % w])
        changed = new.shape != self.flagged.shape or not np.array_equal(new, self.flagged)
        self.flagged = new
        return changed
