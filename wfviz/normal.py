"""The standard normal distribution's CDF, its logarithm and its quantile, element-wise.

From Python's ``math.erfc`` of the smaller tail and ``statistics.NormalDist`` (Wichura's AS241),
with an asymptotic series below -20 as SciPy's ``log_ndtr``, so the far tails keep their
precision. For the small arrays of the tracking rules (a value per gate or track; the elements
go through Python one by one): importing ``scipy.special`` would cost about 0.2 s of every
run's start-up. ``tests/test_normal.py`` checks them against SciPy.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

_SQRT1_2 = math.sqrt(0.5)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_erfc = np.frompyfunc(math.erfc, 1, 1)
_inv_cdf = np.frompyfunc(NormalDist().inv_cdf, 1, 1)


def cdf(x: np.ndarray | float) -> np.ndarray:
    """Φ(x) = P(N(0, 1) <= x)."""
    x = np.asarray(x, dtype=np.float64)
    q = _upper(x)
    return np.where(x > 0, 1.0 - q, q)


def log_cdf(x: np.ndarray | float) -> np.ndarray:
    """ln Φ(x), accurate far into both tails."""
    x = np.asarray(x, dtype=np.float64)
    q = _upper(x)
    with np.errstate(divide="ignore"):
        out = np.where(x > 0, np.log1p(-q), np.log(q))
    far = x <= -20.0
    if far.any():  # Φ(x) = φ(x) / -x * (1 - 1/x² + 3/x⁴ - ...), the series to 10 terms
        y = x[far]
        inv = 1.0 / (y * y)
        term = np.ones_like(y)
        series = np.ones_like(y)
        for n in range(1, 11):
            term = term * -(2 * n - 1) * inv
            series = series + term
        out = np.array(out)
        out[far] = -0.5 * y * y - np.log(-y) - _LOG_SQRT_2PI + np.log(series)
    return out


def _upper(x: np.ndarray) -> np.ndarray:
    """Φ(-|x|), the smaller tail (no cancellation)."""
    return 0.5 * np.asarray(_erfc(np.abs(x) * _SQRT1_2), dtype=np.float64)


def quantile(p: np.ndarray | float) -> np.ndarray:
    """Φ⁻¹(p): -inf at p = 0, +inf at p = 1, NaN outside [0, 1]."""
    p = np.asarray(p, dtype=np.float64)
    inside = (p > 0.0) & (p < 1.0)
    out = np.where(p == 0.0, -np.inf, np.where(p == 1.0, np.inf, np.nan))
    if inside.any():
        out[inside] = np.asarray(_inv_cdf(p[inside]), dtype=np.float64)
    return out
