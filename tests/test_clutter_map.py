"""The scene's clutter map (wfviz.tracking.clutter_map) and the static-clutter prior it gives the
sequential rule: a hovering target on a clear sky is confirmed, the same point amid ground
clutter is not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from wfviz.config import load_config
from wfviz.io.frames import Frame
from wfviz.trackers import config_class, make_tracker
from wfviz.tracking.clutter_map import ClutterMap, static_rate
from wfviz.tracking.rules import MOTION_MIN_POSITIONS, SequentialRule, least_static_prior, static_levels, static_prior
from wfviz.tracking.confirmation import thresholds

TARGET = (64.3, 60.7)


def hovering(n: int = 260, ground: bool = False, seed: int = 0):
    """A target hovering within 0.15 px of TARGET and flickering ±30 %, on a clear sky or amid
    60 fixed bright spots (ground clutter); σ 2 noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:128, 0:128]
    base = np.full((128, 128), 100.0)
    if ground:
        for x, y in rng.uniform(8, 120, size=(60, 2)):
            base += 25 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2.0)
    for i in range(n):
        cx, cy = TARGET[0] + 0.15 * np.sin(i / 7.0), TARGET[1] + 0.15 * np.cos(i / 11.0)
        amp = 30 * (1 + 0.3 * np.sin(i / 3.0))
        img = base + amp * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 2.0) + rng.normal(0, 2, base.shape)
        yield Frame(index=i, time=i / 25, image=np.clip(img, 0, 65535).astype(np.uint16))


def first_confirmed(frames, clutter_map: bool = True) -> int | None:
    """The first frame a confirmed track sits on the hovering target (None: never)."""
    cfg = load_config(None, config_class("gewc"))
    cfg = dataclasses.replace(cfg, tracking=dataclasses.replace(cfg.tracking, clutter_map=clutter_map))
    tracker = make_tracker("gewc", cfg)
    for f in frames:
        for s in tracker.step(f).tracks:
            if s.confirmed and abs(s.x - TARGET[0]) < 3 and abs(s.y - TARGET[1]) < 3:
                return f.index
    return None


def test_hovering_target_on_clear_sky_is_confirmed_without_moving():
    assert first_confirmed(hovering()) is not None
    # without the map every track must prove it moves: the same target is never confirmed
    assert first_confirmed(hovering(), clutter_map=False) is None


def test_the_same_point_amid_ground_clutter_is_not_confirmed():
    assert first_confirmed(hovering(ground=True)) is None


def test_map_counts_in_scene_coordinates_and_forgets():
    m = ClutterMap(cell=16, memory=10.0)
    searched = np.ones((64, 160), dtype=bool)
    for k in range(20):  # a fixed scene point, the camera panning 1 px a frame
        off = np.array([float(k), 0.0])
        m.update(np.array([[20.0 + k, 30.0]]), searched, off)
    count, exposure = m.at(np.array([[20.0 + 19, 30.0], [20.0 + 19, 62.0]]), np.array([19.0, 0.0]))
    rate = static_rate(count, exposure)
    assert rate[0] > 0.5            # the spot's cell: about one a frame
    assert rate[1] < rate[0] / 3    # two cells away: only the neighbourhood's share
    for k in range(20, 80):         # the spot is gone: the map forgets it
        m.update(np.zeros((0, 2)), searched, np.array([float(k), 0.0]))
    count, exposure = m.at(np.array([[20.0 + 79, 30.0]]), np.array([79.0, 0.0]))
    assert static_rate(count, exposure)[0] < 0.01


def test_cells_never_searched_weigh_nothing():
    m = ClutterMap(cell=16, memory=50.0)
    searched = np.zeros((64, 64), dtype=bool)
    searched[:32] = True            # ground below row 32 is not searched
    for _ in range(40):
        m.update(np.zeros((0, 2)), searched, np.zeros(2))
    count, exposure = m.at(np.array([[30.0, 24.0], [30.0, 56.0]]), np.zeros(2))
    rate = static_rate(count, exposure)
    assert rate[0] < 0.02           # next to the unsearched ground, still a clear sky
    assert rate[1] > 5              # never watched: taken for clutter


@pytest.mark.parametrize("prior", [1.0, 0.1, 1e-6])
def test_levels_fall_with_the_prior_and_are_full_without_it(prior):
    th = thresholds(1.0, 10.0, 0.01, 0.001)
    clutter_level, motion_level = static_levels(th, np.array([prior]))
    if prior == 1.0:
        assert clutter_level[0] == pytest.approx(th.confirm) and motion_level[0] == pytest.approx(th.motion)
    elif prior < th.alpha:
        assert clutter_level[0] == 0 and motion_level[0] == 0
    else:
        assert 0 < clutter_level[0] < th.confirm and 0 < motion_level[0] < th.motion
    assert static_prior(np.array([0.0]), np.array([1e9]), np.array([0.0]))[0] < 1e-6


def test_the_map_and_each_tracks_prior_are_recorded(tmp_path):
    from typer.testing import CliRunner
    from rerun.chunk import RrdReader

    from wfviz.cli import app

    out = tmp_path / "r.rrd"
    res = CliRunner().invoke(app, ["record", "synth:fov70-maneuver", "--stop", "20", "-o", str(out)])
    assert res.exit_code == 0, res.output
    paths = {str(ch.entity_path) for ch in RrdReader(out).stream()}
    assert "/clutter/map" in paths
    assert any(p.endswith("/clutter_map_static_prior") for p in paths)


def test_min_hits_asks_for_the_motion_test_while_the_least_prior_exceeds_alpha():
    """``min_hits`` (the explanation's ``latency``) is a true lower bound: the motion test needs
    6 positions wherever the clutter map's least possible prior exceeds α."""
    tc = load_config(None, config_class("gewc")).tracking
    rule = SequentialRule(tc)
    assert least_static_prior(tc) == pytest.approx(-np.expm1(-9 * 0.05 / (9 * tc.clutter_memory + 0.05)))
    many = thresholds(tc.false_tracks_per_1000, 50.0, tc.beta, tc.p_lost)  # α 2e-5: below the least prior
    few = thresholds(tc.false_tracks_per_1000, 1.0, tc.beta, tc.p_lost)    # α 1e-3: above it
    assert rule.min_hits(many) == MOTION_MIN_POSITIONS
    assert rule.min_hits(few) == 2  # the motion test need not be asked for: a hit after the birth
    assert SequentialRule(dataclasses.replace(tc, clutter_map=False)).min_hits(few) == MOTION_MIN_POSITIONS


def test_no_track_is_confirmed_with_fewer_hits_than_min_hits():
    tracker = make_tracker("gewc", load_config(None, config_class("gewc")))
    for f in hovering(120):
        r = tracker.step(f)
        hits = {s.track_id: s.hits for s in r.tracks}
        for tid, d in r.verdicts.all().items():
            if d.verdict == "confirm":
                assert hits[tid] >= r.verdicts.min_hits, (f.index, tid, hits[tid], r.verdicts.min_hits)
