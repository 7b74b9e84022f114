"""The CLI end to end: demo recording read back with Rerun's own reader, track, config."""

from __future__ import annotations

import csv
import re
import tomllib
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from conftest import wfviz
from wfviz.config import config_from_dict
from wfviz.evaluate import read_points, score_targets
from wfviz.trackers.gewc.config import GEWCConfig

N_FRAMES = 120  # covers the crossing (frames 73-83) and target 4's birth (frame 30)
STAGES = ["defects", "mask", "horizon", "suppress", "detect", "associate", "centroid", "kalman", "total"]


def rrd_index(path: Path) -> tuple[dict[str, set[int]], set[str]]:
    """{entity: frames with data} and the set of entities with static data."""
    frames: dict[str, set[int]] = defaultdict(set)
    static: set[str] = set()
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
            continue
        batch = chunk.to_record_batch()
        if "frame" in batch.schema.names:
            frames[chunk.entity_path].update(batch.column("frame").to_pylist())
    return frames, static


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    cwd = tmp_path_factory.mktemp("demo")
    proc = wfviz("demo", "--frames", str(N_FRAMES), cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    rrd = cwd / "recordings" / "demo-gewc.rrd"
    return cwd, rrd, proc.stdout


def test_demo_writes_outputs_and_summary(demo_run):
    cwd, rrd, stdout = demo_run
    assert rrd.exists() and (cwd / "recordings" / "demo-gewc.csv").exists()
    assert not list((cwd / "recordings").glob("*.part")) and not list((cwd / "recordings").glob(".*wfviz-part"))
    assert f"{N_FRAMES} frames" in stdout and "rerun recordings/demo-gewc.rrd" in stdout


def test_recording_has_every_required_entity_at_expected_frames(demo_run):
    _, rrd, _ = demo_run
    frames, static = rrd_index(rrd)
    every = set(range(N_FRAMES))
    for path in ["/camera/image", "/camera/detections", "/camera/predictions", "/camera/gates",
                 "/camera/centroids", "/camera/tracks", "/suppressed/image"]:
        assert frames[path] == every, path
    for stage in STAGES:
        assert frames[f"/timing/{stage}"] == every, stage
    assert frames["/camera/horizon"] == set(range(0, N_FRAMES, 10))
    assert {"/camera/mask", "/config", "/"} <= static
    assert "/log" in frames
    gewc = [p for p in frames if p.startswith("/gewc/")]
    innov = [p for p in frames if p.startswith("/kalman/") and p.endswith("/innovation")]
    cov = [p for p in frames if p.startswith("/kalman/") and p.endswith("/cov_trace")]
    # four targets, each tracked by one confirmed track for most of the clip
    assert sum(len(frames[p]) > 60 for p in gewc) >= 4
    assert sum(len(frames[p]) > 60 for p in innov) >= 4 and sum(len(frames[p]) > 60 for p in cov) >= 4
    assert RrdReader(rrd).blueprints(), "default blueprint is embedded"
    # the demo scores itself against its truth
    for path in ["/camera/truth", "/eval/cle", "/eval/missed", "/eval/false_alarms"]:
        assert frames[path] == every, path
    assert "/eval/summary" in static


def test_log_tells_births_confirmations_and_meetings(demo_run):
    _, rrd, _ = demo_run
    texts = []
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path == "/log":
            col = chunk.to_record_batch().column("TextLog:text").to_pylist()
            texts += [t for row in col for t in (row or [])]
    joined = "\n".join(texts)
    for word in ("started at", "within the safety distance", "separated"):
        assert word in joined, word
    assert re.search(r"confirmed after \d+ hits", joined)


def test_demo_tracks_every_target_without_identity_swap(demo_run):
    cwd, _, _ = demo_run
    with open(cwd / "recordings" / "demo-gewc.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:5] == ["frame", "track_id", "x", "y", "confirmed"]
    tracks = read_points(cwd / "recordings" / "demo-gewc.csv", "track_id", confirmed_only=True)
    truth = read_points(cwd / "recordings" / "demo-gewc-truth.csv", "target_id")
    scores = score_targets(tracks, truth, gate=3.0)
    assert len(scores) == 4
    mains = set()
    for s in scores:
        assert s.matched >= s.frames - 8, (s.target_id, s.matched, s.frames)  # confirmation latency
        assert s.id_switches == 0, s
        mains.add(s.main_track)
    assert len(mains) == 4
    # every confirmed track is one of the four (no false confirmed track)
    confirmed_ids = {int(r["track_id"]) for r in rows if r["confirmed"] == "1"}
    assert confirmed_ids == mains
    errors = np.concatenate([s.errors for s in scores])
    print(f"CLE over {errors.size} points: RMS {np.sqrt(np.mean(errors**2)):.3f} px, "
          f"p99 {np.percentile(errors, 99):.3f} px, max {errors.max():.3f} px")
    assert np.sqrt(np.mean(errors**2)) < 0.6
    assert np.mean(errors <= 1.5) >= 0.99 and errors.max() <= 2.0


def test_image_every_and_no_images(tmp_path):
    clip = tmp_path / "clip.npy"
    from wfviz.synth.demo import demo_clip
    np.save(clip, np.stack([f.image for f in demo_clip().frames(0, 12)]))
    out = tmp_path / "a.rrd"
    proc = wfviz("record", str(clip), "-o", str(out), "--image-every", "5", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    frames, _ = rrd_index(out)
    assert frames["/camera/image"] == {0, 5, 10} and frames["/suppressed/image"] == {0, 5, 10}
    assert frames["/camera/detections"] == set(range(12))
    assert (tmp_path / "a.csv").exists()
    proc = wfviz("record", str(clip), "-o", str(tmp_path / "b.rrd"), "--no-images", "--start", "2",
                 "--stop", "9", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    frames, _ = rrd_index(tmp_path / "b.rrd")
    assert "/camera/image" not in frames and frames["/camera/predictions"] == set(range(2, 9))


def test_default_output_name_and_track_command(tmp_path):
    from wfviz.synth.demo import demo_clip
    folder = tmp_path / "scene"
    demo_clip().save(folder, 0, 10)
    proc = wfviz("record", str(folder), "--no-images", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "recordings" / "scene-gewc.rrd").exists()
    assert (tmp_path / "recordings" / "scene-gewc.csv").exists()
    proc = wfviz("track", str(folder), "--tracks", str(tmp_path / "t.csv"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    a = (tmp_path / "t.csv").read_text()
    b = (tmp_path / "recordings" / "scene-gewc.csv").read_text()
    assert a == b and a.startswith("frame,track_id,x,y,confirmed")


def test_config_prints_loadable_defaults(tmp_path):
    proc = wfviz("config", cwd=tmp_path)
    assert proc.returncode == 0
    assert config_from_dict(tomllib.loads(proc.stdout), GEWCConfig) == GEWCConfig()
    assert "q = 0.2" in proc.stdout and "r = 0.4" in proc.stdout and "confirm_hits = 6" in proc.stdout


def test_bad_input_is_one_line_error(tmp_path):
    proc = wfviz("record", str(tmp_path / "missing.avi"), cwd=tmp_path)
    assert proc.returncode == 2
    assert "missing.avi" in proc.stderr and "Traceback" not in proc.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("[kalman]\nqq = 1\n")
    proc = wfviz("track", str(tmp_path), "--tracks", "x.csv", "--config", str(bad), cwd=tmp_path)
    assert proc.returncode == 2 and "did you mean 'q'" in proc.stderr


def test_eval_command_table_and_json(demo_run, tmp_path):
    cwd, _, stdout = demo_run
    assert "MOTA" in stdout and "IDF1" in stdout  # the demo prints its scores
    tracks, truth = cwd / "recordings" / "demo-gewc.csv", cwd / "recordings" / "demo-gewc-truth.csv"
    out = tmp_path / "scores.json"
    proc = wfviz("eval", str(tracks), str(truth), "--json", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "MOTA" in proc.stdout and "CLE" in proc.stdout
    import json
    data = json.loads(out.read_text())
    assert data["id_switches"] == 0 and data["mota"] > 0.9 and data["false_positives"] == 0
    proc = wfviz("eval", str(tracks), str(tmp_path / "nope.csv"), cwd=tmp_path)
    assert proc.returncode == 2 and "nope.csv" in proc.stderr


def test_record_with_truth_logs_eval_entities(tmp_path):
    from wfviz.synth.demo import demo_clip
    folder = tmp_path / "scene"
    demo_clip().save(folder, 0, 15)
    proc = wfviz("record", str(folder), "-o", str(tmp_path / "r.rrd"), "--no-images",
                 "--truth", str(folder / "truth.csv"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    frames, static = rrd_index(tmp_path / "r.rrd")
    assert frames["/camera/truth"] == set(range(15)) and frames["/eval/missed"] == set(range(15))
    assert "/eval/summary" in static and "MOTA" in proc.stdout
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,target_id,x,y\n0,1,abc,3\n")
    proc = wfviz("record", str(folder), "-o", str(tmp_path / "s.rrd"), "--truth", str(bad), cwd=tmp_path)
    assert proc.returncode == 2 and "bad.csv:2" in proc.stderr and "'x'" in proc.stderr
    assert not (tmp_path / "s.rrd").exists() and not list(tmp_path.glob(".s.rrd.*wfviz-part"))


def test_bench_prints_per_stage_table(tmp_path):
    from wfviz.synth.demo import demo_clip
    clip = tmp_path / "clip.npy"
    np.save(clip, np.stack([f.image for f in demo_clip().frames(0, 8)]))
    proc = wfviz("bench", str(clip), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert "5 frames timed" in lines[0]  # 3 warm-up frames are not timed
    stages = [line.split()[0] for line in lines[2:-1]]
    assert stages[0] == "decode" and stages[-1] == "total" and "centroid" in stages
    assert not list(tmp_path.glob("*.csv")) and not list(tmp_path.glob("*.rrd"))  # writes nothing
    proc = wfviz("bench", str(clip), "--stop", "2", cwd=tmp_path)
    assert proc.returncode == 2 and "need more than 3 frames" in proc.stderr
