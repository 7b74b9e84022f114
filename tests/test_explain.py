"""``--explain``: every truth point's cause on scenes built so that the cause is known by
construction, consistency with the tracks and the scores, and ``wfviz eval --explain``."""

from __future__ import annotations

import csv
import json
import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from conftest import invoke, rows

H, W = 120, 160
SIGMA = 10.0
GATE = 3.0


def _spot(frame: np.ndarray, x: float, y: float, amplitude: float, width: float = 0.8) -> None:
    """Add a Gaussian spot of peak ``amplitude`` at (x, y) to ``frame`` (in place)."""
    yy, xx = np.mgrid[0:frame.shape[0], 0:frame.shape[1]]
    frame += amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * width ** 2))


def scene(tmp: Path, n: int, draw: Callable[[int, np.ndarray], list[tuple[int, float, float, int]]],
          background: Callable[[], np.ndarray] | None = None, seed: int = 0) -> tuple[Path, Path]:
    """A .npy clip of ``n`` frames (noise σ = SIGMA on ``background``, default flat 1000) and its
    truth CSV: ``draw(k, frame)`` adds frame k's objects and returns its truth rows
    (target_id, x, y, visible)."""
    rng = np.random.default_rng(seed)
    base = background() if background is not None else np.full((H, W), 1000.0)
    frames, truth = [], []
    for k in range(n):
        f = base.copy()
        for tid, x, y, vis in draw(k, f):
            truth.append((k, tid, x, y, vis))
        f += rng.normal(0.0, SIGMA, f.shape)
        frames.append(np.clip(f, 0, 65535).astype(np.uint16))
    clip, tpath = tmp / "clip.npy", tmp / "truth.csv"
    np.save(clip, np.stack(frames))
    with open(tpath, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "target_id", "x", "y", "visible"])
        w.writerows(truth)
    return clip, tpath


def explain(tmp: Path, clip: Path, truth: Path, *extra: str) -> tuple[list[dict], list[dict], str]:
    """Track ``clip`` with ``--explain``: (its explain rows, its false-track rows, the output)."""
    r = invoke("track", str(clip), "--tracks", str(tmp / "tracks.csv"), "--truth", str(truth),
               "--explain", str(tmp / "explain.csv"), *extra)
    assert r.exit_code == 0, r.output
    return rows(tmp / "explain.csv"), rows(tmp / "explain-false.csv"), r.output


def causes(rs: list[dict], after: int = 0) -> Counter:
    return Counter(r["cause"] for r in rs if int(r["frame"]) >= after)


def test_a_target_below_threshold_is_not_detected_with_its_significance(tmp_path: Path) -> None:
    clip, truth = scene(tmp_path, 30, lambda k, f: (_spot(f, 30 + 2 * k, 60, 2.0 * SIGMA), [(1, 30 + 2 * k, 60, 1)])[1])
    rs, _, out = explain(tmp_path, clip, truth)
    assert len(rs) == 30 and causes(rs)["not_detected"] >= 28, causes(rs)
    for r in rs:
        if r["cause"] == "not_detected":
            assert r["detail"].startswith("below threshold")
            assert float(r["significance"]) <= float(r["threshold"]) and 0.5 < float(r["significance"]) < 4.0
    assert "dominant miss cause: not_detected" in out


def test_a_hidden_target_is_hidden_and_not_counted_as_visible(tmp_path: Path) -> None:
    def draw(k: int, f: np.ndarray) -> list:
        _spot(f, 30 + 2 * k, 60, 2.0 * SIGMA)
        return [(1, 30 + 2 * k, 60, 0 if k % 2 else 1)]
    clip, truth = scene(tmp_path, 20, draw)
    rs, _, out = explain(tmp_path, clip, truth)
    hidden = [r for r in rs if r["cause"] == "hidden"]
    assert [int(r["frame"]) for r in hidden] == list(range(1, 20, 2))
    assert "10 visible truth points (10 hidden)" in out


