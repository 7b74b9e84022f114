"""Kalman filter and track management against hand-computed numbers and scripted scenes."""

from __future__ import annotations

import numpy as np
import pytest

from wfviz import kalman
from wfviz.clip import Frame
from wfviz.config import ClutterConfig, GEWCConfig, KalmanConfig, TrackingConfig, config_from_dict
from wfviz.trackers.gewc import GEWCTracker
from wfviz.tracking import TrackManager, extrapolate


def test_one_kalman_step_matches_hand_computation():
    m = kalman.CVModel.make(q=0.2, r=0.4)
    x = np.array([[10.0, 20.0, 1.0, -2.0]])
    P = np.eye(4)[None] * 1.0
    xp, Pp = kalman.predict(x, P, m)
    # x⁻ = Φx: position + velocity; P⁻ = ΦPΦᵀ + Q
    assert np.allclose(xp, [[11.0, 18.0, 1.0, -2.0]])
    # ΦPΦᵀ with P = I: [[2,0,1,0],[0,2,0,1],[1,0,1,0],[0,1,0,1]] + 0.2 I
    assert np.allclose(Pp[0], [[2.2, 0, 1, 0], [0, 2.2, 0, 1], [1, 0, 1.2, 0], [0, 1, 0, 1.2]])
    z = np.array([[12.0, 18.5]])
    xu, Pu, nu = kalman.update(xp, Pp, z, m)
    assert np.allclose(nu, [[1.0, 0.5]])
    # S = 2.2 + 0.4 = 2.6; K_pos = 2.2/2.6, K_vel = 1/2.6
    assert np.allclose(xu, [[11 + 2.2 / 2.6, 18 + 0.5 * 2.2 / 2.6, 1 + 1 / 2.6, -2 + 0.5 / 2.6]])
    assert np.isclose(Pu[0, 0, 0], 2.2 - 2.2 * 2.2 / 2.6)
    assert np.isclose(Pu[0, 2, 2], 1.2 - 1 / 2.6)
    assert np.isclose(Pu[0, 0, 2], 1 - 2.2 / 2.6)


def test_extrapolation_eq15_reading():
    # s(k) = s(k-1) + (s(k-1) - s(k-3)) / 2: constant velocity is continued exactly
    assert extrapolate([(0.0, 0.0), (2.0, 1.0), (4.0, 2.0)]) == (6.0, 3.0)


def _run(manager, frames):
    events = []
    for f, dets in enumerate(frames):
        preds = manager.predict(f)
        xy = np.array(dets, dtype=float).reshape(-1, 2)
        pairs = manager.associate(preds, xy)
        used = np.zeros(len(xy), bool)
        used[list(pairs.values())] = True
        claimed = manager.claimed(preds, xy)
        events += manager.update({i: tuple(xy[d]) for i, d in pairs.items()}, xy[~used & ~claimed])
    return events


def test_confirmation_after_six_hits_and_deletion_after_three_misses():
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    frames = [[(50 + 1.0 * k, 40 + 0.5 * k)] for k in range(8)] + [[]] * 3
    events = _run(mgr, frames[:5])
    assert not any(e.kind == "confirmed" for e in events)          # 5 hits: still tentative
    events = _run_from(mgr, frames, 5, 6)
    assert [e.kind for e in events] == ["confirmed"]                  # the 6th hit confirms
    events = _run_from(mgr, frames, 6, 10)
    assert not any(e.kind == "deleted" for e in events)               # 2 misses: kept
    events = _run_from(mgr, frames, 10, 11)
    assert [e.kind for e in events] == ["deleted"]                    # 3rd consecutive miss
    assert len(mgr) == 0


