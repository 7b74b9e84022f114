"""Tracking metrics against ground truth: motmetrics numbers, CLE, Pd / p_f, latency, CSV errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from wfviz.evaluate import (EvalResult, TruthError, evaluate, evaluate_points, format_table, frame_errors,
                            read_points, read_truth)

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


# --- matching with extended targets: the truth's box (w, h) --------------------------------------

# one 23 x 14 px target at (100, 50), as the Svanstrom helicopters: grown by 0.5 px a side, the box
# holds |dx| <= 12, |dy| <= 7.5
BOXED = """
frame,target_id,x,y,w,h
0,1,100,50,23,14
1,1,100,50,23,14
2,1,100,50,23,14
3,1,100,50,23,14
"""
BOXED_TRACKS = """
frame,track_id,x,y,confirmed
0,5,108,50,1
1,5,100,58,1
2,5,112,57.5,1
3,5,112.1,50,1
"""


def test_track_inside_the_truth_box_matches_beyond_the_gate(tmp_path):
    truth, tracks = write(tmp_path / "truth.csv", BOXED), write(tmp_path / "tracks.csv", BOXED_TRACKS)
    r = evaluate(tracks, truth)  # 8 px right: in the box; 8 px down: out; the grown corner: in; 12.1 px: out
    assert (r.matches, r.misses, r.false_positives) == (2, 2, 2)
    assert r.match_rule == "gate 3 px or inside the truth box (w,h) grown 0.5 px a side"
    assert r.cle_mean == pytest.approx((8 + math.hypot(12, 7.5)) / 2)  # errors stay centre distances
    assert format_table(r).splitlines()[0] == f"frames 4   truth points 4   {r.match_rule}"
    gate_only = evaluate(tracks, truth, use_boxes=False)
    assert (gate_only.matches, gate_only.false_positives, gate_only.match_rule) == (0, 4, "gate 3 px")
    t = read_truth(truth)
    assert t.boxes == {f: {1: (23.0, 14.0)} for f in range(4)}
    assert frame_errors([(5, 108.0, 50.0)], t.shown[0], 3.0, (), t.boxes[0]).matches == ((5, 1, 8.0),)
    assert frame_errors([(5, 100.0, 58.0)], t.shown[1], 3.0, (), t.boxes[1]).false_alarms == 1
    assert frame_errors([(5, 108.0, 50.0)], t.shown[0], 3.0).matches == ()  # no boxes given: the gate


def test_box_rule_still_assigns_by_distance_to_the_centre():
    truth = {0: [(1, 100.0, 50.0), (2, 110.0, 50.0)]}
    boxes = {0: {1: (23.0, 14.0), 2: (23.0, 14.0)}}
    fe = frame_errors([(5, 107.0, 50.0)], truth[0], 3.0, (), boxes[0])  # in both boxes, 3 px from target 2
    assert fe.matches == ((5, 2, 3.0),) and (fe.missed, fe.false_alarms) == (1, 0)
    fe = frame_errors([(5, 101.0, 50.0), (6, 109.0, 50.0)], truth[0], 3.0, (), boxes[0])
    assert sorted(fe.matches) == [(5, 1, 1.0), (6, 2, 1.0)]
    r = evaluate_points({0: [(5, 101.0, 50.0), (6, 94.0, 50.0)]}, {0: truth[0][:1]}, 3.0, boxes=boxes)
    assert (r.matches, r.false_positives, r.cle_mean) == (1, 1, 1.0)  # one target, one match: the nearer


def test_box_of_a_hidden_target_ignores_a_track_inside_it(tmp_path):
    truth = write(tmp_path / "truth.csv", """