def test_a_target_on_a_static_flickering_spot_is_held_back_by_the_motion_test(tmp_path: Path) -> None:
    def draw(k: int, f: np.ndarray) -> list:  # new at its place each frame (it flickers), never moves
        _spot(f, 80 + 0.02 * k, 60, (10.0 if k % 2 else 25.0) * SIGMA)
        return [(1, 80 + 0.02 * k, 60, 1)]
    clip, truth = scene(tmp_path, 40, draw)
    rs, _, _ = explain(tmp_path, clip, truth)
    late = [r for r in rs if int(r["frame"]) >= 10]
    assert late and all(r["cause"] == "not_confirmed" for r in late), causes(late)
    assert all("motion" in r["detail"] for r in late), {r["detail"] for r in late}
    young = [r for r in rs if r["cause"] == "latency"]
    assert young and all(int(r["frame"]) < 10 for r in young)
    # the test column names the blocking test, with its statistic short of its level
    assert all(r["test"].startswith("motion") and float(r["statistic"]) < float(r["level"]) for r in late), late[:3]
    assert all(r["test"] == "" or r["test"] in r["detail"] for r in young)
    r = invoke("eval", "--explain", str(tmp_path / "explain.csv"), "--json", str(tmp_path / "w.json"))
    assert "not_confirmed held back by: motion" in r.output, r.output
    held = json.loads((tmp_path / "w.json").read_text())["explain"]["held_back"]
    assert sum(held["not_confirmed"].values()) == len([r for r in rs if r["cause"] == "not_confirmed"])


def test_a_target_that_jumps_away_from_its_confirmed_track_is_lost(tmp_path: Path) -> None:
    def draw(k: int, f: np.ndarray) -> list:
        x = 20 + 1.5 * k + (40 if k >= 20 else 0)  # confirmed by frame 20, then 40 px away
        _spot(f, x, 60, 15.0 * SIGMA)
        return [(1, x, 60, 1)]
    clip, truth = scene(tmp_path, 34, draw)
    rs, _, _ = explain(tmp_path, clip, truth)
    before = causes([r for r in rs if 8 <= int(r["frame"]) < 20])
    assert before == {"matched": 12}, before
    after = [r for r in rs if int(r["frame"]) >= 20 and r["cause"] != "matched"]
    assert after and all(r["cause"] == "lost" for r in after), causes(after)
    assert int(after[0]["track_id"]) > 0 and "off it" in after[0]["detail"]
    # why it did not follow: predicted far from the target, its detection outside the gate
    assert "predicted" in after[0]["detail"] and "outside that gate" in after[0]["detail"], after[0]["detail"]
    assert any("ended at frame" in r["detail"] for r in after)
    # the prediction's offset: inside the gate on the straight matched frames, the jump's 40 px after
    matched = [r for r in rs if 8 <= int(r["frame"]) < 20]
    assert all(float(r["pred_dist"]) < 1.5 and float(r["pred_gate"]) < 0.5 for r in matched), matched
    jump = after[0]
    assert float(jump["pred_dist"]) > 35 and float(jump["pred_gate"]) > 1, jump
    assert all(r["pred_dist"] == "" for r in rs if not r["track_id"])  # no track: no prediction


def test_a_target_on_a_hot_pixel_is_replaced_as_a_defect(tmp_path: Path) -> None:
    def draw(k: int, f: np.ndarray) -> list:  # one pixel, fixed: what a hot pixel looks like
        f[50, 70] += 40 * SIGMA
        return [(1, 70.0, 50.0, 1)]
    clip, truth = scene(tmp_path, 25, draw)
    rs, _, _ = explain(tmp_path, clip, truth)
    late = [r for r in rs if int(r["frame"]) >= 10]
    assert late and all(r["cause"] == "not_detected" and "defect" in r["detail"] for r in late), \
        {(r["cause"], r["detail"]) for r in late}


