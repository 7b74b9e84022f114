"""Hot pixels are flagged and removed; static real targets are not."""

from __future__ import annotations

import numpy as np

from wfviz.config import GEWCConfig
from wfviz.frames import Frame
from wfviz.synth.psf import add_gaussian_spot
from wfviz.trackers import make_tracker


def frames(n, hot=((40, 50), (70, 20)), static_spot=(30.4, 80.6), seed=0):
    rng = np.random.default_rng(seed)
    for k in range(n):
        img = 1000.0 + rng.normal(0, 10, (100, 120))
        add_gaussian_spot(img, *static_spot, 120.0, 1.0)      # a target that does not move
        add_gaussian_spot(img, 10 + 1.5 * k, 15 + 0.5 * k, 120.0, 1.0)  # a moving one
        for r, c in hot:
            img[r, c] += 400.0
        yield Frame(k, k / 20, img.astype(np.uint16))


def test_hot_pixels_are_flagged_and_never_confirmed():
    trk = make_tracker("gewc")
    confirmed_at = set()
    for f in frames(40):
        res = trk.step(f)
        confirmed_at |= {(round(t.y), round(t.x)) for t in res.tracks if t.confirmed}
    flagged = {tuple(p) for p in res.bad_pixels}
    assert {(40, 50), (70, 20)} <= flagged
    assert not {(40, 50), (70, 20)} & confirmed_at
    # the static and the moving target are both confirmed, and not flagged
    assert any(abs(t.x - 30.4) < 1 and abs(t.y - 80.6) < 1 and t.confirmed for t in res.tracks)
    assert any(abs(t.x - (10 + 1.5 * 39)) < 1.5 and t.confirmed for t in res.tracks)
    assert (81, 30) not in flagged


def test_disabled_defects_let_hot_pixels_through():
    cfg = GEWCConfig()
    from dataclasses import replace
    cfg = replace(cfg, defects=replace(cfg.defects, enabled=False))
    trk = make_tracker("gewc", cfg)
    for f in frames(20):
        res = trk.step(f)
    assert any((round(t.y), round(t.x)) == (40, 50) and t.confirmed for t in res.tracks)


def test_dead_pixels_are_flagged_and_leave_no_track():
    trk = make_tracker("gewc")
    for f in frames(30, hot=()):
        img = f.image.copy()
        img[60, 90] = 0  # dead
        res = trk.step(Frame(f.index, f.time, img))
    assert (60, 90) in {tuple(p) for p in res.bad_pixels}
    assert not any(abs(t.x - 90) < 4 and abs(t.y - 60) < 4 for t in res.tracks if t.confirmed)