def test_confirmation_waits_for_round_hits_with_confirm_blobness():
    """A track whose hits are ridge-like (low mean blobness) is never confirmed; a round one is."""
    for shape, confirmed in ((0.1, False), (0.8, True)):
        mgr = TrackManager(KalmanConfig(), TrackingConfig(confirm_blobness=0.4))
        events = []
        for f in range(10):
            preds = mgr.predict(f)
            xy = np.array([[50 + 1.0 * f, 40.0]])
            pairs = mgr.associate(preds, xy)
            born = xy[[i for i in range(len(xy)) if i not in pairs.values()]]
            events += mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, born,
                                 shapes={i: shape for i in pairs}, birth_shapes=np.full(len(born), shape))
        got = [e for e in events if e.kind == "confirmed"]
        assert bool(got) == confirmed
        if confirmed:
            assert got[0].frame == 5 and "mean blobness 0.80" in got[0].message



def _scored_run(tcfg: TrackingConfig, points: list, shift: tuple[float, float] = (0.0, 0.0),
                score: float = 1.5, labels: list[float] | None = None) -> tuple[list, TrackManager]:
    """Feed one detection per frame (None: nothing seen) with significance ``score`` (and
    static-clutter label ``labels[f]``); the camera moves the scene by ``shift`` px per frame."""
    mgr = TrackManager(KalmanConfig(), tcfg)
    if labels is not None:
        mgr.clutter_rule = ClutterConfig(enabled=True)
    events = []
    for f, point in enumerate(points):
        if f:
            mgr.shift(*shift)
        preds = mgr.predict(f)
        xy = np.array([] if point is None else [point], dtype=float).reshape(-1, 2)
        pairs = mgr.associate(preds, xy)
        born = xy[[j for j in range(len(xy)) if j not in pairs.values()]]
        lab = None if labels is None else labels[f]
        events += mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, born,
                             scores={i: score for i in pairs}, birth_scores=np.full(len(born), score),
                             clutter=None if lab is None else {i: lab for i in pairs},
                             birth_clutter=None if lab is None else np.full(len(born), lab))
    return events, mgr


_LOW_SCR = dict(confirm_hits=4, confirm_significance=4.0)


@pytest.mark.parametrize("case,moving,points,shift,frame", [
    ("straight mover", 6.0, [(50 + 3.0 * f, 40.0) for f in range(10)], (0, 0), 3),
    ("option off", 0.0, [(50 + 3.0 * f, 40.0) for f in range(10)], (0, 0), None),
    ("slow mover: waits for 6 px", 6.0, [(50 + 1.0 * f, 40.0) for f in range(10)], (0, 0), 6),
    ("zig-zag", 6.0, [(50 + 2.0 * f, 40.0 + 2.0 * (f % 2)) for f in range(10)], (0, 0), None),
    ("fixed in the image, camera panning", 6.0, [(50.0, 40.0)] * 10, (-3.0, 0), None),
    ("fixed in the scene, camera panning", 6.0, [(50 - 3.0 * f, 40.0) for f in range(10)], (-3.0, 0), None),
    ("a missed frame", 6.0, [(50 + 3.0 * f, 40.0) if f != 2 else None for f in range(10)], (0, 0), None),
])
def test_confirm_moving_relaxes_the_significance_for_straight_movers(case, moving, points, shift, frame):
    """Mean significance 1.5 < 4: only a gapless track moving 6 px in a straight line, in the
    scene and in the image alike, is confirmed (at confirm_moving_significance 1)."""
    events, mgr = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=moving), points, shift)
    got = [e for e in events if e.kind == "confirmed"]
    assert len(mgr) == 1 and mgr.states()[0].hits == sum(p is not None for p in points), case
    assert (got[0].frame if got else None) == frame, case
    if got:
        assert "mean significance 1.5 (a mover:" in got[0].message


def test_confirm_moving_still_needs_its_own_significance():
    points = [(50 + 3.0 * f, 40.0) for f in range(10)]
    events, _ = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=6.0, confirm_moving_significance=2.0),
                            points)
    assert not any(e.kind == "confirmed" for e in events)
    events, _ = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=6.0), points, score=4.5)
    got = [e for e in events if e.kind == "confirmed"]  # significant anyway: no mover note
    assert got[0].frame == 3 and "mover" not in got[0].message


