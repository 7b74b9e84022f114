"""Hot pixels are flagged and removed; static real targets are not.

Under the default sequential confirmation (``tracking.confirm = "sprt"``) nothing that stays
put is confirmed (the motion test), so a static target is tracked but stays tentative; the
paper's rule (``confirm = "hits"``) confirms it, and a hot pixel let through, after six hits.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from wfviz.io.frames import Frame
from wfviz.synth.demo import demo_clip
from wfviz.synth.psf import add_gaussian_spot
from wfviz.trackers import make_tracker
from wfviz.trackers.gewc.config import GEWCConfig


def frames(n, hot=((40, 50), (70, 20)), static_spot=(30.4, 80.6), seed=0):
    rng = np.random.default_rng(seed)
    for k in range(n):
        img = 1000.0 + rng.normal(0, 10, (100, 120))
        add_gaussian_spot(img, *static_spot, 120.0, 1.0)      # a target that does not move
        add_gaussian_spot(img, 10 + 1.5 * k, 15 + 0.5 * k, 120.0, 1.0)  # a moving one
        for r, c in hot:
            img[r, c] += 400.0
        yield Frame(k, k / 20, img.astype(np.uint16))


def _config(confirm: str = "sprt", defects: bool = True, mode: str = "cfar") -> GEWCConfig:
    """The default GEWC configuration with ``tracking.confirm``, ``defects.enabled`` and
    ``detection.mode`` set."""
    cfg = GEWCConfig()
    return replace(cfg, defects=replace(cfg.defects, enabled=defects),
                   tracking=replace(cfg.tracking, confirm=confirm),
                   detection=replace(cfg.detection, mode=mode))




def _near(t, x: float, y: float, tol: float = 1.0) -> bool:
    return abs(t.x - x) < tol and abs(t.y - y) < tol


def _run_hot_pixel_clip(trk):
    """40 frames of the clip; (last result, positions ever confirmed, flagged pixels), after
    checking that both hot pixels are flagged and never confirmed."""
    confirmed_at = set()
    for f in frames(40):
        res = trk.step(f)
        confirmed_at |= {(round(t.y), round(t.x)) for t in res.tracks if t.confirmed}
    flagged = {tuple(p) for p in res.front.bad_pixels}
    assert {(40, 50), (70, 20)} <= flagged
    assert not {(40, 50), (70, 20)} & confirmed_at
    return res, confirmed_at, flagged


def test_hot_pixels_are_flagged_and_never_confirmed():
    """Defaults: both hot pixels flagged and never confirmed; the mover confirmed; the static
    target neither flagged nor removed (tracked in every frame), but, as it does not move,
    not confirmed by the sequential test."""
    trk = make_tracker("gewc")
    res, confirmed_at, flagged = _run_hot_pixel_clip(trk)
    assert any(abs(t.x - (10 + 1.5 * 39)) < 1.5 and t.confirmed for t in res.tracks)
    static = [t for t in res.tracks if _near(t, 30.4, 80.6)]
    assert len(static) == 1 and static[0].misses == 0 and static[0].hits >= 30
    assert not static[0].confirmed and not any(abs(x - 30.4) < 1 and abs(y - 80.6) < 1
                                               for y, x in confirmed_at)
    assert (81, 30) not in flagged


@pytest.mark.parametrize("mode", ["global", "cfar"])
def test_hits_rule_hot_pixels_are_flagged_and_never_confirmed_and_the_static_target_is(mode):
    """confirm = "hits" (the paper; with its global threshold and with CFAR detection): hot
    pixels flagged and never confirmed; the static and the moving target both confirmed, and
    not flagged."""
    trk = make_tracker("gewc", _config("hits", mode=mode))
    res, confirmed_at, flagged = _run_hot_pixel_clip(trk)
    assert any(_near(t, 30.4, 80.6) and t.confirmed for t in res.tracks)
    assert any(abs(t.x - (10 + 1.5 * 39)) < 1.5 and t.confirmed for t in res.tracks)
    assert (81, 30) not in flagged


def test_flagged_hot_pixels_are_not_detected():
    """Defaults: once flagged (in the previous frame's result), a hot pixel yields no detection."""
    trk = make_tracker("gewc")
    flagged: set[tuple[int, int]] = set()
    seen = []
    for f in frames(20):
        res = trk.step(f)
        seen += [(f.index, r, c) for r, c in flagged
                 if any(abs(x - c) < 1.5 and abs(y - r) < 1.5 for x, y in res.detections.xy)]
        flagged = {(int(r), int(c)) for r, c in res.front.bad_pixels}
    assert {(40, 50), (70, 20)} <= flagged
    assert seen == []


def test_hits_rule_disabled_defects_let_hot_pixels_through():
    """confirm = "hits": without the defects stage a hot pixel is confirmed like a target."""
    trk = make_tracker("gewc", _config("hits", defects=False))
    for f in frames(20):
        res = trk.step(f)
    assert any((round(t.y), round(t.x)) == (40, 50) and t.confirmed for t in res.tracks)


def test_disabled_defects_let_hot_pixels_through_to_the_tracker():
    """Defaults without the defects stage: nothing is flagged, and a track sits on each hot
    pixel in every frame; the sequential test alone keeps them (fixed spots) unconfirmed."""
    trk = make_tracker("gewc", _config(defects=False))
    for f in frames(20):
        res = trk.step(f)
    assert len(res.front.bad_pixels) == 0
    for r, c in ((40, 50), (70, 20)):
        on = [t for t in res.tracks if _near(t, c, r, 0.5)]
        assert len(on) == 1 and on[0].hits == 20 and not on[0].confirmed
    assert any(abs(t.x - (10 + 1.5 * 19)) < 1.5 and t.confirmed for t in res.tracks)  # the mover is


def test_dead_pixels_are_flagged_and_leave_no_track():
    """Defaults: a dead pixel is flagged, and no confirmed track lies near it."""
    trk = make_tracker("gewc")
    for f in frames(30, hot=()):
        img = f.image.copy()
        img[60, 90] = 0  # dead
        res = trk.step(Frame(f.index, f.time, img))
    assert (60, 90) in {tuple(p) for p in res.front.bad_pixels}
    assert not any(abs(t.x - 90) < 4 and abs(t.y - 60) < 4 for t in res.tracks if t.confirmed)


# -- defects from time, not space (issue 35): the demo has none; injected ones are found ---------

HOT = ((150, 320), (200, 250), (400, 300), (380, 420))  # (row, col): sky, sky, textured ground, ground
DEAD = ((120, 400), (420, 250))
DEMO_FRAMES = 80


def _demo_flags(inject: bool) -> tuple[list[set[tuple[int, int]]], list[list[tuple[float, float]]]]:
    """Default GEWC over the demo's first frames (with ``inject``: the HOT pixels at a constant
    15 000 DN and the DEAD ones at 0): the flagged pixels and the targets' (x, y) per frame."""
    clip = demo_clip(n_frames=DEMO_FRAMES)
    trk = make_tracker("gewc")
    flagged, targets = [], []
    for f in clip.frames():
        img = f.image
        if inject:
            img = img.copy()
            for r, c in HOT:
                img[r, c] = 15000
            for r, c in DEAD:
                img[r, c] = 0
        res = trk.step(Frame(f.index, f.time, img))
        flagged.append({(int(r), int(c)) for r, c in res.front.bad_pixels})
        targets.append([(t.x, t.y) for t in clip.truth_at(f.index)])
    return flagged, targets


@pytest.fixture(scope="module")
def demo_runs() -> dict[bool, tuple[list[set[tuple[int, int]]], list[list[tuple[float, float]]]]]:
    return {inject: _demo_flags(inject) for inject in (False, True)}


def test_demo_flags_no_defects(demo_runs) -> None:
    """The demo (sky, textured ground, buildings, no sensor defects) flags nothing, in any frame."""
    flagged, _ = demo_runs[False]
    assert max(len(f) for f in flagged) == 0


def test_injected_hot_and_dead_pixels_are_flagged(demo_runs) -> None:
    """The demo with 4 hot and 2 dead pixels injected (on sky and textured ground): every one is
    flagged by frame 6 and stays flagged to the end; nothing else is ever flagged."""
    flagged, _ = demo_runs[True]
    true = set(HOT) | set(DEAD)
    assert all(true <= f for f in flagged[6:])
    assert all(f <= true for f in flagged)


def test_moving_targets_are_never_flagged(demo_runs) -> None:
    """No flagged pixel within 3 px of any of the demo's moving targets, in any frame."""
    for flagged, targets in demo_runs.values():
        for f, xy in zip(flagged, targets):
            assert not [(r, c) for r, c in f for x, y in xy if np.hypot(c - x, r - y) <= 3]


@pytest.mark.parametrize("speed", [0.1, 0.3, 1.0])
def test_slow_small_target_is_not_flagged(speed: float) -> None:
    """A small target (σ 0.7 px) that creeps over the sensor at ``speed`` px a frame is never
    flagged, while a hot pixel in the same frames is."""
    rng = np.random.default_rng(3)
    trk = make_tracker("gewc")
    for k in range(50):
        img = 1000.0 + rng.normal(0, 10, (100, 120))
        x, y = 30.5 + speed * k, 50.5 + 0.3 * speed * k
        add_gaussian_spot(img, x, y, 150.0, 0.7)
        img[40, 90] += 400.0
        res = trk.step(Frame(k, k / 20, img.astype(np.uint16)))
        bp = res.front.bad_pixels
        assert not len(bp) or np.hypot(bp[:, 1] - x, bp[:, 0] - y).min() > 3
    assert (40, 90) in {tuple(p) for p in bp.tolist()}


def test_a_defect_that_stops_is_unflagged() -> None:
    """A hot pixel that stops being hot (frame 20) is unflagged within a few frames."""
    trk = make_tracker("gewc")
    for f in frames(40, hot=((40, 50),)):
        img = f.image.copy()
        if f.index >= 20:
            img[40, 50] = img[39, 50]
        res = trk.step(Frame(f.index, f.time, img))
        if f.index == 19:
            assert (40, 50) in {tuple(p) for p in res.front.bad_pixels.tolist()}
    assert (40, 50) not in {tuple(p) for p in res.front.bad_pixels.tolist()}
