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
    assert m.steady[0] < 1.0                                  # below 1 px
    assert m.steady[0] >= STEADY_Z * m.steady_error[0]        # but many standard errors


def test_one_jump_is_not_steady_progress():
    rng = np.random.default_rng(2)
    k = 32
    xy = np.zeros((k, 2)) + rng.normal(0, 0.05, (k, 2))
    xy[k // 3 + 2:, 0] += 2.0                                 # the centroid jumps once by 2 px
    m = _track(xy)
    assert m.steady[0] < STEADY_Z * m.steady_error[0]


def test_one_jump_in_the_middle_part_is_not_steady_progress():
    """A fixed object's centroid that moves once to a neighbouring part of the object halfway
    through its history (IR_HELICOPTER_033 track 6): the median of a middle third straddles the
    jump and shows half of it as progress on both sides; with 4 parts one difference is free of it."""
    from wfviz.tracking.rules import STEADY_PARTS

    rng = np.random.default_rng(3)
    k = 32
    t = np.concatenate([np.arange(12, 28), np.arange(38, 54)]).astype(float)
    xy = np.zeros((k, 2)) + rng.normal(0, 0.05, (k, 2))
    xy[k // 2:] += (-3.0, -0.9)                               # jumps once by 3 px, then stays
    ok = np.ones((1, k), dtype=bool)
    thirds = motion(t[None], xy[None], ok, 0.3, parts=3)
    assert thirds.steady[0] > 1.0                             # the old test: half the jump each side
    m = motion(t[None], xy[None], ok, 0.3, parts=STEADY_PARTS)
    assert m.t2[0] > 100                                      # T² alone takes the jump for motion
    assert m.steady[0] < min(1.0, STEADY_Z * m.steady_error[0])


def test_constant_velocity_makes_steady_progress_between_all_parts():
    from wfviz.tracking.rules import STEADY_PARTS

    rng = np.random.default_rng(4)
    k = 12
    xy = np.column_stack([0.5 * np.arange(k), 0.2 * np.arange(k)]) + rng.normal(0, 0.3, (k, 2))
    m = motion(np.arange(k, dtype=float)[None], xy[None], np.ones((1, k), dtype=bool), 0.3, parts=STEADY_PARTS)
    assert m.steady[0] >= min(1.0, STEADY_Z * m.steady_error[0])


def test_three_positions_of_a_fast_straight_mover_make_significant_progress():
    """From 3 positions on (one a part) a fast target's progress is tested in standard errors of
    its own path's scatter: it need not wait for 6 positions."""
    rng = np.random.default_rng(3)
    xy = np.column_stack([3.0 * np.arange(3), 1.0 * np.arange(3)]) + rng.normal(0, 0.1, (3, 2))
    m = motion(np.arange(3, dtype=float)[None], xy[None], np.ones((1, 3), dtype=bool), 0.3, 4)
    assert m.per_part[0] == 1 and m.parts[0] == 3
    assert m.steady[0] >= STEADY_Z * m.steady_error[0]


def test_three_positions_that_zigzag_are_not_steady_progress():
    """Three hits linked across erratic jumps (noise, or clutter picked up at random) have as
    much progress, but their path's scatter (each position off the chord of its neighbours)
    makes it insignificant."""
    xy = np.array([[0.0, 0.0], [4.1, -6.3], [2.8, -10.0]])
    m = motion(np.arange(3, dtype=float)[None], xy[None], np.ones((1, 3), dtype=bool), 0.3, 4)
    assert m.steady[0] > 3.0
    assert m.steady[0] < STEADY_Z * m.steady_error[0]
