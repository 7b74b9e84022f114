"""The false tracks of the DAUB ground sequences: tracks that hop from one static spot to the
next across their misses (the motion test's consecutive progress,
:func:`wfviz.tracking.confirmation.consecutive_progress`, holds them back; the explanation names
them ``hopping``) and tracks on a road whose detected piece slides along it
(:func:`wfviz.tracking.confirmation.slide`; explained as ``structure``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from wfviz.config import KalmanConfig, TrackingConfig
from wfviz.evaluate import frame_errors
from wfviz.explain.false_tracks import FalseCauses
from wfviz.explain.types import FalseCause
from wfviz.stages.detection import Detections
from wfviz.trackers.base import FrameResult
from wfviz.tracking import Measurements, TrackManager, TrackState
from wfviz.tracking.confirmation import consecutive_progress, motion, slide


def _chain(frames: list[int], spots: list[tuple[float, float]], per: int, noise: float = 0.1,
           seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Hits at ``frames``: the first ``per`` on the first spot, the next ``per`` on the second..."""
    rng = np.random.default_rng(seed)
    xy = np.array([spots[i // per] for i in range(len(frames))], dtype=float) + rng.normal(0, noise, (len(frames), 2))
    return np.asarray(frames, dtype=float), xy


def _share(t: np.ndarray, xy: np.ndarray) -> float:
    ok = np.ones((1, len(t)), dtype=bool)
    v = motion(t[None], xy[None], ok, 0.3).velocity
    return float(consecutive_progress(t[None], xy[None], ok, v)[0])


def test_a_target_seen_with_gaps_keeps_its_pace_between_consecutive_hits() -> None:
    rng = np.random.default_rng(1)
    t = np.array([f for f in range(30) if f % 3 != 2], dtype=float)  # every third frame missed
    xy = np.column_stack([0.8 * t, 0.3 * t]) + rng.normal(0, 0.2, (len(t), 2))
    assert _share(t, xy) > 0.8


def test_a_chain_of_static_spots_makes_its_progress_in_the_jumps() -> None:
    """Four spots 5 px apart, 3 hits on each, 3 missed frames between: the jumps make the way;
    the steady-progress test alone takes it for motion."""
    t, xy = _chain([0, 1, 2, 6, 7, 8, 12, 13, 14, 18, 19, 20], [(10, 10), (15, 11), (20, 12), (25, 13)], 3)
    assert _share(t, xy) < 0.2
    ok = np.ones((1, len(t)), dtype=bool)
    assert motion(t[None], xy[None], ok, 0.3, parts=4).steady[0] > 1.5 / 3


def test_without_a_missed_frame_the_share_is_not_measured() -> None:
    t = np.arange(8, dtype=float)
    xy = np.column_stack([0.5 * t, 0 * t])
    assert np.isnan(_share(t, xy))


def _manager(share: float = 0.5, max_slide: float = 1.75) -> TrackManager:
    return TrackManager(KalmanConfig(), dataclasses.replace(TrackingConfig(), consecutive_share=share,
                                                            max_slide=max_slide, clutter_map=False))


def _run(m: TrackManager, positions: list[tuple[float, float] | None], size: tuple[int, int] = (3, 3)) -> bool:
    """Feed one bright, new detection a frame (None: nothing) whose component is ``size`` (w, h)
    px; whether a track got confirmed."""
    confirmed = False
    for k, p in enumerate(positions):
        preds = m.predict(k)
        xy = np.zeros((0, 2)) if p is None else np.array([p], dtype=float)
        n = len(xy)
        m.update(m.associate(preds, xy), Measurements(xy, significance=np.full(n, 12.0), blobness=np.ones(n),
                                                      novelty=np.full(n, 12.0), size=np.tile(size, (n, 1))))
        confirmed |= bool(m.confirmed_ids)
    return confirmed


def _hops() -> list[tuple[float, float] | None]:
    """Five spots 4 px apart along x, 4 frames on each, then 3 frames with nothing."""
    out: list[tuple[float, float] | None] = []
    for s in range(5):
        out += [(20.0 + 4 * s, 30.0)] * 4 + [None] * 3
    return out


def test_the_motion_test_holds_a_hopping_chain_back_and_confirms_a_target_with_gaps() -> None:
    assert _run(_manager(share=0.0), _hops()), "the chain was expected to pass the other motion tests"
    assert not _run(_manager(), _hops())
    target = [None if k % 4 == 3 else (20.0 + 1.0 * k, 30.0 + 0.2 * k) for k in range(35)]
    assert _run(_manager(), target)


def test_slide_is_the_components_length_along_the_way_over_across() -> None:
    size = np.array([[[8.0, 4.0]] * 5, [[3.0, 3.0]] * 5, [[8.0, 4.0]] * 5])
    ok = np.ones((3, 5), dtype=bool)
    r = slide(size, ok, np.array([[1.0, 0.0], [1.0, 0.0], [0.0, -1.0]]))
    assert np.allclose(r, [2.0, 1.0, 0.5])
    assert np.isnan(slide(np.full((1, 5, 2), np.nan), ok[:1], np.array([[1.0, 0.0]]))[0])


def test_the_motion_test_holds_back_a_piece_of_a_line_sliding_along_it() -> None:
    """A detection moving 1 px a frame along x: on 8 x 4 px components (a road's piece) it is not
    confirmed; compact (3 x 3), or moving across them (4 x 8), it is."""
    way = [(20.0 + k, 30.0) for k in range(30)]
    assert _run(_manager(max_slide=0.0), way, (8, 4)), "expected to confirm without the test"
    assert not _run(_manager(), way, (8, 4))
    assert _run(_manager(), way, (3, 3))
    assert _run(_manager(), way, (4, 8))


def test_a_slow_elongated_target_is_not_judged_by_its_direction() -> None:
    """Below SLIDE_SPEED a track's way has no direction to compare its components with (a
    hovering helicopter's body): the slide test does not hold it back."""
    from wfviz.tracking.rules import SLIDE_SPEED

    way = [(20.0 + 0.5 * SLIDE_SPEED * k, 30.0) for k in range(60)]
    assert _run(_manager(), way, (8, 4))


def _result(k: int, tracks: list[TrackState], boxes: list[tuple[float, float, int, int]]) -> FrameResult:
    n = len(boxes)
    xy = np.array([[x, y] for x, y, _, _ in boxes], dtype=float).reshape(-1, 2)
    bbox = np.array([[int(x) - w // 2, int(y) - h // 2, w, h] for x, y, w, h in boxes], dtype=np.int64).reshape(-1, 4)
    dets = Detections(xy, np.array([w * h // 2 for *_, w, h in boxes]).reshape(-1), np.ones(n), np.ones(n), bbox,
                      np.arange(1, n + 1), np.zeros((1, 1), dtype=np.int32), 1.0)
    return FrameResult(k, float(k), tuple(tracks), (), dets, (), {})


def _explain(states: list[tuple[float, float, bool, int]], w: int = 3, h: int = 3) -> list:
    """Explain one confirmed track (no truth) at (x, y) with ``hits`` so far; a hit's component
    is ``w`` x ``h`` px. Returns each frame's explanations."""
    causes = FalseCauses(3.0)
    out = []
    for k, (x, y, hit, hits) in enumerate(states):
        t = TrackState(1, x, y, 0.0, 0.0, True, False, hits, 0 if hit else 1)
        r = _result(k, [t], [(x, y, w, h)] if hit else [])
        out.append(causes.explain(r, [], frame_errors([(1, x, y)], [])))
    return out


def test_a_false_track_that_hopped_between_spots_is_explained_as_hopping() -> None:
    states, hits = [], 0
    for k, p in enumerate(_hops()):
        if p is not None:
            hits += 1
            last = p
        states.append((*last, p is not None, hits))
    rows = _explain(states)
    assert rows[-1][0].cause is FalseCause.HOPPING, rows[-1][0]
    assert "consecutive frames" in rows[-1][0].detail


def test_a_false_track_sliding_along_a_line_is_structure_and_keeps_its_cause() -> None:
    """Hits on 8 x 4 px components (not elongated enough to be a line on their own), moving 1 px a
    frame along them: sliding along a line; compact ones: unknown. A track that slid, then
    takes compact hits, keeps its cause."""
    states = [(20.0 + k, 30.0, True, k + 1) for k in range(8)]
    rows = _explain(states, w=8, h=4)
    assert rows[-1][0].cause is FalseCause.STRUCTURE and "slides along a line" in rows[-1][0].detail
    assert _explain(states, w=3, h=3)[-1][0].cause is FalseCause.UNKNOWN
    causes = FalseCauses(3.0)
    for k in range(20):
        x, y = 20.0 + k, 30.0
        t = TrackState(1, x, y, 0.0, 0.0, True, False, k + 1, 0)
        last = causes.explain(_result(k, [t], [(x, y, 8 if k < 8 else 3, 4 if k < 8 else 3)]), [],
                              frame_errors([(1, x, y)], []))
    assert last[0].cause is FalseCause.STRUCTURE and last[0].detail.startswith("since frame"), last[0]
