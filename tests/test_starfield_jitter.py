"""Star field under frame jitter with hot pixels (issue 19): registration of a drifting,
slightly rotating field whose brightest points are hot pixels, sharp-point flags, and the
independent sample S5 (../shared/data/independent/S5, 300 stars, jitter, hot pixels, two
targets of peak SNR 3.2-5) through the CLI. S5 is skipped where the data is absent."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wfviz.evaluate import read_truth
from wfviz.io.frames import Frame
from wfviz.trackers.starfield import StarfieldTracker
from wfviz.trackers.starfield.config import StarSegmentationConfig
from wfviz.trackers.starfield.metrics import chain_rows, paper_scores
from wfviz.trackers.starfield.registration import apply
from wfviz.trackers.starfield.segmentation import SHARP_FRACTION, segment, sharpness

ROOT = Path(__file__).resolve().parent.parent
S5 = ROOT.parent / "shared" / "data" / "independent" / "S5"
SIZE = 512
CENTRE = ((SIZE - 1) / 2.0, (SIZE - 1) / 2.0)


def _sky_to_image(k: int) -> np.ndarray:
    """2x3 map of frame k: drift (1.3, -0.9) px and 0.02 deg a frame about the centre."""
    a = np.radians(0.02 * k)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    c = np.array(CENTRE)
    return np.column_stack([R, c - R @ c + np.array([1.3, -0.9]) * k])


def _render(k: int, stars: np.ndarray, flux: np.ndarray, hot: np.ndarray, rng) -> np.ndarray:
    img = np.full((SIZE, SIZE), 1600.0)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    for (x, y), f in zip(apply(_sky_to_image(k), stars), flux):
        x0, y0 = int(round(x)), int(round(y))
        if not (4 <= x0 < SIZE - 4 and 4 <= y0 < SIZE - 4):
            continue
        sl = np.s_[y0 - 4:y0 + 5, x0 - 4:x0 + 5]
        img[sl] += f / (2 * np.pi * 1.15 ** 2) * np.exp(-((xx[sl] - x) ** 2 + (yy[sl] - y) ** 2) / (2 * 1.15 ** 2))
    img += rng.normal(0, 8.0, img.shape)
    img[hot[:, 1], hot[:, 0]] += 6000.0  # hot pixels: brighter than every star's peak
    return np.clip(img, 0, 16383).astype(np.uint16)


def _field(seed: int = 3):
    rng = np.random.default_rng(seed)
    stars = rng.uniform(10, SIZE - 10, (120, 2))
    flux = 400.0 * 10 ** rng.uniform(0, 1.2, len(stars))
    hot = rng.integers(8, SIZE - 8, (40, 2))
    return rng, stars, flux, hot


def test_sharpness_separates_hot_pixels_from_stars():
    rng, stars, flux, hot = _field()
    seg = segment(_render(0, stars, flux, hot, rng), StarSegmentationConfig())
    s = sharpness(seg.points, seg.residual)
    d_hot = np.min(np.hypot(*(seg.points.xy[:, None, :] - hot[None]).transpose(2, 0, 1)), axis=1)
    on_hot = d_hot < 1.0
    assert on_hot.sum() >= 35
    assert (s[on_hot] > SHARP_FRACTION).mean() >= 0.95
    on_star = np.min(np.hypot(*(seg.points.xy[:, None, :] - apply(_sky_to_image(0), stars)[None])
                              .transpose(2, 0, 1)), axis=1) < 1.0
    assert on_star.sum() >= 80 and not (s[on_star & ~on_hot] > SHARP_FRACTION).any()


def test_drifting_rotating_field_with_bright_hot_pixels_is_registered():
    """The chained registration maps every frame to the first within 0.1 px although the 40
    hot pixels, static on the sensor, are the brightest points of every frame."""
    rng, stars, flux, hot = _field()
    tracker = StarfieldTracker()
    H = lambda m: np.vstack([m, [0.0, 0.0, 1.0]])  # noqa: E731
    grid = np.mgrid[32:SIZE - 32:64, 32:SIZE - 32:64].reshape(2, -1).T.astype(float)
    for k in range(6):
        r = tracker.step(Frame(k, float(k), _render(k, stars, flux, hot, rng)))
        truth = (H(_sky_to_image(0)) @ np.linalg.inv(H(_sky_to_image(k))))[:2]
        err = np.hypot(*(apply(truth, grid) - apply(r.to_reference, grid)).T).max()
        assert err < 0.1, (k, err, r.registration.method, r.registration.note)
        if k:
            # the frame-to-frame rotation estimate's own spread is 0.002 deg (sd over 8 such
            # fields x 5 frames, 110 pairs of rms 0.1 px): 0.0075 is ~3.7 sd
            assert r.registration.ok and abs(r.registration.rotation - 0.02) < 0.0075
            assert len(r.registration.pairs) >= 80
            paired_xy = r.stars.xy[r.registration.pairs[:, 1]]
            d_hot = np.min(np.hypot(*(paired_xy[:, None, :] - hot[None]).transpose(2, 0, 1)), axis=1)
            assert (d_hot > 1.0).all()  # no hot pixel paired as a star
        assert not any(t.confirmed for t in r.tracks)  # no target in this field


@pytest.mark.skipif(not (S5 / "frames").is_dir(), reason=f"independent sample S5 not found at {S5}")
def test_s5_cli_tracks_both_targets(tmp_path):
    """`wfviz track S5 --tracker starfield`: both targets confirmed, no false track (floors a
    little below the measured: online p_d 0.75 / 0.80 -- confirmation takes 5 points -- and
    the paper's p_d on the chains 1.00 / 1.00, p_f 0)."""
    out = tmp_path / "s5.csv"
    p = subprocess.run([sys.executable, "-m", "wfviz", "track", str(S5), "--tracker", "starfield",
                        "--tracks", str(out)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    e = subprocess.run([sys.executable, "-m", "wfviz", "eval", str(out), str(S5 / "truth.csv")],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert e.returncode == 0, e.stderr
    rows = {int(line.split()[0]): line.split() for line in e.stdout.splitlines()
            if line.split() and line.split()[0] in ("1", "2") and len(line.split()) >= 4}
    assert set(rows) == {1, 2}, e.stdout
    assert float(rows[1][3]) >= 0.70 and float(rows[2][3]) >= 0.75, e.stdout
    assert "false positives 0" in e.stdout, e.stdout


@pytest.mark.skipif(not (S5 / "frames").is_dir(), reason=f"independent sample S5 not found at {S5}")
def test_s5_paper_metrics_on_the_chains():
    from wfviz.io.clip import open_clip

    tracker = StarfieldTracker()
    for f in open_clip(S5 / "frames").frames():
        tracker.step(f)
    shown, hidden = read_truth(S5 / "truth.csv")
    s = paper_scores(chain_rows(tracker.manager.chains()), shown, hidden)
    print(s.table())
    assert s.p_d[1] >= 0.95 and s.p_d[2] >= 0.95  # measured 1.00 / 1.00
    assert s.p_f <= 0.02  # measured 0
    meta = json.loads((S5 / "meta.json").read_text())
    assert len(meta["sensor"]["hot_pixels"]) > 0


def test_robust_fit_ignores_two_fifths_of_wrong_pairs():
    """RANSAC before the least-squares fit: 40 % of the pairs wrong by up to 8 px (mis-paired
    stars) leave the rotation and shift of the other 60 % within 0.02 px at the field's edge."""
    from wfviz.trackers.starfield.registration import robust_fit, rigid_matrix

    rng = np.random.default_rng(5)
    a = rng.uniform(0, SIZE, (100, 2))
    truth = rigid_matrix(1.7, -0.6, 0.3, CENTRE)
    b = apply(truth, a) + rng.normal(0, 0.05, a.shape)
    wrong = rng.random(len(a)) < 0.4
    b[wrong] += rng.uniform(-8, 8, (int(wrong.sum()), 2))
    motion, keep, rms = robust_fit(a, b, CENTRE, 1.0)
    corners = np.array([[0, 0], [SIZE - 1, 0], [0, SIZE - 1], [SIZE - 1, SIZE - 1]], dtype=float)
    err = np.hypot(*(apply(rigid_matrix(*motion, CENTRE), corners) - apply(truth, corners)).T)
    assert err.max() < 0.02, err
    assert not keep[wrong].any() or keep[wrong].mean() < 0.05
    assert rms < 0.1
