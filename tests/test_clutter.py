"""Static clutter (wfviz.clutter) and the meeting-mode options for cluttered scenes."""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.clutter import StaticClutter
from wfviz.config import ClutterConfig, KalmanConfig, TrackingConfig
from wfviz.tracking import TrackManager

GROUND = np.array([[20.0 + 15 * i, 30.0 + 11 * (i % 4)] for i in range(12)])  # 12 fixed spots


def _frames(n: int, pan: tuple[float, float] = (0.7, 0.4), target_speed: float = 1.0):
    """Ground spots fixed in the scene under a panning camera, plus a target moving over it."""
    for k in range(n):
        off = np.array(pan) * k
        target = np.array([100.0 + target_speed * k, 100.0]) + off
        yield np.vstack([GROUND + off, target]), off


def test_static_crowded_spots_are_clutter_and_the_moving_target_is_not():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10))
    labels = [sc.update(xy, off) for xy, off in _frames(20)]
    assert np.isnan(labels[0]).all()               # crowded, not decidable yet
    for lab in labels[12:]:
        assert (lab[:12] == 1).all() and lab[12] == 0  # the target moved 10 px in the scene


def test_without_the_camera_shift_the_panned_ground_is_not_static():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10))
    labels = [sc.update(xy, (0.0, 0.0)) for xy, _ in _frames(20)]
    assert (labels[-1] == 0).all()  # 8 px of pan in 10 frames: nothing stays put in the image


def test_a_hovering_target_alone_is_never_clutter():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10))
    for k in range(20):
        lab = sc.update(np.array([[50.0, 40.0], [90.0, 20.0 + 2 * k]]), (0.0, 0.0))
        assert (lab == 0).all()  # 2 detections: not crowded (min_neighbours 10)


def test_neighbourhood_radius_limits_the_crowd():
    cfg = ClutterConfig(enabled=True, lag=3, neighbourhood=10.0, min_neighbours=2)
    sc = StaticClutter(cfg)
    pts = np.array([[10.0, 10], [14, 10], [10, 14], [80, 80]])  # a cluster of 3 and a lone spot
    for _ in range(6):
        lab = sc.update(pts, (0.0, 0.0))
    assert lab.tolist() == [1.0, 1.0, 1.0, 0.0]


def _run(mgr: TrackManager, frames: list[np.ndarray], labels: list[np.ndarray] | None = None):
    events = []
    for f, xy in enumerate(frames):
        preds = mgr.predict(f)
        pairs = mgr.associate(preds, xy)
        used = np.zeros(len(xy), bool)
        used[list(pairs.values())] = True
        born = ~used & ~mgr.claimed(preds, xy)
        lab = None if labels is None else labels[f]
        events += mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, xy[born],
                             clutter=None if lab is None else {i: float(lab[d]) for i, d in pairs.items()},
                             birth_clutter=None if lab is None else lab[born])
    return events


@pytest.mark.parametrize("wait", [False, True])
def test_track_on_static_clutter_is_deleted_or_never_confirmed(wait):
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    mgr.clutter_rule = ClutterConfig(enabled=True, max_static=0.5, min_known=2, memory=0.25, wait=wait)
    xy = [np.array([[40.0, 40.0]])] * 20
    labels = [np.array([np.nan])] * 10 + [np.array([1.0])] * 10  # decided from frame 10 on
    events = _run(mgr, xy, labels)
    kinds = [(e.kind, e.frame) for e in events]
    if wait:
        assert not any(k == "confirmed" for k, _ in kinds)
    else:
        assert ("confirmed", 5) in kinds
        assert ("deleted", 11) in kinds  # second decided static label
        assert any("static clutter" in e.message for e in events)
    assert not any(s.confirmed for s in mgr.states())


def test_track_with_clean_labels_is_confirmed_as_usual():
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    mgr.clutter_rule = ClutterConfig(enabled=True, max_static=0.5, min_known=2, memory=0.25, wait=True)
    xy = [np.array([[40.0 + k, 40.0]]) for k in range(10)]
    events = _run(mgr, xy, [np.array([0.0])] * 10)
    assert [e.frame for e in events if e.kind == "confirmed"] == [5]


def _pair_frames(n: int, gap: float) -> list[np.ndarray]:
    return [np.array([[50.0, 50.0], [50.0 + gap, 50.0]]) for _ in range(n)]


def test_static_pair_meets_by_default_but_not_with_meeting_overlap():
    frames = _pair_frames(30, 12.0)
    default = TrackManager(KalmanConfig(), TrackingConfig())
    _run(default, frames)
    assert all(s.meeting for s in default.states())  # the paper: within 20 px = meeting
    overlap = TrackManager(KalmanConfig(), TrackingConfig(meeting_overlap=True))
    _run(overlap, frames)
    assert not any(s.meeting for s in overlap.states())
    assert all(s.hits == 30 for s in overlap.states())  # both keep their own detections


def test_meeting_track_that_loses_its_target_is_deleted_with_meeting_misses():
    frames = _pair_frames(12, 8.0) + [np.zeros((0, 2))] * 10  # both spots vanish at frame 12
    default = TrackManager(KalmanConfig(), TrackingConfig())
    _run(default, frames)
    assert len(default) == 2  # the paper: no misses counted while meeting
    strict = TrackManager(KalmanConfig(), TrackingConfig(meeting_misses=True))
    events = _run(strict, frames)
    assert len(strict) == 0
    assert sorted(e.frame for e in events if e.kind == "deleted") == [14, 14]


def test_a_spot_far_above_its_threshold_is_never_clutter():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10))
    contrast = np.full(len(GROUND) + 1, 1.5)
    contrast[0] = 6.0  # one ground spot 6x its threshold (bright = 4)
    labels = [sc.update(xy, off, contrast) for xy, off in _frames(20)]
    assert labels[-1][0] == 0 and (labels[-1][1:12] == 1).all()
