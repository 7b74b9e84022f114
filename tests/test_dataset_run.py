"""`wfviz run DATASET`: the clips found in a folder or a list file, one row per clip in
results.csv, the summary, resume, goal expressions, --record-failing, --jobs 2 against --jobs 1,
and one-line refusals of bad inputs."""

from __future__ import annotations

import math
import operator
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import WFVIZ, invoke, one_line_error, rows, temporaries, wfviz
from wfviz.dataset.discover import discover, labels
from wfviz.dataset.goals import METRICS, parse_goal

SCORE_COLUMNS = ("frames", "status", "pd", "pd_settled", "fa_per_frame", "mota", "idf1", "hota", "id_switches",
                 "cle_rms", "goal", "dominant_miss_cause", "matched", "not_detected", "latency", "config_hash")


def _write_dataset(root: Path) -> Path:
    """setA/u and setB/u (uniform-50hz, 14 frames, two seeds: their labels collide), low/frames
    with low/truth.csv beside it (lowsnr-tbd, never detected: Pd 0), notruth (frames only), a
    clip folder of two unreadable images (fails), a set README and a 1-image folder (no clips)."""
    from wfviz.synth.scenarios import make_scenario, write_scenario

    write_scenario(make_scenario("uniform-50hz", seed=0, n_frames=14), root / "setA" / "u")
    write_scenario(make_scenario("uniform-50hz", seed=1, n_frames=14), root / "setB" / "u")
    write_scenario(make_scenario("lowsnr-tbd", seed=0, n_frames=20), root / "low" / "frames")
    shutil.move(root / "low" / "frames" / "truth.csv", root / "low" / "truth.csv")
    notruth = root / "setB" / "notruth"
    notruth.mkdir()
    for f in sorted((root / "setB" / "u").glob("frame_*.png"))[:8]:
        shutil.copy(f, notruth / f.name)
    broken = root / "broken"
    broken.mkdir()
    for i in range(2):
        (broken / f"frame_{i:06d}.png").write_bytes(b"not a png")
    (root / "setA" / "README.md").write_text("# set A\n")
    (root / "preview").mkdir()
    shutil.copy(root / "setA" / "u" / "frame_000000.png", root / "preview" / "only.png")
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_dataset(tmp_path_factory.mktemp("data") / "data")


@pytest.fixture(scope="module")
def first(dataset: Path, tmp_path_factory: pytest.TempPathFactory):
    """The dataset run once in this process (--jobs 1): its output folder and CLI result."""
    out = tmp_path_factory.mktemp("run") / "R"
    r = invoke("run", str(dataset), "--out", str(out), "--jobs", "1")
    assert r.exit_code == 0, r.output
    return out, r


def _by_label(path: Path) -> dict[str, dict[str, str]]:
    return {r["label"]: r for r in rows(path)}


# -- discovery ---------------------------------------------------------------------------------------

def test_a_folder_is_searched_for_clips(dataset: Path) -> None:
    clips = {c.label: c for c in discover(dataset)}
    assert sorted(clips) == ["broken", "low", "notruth", "setA-u", "setB-u"]  # colliding names: parent put in front
    assert clips["low"].spec == str(dataset / "low" / "frames")  # a frames folder takes its parent's name
    assert clips["low"].truth == str(dataset / "low" / "truth.csv")  # truth beside it
    assert clips["setA-u"].truth == str(dataset / "setA" / "u" / "truth.csv")
    assert clips["notruth"].truth == ""
    one = discover(dataset / "setA" / "u")  # a clip folder is a dataset of one
    assert [(c.label, c.truth) for c in one] == [("u", str(dataset / "setA" / "u" / "truth.csv"))]


