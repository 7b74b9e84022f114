"""Hot and dead pixels: one-pixel outliers that stay at the same sensor position over many
frames, flagged from their time average and replaced by their 3x3 median.

Not in the GEWC paper; every IR focal plane has such defects. A hot pixel is a static point
source and would become a confirmed track; a dead pixel leaves a positive top-hat ring around
it, which would too.

A pixel's *excess* ``e`` in a frame is how far it lies above the brightest of its 8 neighbours
(a hot pixel), or, negative, below the darkest (a dead one), else 0: the corner or the edge of
a building, a road or a target's body has neighbours at its own level and no excess. Where
``|e|`` exceeds the threshold (the detection's typical threshold, DN: it would be detected) a
pixel's history starts, ``m = e`` and ``s = |e|``, and each frame after it
``s <- (1 - rate) s + rate |e - m|`` and ``m <- (1 - rate) m + rate e`` (``rate`` 0.2: the last
5 frames or so); it is dropped when ``|m|`` falls to half the threshold. It is flagged when at
once

1. ``|m| > threshold``;
2. ``|m| >= steady * s`` (``steady`` 4): the excess held steady, frame after frame, at the
   same sensor position. A defect keeps its offset while noise changes and the scene moves
   past it; a one-frame spike (noise, a passing target) or texture the camera moves across
   does not. A new defect passes after ``log(steady) / -log(1 - rate)`` frames (7);
3. ``|m| >= contrast * roughness`` (``contrast`` 8), the roughness being the mean absolute
   difference of the 80 horizontally or vertically adjacent pixel pairs of the 7x7
   neighbourhood (the pairs with the pixel itself left out) in the frames' time average (same
   ``rate``): the pixel is alone on a smooth background. A local extreme of static ground
   texture stands out by less than its texture's own steps; on a flat background averaging
   leaves the roughness at about 0.4 of the noise σ, so a defect a few σ strong passes.

A flagged pixel stays flagged at half of each level, and is unflagged below it (it stopped).
Limits: a static one-pixel spot of the scene under a still camera (a star, a glint, an
undersampled target that does not move for 7 frames) is flagged; two adjacent defects are not
(each has the other as its brightest neighbour).
"""

from __future__ import annotations

import cv2
import numpy as np

from wfviz.config import DefectsConfig


_DR, _DC = np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij")
_RING = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)  # the 8 neighbours
_AROUND = 3  # the roughness window's half size (7x7)


def _offsets(half: int) -> np.ndarray:
    """(row, col) offsets of a (2 half + 1)² window, row by row: ((2 half + 1)², 2)."""
    k = np.arange(-half, half + 1)
    return np.stack(np.meshgrid(k, k, indexing="ij"), -1).reshape(-1, 2)


_SEVEN = _offsets(3)  # the window the spatial tests read


def _at(offsets: np.ndarray) -> np.ndarray:
    """Positions of ``offsets`` in :data:`_SEVEN`."""
    return np.array([int(np.flatnonzero((_SEVEN == o).all(1))[0]) for o in offsets])


def _pairs() -> tuple[np.ndarray, np.ndarray]:
    """Positions in :data:`_SEVEN` of both ends of every horizontally or vertically adjacent
    pair that does not include the centre: two arrays of 80."""
    first = [(r, c) for r, c in _SEVEN.tolist() for dr, dc in ((0, 1), (1, 0))
             if max(abs(r + dr), abs(c + dc)) <= 3 and (r, c) != (0, 0) and (r + dr, c + dc) != (0, 0)]
    second = [(r + dr, c + dc) for r, c in _SEVEN.tolist() for dr, dc in ((0, 1), (1, 0))
              if max(abs(r + dr), abs(c + dc)) <= 3 and (r, c) != (0, 0) and (r + dr, c + dc) != (0, 0)]
    return _at(np.array(first)), _at(np.array(second))


_FIRST, _SECOND = _pairs()
_FIVE = _at(_offsets(2))


def median3(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, exclude_centre: bool = True) -> np.ndarray:
    """Median of each listed pixel's 3x3 neighbourhood (edge-replicated), optionally without it."""
    h, w = image.shape
    keep = ~((_DR == 0) & (_DC == 0)) if exclude_centre else np.ones_like(_DR, bool)
    rr = np.clip(rows[:, None] + _DR[keep][None, :], 0, h - 1)
    cc = np.clip(cols[:, None] + _DC[keep][None, :], 0, w - 1)
    return np.median(image[rr, cc].astype(np.float64), axis=1)


