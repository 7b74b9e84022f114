"""Tracking metrics against ground truth: motmetrics numbers, CLE, Pd / p_f, latency, CSV errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from wfviz.evaluate import (TruthError, evaluate, evaluate_points, format_table, frame_errors,
                            read_points)

# two targets moving across 10 frames, far apart (never within a gate of each other)
TRUTH = {f: [(1, 10.0 + f, 20.0), (2, 80.0, 50.0 + 2 * f)] for f in range(10)}


def shifted(points: dict, dx: float, dy: float, ids: dict[int, int] | None = None) -> dict:
    """Truth re-labelled as tracks (target i -> track 100 + i unless ``ids``) and offset."""
    ids = ids or {}
    return {f: [(ids.get(i, 100 + i), x + dx, y + dy) for i, x, y in pts] for f, pts in points.items()}


def write(path: Path, text: str) -> Path:
    path.write_text(text.lstrip())
    return path


def test_truth_scored_as_tracks_is_perfect():
    r = evaluate_points(shifted(TRUTH, 0, 0), TRUTH)
    assert (r.mota, r.idf1, r.pd, r.fa_per_frame, r.p_f) == (1.0, 1.0, 1.0, 0.0, 0.0)
    assert r.cle_mean == r.cle_rms == r.motp == 0.0
    assert (r.frames, r.truth_points, r.matches, r.misses, r.false_positives) == (10, 20, 20, 0, 0)
    assert (r.id_switches, r.fragmentations, r.latency_mean) == (0, 0, 0.0)
    assert [(t.target_id, t.matched, t.p_d, t.main_track) for t in r.per_target] == [(1, 10, 1.0, 101),
                                                                                     (2, 10, 1.0, 102)]


def test_fixed_offset_gives_euclidean_cle_and_motp_not_squared():
    r = evaluate_points(shifted(TRUTH, 0.18, 0.24), TRUTH)  # |(0.18, 0.24)| = 0.3 px
    assert r.cle_mean == pytest.approx(0.3)
    assert r.cle_rms == pytest.approx(0.3)
    assert r.motp == pytest.approx(0.3)  # squared distances would give 0.09
    assert r.mota == 1.0 and r.pd == 1.0


def test_empty_tracks_miss_everything():
    r = evaluate_points({}, TRUTH)
    assert r.mota <= 0 and r.pd == 0.0
    assert (r.matches, r.misses, r.false_positives) == (0, 20, 0)
    assert math.isnan(r.cle_mean) and math.isnan(r.latency_mean)
    d = r.to_dict()
    json.dumps(d, allow_nan=False)  # NaN became None
    assert d["motp"] is None and d["per_target"][0]["latency"] is None


def test_exchanged_track_ids_count_one_switch_per_target():
    # From frame 5 on, track 101 follows target 2 and track 102 follows target 1. motmetrics counts
    # an ID switch per truth object whose matched hypothesis changes, so one exchange of two ids is
    # num_switches == 2 (one for each target), and MOTA = 1 - 2 / 20.
    tracks = {f: pts if f < 5 else [(203 - i, x, y) for i, x, y in pts] for f, pts in shifted(TRUTH, 0, 0).items()}
    r = evaluate_points(tracks, TRUTH)
    assert r.id_switches == 2
    assert [t.id_switches for t in r.per_target] == [1, 1]
    assert r.mota == pytest.approx(0.9)
    assert r.idf1 == pytest.approx(0.5)  # each identity is right for 5 of its 10 frames
    assert r.matches == 20 and r.pd == 1.0  # switch frames are still matches


def test_one_target_changing_track_id_counts_one_switch():
    truth = {f: [(1, 10.0 + f, 20.0)] for f in range(10)}
    tracks = {f: [(7 if f < 4 else 9, 10.0 + f, 20.0)] for f in range(10)}
    r = evaluate_points(tracks, truth)
    assert r.id_switches == 1 and r.per_target[0].id_switches == 1
    assert r.mota == pytest.approx(0.9) and r.false_positives == 0


def test_track_outside_gate_is_a_miss_and_a_false_alarm():
    truth = {0: [(1, 10.0, 10.0)]}
    r = evaluate_points({0: [(7, 13.0, 14.0)]}, truth, gate=3.0)  # 5 px away
    assert (r.matches, r.misses, r.false_positives, r.fa_per_frame) == (0, 1, 1, 1.0)
    assert evaluate_points({0: [(7, 13.0, 14.0)]}, truth, gate=5.5).matches == 1
    fe = frame_errors([(7, 13.0, 14.0)], [(1, 10.0, 10.0)], gate=3.0)
    assert (fe.missed, fe.false_alarms, fe.matches) == (1, 1, ())


def test_unconfirmed_rows_are_ignored(tmp_path):
    truth = write(tmp_path / "truth.csv", "frame,target_id,x,y\n0,1,10,10\n1,1,11,10\n")
    tracks = write(tmp_path / "tracks.csv", """
frame,track_id,x,y,confirmed,score
0,5,10,10,0,0.1
0,6,90,90,0,0.1
1,5,11,10,1,0.9
""")
    r = evaluate(tracks, truth)
    assert (r.matches, r.misses, r.false_positives) == (1, 1, 0)
    assert read_points(tracks, "track_id", confirmed_only=True) == {1: [(5, 11.0, 10.0)]}
    assert len(read_points(tracks, "track_id")[0]) == 2


def test_hidden_truth_is_neither_missed_nor_a_false_alarm(tmp_path):
    truth = write(tmp_path / "truth.csv", """
frame,target_id,x,y,visible
0,1,10,10,1
0,2,50,50,1
1,1,11,10,1
1,2,50,51,0
2,1,12,10,1
2,2,50,52,0
""")
    tracks = write(tmp_path / "tracks.csv", """