def test_points_just_above_and_below_the_horizon_are_outside_the_region(tmp_path: Path) -> None:
    """Points 2 px above the line the horizon stage reports (within its 4 px margin) and 5 px
    below it, on a 180° skyline scene."""
    import wfviz.synth  # noqa: F401 - registers synth: clips
    from wfviz.io.clip import open_clip
    from wfviz.trackers import make_tracker

    clip = open_clip("synth:fov180-city-aircraft")
    tracker = make_tracker("gewc")
    lines = {}
    for frame in clip.frames(0, 14):
        res = tracker.step(frame)
        h = res.front.horizon
        if frame.index >= 10 and h is not None:
            lines[frame.index] = h.rows
    assert lines, "the scene's horizon was expected to be found"
    with open(tmp_path / "truth.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "target_id", "x", "y", "visible"])
        for f, rows_ in lines.items():
            cols = np.nonzero(np.isfinite(rows_))[0]
            c = int(cols[len(cols) // 2])
            w.writerow([f, 1, c, float(rows_[c]) - 2.0, 1])
            w.writerow([f, 2, c + 20, float(rows_[c + 20]) + 5.0, 1])
    r = invoke("track", "synth:fov180-city-aircraft", "--stop", "14", "--tracks", str(tmp_path / "t.csv"),
               "--truth", str(tmp_path / "truth.csv"), "--explain", str(tmp_path / "e.csv"))
    assert r.exit_code == 0, r.output
    rs = rows(tmp_path / "e.csv")
    assert len(rs) == 2 * len(lines) and all(r["cause"] == "outside_region" for r in rs), Counter(r["cause"] for r in rs)
    assert all("within the horizon margin" in r["detail"] for r in rs if r["target_id"] == "1")
    assert all("below the horizon" in r["detail"] for r in rs if r["target_id"] == "2")


def _panned_spots(tmp_path: Path) -> tuple[Path, Path]:
    """Five static spots on flat noise under a pan of 1 px a frame."""
    spots = [(30, 30), (60, 90), (100, 40), (130, 80), (80, 20)]

    def draw(k: int, f: np.ndarray) -> list:
        for x, y in spots:
            _spot(f, x + 1.0 * k - 10, y, 20 * SIGMA)
        return [(1, 5.0, 5.0, 0)]
    return scene(tmp_path, 30, draw)


def test_static_spots_under_a_measured_pan_of_a_featureless_sky_give_no_false_track(tmp_path: Path) -> None:
    """The camera's shift is measured here to ±0.5 px only (few corners, phase correlation): the
    motion test asks for progress beyond the registration's errors too, and no spot confirms."""
    clip, truth = _panned_spots(tmp_path)
    _, false, _ = explain(tmp_path, clip, truth)
    assert not false


def test_static_spots_moved_by_an_unmeasured_pan_are_false_tracks_of_camera_motion(tmp_path: Path) -> None:
    """Five static spots on flat noise under a pan of 1 px a frame, the camera's motion not
    compensated: the spots become false tracks, explained as camera motion."""
    clip, truth = _panned_spots(tmp_path)
    (tmp_path / "off.toml").write_text('[tracking]\ncompensate_motion = "off"\n')
    _, false, _ = explain(tmp_path, clip, truth, "--config", str(tmp_path / "off.toml"))
    assert false, "the moving static spots were expected to be confirmed"
    assert Counter(r["cause"] for r in false) == {"camera_motion": len(false)}, Counter(r["cause"] for r in false)


def _mixed(tmp: Path) -> tuple[Path, Path]:
    """Two targets, one bright and one dim, one hidden for a while."""
    def draw(k: int, f: np.ndarray) -> list:
        _spot(f, 20 + 2 * k, 30, 12 * SIGMA)
        _spot(f, 140 - 1.5 * k, 90, 4.5 * SIGMA)
        return [(1, 20 + 2 * k, 30, 1), (2, 140 - 1.5 * k, 90, 0 if 20 <= k < 25 else 1)]
    return scene(tmp, 40, draw, seed=3)


def test_causes_are_consistent_with_the_tracks_and_the_scores(tmp_path: Path) -> None:
    clip, truth = _mixed(tmp_path)
    invoke("track", str(clip), "--tracks", str(tmp_path / "plain.csv"))
    rs, _, _ = explain(tmp_path, clip, truth, "--gate", str(GATE))
    assert (tmp_path / "plain.csv").read_bytes() == (tmp_path / "tracks.csv").read_bytes()  # no effect on tracks
    truth_rows = rows(truth)
    assert sorted((int(r["frame"]), int(r["target_id"])) for r in rs) == \
        sorted((int(r["frame"]), int(r["target_id"])) for r in truth_rows)  # one cause per truth point
    invoke("eval", str(tmp_path / "tracks.csv"), str(truth), "--gate", str(GATE), "--json", str(tmp_path / "s.json"))
    scores = json.loads((tmp_path / "s.json").read_text())
    assert sum(r["cause"] == "matched" for r in rs) == scores["matches"]
    assert sum(r["cause"] not in ("matched", "hidden") for r in rs) == scores["misses"]
    tracks: dict[int, list[dict]] = {}
    for t in rows(tmp_path / "tracks.csv"):
        tracks.setdefault(int(t["frame"]), []).append(t)
    for e in rs:
        x, y, f = float(e["x"]), float(e["y"]), int(e["frame"])
        if e["cause"] == "not_detected":
            assert e["det_dist"] == "" or float(e["det_dist"]) > GATE
        if e["cause"] in ("latency", "not_confirmed"):
            near = [t for t in tracks.get(f, []) if t["confirmed"] == "0"
                    and math.hypot(float(t["x"]) - x, float(t["y"]) - y) <= GATE]
            assert any(int(t["track_id"]) == int(e["track_id"]) for t in near), e


def test_eval_explain_prints_where_pd_went_and_writes_it_to_json(tmp_path: Path) -> None:
    clip, truth = _mixed(tmp_path)
    rs, _, _ = explain(tmp_path, clip, truth)
    r = invoke("eval", "--explain", str(tmp_path / "explain.csv"), "--json", str(tmp_path / "w.json"))
    assert r.exit_code == 0, r.output
    assert "where Pd went" in r.output and "dominant miss cause" in r.output
    data = json.loads((tmp_path / "w.json").read_text())["explain"]
    n = Counter(r["cause"] for r in rs)
    assert data["visible"] == sum(v for k, v in n.items() if k != "hidden")
    assert {k: v["count"] for k, v in data["causes"].items() if v["count"]} == {k: v for k, v in n.items() if k != "hidden"}
    assert data["funnel"][-1]["left"] == n["matched"]


def test_explain_without_truth_and_a_malformed_explain_file_fail_in_one_line(tmp_path: Path) -> None:
    clip, _ = _mixed(tmp_path)
    r = invoke("track", str(clip), "--tracks", str(tmp_path / "t.csv"), "--explain", str(tmp_path / "e.csv"))
    assert r.exit_code == 2 and "needs truth" in r.output
    (tmp_path / "bad.csv").write_text("frame,target_id,cause,detail,significance,det_dist,track_id\n0,1,sleepy,,,,\n")
    r = invoke("eval", "--explain", str(tmp_path / "bad.csv"))
    assert r.exit_code == 2 and "bad.csv:2" in r.output and "'sleepy'" in r.output


@pytest.mark.parametrize("tracker", ["fusion", "starfield", "tbd"])
def test_every_tracker_gives_every_visible_point_a_cause(tmp_path: Path, tracker: str) -> None:
    clip, truth = _mixed(tmp_path)
    rs, _, _ = explain(tmp_path, clip, truth, "--tracker", tracker)
    assert len(rs) == len(rows(truth))
    if tracker in ("starfield", "tbd"):  # no shared front end: they say so, never name its stages
        for r in rs:
            if r["cause"] == "not_detected":
                assert "reports no per-pixel significance" in r["detail"], r["detail"]
            assert r["cause"] not in ("outside_region",)


def test_track_needs_no_tracks_csv_to_explain_but_something_to_write(tmp_path: Path) -> None:
    clip, truth = _mixed(tmp_path)
    r = invoke("track", str(clip), "--truth", str(truth), "--explain", str(tmp_path / "e.csv"))
    assert r.exit_code == 0, r.output
    assert "where Pd went" in r.output and (tmp_path / "e.csv").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.npy", "e-false.csv", "e.csv", "truth.csv"]
    r = invoke("track", str(clip))
    assert r.exit_code == 2 and "nothing to write" in r.output
