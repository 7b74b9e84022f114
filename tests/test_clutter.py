"""Static clutter (wfviz.stages.clutter) and the meeting-mode options for cluttered scenes.

The static-clutter labels act on the paper's confirmation rule (``tracking.confirm = "hits"``),
so the track tests with labels configure it; under the default sequential test static clutter
is rejected by its change and motion evidence instead (the last test of the labels section).
"""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.config import ClutterConfig, KalmanConfig, TrackingConfig
from wfviz.stages.clutter import StaticClutter
from wfviz.tracking import Measurements, TrackManager

GROUND = np.array([[20.0 + 15 * i, 30.0 + 11 * (i % 4)] for i in range(12)])  # 12 fixed spots
SHAPE = (160, 240)


def _render(xy: np.ndarray, amplitude: float = 10.0) -> np.ndarray:
    """A background-suppressed frame: a Gaussian spot (sigma 0.8 px) at each position."""
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(np.float32)
    img = np.zeros(SHAPE, np.float32)
    for x, y in xy:
        img += amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 0.8 ** 2))
    return img


def _label(sc: StaticClutter, xy: np.ndarray, off, contrast=None) -> np.ndarray:
    return sc.update(xy, _render(xy), off, contrast)


def _frames(n: int, pan: tuple[float, float] = (0.7, 0.4), target_speed: float = 1.0):
    """Ground spots fixed in the scene under a panning camera, plus a target moving over it."""
    for k in range(n):
        off = np.array(pan) * k
        target = np.array([100.0 + target_speed * k, 100.0]) + off
        yield np.vstack([GROUND + off, target]), off


def test_static_crowded_spots_are_clutter_and_the_moving_target_is_not():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10, min_lag=0))
    labels = [_label(sc, xy, off) for xy, off in _frames(20)]
    assert np.isnan(labels[0]).all()               # crowded, not decidable yet
    assert np.isnan(labels[9]).all()
    for lab in labels[10:]:
        assert (lab[:12] == 1).all() and lab[12] == 0  # the target moved 10 px in the scene


def test_a_fast_pan_decides_before_lag_frames():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10, min_lag=3, min_shift=3.0))
    labels = [_label(sc, xy, off) for xy, off in _frames(12, pan=(0.9, 0.0))]
    assert np.isnan(labels[3][:12]).all()  # 2.7 px of pan in 3 frames: cannot call it static yet
    assert labels[3][12] == 0  # but the target has left its place of 3 frames ago
    assert (labels[4][:12] == 1).all() and labels[4][12] == 0  # 3.6 px after 4 frames


def test_a_still_camera_decides_static_only_at_the_full_lag():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10, min_lag=3))
    labels = [_label(sc, xy, off) for xy, off in _frames(12, pan=(0.0, 0.0))]
    assert np.isnan(labels[2]).all()  # no lag of min_lag frames yet
    for lab in labels[3:10]:  # short lags: the target left its spot of 3+ frames ago ...
        assert np.isnan(lab[:12]).all() and lab[12] == 0  # ... the ground may be a slow target
    assert (labels[10][:12] == 1).all() and labels[10][12] == 0


def test_a_slow_target_under_a_still_camera_is_not_called_static_early():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10, min_lag=3))
    labels = [_label(sc, xy, off) for xy, off in _frames(11, pan=(0.0, 0.0), target_speed=0.3)]
    assert all(np.isnan(lab[12]) for lab in labels[:6])  # within 1.5 px of itself: undecided
    assert not any(lab[12] == 1 for lab in labels)  # never static ...
    assert labels[10][12] == 0  # ... and moved once 3 px from its place 10 frames ago