frame,target_id,x,y,visible,w,h
0,1,100,50,1,23,14
0,2,200,50,0,23,14
1,1,100,50,1,,
1,2,200,50,0,,
""")
    tracks = write(tmp_path / "tracks.csv", "frame,track_id,x,y\n0,6,208,50\n1,6,208,50\n")
    r = evaluate(tracks, truth, all_rows=True)
    assert (r.ignored, r.false_positives, r.misses) == (1, 1, 2)  # frame 1 has no box: a false alarm
    assert "inside the truth box" in r.match_rule
    assert evaluate(tracks, truth, all_rows=True, use_boxes=False).ignored == 0
    t = read_truth(truth)
    assert t.boxes == {0: {1: (23.0, 14.0), 2: (23.0, 14.0)}}
    fe = frame_errors([(6, 208.0, 50.0)], t.shown[0], 3.0, t.hidden[0], t.boxes[0])
    assert (fe.missed, fe.false_alarms) == (1, 0)


def test_truth_without_boxes_scores_as_before(tmp_path):
    rows = "".join(f"{f},1,{10 + f},20\n{f},2,80,{50 + 2 * f}\n" for f in range(10))
    plain = write(tmp_path / "plain.csv", "frame,target_id,x,y\n" + rows)
    empty = write(tmp_path / "empty.csv", "frame,target_id,x,y,w,h\n" + rows.replace("\n", ",,\n"))
    tracks = write(tmp_path / "tracks.csv", "frame,track_id,x,y,confirmed\n" + "".join(
        f"{f},{100 + i},{x + 2.5},{y},1\n" for f, pts in TRUTH.items() for i, x, y in pts))
    a, b = evaluate(tracks, plain), evaluate(tracks, empty)  # w,h columns left empty: no boxes
    assert a == b and a.match_rule == "gate 3 px" and read_truth(empty).boxes == {}
    assert format_table(a).splitlines()[0] == "frames 10   truth points 20   gate 3 px"
    assert a.to_dict() == evaluate_points(shifted(TRUTH, 2.5, 0), TRUTH).to_dict()
    shown, hidden = read_truth(plain)  # still unpacks, and equals, as (visible, hidden)
    assert (shown, hidden) == read_truth(plain) and shown == TRUTH and hidden == {}


@pytest.mark.parametrize("text, message", [
    ("frame,target_id,x,y,w,h\n0,1,10,10,5,\n", "truth.csv:2: column 'h': empty"),
    ("frame,target_id,x,y,w,h\n0,1,10,10,-5,4\n", "truth.csv:2: column 'w': -5 is negative"),
    ("frame,target_id,x,y,w,h\n0,1,10,10,5,big\n", "truth.csv:2: column 'h': 'big' is not a number"),
])
def test_bad_box_sizes_name_line_and_column(tmp_path, text, message):
    with pytest.raises(TruthError) as err:
        read_truth(write(tmp_path / "truth.csv", text))
    assert str(err.value).startswith(message)


def test_score_sink_and_frame_truth_use_the_boxes(tmp_path):
    from types import SimpleNamespace

    from wfviz.sinks import FrameTruth, RunEnd, ScoreSink, Step

    truth = read_truth(write(tmp_path / "truth.csv", BOXED))
    sink = ScoreSink(truth, 3.0)
    steps = []
    for f, (x, y) in enumerate([(108, 50), (100, 58), (112, 57.5), (112.1, 50)]):
        track = SimpleNamespace(track_id=5, x=float(x), y=float(y), confirmed=True)
        steps.append(Step(SimpleNamespace(index=f), (SimpleNamespace(tracks=[track]),), 0.0, 0.0))
        sink.publish(steps[-1])
    end = RunEnd(4, None)
    sink.conclude(end)
    per_frame = [s.facts.get(FrameTruth).errors.matches for s in steps]
    assert per_frame == [((5, 1, 8.0),), (), ((5, 1, math.hypot(12, 7.5)),), ()]
    assert end.facts.get(EvalResult).matches == 2 and "truth box" in end.facts.get(EvalResult).match_rule
    plain = ScoreSink((truth.shown, truth.hidden), 3.0)  # a bare (shown, hidden) pair: the gate only
    for s in steps:
        plain.publish(Step(s.frame, s.results, 0.0, 0.0))
    plain.conclude(RunEnd(4, None))
    assert plain.scores is not None and (plain.scores.matches, plain.scores.match_rule) == (0, "gate 3 px")


def test_cli_eval_prints_and_writes_the_rule_and_takes_no_boxes(tmp_path):
    from typer.testing import CliRunner

    from wfviz.cli import app

    truth, tracks = write(tmp_path / "truth.csv", BOXED), write(tmp_path / "tracks.csv", BOXED_TRACKS)
    out = tmp_path / "s.json"
    r = CliRunner().invoke(app, ["eval", str(tracks), str(truth), "--json", str(out)])
    assert r.exit_code == 0, r.output
    assert "truth points 4   gate 3 px or inside the truth box (w,h) grown 0.5 px a side" in r.output
    d = json.loads(out.read_text())
    assert d["match_rule"].startswith("gate 3 px or inside the truth box") and d["matches"] == 2
    r = CliRunner().invoke(app, ["eval", str(tracks), str(truth), "--json", str(out), "--no-boxes", "--gate", "8"])
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert (d["match_rule"], d["matches"], d["gate"]) == ("gate 8 px", 2, 8.0)  # 8 px right and 8 px down
    assert r.output.splitlines()[0] == "frames 4   truth points 4   gate 8 px"


def test_compare_disagreements_match_inside_the_box():
    from wfviz.compare.differences import Disagreements

    shown, boxes = [(1, 100.0, 50.0)], {1: (23.0, 14.0)}
    runs = [[(5, 108.0, 50.0)], [(7, 100.0, 50.5)]]  # run a 8 px off but in the box, run b on the centre
    cmp = Disagreements(["a", "b"], gate=3.0).update(0, runs, shown, (), boxes)
    assert cmp.marks == () and [r.pd for r in cmp.runs] == [1.0, 1.0]
    cmp = Disagreements(["a", "b"], gate=3.0).update(0, runs, shown, ())  # the gate only: a misses
    assert [m.kind for m in cmp.marks] == ["missed", "false_track"] and cmp.runs[0].pd == 0.0