frame,track_id,x,y
0,5,10,10
0,6,50,50
1,5,11,10
1,6,50,51.5
2,5,12,10
2,7,50,30
""")
    r = evaluate(tracks, truth, all_rows=True)  # no 'confirmed' column: every row counts
    assert r.truth_points == 4 and r.matches == 4 and r.misses == 0
    assert r.ignored == 1  # track 6 on hidden target 2 in frame 1
    assert r.false_positives == 1  # track 7 in frame 2 is 22 px from the hidden target
    assert [(t.target_id, t.frames, t.p_d) for t in r.per_target] == [(1, 3, 1.0), (2, 1, 1.0)]
    fe = frame_errors([(6, 50, 51.5)], [], hidden=[(2, 50, 51)])
    assert (fe.missed, fe.false_alarms) == (0, 0)


def test_confirmation_latency(tmp_path):
    truth = write(tmp_path / "truth.csv", "frame,target_id,x,y\n" + "".join(
        f"{f},1,{10 + f},10\n" for f in range(2, 8)) + "".join(
        f"{f},2,60,{30 + f}\n" for f in range(4, 8)) + "".join(
        f"{f},3,200,200\n" for f in range(0, 8)))
    tracks = write(tmp_path / "tracks.csv", "frame,track_id,x,y,confirmed\n" + "".join(
        f"{f},9,{10 + f},10,{int(f >= 5)}\n" for f in range(2, 8)) + "".join(
        f"{f},4,60,{30 + f},1\n" for f in range(4, 8)))
    r = evaluate(tracks, truth)
    lat = {t.target_id: t.latency for t in r.per_target}
    assert lat[1] == 3 and lat[2] == 0 and math.isnan(lat[3])  # target 3 is never found
    assert r.latency_mean == 1.5
    assert "target" in format_table(r) and format_table(r).count("\n") == 9  # 7 header lines + 3 targets


def test_pd_per_target_and_pf():
    truth = {0: [(1, 0.0, 0.0)], 1: [(1, 1.0, 0.0), (2, 40.0, 40.0)], 2: [(1, 2.0, 0.0), (2, 41.0, 40.0)],
             3: [(1, 3.0, 0.0)]}
    tracks = {0: [(5, 0.0, 0.0)], 1: [(5, 1.0, 0.0), (6, 40.0, 40.0), (8, 90.0, 0.0)],
              2: [(6, 41.0, 40.0), (8, 91.0, 0.0)], 3: [(5, 3.0, 0.0)]}
    r = evaluate_points(tracks, truth)
    assert {t.target_id: t.p_d for t in r.per_target} == {1: 0.75, 2: 1.0}  # k_i / T_i = 3/4, 2/2
    assert r.false_positives == 2 and r.p_f == pytest.approx(2 / (6 + 2))
    assert r.pd == pytest.approx(5 / 6) and r.fa_per_frame == pytest.approx(2 / 4)


def test_frame_errors_on_a_hand_made_frame():
    tracks = [(1, 0.0, 0.0), (2, 10.0, 10.0), (3, 50.0, 50.0), (4, 11.0, 10.0)]
    truth = [(7, 0.5, 0.0), (8, 10.0, 12.0), (9, 100.0, 100.0)]
    fe = frame_errors(tracks, truth, gate=3.0)
    # 8 can take track 2 (2 px) or 4 (~2.24 px): optimal total picks 2; tracks 3 and 4 are false alarms
    assert sorted(fe.matches) == [(1, 7, 0.5), (2, 8, 2.0)]
    assert (fe.missed, fe.false_alarms) == (1, 2)
    assert fe.cle_mean == pytest.approx(1.25)
    assert math.isnan(frame_errors([], truth).cle_mean)


@pytest.mark.parametrize("text, message", [
    ("frame,target_id,x,y\n0,1,10,10\n1,1,abc,10\n", "truth.csv:3: column 'x': 'abc' is not a number"),
    ("frame,target_id,x,y\n0,1,10,10\n\n1.5,1,3,10\n", "truth.csv:4: column 'frame': '1.5' is not an integer"),
    ("frame,target_id,x,y\n0,1,10\n", "truth.csv:2: column 'y': empty"),
    ("frame,target_id,x,y,visible\n0,1,10,10,maybe\n", "truth.csv:2: column 'visible': 'maybe' is not 0 or 1"),
    ("frame,target_id,x,y\n0,1,10,10\n0,1,12,10\n", "truth.csv:3: column 'target_id': 1 repeated in frame 0"),
    ("frame,id,x,y\n0,1,10,10\n", "truth.csv:1: missing column 'target_id'"),
])
def test_truth_errors_name_file_line_and_column(tmp_path, text, message):
    truth = write(tmp_path / "truth.csv", text)
    tracks = write(tmp_path / "tracks.csv", "frame,track_id,x,y\n")
    with pytest.raises(TruthError) as err:
        evaluate(tracks, truth)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_empty_files_are_zero_rows(tmp_path):
    empty = write(tmp_path / "tracks.csv", "")
    truth = write(tmp_path / "truth.csv", "frame,target_id,x,y\n0,1,10,10\n")
    r = evaluate(empty, truth)
    assert (r.frames, r.misses, r.pd) == (1, 1, 0.0)
    assert json.dumps(r.to_dict(), allow_nan=False)
    with pytest.raises(TruthError, match="none.csv: no truth rows"):  # nothing to score against
        evaluate(empty, write(tmp_path / "none.csv", "frame,target_id,x,y\n"))
    r = evaluate_points({}, {})  # in memory (a run over frames without truth): zeros, no error
    assert (r.frames, r.truth_points, r.per_target) == (0, 0, ())
    assert json.dumps(r.to_dict(), allow_nan=False)
