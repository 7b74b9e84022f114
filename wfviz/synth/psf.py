"""Pixel-integrated Gaussian point-spread functions.

Coordinates: x = column, y = row, origin at the centre of the top-left pixel, so pixel
(r, c) covers x in [c - 0.5, c + 0.5] and y in [r - 0.5, r + 0.5].
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

_SQRT2 = math.sqrt(2.0)


def _pixel_fractions(lo: int, hi: int, centre: float, sigma: float) -> np.ndarray:
    """Fraction of a unit 1-D Gaussian falling in each pixel ``lo <= i < hi``."""
    edges = (np.arange(lo, hi + 1, dtype=np.float64) - 0.5 - centre) / (_SQRT2 * sigma)
    return 0.5 * np.diff(erf(edges))


def add_gaussian_spot(
    image: np.ndarray,
    x: float,
    y: float,
    peak: float,
    sigma: float,
    sigma_y: float | None = None,
) -> None:
    """Add, in place, a pixel-integrated Gaussian spot centred at (x, y).

    ``peak`` is the continuous profile's peak value, so the integrated flux is
    ``peak * 2*pi * sigma * sigma_y``. ``sigma`` is the x (column) width and ``sigma_y``
    the y (row) width (default: ``sigma``). Only a patch of +-ceil(5 sigma) pixels around
    the centre is touched, clipped at the image border. ``image`` must be float32/float64.
    """
    if image.dtype not in (np.float32, np.float64):
        raise TypeError(f"image must be float32 or float64, not {image.dtype}")
    sy = sigma if sigma_y is None else sigma_y
    if sigma <= 0 or sy <= 0:
        raise ValueError("sigma must be positive")
    rows, cols = image.shape
    hx, hy = math.ceil(5 * sigma), math.ceil(5 * sy)
    c0, c1 = max(round(x) - hx, 0), min(round(x) + hx + 1, cols)
    r0, r1 = max(round(y) - hy, 0), min(round(y) + hy + 1, rows)
    if c0 >= c1 or r0 >= r1:
        return
    flux = peak * 2.0 * math.pi * sigma * sy
    px = _pixel_fractions(c0, c1, x, sigma)
    py = _pixel_fractions(r0, r1, y, sy)
    image[r0:r1, c0:c1] += (flux * np.outer(py, px)).astype(image.dtype, copy=False)


def gaussian_spot_image(
    shape: tuple[int, int], x: float, y: float, peak: float, sigma: float
) -> np.ndarray:
    """Return a float64 image of ``shape`` holding one spot (see ``add_gaussian_spot``)."""
    image = np.zeros(shape, dtype=np.float64)
    add_gaussian_spot(image, x, y, peak, sigma)
    return image