def test_videos_and_stacks_are_clips_and_the_output_folder_is_not_searched(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    np.save(tmp_path / "a" / "stack.npy", np.zeros((3, 20, 20), np.uint16))
    (tmp_path / "a" / "truth.csv").write_text("frame,target_id,x,y\n0,1,2,3\n")
    (tmp_path / "b.avi").write_bytes(b"")
    (tmp_path / ".hidden").mkdir()
    np.save(tmp_path / ".hidden" / "x.npy", np.zeros((3, 20, 20), np.uint16))
    (tmp_path / "out").mkdir()
    np.save(tmp_path / "out" / "y.npy", np.zeros((3, 20, 20), np.uint16))
    found = discover(tmp_path, exclude=tmp_path / "out")
    assert [(c.label, Path(c.spec).name, Path(c.truth).name if c.truth else "") for c in found] == \
        [("stack", "stack.npy", "truth.csv"), ("b", "b.avi", "")]


def test_a_list_file_names_clips_relative_to_itself(dataset: Path, tmp_path: Path) -> None:
    listing = tmp_path / "clips.txt"
    rel = os.path.relpath(dataset, tmp_path)
    listing.write_text(f"# my clips\n{rel}/setA/u   # the first\n\n{rel}/low/frames={rel}/low/truth.csv\n"
                       f"synth:lowsnr-tbd:3\n{rel}/setB/notruth\n")
    found = discover(listing)
    assert [c.label for c in found] == ["u", "low", "lowsnr-tbd-3", "notruth"]
    assert Path(found[0].truth).resolve() == (dataset / "setA" / "u" / "truth.csv").resolve()
    assert Path(found[1].truth).resolve() == (dataset / "low" / "truth.csv").resolve()
    assert found[2].synthetic and found[2].truth == "" and found[3].truth == ""
    listing.write_text(f"{rel}/setA/u\n{rel}/nothing-here\n")
    with pytest.raises(ValueError, match=r"clips\.txt:2: .*nothing-here: no such clip"):
        discover(listing)
    listing.write_text(f"{rel}/setA/u={rel}/missing.csv\n")
    with pytest.raises(ValueError, match=r"clips\.txt:1: .*missing\.csv: no such truth file"):
        discover(listing)


_PART = st.sampled_from(["a", "b", "A", "frames", "c.d", "x y", ".e"])


@settings(max_examples=200, deadline=None, derandomize=True)
@given(paths=st.lists(st.tuples(st.lists(_PART, min_size=1, max_size=4), st.sampled_from(["", ".avi", ".npy"])),
                      min_size=1, max_size=8))
def test_labels_are_unique_and_plain_file_names(paths: list[tuple[list[str], str]]) -> None:
    specs = list(dict.fromkeys("/d/" + "/".join(parts) + ext for parts, ext in paths))
    got = labels(specs)
    assert len({g.lower() for g in got}) == len(specs), (specs, got)  # apart even where case is not
    assert all(g and "/" not in g and not g.startswith(".") for g in got), got


def test_no_clips_is_one_line_exit_2(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "README.md").write_text("nothing\n")
    one_line_error(wfviz("run", str(tmp_path / "empty"), "--out", str(tmp_path / "R")), "no clips found")
    assert not (tmp_path / "R").exists()


@pytest.mark.parametrize("case", ["missing", "not a dataset", "list names a missing clip", "out is a file",
                                  "out inside a clip", "out is the dataset", "no --out"])
def test_bad_inputs_are_refused_in_one_line(dataset: Path, tmp_path: Path, case: str) -> None:
    out = tmp_path / "R"
    dset = dataset
    words: tuple[str, ...]
    if case == "missing":
        dset, words = tmp_path / "nope", ("nope", "no such folder")
    elif case == "not a dataset":
        dset = tmp_path / "clips.csv"
        dset.write_text("a,b\n")
        words = ("clips.csv", "not a dataset")
    elif case == "list names a missing clip":
        dset = tmp_path / "clips.list"
        dset.write_text("gone/clip\n")
        words = ("clips.list:1", "no such clip")
    elif case == "out is a file":
        out.write_text("x")
        words = ("is a file",)
    elif case == "out inside a clip":
        out = dataset / "setA" / "u" / "R"
        words = ("inside the clip folder",)
    elif case == "out is the dataset":
        out = dataset
        words = ("is the dataset folder",)
    else:
        words = ("--out DIR is required",)
    before = sorted(p for p in dataset.rglob("*"))
    r = invoke("run", str(dset), *(["--out", str(out)] if case != "no --out" else []), "--jobs", "1")
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wfviz: error:"), r.stderr
    assert all(w in lines[0] for w in words), (words, lines[0])
    assert sorted(p for p in dataset.rglob("*")) == before


# -- goals -------------------------------------------------------------------------------------------

def test_goal_expressions() -> None:
    g = parse_goal("pd<0.9 or fa_per_frame>0.1")
    assert g.holds({"pd": 0.5, "fa_per_frame": 0.0}) and g.holds({"pd": 0.95, "fa_per_frame": 0.2})
    assert not g.holds({"pd": 0.95, "fa_per_frame": 0.05})
    assert not g.holds({"pd": math.nan, "fa_per_frame": 0.05})  # NaN: the condition is false
    both = parse_goal("pd >= 0.9 and fa_per_frame <= 0.1 or id_switches>3")  # and binds first
    assert both.holds({"pd": 0.1, "fa_per_frame": 1.0, "id_switches": 4})
    assert both.holds({"pd": 0.95, "fa_per_frame": 0.0, "id_switches": 0})
    assert not both.holds({"pd": 0.95, "fa_per_frame": 0.5, "id_switches": 0})
    assert parse_goal("hota!=1e-1 AND mota==-2.5").any_of[0][1].value == -2.5


_OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge, "==": operator.eq,
        "!=": operator.ne}
