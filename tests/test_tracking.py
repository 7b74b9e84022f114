"""Kalman filter and track management against hand-computed numbers and scripted scenes.

The default confirmation is the sequential test (``tracking.confirm = "sprt"``,
:mod:`wfviz.tracking.confirmation`); tests of the paper's rule and of its options (confirm_blobness,
confirm_moving, confirm_significance, reacquire, clutter labels) configure ``confirm = "hits"``.
"""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.config import ClutterConfig, KalmanConfig, TrackingConfig, config_from_dict
from wfviz.io.clip import Frame
from wfviz.trackers.gewc import GEWCTracker
from wfviz.trackers.gewc.config import GEWCConfig
from wfviz.tracking import confirmation, kalman
from wfviz.tracking import Measurements, TrackManager, extrapolate


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
        events += manager.update(manager.associate(preds, xy), Measurements(xy))  # births: unused, unclaimed
    return events


def test_paper_rule_confirms_after_six_hits_and_deletes_after_three_misses():
    """confirm = "hits" (the paper): confirmed at the 6th hit, deleted at the 3rd consecutive miss."""
    mgr = TrackManager(KalmanConfig(), TrackingConfig(confirm="hits"))
    frames = [[(50 + 1.0 * k, 40 + 0.5 * k)] for k in range(8)] + [[]] * 3
    events = _run(mgr, frames[:5])
    assert not any(e.kind == "confirmed" for e in events)          # 5 hits: still tentative
    held = mgr.decision(mgr.track_ids[0])                            # the test that holds it back
    assert (held.verdict, held.rule, held.test, held.reason) == ("keep", "hits", "hits", "hits 5 < 6")
    events = _run_from(mgr, frames, 5, 6)
    assert [e.kind for e in events] == ["confirmed"]                  # the 6th hit confirms
    assert mgr.decision(mgr.track_ids[0]).verdict == "confirm" and mgr.confirmed_ids == mgr.track_ids
    events = _run_from(mgr, frames, 6, 10)
    assert not any(e.kind == "deleted" for e in events)               # 2 misses: kept
    events = _run_from(mgr, frames, 10, 11)
    assert [e.kind for e in events] == ["deleted"]                    # 3rd consecutive miss
    assert len(mgr) == 0
    gone = mgr.decisions[events[0].track_id]                          # the deleted track's decision
    assert (gone.verdict, gone.test, gone.reason) == ("delete", "misses", events[0].message)


def test_hits_rule_confirmation_waits_for_round_hits_with_confirm_blobness():
    """confirm = "hits": a track whose hits are ridge-like (low mean blobness) is never
    confirmed; a round one is, at its 6th hit."""
    for shape, confirmed in ((0.1, False), (0.8, True)):
        mgr = TrackManager(KalmanConfig(), TrackingConfig(confirm="hits", confirm_blobness=0.4))
        events = []
        for f in range(10):
            preds = mgr.predict(f)
            xy = np.array([[50 + 1.0 * f, 40.0]])
            assoc = mgr.associate(preds, xy)
            events += mgr.update(assoc, Measurements(xy, blobness=np.full(len(xy), shape)),
                                 start=~assoc.used())  # births: every unused detection
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
        assoc = mgr.associate(preds, xy)
        lab = None if labels is None else labels[f]
        events += mgr.update(assoc, Measurements(xy, significance=np.full(len(xy), score),
                                                 clutter=None if lab is None else np.full(len(xy), lab)),
                             start=~assoc.used())
    return events, mgr


_LOW_SCR = dict(confirm="hits", confirm_hits=4, confirm_significance=4.0)  # the paper's rule


