"""The standard normal functions of the tracking rules against SciPy's."""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr, ndtr, ndtri

from wfviz import normal


def _close(got: np.ndarray, want: np.ndarray, rtol: float) -> None:
    assert np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    np.testing.assert_allclose(got[ok], want[ok], rtol=rtol, atol=1e-300)


def test_cdf_and_its_log_match_scipy_into_both_tails() -> None:
    x = np.concatenate([np.linspace(-37.0, 37.0, 7401), [-np.inf, np.inf, np.nan, 0.0]])
    _close(normal.cdf(x), ndtr(x), 1e-13)
    _close(normal.log_cdf(x), log_ndtr(x), 1e-12)
    far = np.linspace(-200.0, -20.0, 181)  # the asymptotic series
    _close(normal.log_cdf(far), log_ndtr(far), 1e-13)
    assert normal.log_cdf(-4.0).shape == () and float(normal.cdf(0.0)) == 0.5


def test_quantile_matches_scipy_and_its_edges() -> None:
    p = np.concatenate([np.linspace(0.0, 1.0, 2001), 1.0 - np.logspace(-15, -1, 60),
                        np.logspace(-300, -1, 60), [np.nan, -0.5, 1.5]])
    _close(normal.quantile(p), ndtri(p), 1e-13)
    assert float(normal.quantile(0.5)) == 0.0