@pytest.mark.parametrize("labels,frame", [([0.0] * 10, 3), ([0.0, 1.0] * 5, None)])
def test_confirm_moving_needs_the_clutter_stage_to_agree(labels, frame):
    """Half its hits judged static (mean 0.5: allowed by clutter.max_static, above the mover's
    0.25): the straight track is not a mover."""
    events, _ = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=6.0),
                            [(50 + 3.0 * f, 40.0) for f in range(10)], labels=labels)
    got = [e for e in events if e.kind == "confirmed"]
    assert (got[0].frame if got else None) == frame

def _confirmed_track(mgr: TrackManager, frames: int = 8) -> None:
    for f in range(frames):  # a target moving 1 px/frame in x, confirmed at the 6th hit
        preds = mgr.predict(f)
        xy = np.array([[50.0 + f, 40.0]])
        pairs = mgr.associate(preds, xy)
        mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, xy[len(pairs):])


@pytest.mark.parametrize("radius,eligible,kept", [(0.0, True, False), (15.0, True, True),
                                                  (15.0, False, False), (6.0, True, False)])
def test_reacquire_after_a_jump_out_of_the_gate(radius, eligible, kept):
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    _confirmed_track(mgr)
    tid = mgr.track_ids[0]
    preds = mgr.predict(8)  # predicted near (58, 40); the target jumped 8 px down
    xy = np.array([[58.0, 48.0]])
    pairs = mgr.associate(preds, xy)
    assert pairs == {}  # outside the gate
    if radius > 0:
        pairs = mgr.reacquire(preds, xy, pairs, np.array([eligible]), radius)
    born = xy[[j for j in range(len(xy)) if j not in pairs.values()]]
    events = mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, born)
    assert (0 in pairs) == kept
    if kept:
        assert [e.kind for e in events] == ["reacquired"] and "8.0 px from its prediction" in events[0].message
        assert np.abs(mgr.innovations()[tid]).max() < 1e-9  # the filter restarted at the detection
        assert abs(mgr.x[0, 1] - 48.0) < 1e-9 and abs(mgr.velocity(0)[0] - 1.0) < 0.3  # velocity kept
    else:
        assert mgr.states()[0].misses == 1 and len(mgr) == 2  # a miss, and a new tentative track


def test_reacquire_leaves_detections_in_another_confirmed_gate():
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    for f in range(8):  # two targets 12 px apart
        preds = mgr.predict(f)
        xy = np.array([[50.0 + f, 40.0], [50.0 + f, 52.0]])
        pairs = mgr.associate(preds, xy)
        mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, xy[[j for j in range(2) if j not in pairs.values()]])
    preds = mgr.predict(8)
    xy = np.array([[58.0, 52.0]])  # only the second target is seen
    pairs = mgr.associate(preds, xy)
    assert mgr.reacquire(preds, xy, pairs, np.array([True]), 15.0) == pairs  # the first takes nothing


def _run_from(mgr, frames, a, b):
    events = []
    for f in range(a, b):
        preds = mgr.predict(f)
        xy = np.array(frames[f], dtype=float).reshape(-1, 2)
        pairs = mgr.associate(preds, xy)
        used = np.zeros(len(xy), bool)
        used[list(pairs.values())] = True
        events += mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, xy[~used])
    return events


def test_no_measurement_goes_to_two_tracks():
    mgr = TrackManager(KalmanConfig(), TrackingConfig(safety_distance=0.0))
    _run(mgr, [[(10, 10), (14, 10)]] * 7)
    preds = mgr.predict(7)
    pairs = mgr.associate(preds, np.array([[12.0, 10.0]]))
    assert len(pairs) == 1


@pytest.mark.parametrize("tcfg", [TrackingConfig(),
                                  TrackingConfig(meeting_overlap=True, meeting_misses=True)],
                         ids=["paper", "cluttered-scene-options"])