@pytest.mark.parametrize("case,moving,points,shift,frame", [
    ("straight mover", 6.0, [(50 + 3.0 * f, 40.0) for f in range(10)], (0, 0), 3),
    ("option off", 0.0, [(50 + 3.0 * f, 40.0) for f in range(10)], (0, 0), None),
    ("slow mover: waits for 6 px", 6.0, [(50 + 1.0 * f, 40.0) for f in range(10)], (0, 0), 6),
    ("zig-zag", 6.0, [(50 + 2.0 * f, 40.0 + 2.0 * (f % 2)) for f in range(10)], (0, 0), None),
    ("fixed in the image, camera panning", 6.0, [(50.0, 40.0)] * 10, (-3.0, 0), None),
    ("fixed in the scene, camera panning", 6.0, [(50 - 3.0 * f, 40.0) for f in range(10)], (-3.0, 0), None),
    ("a missed frame", 6.0, [(50 + 3.0 * f, 40.0) if f != 2 else None for f in range(10)], (0, 0), None),
])
def test_hits_rule_confirm_moving_relaxes_the_significance_for_straight_movers(case, moving, points, shift, frame):
    """confirm = "hits", mean significance 1.5 < 4: only a gapless track moving 6 px in a
    straight line, in the scene and in the image alike, is confirmed (at
    confirm_moving_significance 1)."""
    events, mgr = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=moving), points, shift)
    got = [e for e in events if e.kind == "confirmed"]
    assert len(mgr) == 1 and mgr.states()[0].hits == sum(p is not None for p in points), case
    assert (got[0].frame if got else None) == frame, case
    if got:
        assert "mean significance 1.5 (a mover:" in got[0].message


def test_hits_rule_confirm_moving_still_needs_its_own_significance():
    """confirm = "hits": a straight mover below confirm_moving_significance is not confirmed."""
    points = [(50 + 3.0 * f, 40.0) for f in range(10)]
    events, _ = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=6.0, confirm_moving_significance=2.0),
                            points)
    assert not any(e.kind == "confirmed" for e in events)
    events, _ = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=6.0), points, score=4.5)
    got = [e for e in events if e.kind == "confirmed"]  # significant anyway: no mover note
    assert got[0].frame == 3 and "mover" not in got[0].message


@pytest.mark.parametrize("labels,frame", [([0.0] * 10, 3), ([0.0, 1.0] * 5, None)])
def test_hits_rule_confirm_moving_needs_the_clutter_stage_to_agree(labels, frame):
    """confirm = "hits" with clutter labels. Half its hits judged static (mean 0.5: allowed by
    clutter.max_static, above the mover's 0.25): the straight track is not a mover."""
    events, _ = _scored_run(TrackingConfig(**_LOW_SCR, confirm_moving=6.0),
                            [(50 + 3.0 * f, 40.0) for f in range(10)], labels=labels)
    got = [e for e in events if e.kind == "confirmed"]
    assert (got[0].frame if got else None) == frame

def _confirmed_track(mgr: TrackManager, frames: int = 8) -> None:
    """A target moving 1 px/frame in x (confirmed at the 6th hit under confirm = "hits")."""
    for f in range(frames):
        preds = mgr.predict(f)
        xy = np.array([[50.0 + f, 40.0]])
        assoc = mgr.associate(preds, xy)
        mgr.update(assoc, Measurements(xy), start=np.arange(len(xy)) >= len(assoc.pairs))


@pytest.mark.parametrize("radius,eligible,kept", [(0.0, True, False), (15.0, True, True),
                                                  (15.0, False, False), (6.0, True, False)])
