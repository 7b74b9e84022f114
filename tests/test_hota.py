"""HOTA (wfviz.hota): the paper's definitions on hand-computed cases, TrackEval's reference
implementation where it is importable, and HOTA, DetA, AssA in ``wfviz eval`` and ``wfviz track --truth``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import invoke, rows, wfviz
from test_backfill import _mover
from wfviz.evaluate import evaluate_points
from wfviz.hota import ALPHAS, hota, point_similarity

#: two targets 10 frames, far apart; as tracks 101 and 102
TRUTH = {f: [(1, 10.0 + f, 20.0), (2, 80.0, 50.0 + 2 * f)] for f in range(10)}
TRACKS = {f: [(100 + i, x, y) for i, x, y in pts] for f, pts in TRUTH.items()}


def frames_of(truth: dict, tracks: dict, gate: float = 3.0) -> list:
    """(truth ids, track ids, similarity) per frame, as wfviz.evaluate builds them."""
    out = []
    for f in sorted(set(truth) | set(tracks)):
        g, t = truth.get(f, []), tracks.get(f, [])
        a, b = np.array([p[1:] for p in g]).reshape(-1, 2), np.array([p[1:] for p in t]).reshape(-1, 2)
        d = np.hypot(*np.moveaxis(a[:, None, :] - b[None, :, :], 2, 0))
        out.append(([p[0] for p in g], [p[0] for p in t], point_similarity(d, gate)))
    return out


def test_alphas_and_similarity_follow_the_paper():
    assert len(ALPHAS) == 19 and ALPHAS[0] == pytest.approx(0.05) and ALPHAS[-1] == pytest.approx(0.95)
    assert point_similarity(np.array([0.0, 1.5, 3.0, 7.0]), 3.0).tolist() == [1.0, 0.5, 0.0, 0.0]


def test_perfect_tracks_score_one():
    h = hota(frames_of(TRUTH, TRACKS))
    assert (h.hota, h.det_a, h.ass_a) == (1.0, 1.0, 1.0)
    r = evaluate_points(TRACKS, TRUTH)
    assert (r.hota, r.det_a, r.ass_a) == (1.0, 1.0, 1.0)


def test_an_id_switch_halfway_lowers_assa_not_deta():
    # target 1's track changes id 101 -> 201 at frame 5: each of its identity pairs is right for
    # 5 of 10 truth frames and 5 of 5 track frames, TPA / (TPA + FNA + FPA) = 5 / 10
    tracks = {f: [(201 if i == 101 and f >= 5 else i, x, y) for i, x, y in pts] for f, pts in TRACKS.items()}
    h = hota(frames_of(TRUTH, tracks))
    assert h.det_a == 1.0
    assert h.ass_a == pytest.approx((10 * 0.5 + 10 * 1.0) / 20)
    assert h.hota == pytest.approx(math.sqrt(0.75))


def test_a_missed_target_lowers_deta_not_assa():
    tracks = {f: [p for p in pts if p[0] == 101] for f, pts in TRACKS.items()}
    h = hota(frames_of(TRUTH, tracks))
    assert h.det_a == pytest.approx(10 / 20)  # TP 10, FN 10, FP 0
    assert h.ass_a == 1.0
    assert h.hota == pytest.approx(math.sqrt(0.5))


def test_localisation_error_counts_at_the_thresholds_it_meets():
    # 1 px off with a 3 px gate: similarity 2/3 reaches α = 0.05 ... 0.65 (13 of 19 thresholds)
    tracks = {f: [(i, x + 0.6, y + 0.8) for i, x, y in pts] for f, pts in TRACKS.items()}
    h = hota(frames_of(TRUTH, tracks))
    assert (h.det_a, h.ass_a, h.hota) == pytest.approx((13 / 19, 13 / 19, 13 / 19))
    assert hota(frames_of(TRUTH, tracks, gate=1.0)).hota == 0.0  # at the gate: similarity 0


def test_the_assignment_prefers_the_identity_that_aligns_over_the_sequence():
    # frames 0-8: track 101 on target 1, 102 on target 2; frame 9: target 1 alone, track 102 exactly
    # on it and 101 1 px off. Similarity alone would take 102; the alignment-weighted assignment
    # takes 101 (score 0.887 * 2/3 against 0.031 * 1), so 102 is a false positive there.
    truth = {f: pts for f, pts in TRUTH.items() if f < 9} | {9: [(1, 10.0, 20.0)]}
    tracks = {f: pts for f, pts in TRACKS.items() if f < 9} | {9: [(101, 11.0, 20.0), (102, 10.0, 20.0)]}
    h = hota(frames_of(truth, tracks))
    lo, hi = 13, 6  # thresholds met by similarity 2/3, and the others
    det = (lo * 19 / (19 + 20 - 19) + hi * 18 / (19 + 20 - 18)) / 19
    ass_lo = (10 * 1.0 + 9 * 9 / 10) / 19  # pairs (1, 101): 10 of 10 and 10; (2, 102): 9 of 9 and 10
    ass_hi = (9 * 9 / 11 + 9 * 9 / 10) / 18  # (1, 101): 9 of 10 and 10
    assert h.det_a == pytest.approx(det)
    assert h.ass_a == pytest.approx((lo * ass_lo + hi * ass_hi) / 19)
    hotas = [math.sqrt(19 / 20 * ass_lo)] * lo + [math.sqrt(18 / 21 * ass_hi)] * hi
    assert h.hota == pytest.approx(sum(hotas) / 19)


def test_nothing_to_score_is_nan_and_one_side_empty_is_zero():
    assert math.isnan(hota([]).hota)
    assert math.isnan(hota([([], [], np.zeros((0, 0)))]).det_a)
    assert hota(frames_of(TRUTH, {})) == hota(frames_of({}, TRACKS)) == hota(frames_of(TRUTH, {}))
    assert (hota(frames_of(TRUTH, {})).hota, hota(frames_of({}, TRACKS)).det_a) == (0.0, 0.0)


def test_hidden_truth_tracks_are_not_false_positives():
    hidden = {f: [(9, 40.0, 40.0)] for f in range(10)}
    tracks = {f: pts + [(300, 40.5, 40.0)] for f, pts in TRACKS.items()}
    assert evaluate_points(tracks, TRUTH, hidden=hidden).det_a == 1.0
    assert evaluate_points(tracks, TRUTH).det_a == pytest.approx(20 / 30)


def _random_frames(rng: np.random.Generator, grid: bool) -> list:
    gate = float(rng.choice([3.0, 5.0]))
    truth, tracks = {}, {}
    for f in range(int(rng.integers(1, 30))):
        g = rng.choice(5, int(rng.integers(0, 6)), replace=False)
        t = rng.choice(9, int(rng.integers(0, 10)), replace=False)
        xy = (lambda n: rng.integers(0, 4, (n, 2)).astype(float)) if grid else (lambda n: rng.uniform(0, 8, (n, 2)))
        truth[f] = [(int(i), *p) for i, p in zip(g, xy(len(g)))]
        tracks[f] = [(int(i), *p) for i, p in zip(t, xy(len(t)))]
    return frames_of(truth, tracks, gate)


def test_matches_trackeval_reference_implementation():
    """Against TrackEval's HOTA (not a dependency: run with it importable, e.g. its wheel unpacked
    on PYTHONPATH; it needs pycocotools and opencv-python, which clash with the headless OpenCV)."""
    pytest.importorskip("trackeval")
    from trackeval.metrics import HOTA

    rng = np.random.default_rng(3)
    for case in range(200):
        frames = _random_frames(rng, grid=case % 2 == 1)  # grid points: ties in the assignment
        gids = sorted({i for g, _, _ in frames for i in g})
        tids = sorted({i for _, t, _ in frames for i in t})
        data = {"num_gt_dets": sum(len(g) for g, _, _ in frames),
                "num_tracker_dets": sum(len(t) for _, t, _ in frames),
                "num_gt_ids": len(gids), "num_tracker_ids": len(tids),
                "gt_ids": [np.array([gids.index(i) for i in g], int) for g, _, _ in frames],
                "tracker_ids": [np.array([tids.index(i) for i in t], int) for _, t, _ in frames],
                "similarity_scores": [s for _, _, s in frames]}
        if not data["num_gt_dets"] + data["num_tracker_dets"]:
            continue
        ref = HOTA().eval_sequence(data)
        h = hota(frames)
        assert (h.hota, h.det_a, h.ass_a) == pytest.approx(
            tuple(float(np.mean(ref[k])) for k in ("HOTA", "DetA", "AssA")), abs=1e-12), case


def test_eval_and_track_print_hota(tmp_path: Path):
    clip, truth = _mover(tmp_path)
    tracks, out = tmp_path / "tracks.csv", tmp_path / "s.json"
    r = invoke("track", str(clip), "--tracks", str(tracks), "--truth", str(truth))
    assert r.exit_code == 0, r.output
    printed = r.output.split("HOTA ")[1].split()[0]
    e = invoke("eval", str(tracks), str(truth), "--json", str(out))
    assert e.exit_code == 0, e.output
    d = json.loads(out.read_text())
    assert 0 < d["hota"] < 1 and 0 < d["det_a"] < 1 and 0 < d["ass_a"] <= 1  # latency, centre error
    assert f"HOTA {d['hota']:.3f} (DetA {d['det_a']:.3f}, AssA {d['ass_a']:.3f})" in e.output
    assert printed == f"{d['hota']:.3f}"  # the same score printed by track --truth


def test_tune_objective_hota_chooses_the_highest_mean_hota(tmp_path: Path):
    (tmp_path / "space.toml").write_text("[detection]\nk_sigma = { low = 3.0, high = 6.0 }\n"
                                         "[tracking]\np_detect = { low = 0.6, high = 0.98 }\n")
    clips = ["synth:fov70-maneuver:0", "synth:uniform-50hz:0"]
    proc = wfviz("tune", *clips, "--out", "h", "--space", "space.toml", "--stop", "16", "--workers", "1",
                 "--trials", "3", "--objective", "hota", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    every = rows(tmp_path / "h" / "trials.csv")
    for r in every:
        per_clip = [float(r[f"{c.split(':')[1]}-0_hota"]) for c in clips]
        assert 0 < float(r["tune_hota"]) == pytest.approx(sum(per_clip) / 2)
    best = max(every, key=lambda r: (float(r["tune_hota"]), -int(r["trial"])))
    assert (tmp_path / "h" / "best.toml").read_text().startswith(f"# wfviz tune: trial {best['trial']} of")
    assert "objective: maximize hota" in (tmp_path / "h" / "report.md").read_text()
