"""Static clutter: detections that stay put in the scene amid other detections (not in the paper).

A panning camera over textured ground sees bright spots of the terrain (tree crowns, roofs,
field edges) that pass every single-frame test a target passes. Two things give them away:
they keep their place in the scene (camera motion removed) and they come in crowds. A target
moves relative to the ground, and a lone point in clean sky is a target even when it hovers
(a hovering target amid ground clutter is lost: there is nothing to tell it from the ground).

:class:`StaticClutter` labels each detection of a frame (scene coordinates come from the
accumulated camera shift, see :class:`wfviz.registration.MotionEstimator`):

- ``0``: not clutter-like (moved relative to the scene, alone in its neighbourhood, or
  ``bright`` times its threshold or more);
- ``1``: static and crowded;
- ``NaN``: crowded but not yet decidable (fewer than ``lag`` frames seen).

The track manager averages these labels over each track's hits
(:meth:`wfviz.tracking.TrackManager.update`).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.spatial import cKDTree

from wfviz.config import ClutterConfig

_SPREAD = 2  # frames either side of the lag that are searched for the earlier detection


class StaticClutter:
    """Labels detections as static clutter (1), not clutter (0) or undecided (NaN)."""

    def __init__(self, config: ClutterConfig) -> None:
        self.config = config
        self._history: deque[np.ndarray] = deque(maxlen=config.lag + _SPREAD + 1)

    def update(self, xy: np.ndarray, offset: tuple[float, float],
               contrast: np.ndarray | None = None) -> np.ndarray:
        """Labels of this frame's detections ``xy`` (N, 2); ``offset``: accumulated camera
        shift; ``contrast``: each detection's peak / the threshold it passed (None: not used)."""
        c = self.config
        scene = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.asarray(offset, dtype=np.float64)
        history = self._history
        n = len(scene)
        labels = np.zeros(n)
        if n:
            if c.neighbourhood > 0:
                others = cKDTree(scene).query_ball_point(scene, c.neighbourhood, return_length=True) - 1
                crowded = others >= c.min_neighbours
            else:  # the whole frame
                crowded = np.full(n, n - 1 >= c.min_neighbours)
            if crowded.any():
                if len(history) <= c.lag:
                    labels[crowded] = np.nan
                else:
                    back = len(history) - c.lag  # index of the frame `lag` frames ago
                    earlier = np.concatenate([history[j] for j in range(
                        max(back - _SPREAD, 0), min(back + _SPREAD + 1, len(history)))])
                    static = np.zeros(n, dtype=bool)
                    if len(earlier):
                        dist, _ = cKDTree(earlier).query(scene, distance_upper_bound=c.radius * (1 + 1e-9))
                        static = np.isfinite(dist)
                    labels[crowded] = static[crowded]
            if contrast is not None and c.bright > 0:
                labels[np.asarray(contrast) >= c.bright] = 0.0
        history.append(scene)
        return labels