def window(image: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The 7x7 neighbourhood of each listed pixel (edge-replicated), row by row: (n, 49)."""
    padded = cv2.copyMakeBorder(image, 3, 3, 3, 3, cv2.BORDER_REPLICATE)
    w = padded.shape[1]
    centre = (rows + 3) * w + cols + 3
    return padded.ravel()[centre[:, None] + (_SEVEN[:, 0] * w + _SEVEN[:, 1])[None, :]]


def roughness(around: np.ndarray) -> np.ndarray:
    """Mean absolute difference of the 80 adjacent pixel pairs of 7x7 neighbourhoods
    (:func:`window`) that leave the centre out."""
    return np.abs(around[:, _FIRST] - around[:, _SECOND]).mean(axis=1)


def height(around: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """How far the centre of 7x7 neighbourhoods (:func:`window`) lies above the darkest pixel
    of its 5x5 neighbourhood (``sign`` > 0) or below the brightest (``sign`` < 0)."""
    five = around[:, _FIVE]
    centre = around[:, _SEVEN.shape[0] // 2]
    return np.where(sign > 0, centre - five.min(axis=1), five.max(axis=1) - centre)


class BadPixels:
    """The histories of one-pixel outliers and the hot and dead pixels flagged from them;
    :meth:`clean` replaces flagged pixels in a frame."""

    def __init__(self, cfg: DefectsConfig) -> None:
        self.cfg = cfg
        self.average: np.ndarray | None = None  # the frames' time average (float32)
        self.index = np.zeros(0, dtype=np.int64)  # flat indices of the pixels with a history
        self.mean = np.zeros(0, dtype=np.float32)    # m: their excess' time average (DN)
        self.spread = np.zeros(0, dtype=np.float32)  # s: time average of |e - m| (DN)
        self._on = np.zeros(0, dtype=bool)           # flagged
        self.flagged = np.zeros((0, 2), dtype=np.int64)  # (row, col)

    def clean(self, image: np.ndarray) -> np.ndarray:
        """A copy of ``image`` with flagged pixels replaced by their 3x3 median (or ``image``)."""
        if not self.cfg.enabled or len(self.flagged) == 0:
            return image
        r, c = self.flagged[:, 0], self.flagged[:, 1]
        out = image.copy()
        out[r, c] = median3(image, r, c).astype(image.dtype)
        return out

    def update(self, raw: np.ndarray, threshold: float) -> bool:
        """Add this frame (as read, defects not replaced); ``threshold``: the detection's
        typical threshold (DN). True if the set of flagged pixels changed."""
        if not self.cfg.enabled or not np.isfinite(threshold):
            return False
        c, t = self.cfg, np.float32(threshold)
        src = raw if raw.dtype in (np.uint8, np.uint16, np.float32) else raw.astype(np.float32)
        if self.average is None or self.average.shape != src.shape:
            self.average = src.astype(np.float32)
            self.index = np.zeros(0, dtype=np.int64)
            self.mean = self.spread = np.zeros(0, dtype=np.float32)
            self._on = np.zeros(0, dtype=bool)
        else:
            cv2.accumulateWeighted(src, self.average, c.rate)
        # excess over the brightest neighbour / below the darkest (saturated at 0 for integers)
        above = cv2.subtract(src, cv2.dilate(src, _RING, borderType=cv2.BORDER_REFLECT_101))
        below = cv2.subtract(cv2.erode(src, _RING, borderType=cv2.BORDER_REFLECT_101), src)
        seen = (above > t) | (below > t)
        old = self.index
        seen.ravel()[old] = True
        index = np.flatnonzero(seen)  # this frame's outliers and the pixels with a history
        e = (np.maximum(above.ravel()[index], 0).astype(np.float32)
             - np.maximum(below.ravel()[index], 0).astype(np.float32))
        mean, spread, on = e.copy(), np.abs(e), np.zeros(len(index), dtype=bool)
        if len(old):
            k = np.searchsorted(index, old)
            m, s = self.mean, self.spread
            rate = np.float32(c.rate)
            mean[k] = (1 - rate) * m + rate * e[k]
            spread[k] = (1 - rate) * s + rate * np.abs(e[k] - m)
            on[k] = self._on
        size = np.abs(mean)
        keep = size > t / 2
        index, mean, spread, on, size = index[keep], mean[keep], spread[keep], on[keep], size[keep]
        level = np.where(on, np.float32(0.5), np.float32(1.0))
        ok = (size > level * t) & (size >= level * np.float32(c.steady) * spread)
        w = src.shape[1]
        test = np.flatnonzero(ok)  # alone: sharp (cheaper, first), then on a smooth background
        if len(test):
            around = window(self.average, index[test] // w, index[test] % w)
            sharp = size[test] >= np.float32(c.sharp) * height(around, mean[test])
            test, around = test[sharp], around[sharp]
            ok[:] = False
            ok[test] = size[test] >= np.float32(c.contrast) * roughness(around)
        self.index, self.mean, self.spread, self._on = index, mean, spread, ok
        flagged = index[ok]
        return self._set(np.column_stack([flagged // w, flagged % w]))

    def _set(self, new: np.ndarray) -> bool:
        """Replace :attr:`flagged` by ``new``; True if it changed."""
        changed = new.shape != self.flagged.shape or not np.array_equal(new, self.flagged)
        self.flagged = new
        return changed