def test_the_test_compares_the_position_now_with_the_same_position_then():
    """A merged component's peak may lie pixels from its centroid: the floor is the image
    at the centroid now, not that peak."""
    sc = StaticClutter(ClutterConfig(enabled=True, lag=2, min_lag=0, min_neighbours=1))
    spot = np.array([[40.0, 40.0], [90.0, 90.0]])
    for _ in range(2):
        sc.update(spot, _render(spot, 4.0), (0.0, 0.0))  # faint ground spots
    now = _render(spot, 6.0)
    now[40, 43] = 40.0  # a hot pixel merged into the first spot's component, 3 px away
    assert sc.update(spot, now, (0.0, 0.0)).tolist() == [1.0, 1.0]


def test_a_spot_that_was_outside_the_frame_is_undecided_not_moved():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10, min_lag=0))
    for k in range(14):  # the camera pans right: the scene moves left, new ground enters at the right
        off = np.array([-2.0 * k, 0.0])
        new = np.array([[SHAPE[1] - 5.0, 80.0]])  # always just inside the right edge: new ground
        lab = _label(sc, np.vstack([GROUND[:11] + off + [40, 0], new]), off)
    assert np.isnan(lab[-1])  # 16 px outside the frame (x = 255, last column 239) 10 frames ago


def test_without_the_camera_shift_the_panned_ground_is_not_static():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10, min_lag=0))
    labels = [_label(sc, xy, (0.0, 0.0)) for xy, _ in _frames(20)]
    assert (labels[-1] == 0).all()  # 8 px of pan in 10 frames: nothing stays put in the image


def test_a_spot_that_brightens_well_beyond_its_past_is_not_static():
    cfg = ClutterConfig(enabled=True, lag=4, min_lag=0, persist=0.35)
    sc = StaticClutter(cfg)
    for k in range(8):
        img = _render(GROUND)
        img[30, 20] = 10.0 if k < 6 else 40.0  # the first spot flares 4x in frame 6
        lab = sc.update(GROUND, img, (0.0, 0.0))
    assert lab[0] == 0 and (lab[1:] == 1).all()


def test_a_hovering_target_alone_is_never_clutter():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10))
    for k in range(20):
        lab = _label(sc, np.array([[50.0, 40.0], [90.0, 20.0 + 2 * k]]), (0.0, 0.0))
        assert (lab == 0).all()  # 2 detections: not crowded (min_neighbours 10)


def test_neighbourhood_radius_limits_the_crowd():
    cfg = ClutterConfig(enabled=True, lag=3, min_lag=0, neighbourhood=10.0, min_neighbours=2)
    sc = StaticClutter(cfg)
    pts = np.array([[10.0, 10], [14, 10], [10, 14], [80, 80]])  # a cluster of 3 and a lone spot
    for _ in range(6):
        lab = _label(sc, pts, (0.0, 0.0))
    assert lab.tolist() == [1.0, 1.0, 1.0, 0.0]


def test_the_four_pixels_around_the_position_are_looked_up():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=2, min_lag=0, min_neighbours=1))
    earlier = np.zeros(SHAPE, np.float32)
    earlier[30, 21] = 10.0  # a one-pixel spot at x = 21
    sc.update(np.zeros((0, 2)), earlier, (0.0, 0.0))
    sc.update(np.zeros((0, 2)), earlier, (0.0, 0.0))
    xy = np.array([[20.4, 30.0], [19.4, 30.0]])  # rounds to 20 (dark); its corners reach 21
    now = np.zeros(SHAPE, np.float32)
    now[30, 20] = now[30, 19] = 10.0  # both detections' own pixels, bright now
    lab = sc.update(xy, now, (0.0, 0.0))
    assert lab.tolist() == [1.0, 0.0]


def test_nan_pixels_in_the_earlier_image_do_not_hide_the_spot():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=1, min_lag=0, min_neighbours=1))
    earlier = np.zeros(SHAPE, np.float32)
    earlier[30, 20], earlier[30, 21] = np.nan, 10.0
    sc.update(np.zeros((0, 2)), earlier, (0.0, 0.0))
    xy = np.array([[20.5, 30.0], [60.0, 60.0]])
    lab = sc.update(xy, _render(xy), (0.0, 0.0))
    assert lab.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("section,message", [({"lag": 5, "min_lag": 8}, "clutter.min_lag"),
                                             ({"max_static": 0.6, "delete_static": 0.5},
                                              "clutter.delete_static")])
