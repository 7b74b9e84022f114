"""Background suppression: 5x5 minimum background prediction, positive residual."""

from __future__ import annotations

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
