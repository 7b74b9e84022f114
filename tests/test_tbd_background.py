"""Track-before-detect on a background and noise it must estimate (issue 19): per-pixel running
background, per-tile noise from frame differences, hot pixels excluded (wfviz.trackers.tbd.background)."""

from __future__ import annotations

import csv
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from wfviz.io.frames import Frame
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers.tbd import TBDTracker
from wfviz.trackers.tbd.background import PixelBackground

ROOT = Path(__file__).resolve().parent.parent
S6 = ROOT.parent / "shared" / "data" / "independent" / "S6"


def _count_ok(est: np.ndarray, true: np.ndarray, latency: int = 5) -> float:
    return float(np.mean([est[k] in set(true[max(0, k - latency + 1):k + 1].tolist()) for k in range(len(true))]))


def test_noise_and_background_estimated_with_structure_and_hot_pixel():
    """A static textured background (std 5 sigma), sigma 7 DN and a hot pixel: after 20 frames the
    normalised frame has unit std, the hot pixel is excluded."""
    g = np.random.default_rng(1)
    texture = 5000.0 + 35.0 * g.standard_normal((64, 64))
    texture[10, 20] += 3000.0
    bg = PixelBackground()
    for k in range(30):
        nf = bg.step(texture + 7.0 * g.standard_normal((64, 64)))
    assert abs(nf.sigma - 7.0) < 0.5
    assert nf.excluded[10, 20] and nf.excluded.sum() <= 3
    assert 0.85 < float(nf.y.std()) < 1.1


def test_lowsnr_count_right_on_an_unknown_offset_and_noise():
    """lowsnr-tbd's frames (sigma 20 on 1000) times 2.5 (sigma 50) plus 7000 DN of offset and a
    hot pixel: the count still follows the truth within the 5-frame latency in >= 85 % of
    frames (the test on the plain scenario asks 90 %) and is 0 before the first target."""
    clip = make_scenario("lowsnr-tbd", seed=0, snr=3.0)
    true = np.zeros(clip.n_frames, dtype=int)
    for row in clip.truth():
        true[row.frame] += row.visible
    texture = np.zeros((64, 64))
    texture[40, 12] += 5000.0
    tracker = TBDTracker()
    est = []
    for f in clip.frames():
        img = f.image.astype(np.float64) * 2.5 + 7000.0 + texture
        est.append(tracker.step(Frame(f.index, f.time, np.clip(np.rint(img), 0, 65535).astype(np.uint16))).count)
    est = np.array(est)
    assert _count_ok(est, true) >= 0.85, (est, true)
    assert set(est[:3].tolist()) == {0}
    assert {1, 2, 3} <= set(est.tolist())


def test_s6_independent_tbd_sample_cli(tmp_path):
    """The independent S6 sample (three targets at peak A/sigma = 3 on a textured background,
    signal-dependent noise, a hot pixel): `wfviz track --tracker tbd` then the count within the
    5-frame latency, Pd and false alarms per frame of the confirmed tracks (measured 0.99, 0.93,
    0.01)."""
    if not (S6 / "truth.csv").exists():
        pytest.skip(f"{S6}: independent samples not present")
    out = tmp_path / "s6.csv"
    subprocess.run([sys.executable, "-m", "wfviz", "track", str(S6), "--tracker", "tbd", "--tracks", str(out)],
                   check=True, capture_output=True)
    truth = defaultdict(list)
    n = len(list((S6 / "frames").glob("*.png")))
    for r in csv.DictReader(open(S6 / "truth.csv")):
        if r["visible"] == "1":
            truth[int(r["frame"])].append((float(r["x"]), float(r["y"])))
    tracks = defaultdict(list)
    for r in csv.DictReader(open(out)):
        if r["confirmed"] == "1":
            tracks[int(r["frame"])].append((float(r["x"]), float(r["y"])))
    true = np.array([len(truth[k]) for k in range(n)])
    est = np.array([len(tracks[k]) for k in range(n)])
    hits = fa = 0
    for k in range(n):
        used = set()
        for x, y in tracks[k]:
            d = [(np.hypot(x - tx, y - ty), j) for j, (tx, ty) in enumerate(truth[k]) if j not in used]
            best = min(d) if d else (np.inf, -1)
            if best[0] <= 3.0:
                used.add(best[1])
                hits += 1
            else:
                fa += 1
    assert _count_ok(est, true) >= 0.93, (est, true)
    assert hits / true.sum() >= 0.88
    assert fa / n <= 0.05