def test_inconsistent_clutter_settings_are_a_config_error(section, message):
    from wfviz.config import ConfigError, config_from_dict
    from wfviz.trackers.gewc.config import GEWCConfig
    with pytest.raises(ConfigError, match=message):
        config_from_dict({"clutter": section}, GEWCConfig)


def _run(mgr: TrackManager, frames: list[np.ndarray], labels: list[np.ndarray] | None = None,
         novelty: float | None = None):
    """Feed ``frames`` of detections (and their static-clutter ``labels``, and one change
    significance ``novelty`` for every hit) to ``mgr``; returns the events."""
    events = []
    for f, xy in enumerate(frames):
        preds = mgr.predict(f)
        n = len(xy)
        events += mgr.update(mgr.associate(preds, xy), Measurements(
            xy, significance=None if novelty is None else np.full(n, 10.0),
            novelty=None if novelty is None else np.full(n, novelty),
            clutter=None if labels is None else np.asarray(labels[f], dtype=float)))
    return events


_HITS = TrackingConfig(confirm="hits")  # the paper's rule, where the clutter labels act


@pytest.mark.parametrize("wait", [False, True])
def test_hits_rule_track_on_static_clutter_is_deleted_or_never_confirmed(wait):
    """confirm = "hits": labels undecided for 10 frames, then static. With ``wait`` the track
    is never confirmed; without, it is confirmed at its 6th hit and deleted as clutter."""
    mgr = TrackManager(KalmanConfig(), _HITS)
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


def test_hits_rule_track_with_clean_labels_is_confirmed_as_usual():
    """confirm = "hits": labels 0 (not static) do not delay the 6th-hit confirmation."""
    mgr = TrackManager(KalmanConfig(), _HITS)
    mgr.clutter_rule = ClutterConfig(enabled=True, max_static=0.5, min_known=2, memory=0.25, wait=True)
    xy = [np.array([[40.0 + k, 40.0]]) for k in range(10)]
    events = _run(mgr, xy, [np.array([0.0])] * 10)
    assert [e.frame for e in events if e.kind == "confirmed"] == [5]


def test_hits_rule_the_first_labels_are_averaged_plainly():
    """confirm = "hits"."""
    # labels 1, 0, 0, 0, 0, 0: plain mean 1/6 at the 6th hit (confirmed); a running mean with
    # weight 0.1 started at the first label would still be at 0.9**5 = 0.59 (held back)
    mgr = TrackManager(KalmanConfig(), _HITS)
    mgr.clutter_rule = ClutterConfig(enabled=True, max_static=0.5, memory=0.1)
    xy = [np.array([[40.0 + k, 40.0]]) for k in range(8)]
    events = _run(mgr, xy, [np.array([1.0])] + [np.array([0.0])] * 7)
    assert [e.frame for e in events if e.kind == "confirmed"] == [5]


def test_hits_rule_a_confirmed_track_survives_a_short_static_spell_but_not_a_long_one():
    """confirm = "hits": the running mean of the labels deletes a confirmed track only once it
    exceeds delete_static."""
    mgr = TrackManager(KalmanConfig(), _HITS)
    mgr.clutter_rule = ClutterConfig(enabled=True, max_static=0.5, delete_static=0.8, memory=0.1)
    xy = [np.array([[40.0, 40.0]])] * 40
    labels = [np.array([0.0])] * 10 + [np.array([1.0])] * 30
    events = _run(mgr, xy[:13], labels[:13])
    assert [e.frame for e in events if e.kind == "confirmed"] == [5]
    assert len(mgr) == 1 and mgr.states()[0].confirmed  # mean 1 - 0.9**3 = 0.27 after three static hits
    for f in range(13, 40):
        preds = mgr.predict(f)
        events += mgr.update(mgr.associate(preds, xy[f]), Measurements(xy[f], clutter=np.ones(len(xy[f]))),
                             start=False)
    deleted = [e for e in events if e.kind == "deleted"]
    # plain mean over 10 labels (0), then 1 - 0.9**n > 0.8 from the 16th static label on
    assert [e.frame for e in deleted] == [25] and "static clutter" in deleted[0].message


