"""Static clutter: detections that stay put in the scene amid other detections (not in the paper).

A panning camera over textured ground sees bright spots of the terrain (tree crowns, roofs,
field edges) that pass every single-frame test a target passes. Two things give them away:
they keep their place in the scene (camera motion removed) and they come in crowds. A target
moves relative to the ground, and a lone point in clean sky is a target even when it hovers
(a hovering target amid ground clutter is lost: there is nothing to tell it from the ground).

:class:`StaticClutter` labels each detection of a frame. Its scene position (from the
accumulated camera shift, see :class:`wfviz.stages.registration.CameraMotion`) is looked up in the
background-suppressed images of ``lag`` (±2) frames earlier: a spot of the ground was there
already, about as bright (at least ``persist`` times as bright as it is there now, taking the
largest of the four pixels around the position in both images), a moving target was not.
Comparing images rather than detections makes the test immune to spots that flicker across the
detection threshold. Labels:

- ``0``: not clutter-like (moved relative to the scene, alone in its neighbourhood, or
  ``bright`` times its threshold or more);
- ``1``: static and crowded;
- ``NaN``: crowded but not decidable (fewer than ``lag`` frames seen, or the point was outside
  the frame then). With ``min_lag`` > 0 (0: the full lag only), an undecidable point is tried
  at shorter lags k down to ``min_lag`` (searching ±k//5 frames around each). Across a camera
  move of at least ``min_shift`` px a short lag decides either way. Under a still camera it
  decides only *not static*: a spot that was not there k frames ago has moved (or appeared),
  but one that was may be a slow target that has not yet left its own earlier image (in the
  scene and in the image alike), so it stays undecided until the full lag.

The track manager averages these labels over each track's hits
(:meth:`wfviz.tracking.TrackManager.update`).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from wfviz.config import ClutterConfig

_SPREAD = 2  # frames either side of the lag that are searched for the earlier spot


class StaticClutter:
    """Labels detections as static clutter (1), not clutter (0) or undecided (NaN)."""

    def __init__(self, config: ClutterConfig) -> None:
        self.config = config
        # per frame: the background-suppressed image and the accumulated camera offset
        self._history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=config.lag + _SPREAD)

    def update(self, xy: np.ndarray, suppressed: np.ndarray, offset: tuple[float, float],
               contrast: np.ndarray | None = None) -> np.ndarray:
        """Labels of this frame's detections ``xy`` (N, 2) in the background-suppressed image
        ``suppressed``; ``offset``: accumulated camera shift; ``contrast``: each detection's
        peak / the threshold it passed (None: not used)."""
        c = self.config
        image = np.asarray(suppressed, dtype=np.float32)
        off = np.asarray(offset, dtype=np.float64)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        history = self._history
        n = len(xy)
        labels = np.zeros(n)
        if n:
            if c.neighbourhood > 0:
                from scipy.spatial import cKDTree  # (not the default: SciPy stays off the start-up)

                others = cKDTree(xy).query_ball_point(xy, c.neighbourhood, return_length=True) - 1
                crowded = others >= c.min_neighbours
            else:  # the whole frame
                crowded = np.full(n, n - 1 >= c.min_neighbours)
            labels[crowded] = np.nan
            todo = crowded.copy()
            scene = xy - off
            # now, at the position itself (a merged component's peak may lie pixels away)
            floor = c.persist * np.maximum(_corner_max(image, xy)[0], 0.0)
            low = c.min_lag if c.min_lag > 0 else c.lag
            for k in range(c.lag, low - 1, -1):
                if not todo.any() or k > len(history):
                    continue
                # camera still: a short lag tells "moved" but not "static" from "slow"
                still = k < c.lag and math.hypot(*(off - history[-k][1])) < c.min_shift
                spread = _SPREAD if k == c.lag else k // 5
                seen = np.zeros(n, dtype=bool)    # inside the lag frame then
                static = np.zeros(n, dtype=bool)  # as bright a spot there in a frame around it
                for j in range(k - spread, k + spread + 1):
                    if not 1 <= j <= len(history):
                        continue
                    earlier, then = history[-j]
                    value, inside = _corner_max(earlier, scene[todo] + then)
                    static[todo] |= inside & (value >= floor[todo]) & (value > 0)
                    if j == k:
                        seen[todo] = inside
                here = todo & seen & ~(still & static)
                labels[here] = static[here]
                todo &= ~here
            if contrast is not None and c.bright > 0:
                labels[np.asarray(contrast) >= c.bright] = 0.0
        # keep a copy only when the conversion did not already make one
        history.append((image.copy() if image is suppressed else image, off.copy()))
        return labels


class Novelty:
    """How new each detection is at its place in the scene: ``1 - earlier / now``, where *now*
    is the background-suppressed image at the detection (largest of the four pixels around it)
    and *earlier* the largest of the same four pixels at its scene position (camera motion
    removed) in the images ``lag - 1 .. lag + 1`` frames back (or as far back as the clip goes,
    at least one frame). A spot of the ground, a star, a lamp or fixed-pattern noise was already
    there, about as bright: novelty near 0. A target that has moved away from where it was: near
    1. A slow one that still covers part of its earlier image: in between. NaN where nothing
    earlier covers the position (the clip's first frame, a region the camera just brought in).
    Not in the paper; the same test on the image as :class:`StaticClutter`, kept continuous.
    """

    def __init__(self, lag: int = 16) -> None:
        self.lag = lag
        self._history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=lag + 1)

    def update(self, xy: np.ndarray, suppressed: np.ndarray, offset: tuple[float, float] | np.ndarray
               ) -> np.ndarray:
        """Novelty of this frame's detections ``xy`` (N, 2); then remembers this frame."""
        image = np.asarray(suppressed, dtype=np.float32)
        off = np.asarray(offset, dtype=np.float64)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.full(len(xy), np.nan)
        hist = self._history
        if len(xy) and hist:
            now = _corner_max(image, xy)[0]
            k = min(self.lag, len(hist))
            earlier = np.full(len(xy), -np.inf)
            seen = np.zeros(len(xy), dtype=bool)
            for j in range(max(k - 1, 1), min(k + 1, len(hist)) + 1):
                then_image, then = hist[-j]
                value, inside = _corner_max(then_image, xy - off + then)
                earlier = np.fmax(earlier, np.where(inside, value, -np.inf))
                seen |= inside
            with np.errstate(invalid="ignore", divide="ignore"):
                nov = 1.0 - np.maximum(earlier, 0.0) / now
            out = np.where(seen & (now > 0), np.clip(nov, -1.0, 1.0), np.nan)
        hist.append((image.copy() if image is suppressed else image, off.copy()))
        return out


def _corner_max(image: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest of the four pixels around each position ``q`` (N, 2; x, y; NaN pixels ignored)
    and whether the position lies inside the image: the spot may sit up to a pixel off in the
    direction the registration's rounding left it."""
    h, w = image.shape
    out = np.full(len(q), -np.inf)
    inside = (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
    if inside.any():
        x0 = np.minimum(np.floor(q[inside, 0]).astype(np.int64), max(w - 2, 0))
        y0 = np.minimum(np.floor(q[inside, 1]).astype(np.int64), max(h - 2, 0))
        x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
        out[inside] = np.fmax(np.fmax(image[y0, x0], image[y0, x1]),
                              np.fmax(image[y1, x0], image[y1, x1]))
    return out, inside