def test_hits_rule_reacquire_after_a_jump_out_of_the_gate(radius, eligible, kept):
    """confirm = "hits": a confirmed track with nothing in its gate re-acquires an eligible
    detection within ``radius`` px of its prediction."""
    mgr = TrackManager(KalmanConfig(), TrackingConfig(confirm="hits"))
    _confirmed_track(mgr)
    assert mgr.states()[0].confirmed  # the premise: only confirmed tracks re-acquire
    tid = mgr.track_ids[0]
    preds = mgr.predict(8)  # predicted near (58, 40); the target jumped 8 px down
    xy = np.array([[58.0, 48.0]])
    assoc = mgr.associate(preds, xy)
    assert assoc.pairs == {}  # outside the gate
    if radius > 0:
        assoc = mgr.reacquire(preds, xy, assoc, np.array([eligible]), radius)
    events = mgr.update(assoc, Measurements(xy), start=~assoc.used())
    assert (0 in assoc.pairs) == kept
    if kept:
        assert [e.kind for e in events] == ["reacquired"] and "8.0 px from its prediction" in events[0].message
        assert np.abs(mgr.innovations()[tid]).max() < 1e-9  # the filter restarted at the detection
        assert abs(mgr.tracks.x[0, 1] - 48.0) < 1e-9 and abs(mgr.velocity(0)[0] - 1.0) < 0.3  # velocity kept
    else:
        assert mgr.states()[0].misses == 1 and len(mgr) == 2  # a miss, and a new tentative track


def test_hits_rule_reacquire_leaves_detections_in_another_confirmed_gate():
    """confirm = "hits": two confirmed targets 12 px apart (safety distance 10: not meeting).
    The first is not seen; a spare detection in the second's gate, 10 px from the first's
    prediction (within the re-acquisition radius), stays where it is."""
    mgr = TrackManager(KalmanConfig(), TrackingConfig(confirm="hits", safety_distance=10.0))
    for f in range(8):
        preds = mgr.predict(f)
        xy = np.array([[50.0 + f, 40.0], [50.0 + f, 52.0]])
        assoc = mgr.associate(preds, xy)
        mgr.update(assoc, Measurements(xy), start=~assoc.used())
    assert [(s.confirmed, s.meeting) for s in mgr.states()] == [(True, False)] * 2  # the premise
    preds = mgr.predict(8)
    xy = np.array([[58.0, 52.0], [58.0, 50.0]])  # the second target, and a spot in its gate
    assoc = mgr.associate(preds, xy)
    assert assoc.pairs == {1: 0} and assoc.claimed.tolist() == [True, True]
    assert mgr.reacquire(preds, xy, assoc, np.array([True, True]), 15.0).pairs == assoc.pairs  # the first takes nothing
    # the same spot outside every confirmed gate is re-acquired (the test above can fail)
    far = np.array([[58.0, 52.0], [66.0, 40.0]])
    assert mgr.reacquire(preds, far, mgr.associate(preds, far), np.array([True, True]), 15.0).pairs == {0: 1, 1: 0}


def _run_from(mgr, frames, a, b):
    events = []
    for f in range(a, b):
        preds = mgr.predict(f)
        xy = np.array(frames[f], dtype=float).reshape(-1, 2)
        assoc = mgr.associate(preds, xy)
        events += mgr.update(assoc, Measurements(xy), start=~assoc.used())
    return events


def test_no_measurement_goes_to_two_tracks():
    mgr = TrackManager(KalmanConfig(), TrackingConfig(safety_distance=0.0))
    _run(mgr, [[(10, 10), (14, 10)]] * 7)
    preds = mgr.predict(7)
    assoc = mgr.associate(preds, np.array([[12.0, 10.0]]))
    assert len(assoc.pairs) == 1


