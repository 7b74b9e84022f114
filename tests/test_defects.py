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