_CONDITION = st.tuples(st.sampled_from(METRICS), st.sampled_from(list(_OPS)),
                       st.sampled_from([-1.0, 0.0, 0.1, 0.5, 0.9, 1.0, 2.0, 2.5e-3]), st.sampled_from(["", " "]))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(groups=st.lists(st.lists(_CONDITION, min_size=1, max_size=3), min_size=1, max_size=3),
       scores=st.fixed_dictionaries({m: st.sampled_from([0.0, 0.1, 0.5, 1.0, 2.0, math.nan]) for m in METRICS}))
def test_goal_expressions_round_trip_and_agree_with_their_meaning(groups, scores) -> None:
    text = " or ".join(" and ".join(f"{m}{sp}{o}{sp}{v!r}" for m, o, v, sp in g) for g in groups)
    goal = parse_goal(text)
    assert parse_goal(str(goal)).any_of == goal.any_of
    expect = any(all(not math.isnan(scores[m]) and _OPS[o](scores[m], v) for m, o, v, _ in g) for g in groups)
    assert goal.holds(scores) == expect, (text, scores)


@pytest.mark.parametrize("bad", ["", "pd", "pd<", "pd<x", "pd=0.9", "speed<1", "pd<0.9 or", "pd<0.9 fa_per_frame>1",
                                 "(pd<0.9)", "pd<0.9; import os", "__import__('os')<1", "pd<0.9 xor mota>0"])
def test_bad_goal_expressions_are_refused(bad: str) -> None:
    with pytest.raises(ValueError, match="--record-failing"):
        parse_goal(bad)


def test_a_bad_expression_on_the_command_line_is_one_line_exit_2(dataset: Path, tmp_path: Path) -> None:
    one_line_error(wfviz("run", str(dataset), "--out", str(tmp_path / "R"), "--record-failing", "pd<<0.9"),
                   "--record-failing", "pd<<0.9")
    assert not (tmp_path / "R").exists()


# -- a run -------------------------------------------------------------------------------------------

