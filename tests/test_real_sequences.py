"""Regression floors on short excerpts of the real IR sequences in ../shared/data/real/.

Floors sit a little below what was measured with configs/real-gewc.toml and
configs/real-fusion.toml (see docs/accuracy.md, "Real sequences"); false-alarm ceilings a little
above. Skipped where the data is absent.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from wfviz.clip import open_clip
from wfviz.evaluate import evaluate_points, read_truth
from wfviz.trackers import load_tracker

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data" / "real"
CONFIG = {"gewc": ROOT / "configs" / "real-gewc.toml", "fusion": ROOT / "configs" / "real-fusion.toml"}

# sequence, frames, measured Pd, measured FA/frame (gate 5 px); GEWC
CASES = [
    ("tensoristd_sky/easy1", 40, 0.925, 0.0),
    ("tensoristd_sky/easy2", 30, 0.900, 0.067),
    ("tensoristd_sky/easy3", 30, 0.900, 0.0),
    ("tensoristd_sky/easy6", 60, 0.950, 0.0),
    ("daub_tensoristd/sequence5", 60, 0.933, 0.0),
    ("daub_tensoristd/sequence8", 60, 0.883, 0.0),
    ("daub_tensoristd/sequence11", 40, 0.900, 0.05),
    ("svanstrom_ir/IR_AIRPLANE_041", 80, 0.963, 0.0),
    ("svanstrom_ir/IR_BIRD_071", 80, 0.963, 0.0),
]
# the same for the fusion tracker
FUSION_CASES = [
    ("tensoristd_sky/easy1", 40, 0.875, 0.0),
    ("daub_tensoristd/sequence8", 60, 0.917, 4.2),
    ("svanstrom_ir/IR_BIRD_071", 80, 0.938, 0.0),
    ("svanstrom_ir/IR_DRONE_020", 80, 0.938, 0.0),
]
ALL = [("gewc", *c) for c in CASES] + [("fusion", *c) for c in FUSION_CASES]


@pytest.mark.parametrize("tracker_name,rel,frames,pd,fa", ALL,
                         ids=[f"{c[0]}-{c[1].split('/')[1]}" for c in ALL])
def test_real_excerpt_floor(tracker_name, rel, frames, pd, fa):
    seq = DATA / rel
    if not (seq / "truth.csv").exists():
        pytest.skip(f"{seq}: real data not present (shared/data/real is not checked out here)")
    tracker = load_tracker(tracker_name, CONFIG[tracker_name])
    tracks = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the truth.csv beside the frames is skipped with a note
        for frame in open_clip(seq).frames(0, frames):
            result = tracker.step(frame)
            tracks[frame.index] = [(t.track_id, t.x, t.y) for t in result.tracks if t.confirmed]
    shown, hidden = read_truth(seq / "truth.csv")
    scores = evaluate_points(tracks, {f: v for f, v in shown.items() if f < frames}, 5.0, hidden)
    print(f"{tracker_name} {rel} ({frames} frames): Pd {scores.pd:.3f}, FA/frame {scores.fa_per_frame:.2f}")
    assert scores.pd >= pd - 0.05
    assert scores.fa_per_frame <= fa * 1.25 + 0.1
