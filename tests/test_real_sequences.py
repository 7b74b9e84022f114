"""Regression floors on the real IR sequences in ../shared/data/real/, default configuration
(one default for every camera: there is no per-sequence or per-camera file).

Each floor sits 0.05 below the Pd measured by ``python benchmarks/validation.py`` (docs/accuracy.md,
"Validation"), each false-alarm ceiling a quarter above the measured rate plus 0.05 a frame;
gate 5 px, confirmed tracks only. The cases span the three sets and both declared halves
(A: where rules and values were chosen, B: held out), and include sequences that miss the goal
(their floors guard what works, their ceilings what does not get worse). Skipped where the data
is absent.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from wfviz.evaluate import evaluate_points, read_truth
from wfviz.io.clip import open_clip
from wfviz.trackers import load_tracker

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data" / "real"

# tracker, sequence, measured Pd, measured FA/frame (whole sequence, defaults)
CASES = [
    ("gewc", "tensoristd_sky/easy2", 0.833, 0.0),
    ("gewc", "tensoristd_sky/easy6", 0.650, 0.28),
    ("gewc", "daub_tensoristd/sequence1", 0.790, 0.010),  # 0.82 before the sub-threshold reads (accuracy.md, issue 36)
    ("gewc", "daub_tensoristd/sequence11", 0.950, 0.20),
    ("gewc", "svanstrom_ir/IR_AIRPLANE_060", 0.860, 0.0),
    ("gewc", "svanstrom_ir/IR_BIRD_017", 0.947, 0.047),
    ("gewc", "svanstrom_ir/IR_BIRD_063", 0.900, 0.10),
    ("gewc", "svanstrom_ir/IR_DRONE_032", 0.940, 0.0),
    ("gewc", "svanstrom_ir/IR_DRONE_110", 0.967, 0.0),
    ("fusion", "daub_tensoristd/sequence11", 0.950, 0.0),
    ("fusion", "svanstrom_ir/IR_AIRPLANE_049", 0.767, 0.133),
    ("fusion", "svanstrom_ir/IR_DRONE_045", 0.947, 0.0),
]


@pytest.mark.parametrize("tracker_name,rel,pd,fa", CASES, ids=[f"{c[0]}-{c[1].split('/')[1]}" for c in CASES])
def test_real_sequence_floor(tracker_name: str, rel: str, pd: float, fa: float) -> None:
    seq = DATA / rel
    if not (seq / "truth.csv").exists():
        pytest.skip(f"{seq}: real data not present (shared/data/real is not checked out here)")
    tracker = load_tracker(tracker_name, None)
    tracks = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the truth.csv beside the frames is skipped with a note
        for frame in open_clip(seq).frames():
            result = tracker.step(frame)
            tracks[frame.index] = [(t.track_id, t.x, t.y) for t in result.tracks if t.confirmed]
    shown, hidden = read_truth(seq / "truth.csv")
    scores = evaluate_points(tracks, shown, 5.0, hidden)
    print(f"{tracker_name} {rel}: Pd {scores.pd:.3f}, FA/frame {scores.fa_per_frame:.3f}")
    assert scores.pd >= pd - 0.05
    assert scores.fa_per_frame <= fa * 1.25 + 0.05
