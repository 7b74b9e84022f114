"""The motion test's steady progress in units of the position scatter: a slow, precisely
measured target makes significant progress in both halves of its history; a centroid that jumps
once to a neighbouring spot does not (wfviz.tracking.confirmation.motion)."""

from __future__ import annotations

import numpy as np

from wfviz.tracking.confirmation import motion
from wfviz.tracking.rules import STEADY_Z


def _track(xy: np.ndarray):
    k = len(xy)
    return motion(np.arange(k, dtype=float)[None], xy[None], np.ones((1, k), dtype=bool), 0.05)


def test_slow_precise_mover_makes_significant_progress_below_one_pixel():
    rng = np.random.default_rng(1)
    k = 32
    xy = np.column_stack([0.07 * np.arange(k), np.zeros(k)]) + rng.normal(0, 0.05, (k, 2))
    m = _track(xy)
    assert m.steady[0] < 1.0                                  # below the fixed 1 px of min_motion / 2
    assert m.steady[0] >= STEADY_Z * m.steady_error[0]        # but many standard errors


def test_one_jump_is_not_steady_progress():
    rng = np.random.default_rng(2)
    k = 32
    xy = np.zeros((k, 2)) + rng.normal(0, 0.05, (k, 2))
    xy[k // 3 + 2:, 0] += 2.0                                 # the centroid jumps once by 2 px
    m = _track(xy)
    assert m.steady[0] < STEADY_Z * m.steady_error[0]