@pytest.mark.parametrize("case,moving,novelty,confirmed", [
    ("static, as it was (static clutter)", False, 0.0, False),
    ("static, new at its place each frame", False, 10.0, False),
    ("moving, new at its place", True, 10.0, True),
])
def test_default_track_on_static_clutter_is_never_confirmed(case, moving, novelty, confirmed):
    """Defaults (confirm = "sprt"): a track on a fixed spot is never confirmed in 40 frames,
    whether or not its hits look new (no motion); the same hits on a mover are (the test
    can fail). The clutter labels play no part here."""
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    xy = [np.array([[40.0 + (1.5 * k if moving else 0.0), 40.0]]) for k in range(40)]
    events = _run(mgr, xy, novelty=novelty)
    assert any(e.kind == "confirmed" for e in events) == confirmed, case
    assert len(mgr) == 1 and mgr.states()[0].hits == 40, case  # one track, on it all along


def _pair_frames(n: int, gap: float) -> list[np.ndarray]:
    return [np.array([[50.0, 50.0], [50.0 + gap, 50.0]]) for _ in range(n)]


def test_hits_rule_static_pair_meets_but_not_with_meeting_overlap():
    """confirm = "hits" (a static pair is never confirmed by the sequential test, and only
    confirmed tracks meet): 12 px apart, within the safety distance, they meet; with
    meeting_overlap (gates that do not overlap) they keep their own detections."""
    frames = _pair_frames(30, 12.0)
    default = TrackManager(KalmanConfig(), _HITS)
    _run(default, frames)
    assert len(default) == 2 and all(s.meeting for s in default.states())  # the paper: within 20 px = meeting
    overlap = TrackManager(KalmanConfig(), TrackingConfig(confirm="hits", meeting_overlap=True))
    _run(overlap, frames)
    assert not any(s.meeting for s in overlap.states())
    assert all(s.hits == 30 for s in overlap.states())  # both keep their own detections


def test_hits_rule_meeting_track_is_kept_while_meeting_without_meeting_misses():
    """confirm = "hits": the paper counts no misses while meeting, so a meeting pair whose
    spots vanish is kept (until the meeting ends)."""
    frames = _pair_frames(12, 8.0) + [np.zeros((0, 2))] * 10  # both spots vanish at frame 12
    default = TrackManager(KalmanConfig(), _HITS)
    _run(default, frames)
    assert len(default) == 2 and default.track_ids == [1, 2]


def test_hits_rule_meeting_track_that_loses_its_target_is_deleted_with_meeting_misses():
    """confirm = "hits" with meeting_misses: a meeting track with nothing near its
    extrapolation counts misses, and both tracks go at the 3rd one (max_misses)."""
    frames = _pair_frames(12, 8.0) + [np.zeros((0, 2))] * 10  # both spots vanish at frame 12
    strict = TrackManager(KalmanConfig(), TrackingConfig(confirm="hits", meeting_misses=True))
    events = _run(strict, frames)
    assert len(strict) == 0
    assert sorted(e.frame for e in events if e.kind == "deleted") == [14, 14]


def test_a_spot_far_above_its_threshold_is_never_clutter():
    sc = StaticClutter(ClutterConfig(enabled=True, lag=10))
    contrast = np.full(len(GROUND) + 1, 1.5)
    contrast[0] = 6.0  # one ground spot 6x its threshold (bright = 4)
    labels = [_label(sc, xy, off, contrast) for xy, off in _frames(20)]
    assert labels[-1][0] == 0 and (labels[-1][1:12] == 1).all()
