"""Hot and dead pixels: one-pixel outliers that stay at the same sensor position over many
frames while the scene and the noise around them change; replaced by their 3x3 median.

Not in the GEWC paper; every IR focal plane has such defects. A hot pixel is a static point
source and would become a track; a dead pixel leaves a positive top-hat ring around it, which
would too. A spatial outlier in one frame is not a defect: noise, a passing target and the
corner of a building are outliers too.

A pixel's *excess* ``e`` in a frame is how far it lies above the brightest of its 8 neighbours
(hot), or, negative, below the darkest (dead), else 0: a corner or an edge of the scene, or a
pixel of a target's body, has a neighbour at its own level and no excess. Where ``|e|`` exceeds
the threshold ``T`` (the detection's typical threshold in DN, ``defects.k_sigma``: the pixel
would be detected) the pixel's history starts with ``m = e`` and ``s = |e|``; each frame after,
``s <- (1 - rate) s + rate |e - m|`` and ``m <- (1 - rate) m + rate e`` (``rate`` 0.3, about
the last 3 frames); the history is dropped when ``|m| <= T / 2``. A pixel is flagged when

1. ``|m| > T``: its time-averaged excess would be detected;
2. ``|m| >= steady * s`` (``steady`` 3): the excess held steady from frame to frame. A defect
   keeps its offset while noise changes and the scene moves past it; a one-frame spike (noise,
   a passing target) or texture the camera moves across does not. A new defect passes after
   ``log(steady) / -log(1 - rate)`` frames (4 after the first: flagged before a track can be
   confirmed at 6 hits);
3. ``|m| >= sharp * height`` (``sharp`` 0.5), ``height`` being how far the pixel lies above
   the darkest pixel of its 5x5 neighbourhood (below the brightest: dead) in the frames' time
   average (same ``rate``): the outlier is most of the pixel's height, not the tip of a larger
   object (a centred Gaussian spot has 0.64 at σ = 0.7 px, 0.39 at σ = 1 px; a hot pixel ~1);
4. ``|m| >= contrast * roughness`` (``contrast`` 6), ``roughness`` being the mean absolute
   step between the 80 horizontally or vertically adjacent pixel pairs of its 7x7
   neighbourhood (pairs with the pixel itself left out) in the time average: alone on a smooth
   background. A local extreme of static textured ground stands out by less than its
   texture's own steps; on a flat background the average's noise (0.42 of the frames' σ)
   leaves a roughness of about 0.47 σ, so a defect ~3 σ strong passes and ``T`` decides.

A flagged pixel stays flagged while it passes 3 and 4 and 1 and 2 at half their levels, and is
unflagged when it fails them (the defect stopped). Without defects nothing is flagged on the
demo (160 frames), on the own scenarios and on the independent samples beyond their listed
defects (docs/pipeline.md). Limits: under a still camera a static one-pixel spot of the scene
(a star, a lit window, an undersampled target, σ ≤ 0.6 px, that stays on one pixel's centre
for 4 frames) is flagged; two adjacent defects are not (each is the other's brightest
neighbour), nor a weak one on rough texture.
"""

from __future__ import annotations

import cv2
import numpy as np

from wfviz.config import DefectsConfig


_DR, _DC = np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij")
_RING = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)  # the 8 neighbours


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
    pair that leaves the centre out: two arrays of 80."""
    ends = [((r, c), (r + dr, c + dc)) for r, c in _SEVEN.tolist() for dr, dc in ((0, 1), (1, 0))
            if max(abs(r + dr), abs(c + dc)) <= 3 and (0, 0) not in ((r, c), (r + dr, c + dc))]
    return _at(np.array([a for a, _ in ends])), _at(np.array([b for _, b in ends]))


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
    h, w = image.shape
    rr = np.clip(rows[:, None] + _SEVEN[None, :, 0], 0, h - 1)  # edge-replicated: clipped indices
    cc = np.clip(cols[:, None] + _SEVEN[None, :, 1], 0, w - 1)
    return image[rr, cc]


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
        seen = (above > t) | (below > t)  # bool: flatnonzero is 15x faster on it than on 0/255 uint8
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