@pytest.mark.parametrize("tcfg", [
    pytest.param(TrackingConfig(confirm="hits"), id="paper"),
    pytest.param(TrackingConfig(confirm="hits", meeting_overlap=True, meeting_misses=True),
                 id="paper-cluttered-scene-options"),
    pytest.param(TrackingConfig(), id="defaults"),
    pytest.param(TrackingConfig(meeting_overlap=True, meeting_misses=True), id="defaults-cluttered-scene-options"),
])
def test_crossing_keeps_both_identities(tcfg):
    """Two targets crossing at ~110°: meeting mode carries both identities through, under the
    paper's rule and under the sequential test (hits of significance 10 that are new at their
    place in the scene, novelty 10, as a moving target's)."""
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
        mgr.update(mgr.associate(preds, xy), Measurements(xy, significance=np.full(len(xy), 10.0),
                                                          novelty=np.full(len(xy), 10.0)))
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
def test_gewc_hits_rule_confirms_a_mover_under_an_edge_only_with_confirm_moving(moving, frame):
    """confirm = "hits" with confirm_significance 4 (the signal-to-clutter ratio over the 31 px
    window, computed with the paper's global threshold: detection.mode = "global")."""
    cfg = config_from_dict({"horizon": {"exclude_ground": "never"}, "detection": {"mode": "global"},
                            "tracking": {"confirm": "hits", "confirm_hits": 4, "confirm_significance": 4.0,
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


def test_gewc_defaults_confirm_the_mover_under_an_edge_and_never_the_spot_that_stays_put():
    """Defaults (sequential test, CFAR detection): the mover along the edge is confirmed, on
    its own path; the spot as bright that stays put on the edge never is (no motion, no change)."""
    tracker = GEWCTracker(config_from_dict({"horizon": {"exclude_ground": "never"}}, GEWCConfig))
    confirmed: dict[int, tuple[int, float, float]] = {}
    ever_near_spot = False
    for f in _edge_clip(n=24):
        for t in tracker.step(f).tracks:
            if t.confirmed:
                confirmed.setdefault(t.track_id, (f.index, t.x, t.y))
                ever_near_spot |= abs(t.x - 130.0) < 6 and abs(t.y - 67.0) < 6
    assert confirmed and not ever_near_spot
    for f, x, y in confirmed.values():  # where the mover was in the confirming frame
        assert abs(x - (30 + 3.0 * f)) < 2.0 and abs(y - 67.0) < 2.0


# -- the sequential test (tracking.confirm = "sprt", the default) ---------------------------

def _sprt_run(points: list, z: float = 10.0, novelty: float = 10.0, density: float | None = None,
              tcfg: TrackingConfig | None = None) -> tuple[list, TrackManager]:
    """Feed one detection per frame (None: nothing seen) of significance ``z`` and change
    significance ``novelty`` (how new it is at its place in the scene) to a TrackManager with
    the default TrackingConfig (or ``tcfg``); ``density``: false detections per pixel."""
    mgr = TrackManager(KalmanConfig(), tcfg or TrackingConfig())
    events = []
    for f, point in enumerate(points):
        preds = mgr.predict(f)
        xy = np.array([] if point is None else [point], dtype=float).reshape(-1, 2)
        assoc = mgr.associate(preds, xy)
        n = len(xy)
        events += mgr.update(assoc, Measurements(xy, significance=np.full(n, z), novelty=np.full(n, novelty),
                                                 density=None if density is None else np.full(n, density)),
                             track_density=None if density is None else np.full(len(preds), density),
                             start=~assoc.used())
    return events, mgr


_MOVER = [(50 + 1.5 * f, 40 + 0.5 * f) for f in range(30)]
_STATIC = [(50.0, 40.0)] * 30


def test_default_confirmation_is_the_sequential_test():
    assert TrackingConfig().confirm == "sprt"


def test_sprt_confirms_a_steady_mover_with_significant_novel_hits():
    """Not before its clutter score (ln(q_target / q_static) per changed hit) reaches the
    confirmation level, and once only."""
    events, mgr = _sprt_run(_MOVER)
    got = [e for e in events if e.kind == "confirmed"]
    assert len(got) == 1 and len(mgr) == 1 and mgr.states()[0].confirmed
    tc, th = TrackingConfig(), mgr.thresholds
    per_hit = float(confirmation.change_evidence(np.array([10.0]), mgr.detection_threshold,
                                                tc.static_change_rate, tc.target_change_rate)[0])
    assert per_hit > 0
    assert got[0].frame + 1 >= np.ceil(th.confirm / per_hit)  # hits so far (born in frame 0)
    assert "persistence" in got[0].message and "not clutter" in got[0].message
    assert not any(e.kind == "deleted" for e in events)


@pytest.mark.parametrize("case,points,novelty", [
    ("static spot, new at its place each frame (blinking)", _STATIC, 10.0),
    ("static spot, as it was (static clutter)", _STATIC, 0.0),
    ("mover with no change evidence", _MOVER, 0.0),
])
def test_sprt_never_confirms_without_motion_or_change_evidence(case, points, novelty):
    """Persistent, significant hits are not enough: a static spot fails the motion test, and a
    track whose hits are not new at their place in the scene fails the clutter test."""
    events, mgr = _sprt_run(points, novelty=novelty)
    assert not any(e.kind == "confirmed" for e in events), case
    assert len(mgr) == 1 and mgr.states()[0].hits == len(points), case  # tracked all along
    assert mgr.rule.stats.score[0] >= mgr.thresholds.confirm, case  # persistence alone would confirm it
    held = mgr.decision(mgr.track_ids[0])  # names the test that holds it back, with its value and level
    test, level = ("not clutter", mgr.thresholds.confirm) if novelty == 0 else ("motion: T²", mgr.thresholds.motion)
    assert held.verdict == "keep" and held.test == test and held.reason.startswith(test), case
    assert held.reason.endswith(f" < {level:.3g}"), case


def test_sprt_drops_faint_hits_in_a_cluttered_gate():
    """Hits at the detection threshold (as noise crosses it) where false detections are dense
    (0.005 per px): the persistence score falls, the tentative tracks are dropped, never
    confirmed; the same hits well above the threshold are confirmed."""
    events, mgr = _sprt_run(_MOVER, z=4.0, density=0.005)
    assert not any(e.kind == "confirmed" for e in events)
    assert any(e.kind == "deleted" for e in events)
    events, _ = _sprt_run(_MOVER, z=10.0, density=0.005)
    assert [e.kind for e in events if e.kind != "born"] == ["confirmed"]


def _misses_to_delete(th: confirmation.Thresholds, p_detect: float) -> int:
    """Consecutive misses that take a confirmed track (score capped at ``th.confirm``) in a
    clean gate (p_fa = 0) to ``th.delete``, in exact arithmetic (a tie deletes: score <= delete)."""
    miss = float(confirmation.score_change(np.array([False]), p_detect, np.array([0.0]))[0])
    return int(np.ceil((th.confirm - th.delete) / -miss - 1e-9))


@pytest.mark.parametrize("later", [0.0, 10.0])
def test_sprt_deletes_a_confirmed_track_that_turns_static(later):
    """A confirmed mover whose hits stop being new at their place (it stopped on a fixed object,
    novelty 0) is deleted as static clutter after ceil(ln((1 - alpha) / beta) / e) unchanged
    hits (e: the evidence of one); while its hits stay new (novelty 10) it is kept."""
    mgr = TrackManager(KalmanConfig(), TrackingConfig())
    events = []
    for f in range(40):
        preds = mgr.predict(f)
        x = 50 + 1.5 * min(f, 20)  # moves for 20 frames, then stays put
        xy = np.array([[x, 40.0]])
        nov = 10.0 if f < 20 else later
        assoc = mgr.associate(preds, xy)
        events += mgr.update(assoc, Measurements(xy, significance=np.full(1, 10.0), novelty=np.full(1, nov)),
                             start=~assoc.used())
    assert [e.frame for e in events if e.kind == "confirmed"] and min(e.frame for e in events if e.kind == "confirmed") < 20
    gone = [e for e in events if e.kind == "deleted" and "static clutter" in e.message]
    if later:
        assert gone == [] and mgr.states()[0].confirmed
    else:
        tc, th = TrackingConfig(), mgr.thresholds
        e = -float(confirmation.change_evidence(np.array([0.0]), mgr.detection_threshold,
                                                tc.static_change_rate, tc.target_change_rate)[0])
        assert len(gone) == 1 and gone[0].frame == 20 + int(np.ceil(-th.drop / e)) - 1


@pytest.mark.parametrize("p_lost", [
    0.001,
    0.005, 0.0002, 0.05,
])
def test_sprt_deletes_a_confirmed_track_after_a_bounded_number_of_misses(p_lost):
    """A confirmed mover that stops being detected is deleted at exactly the miss at which its
    score falls ln(1 / p_lost) below confirmation (confirmation.thresholds), not before."""
    tcfg = TrackingConfig(p_lost=p_lost)
    events, mgr = _sprt_run(_MOVER[:10] + [None] * 10, tcfg=tcfg)
    confirmed = [e.frame for e in events if e.kind == "confirmed"]
    deleted = [e for e in events if e.kind == "deleted"]
    assert len(confirmed) == 1 and confirmed[0] < 9 and len(deleted) == 1
    n = _misses_to_delete(mgr.thresholds, tcfg.p_detect)
    assert 1 <= n < 10
    assert deleted[0].frame == 9 + n  # last hit in frame 9
    assert f"after {n} consecutive misses" in deleted[0].message and len(mgr) == 0


def test_sprt_deletion_bound_follows_p_lost():
    """The bound grows with ln(1 / p_lost): a smaller p_lost keeps a lost track longer."""
    th = [confirmation.thresholds(1.0, 1.0, 0.01, p) for p in (0.05, 0.005, 0.0002)]
    n = [_misses_to_delete(t, 0.9) for t in th]
    assert n == sorted(n) and n[0] < n[-1]
    assert all(t.delete < t.confirm for t in th)


def test_gate_threshold_is_at_most_k_and_falls_with_p_gate():
    """gate_threshold: never above the frame's k; lower for a larger allowed false-alarm
    probability; higher for a larger gate; noise crosses it in the gate with probability at
    most p_gate (union bound over the gate's pixels)."""
    from scipy.stats import norm

    half = np.array([[3.0, 3.0], [8.0, 5.0], [15.0, 15.0]])
    area = (2 * half[:, 0] + 1) * (2 * half[:, 1] + 1)
    k = 4.0
    rows = [confirmation.gate_threshold(half, p, k) for p in (0.001, 0.01, 0.05, 0.2)]
    for t in rows:
        assert t.shape == (3,) and (t <= k).all()
        assert (np.diff(t) >= 0).all()  # a larger gate needs a higher threshold
    for a, b in zip(rows, rows[1:]):
        assert (b <= a).all() and (b < a)[a < k].all()
    t = rows[2]  # p_gate 0.05
    below = t < k
    assert below.any()
    assert np.allclose(area[below] * norm.sf(t[below]), 0.05)
    assert np.allclose(confirmation.gate_threshold(half, 1e-9, k), k)  # clipped to k


def test_every_event_of_every_tracker_has_a_declared_kind():
    """Events carry an EventKind, whose value is the string recordings show (one name per
    meaning: fusion's lost window and the star field's re-segmentation are told apart)."""
    from wfviz.synth.scenarios import make_scenario
    from wfviz.tracking import EventKind
    from wfviz.trackers import make_tracker

    seen = set()
    for name, scenario in (("gewc", "fov70-four-targets"), ("fusion", "uniform-50hz"),
                           ("starfield", "starfield"), ("tbd", "lowsnr-tbd")):
        tracker = make_tracker(name)
        for frame in make_scenario(scenario).frames(0, 30):
            for e in tracker.step(frame).events:
                assert isinstance(e.kind, EventKind), (name, e.kind)
                seen.add(e.kind)
    assert {EventKind.BORN, EventKind.CONFIRMED, EventKind.DELETED, EventKind.COUNT} <= seen
    assert len({k.value for k in EventKind}) == len(EventKind)


def test_every_registered_tracker_names_its_tracker_config_and_recorder():
    """One registry line per tracker: the tracker makes results from its config's defaults, the
    config is a dataclass, and the named recorder is a Recorder under wfviz.record."""
    import dataclasses

    from wfviz.record import Recorder, recorder_class
    from wfviz.trackers import TRACKERS, make_tracker

    for name, entry in TRACKERS.items():
        assert dataclasses.is_dataclass(entry.config), name
        tracker = make_tracker(name)
        assert isinstance(tracker, entry.tracker) and tracker.name == name
        assert tracker.config.tracking.trail_length > 0  # what the Tracker protocol promises the loop
        home = f"wfviz.trackers.{name}."  # one package per tracker: tracker and config live there
        assert entry.tracker.__module__.startswith(home) and entry.config.__module__.startswith(home), name
        rec = recorder_class(name)
        assert issubclass(rec, Recorder) and rec.__module__.startswith("wfviz.record."), name


def test_a_new_confirmation_rule_is_one_rule_class_and_its_registry_entry(monkeypatch):
    """A toy rule with a statistic of its own (hits in a row): it confirms a track at its third
    hit in a row and deletes it at its first miss. Registered under "toy", the manager runs it,
    keeps its column in step with the track table through deletions and births, and each
    track's Decision names the test, its value and its level."""
    from dataclasses import dataclass

    from wfviz.tracking import CONFIRMATION_RULES, Columns, Decisions, Evidence, Rule, Statistic, TrackTable

    @dataclass(eq=False)
    class Streak(Columns):
        run: np.ndarray  # hits in a row (the birth is one)

        @classmethod
        def blank(cls, n: int) -> Streak:
            return cls(run=np.ones(n))

    class ThreeInARow(Rule):
        Stats = Streak

        def decide(self, tracks: TrackTable, e: Evidence) -> Decisions:
            self.stats.run = np.where(e.measured, self.stats.run + 1, 0.0)
            enough = self.stats.run >= 3
            confirm, delete = e.measured & ~tracks.confirmed & enough, e.missed.copy()
            return Decisions(confirm, delete, [""] * len(tracks), (
                Statistic("hits in a row", self.stats.run.copy(), 3.0, ">=", enough),
                Statistic("missed", e.missed.astype(float), 1.0, ">=", delete, deletes=True)))

    monkeypatch.setitem(CONFIRMATION_RULES, "toy", ThreeInARow)
    mgr = TrackManager(KalmanConfig(), TrackingConfig(confirm="toy"))
    a = [(50.0 + f, 40.0) for f in range(4)]
    frames = [[a[0], (100.0, 80.0)], [a[1], (101.0, 80.0)], [a[2]], [a[3], (20.0, 20.0)]]
    events = []
    for f in range(4):
        events += _run_from(mgr, frames, f, f + 1)
        assert len(mgr.rule.stats) == len(mgr)  # the rule's column follows the table
        if f == 1:
            held = mgr.decision(1)
            assert (held.verdict, held.rule, held.test, held.reason) == ("keep", "toy", "hits in a row",
                                                                         "hits in a row 2 < 3")
        if f == 2:
            assert mgr.decision(1).verdict == "confirm" and mgr.decision(2).test == "missed"
    assert [(e.frame, e.kind, e.track_id) for e in events if e.kind != "born"] == [
        (2, "confirmed", 1), (2, "deleted", 2)]
    assert mgr.track_ids == [1, 3] and mgr.confirmed_ids == [1]
    assert mgr.rule.stats.run.tolist() == [4.0, 1.0]


def test_the_confirmation_rules_do_not_import_the_track_manager():
    """The manager imports the rules and what they read and return, never the other way round."""
    import ast
    from pathlib import Path

    import wfviz.tracking

    home = Path(wfviz.tracking.__file__).parent
    for name in ("rules", "decision", "table", "confirmation", "association", "tracks", "kalman"):
        tree = ast.parse((home / f"{name}.py").read_text())
        imported = {f"{n.module}.{a.name}" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module
                    for a in n.names} | {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert not any(m and m.startswith("wfviz.tracking.manager") for m in imported), name