def test_one_row_per_clip_and_the_summary(first) -> None:
    out, r = first
    got = _by_label(out / "results.csv")
    assert list(got) == ["broken", "low", "setA-u", "notruth", "setB-u"]  # in path order
    assert got["broken"]["status"].startswith("failed: ") and "frame_000000.png" in got["broken"]["status"]
    for label in ("low", "setA-u", "setB-u"):
        row = got[label]
        assert row["status"] == "ok" and row["config_hash"] and row["truth"].endswith("truth.csv"), row
        assert (out / "tracks" / f"{label}.csv").is_file() and (out / "explain" / f"{label}.csv").is_file()
        visible = sum(int(row[c]) for c in ("matched", "outside_circle", "outside_region", "not_detected", "lost",
                                            "not_associated", "latency", "not_confirmed"))
        assert math.isclose(float(row["pd"]), int(row["matched"]) / visible, abs_tol=1e-4), row
    assert float(got["setA-u"]["pd"]) > 0.5 and got["low"]["pd"] == "0.0000"
    assert got["low"]["dominant_miss_cause"] == "not_detected" and got["low"]["goal"] == "no"
    assert got["notruth"]["status"] == "ok" and got["notruth"]["pd"] == "" and got["notruth"]["goal"] == ""
    assert int(got["notruth"]["frames"]) == 8 and (out / "tracks" / "notruth.csv").is_file()
    assert not (out / "explain" / "notruth.csv").exists() and not (out / "recordings").exists()
    assert "clips                5" in r.stdout and "scored               3" in r.stdout
    assert "goals met" in r.stdout and "failed: broken:" in r.stdout
    summary = (out / "summary.md").read_text()
    assert "| setA-u | 14 |" in summary and "Where Pd went" in summary and "dominant miss cause" in summary
    assert not temporaries(out)


def test_a_rerun_skips_the_clips_done(first, tmp_path: Path, dataset: Path) -> None:
    out = tmp_path / "R"
    shutil.copytree(first[0], out)
    before = _by_label(out / "results.csv")
    mtimes = {p.name: p.stat().st_mtime_ns for p in (out / "tracks").iterdir()}
    (out / "tracks" / "setB-u.csv").unlink()  # its row alone is not enough: run again
    r = invoke("run", str(dataset), "--out", str(out), "--jobs", "1")
    assert r.exit_code == 0, r.output
    after = _by_label(out / "results.csv")
    assert "3 of 5 clips already done" in r.stderr  # broken (failed) and setB-u (tracks gone) run again
    for label in ("low", "notruth", "setA-u"):
        assert after[label] == before[label]
        assert (out / "tracks" / f"{label}.csv").stat().st_mtime_ns == mtimes[f"{label}.csv"]
    assert (out / "tracks" / "setB-u.csv").is_file()
    assert {k: after["setB-u"][k] for k in SCORE_COLUMNS} == {k: before["setB-u"][k] for k in SCORE_COLUMNS}
    assert after["broken"]["status"].startswith("failed")


def test_a_changed_configuration_reruns_every_clip(first, tmp_path: Path, dataset: Path) -> None:
    out = tmp_path / "R"
    shutil.copytree(first[0], out)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[detection]\nk_sigma = 6.0\n")
    r = invoke("run", str(dataset), "--out", str(out), "--jobs", "1", "--config", str(cfg))
    assert r.exit_code == 0, r.output
    assert "4 clips done with another tracker, configuration or gate are run again" in r.stderr
    before, after = _by_label(first[0] / "results.csv"), _by_label(out / "results.csv")
    assert {r["config_hash"] for r in after.values()} != {r["config_hash"] for r in before.values()}
    assert len({r["config_hash"] for r in after.values()}) == 1
    assert "already done" not in r.stderr


def test_record_failing_records_only_the_failing_clips(first, tmp_path: Path, dataset: Path) -> None:
    out = tmp_path / "R"
    shutil.copytree(first[0], out)
    r = invoke("run", str(dataset), "--out", str(out), "--jobs", "1", "--record-failing", "pd<0.5")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (out / "recordings").iterdir()) == ["low.rrd"]
    got = _by_label(out / "results.csv")
    assert got["low"]["recording"].endswith("low.rrd") and got["setA-u"]["recording"] == ""
    assert "1 in" in r.stdout  # recordings: 1 in .../recordings
    from rerun.chunk import RrdReader  # the recording has the truth drawn in

    paths = {str(c.entity_path) for c in RrdReader(out / "recordings" / "low.rrd").stream()}
    assert any("truth" in p for p in paths), sorted(paths)