def test_crossing_keeps_both_identities(tcfg):
    """Two targets crossing at ~110°: meeting mode carries both identities through."""
    mgr = TrackManager(KalmanConfig(), tcfg)
    rng = np.random.default_rng(0)
    n = 60
    a = np.array([[20 + 2.0 * k, 50 + 1.2 * k] for k in range(n)])
    b = np.array([[20 + 2.0 * k, 122 - 1.2 * k] for k in range(n)])
    ids_a, ids_b, meeting_seen = [], [], False
    for f in range(n):
        dets = [a[f], b[f]] if np.hypot(*(a[f] - b[f])) > 3 else [(a[f] + b[f]) / 2]
        xy = np.array(dets) + rng.normal(0, 0.15, (len(dets), 2))
        preds = mgr.predict(f)
        pairs = mgr.associate(preds, xy)
        used = np.zeros(len(xy), bool)
        used[list(pairs.values())] = True
        mgr.update({i: tuple(xy[d]) for i, d in pairs.items()}, xy[~used & ~mgr.claimed(preds, xy)])
        states = [s for s in mgr.states() if s.confirmed]
        meeting_seen |= any(s.meeting for s in states)
        for truth, ids in ((a[f], ids_a), (b[f], ids_b)):
            d = sorted((np.hypot(s.x - truth[0], s.y - truth[1]), s.track_id) for s in states)
            if d and d[0][0] < 2.0 and (len(d) == 1 or d[1][0] > 4.0):  # unambiguous
                ids.append(d[0][1])
    assert meeting_seen
    assert len(set(ids_a)) == 1 and len(set(ids_b)) == 1 and ids_a[0] != ids_b[0]
    assert len(ids_a) > 40 and len(ids_b) > 40
    assert len([s for s in mgr.states() if s.confirmed]) == 2


def test_assign_confirmed_first_protects_confirmed_gates():
    from wfviz.tracking import assign_confirmed_first
    cost = np.array([[1.0, 5.0, 9.0], [0.5, 0.1, 9.0], [2.0, 2.0, 3.0]])
    ok = np.array([[True, True, False], [True, True, False], [True, True, True]])
    confirmed = np.array([True, False, False])
    # row 0 (confirmed) takes column 0 first although row 1 is cheaper there; columns 0 and 1
    # lie in row 0's gate, so the tentative rows may only take column 2
    assert assign_confirmed_first(cost, ok, confirmed) == {0: 0, 2: 2}
    free = np.zeros(3, dtype=bool)
    assert assign_confirmed_first(cost, ok, confirmed, protected=free) == {0: 0, 1: 1, 2: 2}
    assert assign_confirmed_first(np.zeros((0, 3)), np.zeros((0, 3), bool), np.zeros(0, bool)) == {}


def _edge_clip(n: int = 12, seed: int = 0):
    """A target (peak 25, σ 0.8 px) moving 3 px/frame along a 30-grey-level step edge 3 px
    below it, where the 31 px window's std is the step's (SCR ≈ 1.6), and a spot as bright that
    stays put on the same edge; noise σ 2."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:128, 0:160]
    for k in range(n):
        img = 100.0 + 30.0 * (yy < 64) + rng.normal(0, 2.0, yy.shape)
        for x0 in (30 + 3.0 * k, 130.0):
            img += 25.0 * np.exp(-((xx - x0) ** 2 + (yy - 67.0) ** 2) / (2 * 0.8 ** 2))
        yield Frame(k, k / 25, np.clip(img, 0, 255).astype(np.uint8))


@pytest.mark.parametrize("moving,frame", [(0.0, None), (6.0, 3)])
def test_gewc_confirms_a_mover_under_an_edge_only_with_confirm_moving(moving, frame):
    cfg = config_from_dict({"horizon": {"exclude_ground": "never"},
                            "tracking": {"confirm_hits": 4, "confirm_significance": 4.0,
                                         "confirm_moving": moving}}, GEWCConfig)
    tracker = GEWCTracker(cfg)
    confirmed = {}
    for f in _edge_clip():
        for t in tracker.step(f).tracks:
            if t.confirmed:
                confirmed.setdefault(t.track_id, (f.index, t.x, t.y))
    if frame is None:
        assert confirmed == {}
    else:  # the mover alone, at its 4th frame; never the spot that stays put
        assert [(f, round(x), round(y)) for f, x, y in confirmed.values()] == [(3, 39, 67)]
