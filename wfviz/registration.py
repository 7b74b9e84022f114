"""Global image motion between consecutive frames (camera pan/jitter), by phase correlation."""

from __future__ import annotations

import cv2
import numpy as np


class MotionEstimator:
    """Shift (dx, dy) of the scene from the previous frame to this one, in pixels.

    Frames larger than ``max_size`` are downsampled by an integer factor first (the shift is
    scaled back). A correlation peak weaker than ``min_response`` gives (0, 0).
    """

    def __init__(self, max_size: int = 256, min_response: float = 0.05) -> None:
        self.max_size, self.min_response = max_size, min_response
        self._prev: np.ndarray | None = None
        self._window: np.ndarray | None = None

    def update(self, image: np.ndarray) -> tuple[float, float, float]:
        """(dx, dy, response) of ``image`` relative to the previous call's image."""
        f = max(1, int(np.ceil(max(image.shape) / self.max_size)))
        small = image.astype(np.float32, copy=False)
        if f > 1:
            small = cv2.resize(small, (image.shape[1] // f, image.shape[0] // f), interpolation=cv2.INTER_AREA)
        prev, self._prev = self._prev, small
        if prev is None or prev.shape != small.shape:
            self._window = cv2.createHanningWindow(small.shape[::-1], cv2.CV_32F)
            return 0.0, 0.0, 0.0
        (dx, dy), response = cv2.phaseCorrelate(prev, small, self._window)
        if response < self.min_response:
            return 0.0, 0.0, float(response)
        return float(dx * f), float(dy * f), float(response)