def test_jobs_2_gives_the_rows_of_jobs_1(first, tmp_path: Path, dataset: Path) -> None:
    out = tmp_path / "R2"
    proc = wfviz("run", str(dataset), "--out", str(out), "--jobs", "2")
    assert proc.returncode == 0, proc.stderr
    one, two = _by_label(first[0] / "results.csv"), _by_label(out / "results.csv")
    assert list(two) == list(one)
    for label in one:
        a, b = one[label], two[label]
        assert {k: b[k] for k in SCORE_COLUMNS if k in b} == {k: a[k] for k in SCORE_COLUMNS if k in a}, label
    for f in (first[0] / "tracks").iterdir():
        assert (out / "tracks" / f.name).read_bytes() == f.read_bytes(), f.name


def test_a_second_run_on_the_same_folder_is_refused(first, tmp_path: Path, dataset: Path) -> None:
    import fcntl

    out = tmp_path / "R"
    shutil.copytree(first[0], out)
    before = _by_label(out / "results.csv")
    fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a running `wfviz run` holds it
        r = invoke("run", str(dataset), "--out", str(out), "--jobs", "1")
    finally:
        os.close(fd)
    assert r.exit_code == 2 and "in use by another wfviz run" in r.stderr, r.output
    assert _by_label(out / "results.csv") == before


def test_ray_without_ray_is_refused(dataset: Path, tmp_path: Path) -> None:
    try:
        import ray  # noqa: F401
        pytest.skip("Ray is installed: --ray is not refused")
    except ImportError:
        pass
    one_line_error(wfviz("run", str(dataset), "--out", str(tmp_path / "R"), "--ray"), "needs Ray")
    assert not (tmp_path / "R").exists()


def test_ctrl_c_keeps_the_rows_done(tmp_path: Path, dataset: Path) -> None:
    """SIGINT while clips run: the rows finished are kept, no temporary is left, exit 130, and
    the same command then runs only the rest."""
    data = tmp_path / "many"
    data.mkdir()
    for i in range(8):
        shutil.copytree(dataset / "setA" / "u", data / f"c{i}")
    out = tmp_path / "R"
    proc = subprocess.Popen([*WFVIZ, "run", str(data), "--out", str(out), "--jobs", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not ((out / "results.csv").is_file() and rows(out / "results.csv")):  # a row is written
        assert time.monotonic() < deadline and proc.poll() is None, "no row written in time"
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    done = rows(out / "results.csv")
    assert proc.returncode == 130, (stdout, stderr)
    assert 1 <= len(done) < 8 and all(r["status"] == "ok" for r in done)
    assert "interrupted by SIGINT" in stdout and "resumes" in stdout
    assert not temporaries(out)
    again = invoke("run", str(data), "--out", str(out), "--jobs", "1")
    assert again.exit_code == 0 and f"{len(done)} of 8 clips already done" in again.stderr
    assert len(rows(out / "results.csv")) == 8


# -- the pools ---------------------------------------------------------------------------------------

def test_the_pools_run_any_function_and_stream_results() -> None:
    """Inline and LocalPool run a picklable top-level function, return results in task order and
    hand each to ``on_result`` as it finishes; a worker that dies fails its task only."""
    from wfviz.pools import Inline, LocalPool

    seen: list[tuple[int, int]] = []
    assert Inline(abs).run([-3, 1, -2], lambda: False, lambda i, r: seen.append((i, r))) == [3, 1, 2]
    assert seen == [(0, 3), (1, 1), (2, 2)]
    pool = LocalPool(2, abs, lambda task, why: f"{task}: {why}")
    try:
        seen.clear()
        assert pool.run([-3, 1, -2, 5], lambda: False, lambda i, r: seen.append((i, r))) == [3, 1, 2, 5]
        assert sorted(seen) == [(0, 3), (1, 1), (2, 2), (3, 5)]
    finally:
        pool.close()
    dying = LocalPool(1, os._exit, lambda task, why: f"{task}: {why}")
    try:
        assert dying.run([7], lambda: False) == ["7: the worker process died (exit code 7)"]
    finally:
        dying.close()
