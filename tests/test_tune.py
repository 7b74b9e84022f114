"""`wfviz tune` through the CLI: a small study on short synthetic clips, its files, resume,
failing and interrupted trials, validation columns, the front-end cache and the reproduction
of the best trial with `wfviz track` + `wfviz eval`."""

from __future__ import annotations

import functools
import os
import re
import signal
import subprocess
import sys
import time
import tomllib
from collections import defaultdict
from pathlib import Path

import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from conftest import rows, wfviz as run_wfviz
from wfviz.cli import app
from wfviz.evaluate import evaluate
from wfviz.trackers import TRACKERS, config_class, default_space
from wfviz.tune.space import load_space, parse_space

TUNE = ["synth:fov70-maneuver:0", "synth:uniform-50hz:0"]
VALIDATE = "synth:fov70-four-targets:0"
STOP = "24"
SPACE = """
[detection]
k_sigma = { low = 3.0, high = 6.0 }
[tracking]
false_tracks_per_1000 = { low = 0.05, high = 20.0, log = true }
p_detect = { low = 0.6, high = 0.98 }
min_motion = { low = 0.5, high = 4.0 }
"""


wfviz = functools.partial(run_wfviz, timeout=600)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A 6-trial study (2 tune clips, 1 validation clip), then resumed to 8 trials."""
    cwd = tmp_path_factory.mktemp("tune")
    (cwd / "space.toml").write_text(SPACE)
    args = ["tune", *TUNE, "--validate", VALIDATE, "--out", "st", "--space", "space.toml",
            "--stop", STOP, "--workers", "1", "--seed", "3"]
    t0 = time.perf_counter()
    first = wfviz(*args, "--trials", "6", cwd=cwd)
    seconds = time.perf_counter() - t0
    assert first.returncode == 0, first.stderr
    six = rows(cwd / "st" / "trials.csv")
    second = wfviz(*args, "--trials", "8", cwd=cwd)
    assert second.returncode == 0, second.stderr
    return cwd, six, first, second, seconds


def test_study_files_and_columns(study):
    cwd, six, first, _, seconds = study
    assert seconds < 120, f"a 6-trial study on 24-frame clips took {seconds:.0f} s"
    st = cwd / "st"
    for name in ("trials.csv", "best.toml", "report.md", "study.rrd", "study.journal", "history.png"):
        assert (st / name).is_file(), name
    assert not (st / "work").exists()
    assert len(six) == 6 and all(r["state"] == "complete" for r in six)
    head = list(six[0])
    for col in ("trial", "state", "seconds", "detection.k_sigma", "tracking.p_detect",
                "tune_mota", "tune_idf1", "tune_pd", "tune_fa", "validate_mota", "validate_fa",
                "fov70-maneuver-0_mota", "uniform-50hz-0_mota", "fov70-four-targets-0_mota"):
        assert col in head, col
    # trial 0 is the defaults
    assert six[0]["base"] == "1" and float(six[0]["detection.k_sigma"]) == 4.0
    # the averages are the means of the per-clip scores, the validation clip apart
    for r in six:
        mean = (float(r["fov70-maneuver-0_mota"]) + float(r["uniform-50hz-0_mota"])) / 2
        assert float(r["tune_mota"]) == pytest.approx(mean)
        assert float(r["validate_mota"]) == pytest.approx(float(r["fov70-four-targets-0_mota"]))
    # params differ between trials and stay inside the space
    ks = [float(r["detection.k_sigma"]) for r in six]
    assert len(set(ks)) == 6 and all(3.0 <= k <= 6.0 for k in ks)
    report = (st / "report.md").read_text()
    assert "validation" in report and "gap" in report
    assert "trial" in first.stdout and "validate mota" in first.stdout


def test_resume_adds_trials_and_keeps_the_first(study):
    cwd, six, _, second, _ = study
    eight = rows(cwd / "st" / "trials.csv")
    assert len(eight) == 8
    strip = lambda r: {k: v for k, v in r.items() if k != "seconds"}  # noqa: E731
    assert [strip(r) for r in eight[:6]] == [strip(r) for r in six]
    assert "2 this run" in second.stdout


def test_same_seed_same_trials(study, tmp_path):
    cwd, six, *_ = study
    (tmp_path / "space.toml").write_text(SPACE)
    proc = wfviz("tune", *TUNE, "--validate", VALIDATE, "--out", "again", "--space", "space.toml",
                 "--stop", STOP, "--workers", "1", "--seed", "3", "--trials", "4", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    again = rows(tmp_path / "again" / "trials.csv")
    for a, b in zip(again, six[:4]):
        for k in ("detection.k_sigma", "tracking.p_detect", "tune_mota", "validate_mota"):
            assert a[k] == b[k], k


def test_best_toml_reproduces_the_reported_score(study, tmp_path):
    cwd, *_ = study
    st = cwd / "st"
    best_trial = max(rows(st / "trials.csv"), key=lambda r: (float(r["tune_mota"]), -int(r["trial"])))
    header = (st / "best.toml").read_text().splitlines()[0]
    assert f"trial {best_trial['trial']} " in header
    tomllib.loads((st / "best.toml").read_text())  # valid TOML
    for clip, label in zip(TUNE, ("fov70-maneuver-0", "uniform-50hz-0")):
        proc = wfviz("track", clip, "--config", str(st / "best.toml"), "--tracks", "t.csv", "--stop", STOP,
                     cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        result = evaluate(tmp_path / "t.csv", st / "truth" / f"{label}.csv")
        assert result.mota == float(best_trial[f"{label}_mota"])
        assert result.fa_per_frame == float(best_trial[f"{label}_fa"])


def test_study_recording_has_trial_timeline(study):
    cwd, *_ = study
    trials: dict[str, set[int]] = defaultdict(set)
    static = set()
    for chunk in RrdReader(cwd / "st" / "study.rrd").stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
            continue
        batch = chunk.to_record_batch()
        if "trial" in batch.schema.names:
            trials[chunk.entity_path].update(batch.column("trial").to_pylist())
    for entity in ("/study/tune/mota", "/study/validate/mota", "/study/params/detection.k_sigma",
                   "/study/trials", "/study/log"):
        assert trials.get(entity) == set(range(8)), entity
    assert "/study/pareto" in static


def test_study_recording_keeps_every_trial_in_the_plane(study):
    """Through ``wfviz tune``: after the 8 trials the plane's batch holds 8 points (one per
    trial, labelled with its number), the defaults and the best are marked, and every parameter
    lies on its search range."""
    cwd, *_ = study
    last: dict[str, list] = {}
    scaled: list[float] = []
    for chunk in RrdReader(cwd / "st" / "study.rrd").stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path.startswith("/study/params_scaled/") and "Scalars:scalars" in batch.schema.names:
            scaled += [v[0] for v in batch.column("Scalars:scalars").to_pylist()]
        if chunk.entity_path.startswith("/study/plane/") and "Points2D:labels" in batch.schema.names:
            last[chunk.entity_path] = batch.column("Points2D:labels").to_pylist()[-1]
    assert [int(s.split(":")[0].split()[1]) for s in last["/study/plane/trials"]] == list(range(8))
    assert last["/study/plane/defaults"] == ["defaults (trial 0)"]
    best = max(rows(cwd / "st" / "trials.csv"), key=lambda r: (float(r["tune_mota"]), -int(r["trial"])))
    assert last["/study/plane/best"] == [f"best: trial {best['trial']}"]
    assert len(scaled) == 8 * 4 and all(0.0 <= v <= 1.0 for v in scaled)


GAIN = re.compile(r"^([+-]\d\.\d{3} \[[+-]\d\.\d{3}, [+-]\d\.\d{3}\](, within noise)?|no change)$")


def table(report: str, title: str) -> list[dict[str, str]]:
    """The rows of the first markdown table after the heading ``title`` in ``report``."""
    lines = report.split(title, 1)[1].splitlines()
    body = [line for line in lines[lines.index(next(x for x in lines if x.startswith("|"))):]]
    body = body[:next((i for i, x in enumerate(body) if not x.startswith("|")), len(body))]
    head = [c.strip() for c in body[0].strip("|").split("|")]
    return [dict(zip(head, (c.strip() for c in r.strip("|").split("|")))) for r in body[2:]]


def test_report_gives_every_gain_an_interval(study):
    cwd, *_ = study
    st = cwd / "st"
    report = (st / "report.md").read_text()
    by_trial = {r["trial"]: r for r in rows(st / "trials.csv")}
    base = by_trial["0"]
    best = table(report, "## Best 8 trials")
    assert len(best) == 8 and "validation mota" in best[0] and "gain (validation)" in best[0]
    for r in best:
        n = r["trial"].split()[0]
        if n == "0":
            assert r["gain (tune)"] == "(base)"
            continue
        for role, col in (("tune", "gain (tune)"), ("validate", "gain (validation)")):
            # trials 0-5 ran before the resume: their frame counts came back from the journal
            assert GAIN.match(r[col]), (n, r[col])
            want = float(by_trial[n][f"{role}_mota"]) - float(base[f"{role}_mota"])
            if r[col] == "no change":
                assert want == 0
                continue
            assert float(r[col].split()[0]) == pytest.approx(want, abs=5e-4)
            low, high = (float(x) for x in r[col].split("[")[1].split("]")[0].split(", "))
            assert low <= high and (("within noise" in r[col]) == (low <= 0 <= high))
        assert float(r["validation mota"]) == pytest.approx(float(by_trial[n]["validate_mota"]), abs=5e-4)
    scores = table(report, "## Tune and validation scores")
    assert scores[0]["trial"] == "0 (base)" and scores[0]["gap change from the base"] == "(reference)"
    gap = float(base["tune_mota"]) - float(base["validate_mota"])
    assert float(scores[0]["gap (tune − validation) mota"]) == pytest.approx(gap, abs=5e-4)
    assert "From 8 completed trials" in report and "fewer than 30 trials this is a hint" in report
    for name in ("history.png", "pareto.png", "tune_vs_validation.png"):  # pareto.png: every study
        assert (st / name).is_file() and f"({name})" in report, name


def test_trials_keep_their_frame_counts(study):
    from wfviz.tune.significance import metric, unpack
    from wfviz.tune.study import finished, load_journal

    cwd, *_ = study
    by_trial = {r["trial"]: r for r in rows(cwd / "st" / "trials.csv")}
    trials = finished(load_journal(cwd / "st" / "study.journal"))
    assert len(trials) == 8
    for t in trials:
        for label, packed in t.user_attrs["frames"].items():
            counts = unpack(packed)
            assert len(counts) == int(STOP)
            for m in ("mota", "pd", "idf1", "fa"):
                got = float(metric(counts.sum(0), len(counts), m))
                assert got == pytest.approx(float(by_trial[str(t.number)][f"{label}_{m}"])), (t.number, label, m)


def test_cache_gives_the_same_trials(tmp_path):
    (tmp_path / "space.toml").write_text(SPACE)
    out = {}
    for name, extra in (("cached", []), ("plain", ["--no-cache"])):
        proc = wfviz("tune", *TUNE, "--out", name, "--space", "space.toml", "--stop", "16",
                     "--workers", "1", "--trials", "3", *extra, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        out[name] = [{k: v for k, v in r.items() if k != "seconds"} for r in rows(tmp_path / name / "trials.csv")]
    assert out["cached"] == out["plain"]


def test_pareto_objective_writes_the_front(tmp_path):
    (tmp_path / "space.toml").write_text(SPACE)
    proc = wfviz("tune", *TUNE, "--out", "p", "--space", "space.toml", "--stop", "16", "--workers", "1",
                 "--trials", "5", "--objective", "pareto", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    front = rows(tmp_path / "p" / "pareto.csv")
    every = rows(tmp_path / "p" / "trials.csv")
    assert front and all((tmp_path / "p" / r["config"]).is_file() for r in front)
    pts = [(float(r["tune_pd"]), float(r["tune_fa"])) for r in every]
    for r in front:  # nothing dominates a front point
        pd, fa = float(r["pd"]), float(r["fa"])
        assert not any(a >= pd and b <= fa and (a > pd or b < fa) for a, b in pts)
    assert (tmp_path / "p" / "pareto.png").is_file()
    assert not (tmp_path / "p" / "best.toml").exists()


def test_failing_trial_is_recorded_and_the_study_goes_on(tmp_path, monkeypatch):
    from wfviz.trackers.gewc import tracker as gewc

    step = gewc.GEWCTracker.step

    def flaky(self, frame):
        if self.config.tracking.p_detect < 0.75 and frame.index == 3:
            raise RuntimeError("boom at frame 3")
        return step(self, frame)

    monkeypatch.setattr(gewc.GEWCTracker, "step", flaky)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "space.toml").write_text(SPACE)
    result = CliRunner().invoke(app, ["tune", *TUNE, "--out", "f", "--space", "space.toml", "--stop", "8",
                                      "--workers", "1", "--trials", "8", "--seed", "1"])
    assert result.exit_code == 0, result.output
    got = rows(tmp_path / "f" / "trials.csv")
    assert len(got) == 8
    failed = [r for r in got if r["state"] == "fail"]
    assert failed and all("boom at frame 3" in r["error"] for r in failed)
    assert all(float(r["tracking.p_detect"]) < 0.75 for r in failed)
    assert any(r["state"] == "complete" for r in got)
    assert "Failed trials" in (tmp_path / "f" / "report.md").read_text()


def test_ctrl_c_keeps_finished_trials_and_resumes(tmp_path):
    (tmp_path / "space.toml").write_text(SPACE)
    args = ["tune", *TUNE, "--out", "i", "--space", "space.toml", "--stop", "16", "--workers", "2",
            "--trials", "200"]
    proc = subprocess.Popen([sys.executable, "-m", "wfviz", *args], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    csv_path = tmp_path / "i" / "trials.csv"
    deadline = time.time() + 240
    while time.time() < deadline and (not csv_path.is_file() or len(rows(csv_path)) < 2):
        time.sleep(0.2)
    workers = os.popen(f"pgrep -f spawn_main -P {proc.pid}").read().split()  # its worker processes
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    got = rows(csv_path)
    done = [r for r in got if r["state"] == "complete"]
    assert len(done) >= 2 and "interrupted" in out
    assert all(r["error"] in ("", "interrupted") for r in got)
    assert workers, "no worker process seen"
    time.sleep(0.5)
    assert not [w for w in workers if Path(f"/proc/{w}").exists()], "worker processes outlived the study"
    # the same command goes on from there
    proc2 = wfviz(*args[:-1], str(len(done) + 1), cwd=tmp_path)
    assert proc2.returncode == 0, proc2.stderr
    after = rows(csv_path)
    assert len([r for r in after if r["state"] == "complete"]) == len(done) + 1


def test_print_space_round_trips_for_every_tracker(tmp_path):
    for name in TRACKERS:
        result = CliRunner().invoke(app, ["tune", "--tracker", name, "--print-space"])
        assert result.exit_code == 0, result.output
        path = tmp_path / f"{name}.toml"
        path.write_text(result.stdout)
        assert load_space(path, config_class(name)) == parse_space(default_space(name), config_class(name))


@pytest.mark.parametrize("text, message", [
    ("[detection]\nk_sigm = { low = 3.0, high = 5.0 }\n", "did you mean 'k_sigma'"),
    ("[detecton]\nk_sigma = { low = 3.0, high = 5.0 }\n", "did you mean 'detection'"),
    ("[detection]\nk_sigma = { low = 5.0, high = 3.0 }\n", "must be below high"),
    ("[tracking]\np_detect = { low = 0.0, high = 0.9, log = true }\n", "out of range"),
    ("[detection]\nk_sigma = { low = 3.0 }\n", "needs both low and high"),
    ("[detection]\nk_sigma = { low = 3.0, hihg = 5.0 }\n", "unknown range key 'hihg'"),
    ("[detection]\nmode = { low = 1, high = 2 }\n", "not a number"),
    ("[detection]\nmode = { choices = [\"cfar\", \"nope\"] }\n", "not one of"),
    ("[kalman]\ngate_min = { low = 3.0, high = 40.0 }\n", "must not exceed kalman.gate_max"),
    ("[detection]\nk_sigma = 4.0\n", "no parameter to search"),
])
def test_bad_space_is_one_line_exit_2(tmp_path, text, message):
    (tmp_path / "s.toml").write_text(text)
    proc = wfviz("tune", "synth:uniform-50hz:0", "--out", "x", "--space", "s.toml", cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "s.toml" in lines[0] and message in lines[0], proc.stderr
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("args, message", [
    (["synth:uniform-50hz:0", "--objective", "deta"], "unknown 'deta'"),
    (["synth:uniform-50hz:0"], "--out DIR is required"),
    (["--out", "x"], "no clip to tune on"),
    (["missing-clip.avi", "--out", "x"], "no such file"),
    (["synth:uniform-50hz:0", "--out", "x", "--tracker", "nope"], "unknown tracker"),
    (["synth:uniform-50hz:0", "synth:uniform-50hz:0", "--out", "x"], "given twice"),
])
def test_bad_arguments_are_one_line_exit_2(tmp_path, args, message):
    proc = wfviz("tune", *args, cwd=tmp_path)
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and message in proc.stderr, proc.stderr


def test_clip_without_truth_is_named(tmp_path):
    import numpy as np

    np.save(tmp_path / "c.npy", np.zeros((3, 64, 64), dtype=np.uint16))
    proc = wfviz("tune", "c.npy", "--out", "x", cwd=tmp_path)
    assert proc.returncode == 2 and "c.npy: no truth found" in proc.stderr, proc.stderr


def test_record_best_and_folds(tmp_path):
    (tmp_path / "space.toml").write_text(SPACE)
    proc = wfviz("tune", *TUNE, "--out", "r", "--space", "space.toml", "--stop", "12", "--workers", "1",
                 "--trials", "4", "--record-best", "1", "--folds", "2", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    recs = sorted(p.name for p in (tmp_path / "r" / "recordings").glob("*.rrd"))
    best = max(rows(tmp_path / "r" / "trials.csv"), key=lambda r: (float(r["tune_mota"]), -int(r["trial"])))
    want = {f"trial-{t}-{c}.rrd" for t in {best["trial"], "0"} for c in ("fov70-maneuver-0", "uniform-50hz-0")}
    assert set(recs) == want
    truth_seen = any(chunk.entity_path == "/camera/truth" for chunk in
                     RrdReader(tmp_path / "r" / "recordings" / recs[0]).stream())
    assert truth_seen
    report = (tmp_path / "r" / "report.md").read_text()
    assert "Leave-clips-out cross-validation (2 folds)" in report


@pytest.mark.slow
def test_ray_runs_the_same_trials_as_local_workers(tmp_path):
    pytest.importorskip("ray")
    (tmp_path / "space.toml").write_text(SPACE)
    got = {}
    for name, extra in (("local", []), ("ray", ["--ray", "local"])):
        proc = wfviz("tune", *TUNE, "--out", name, "--space", "space.toml", "--stop", "12", "--workers", "2",
                     "--trials", "4", *extra, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        got[name] = [{k: v for k, v in r.items() if k != "seconds"} for r in rows(tmp_path / name / "trials.csv")]
    assert got["local"] == got["ray"]


def test_cache_keeps_what_fits_and_replays_it_exactly(monkeypatch):
    from wfviz.trackers.gewc.config import GEWCConfig
    from wfviz.tune import cache

    monkeypatch.setattr(cache, "_CACHE", {})
    monkeypatch.setattr(cache, "CACHE_MB", 40)  # room for one 480x320 clip of 16 frames, not two
    config = GEWCConfig()
    first, _ = cache.replay("synth:uniform-50hz:0", 16, config)
    cache.replay("synth:uniform-50hz:1", 16, config)
    assert [k[0] for k in cache._CACHE] == ["synth:uniform-50hz:0"]
    again, front = cache.replay("synth:uniform-50hz:0", 16, config)
    assert [f.index for f in again.frames()] == list(range(16))
    assert again.frames().__next__().image is next(first.frames()).image  # the cached frames themselves


def test_empty_truth_is_refused_before_any_trial(tmp_path):
    import numpy as np

    np.save(tmp_path / "c.npy", np.zeros((3, 64, 64), dtype=np.uint16))
    (tmp_path / "t.csv").write_text("frame,target_id,x,y\n")
    proc = wfviz("tune", "c.npy=t.csv", "--out", "x", cwd=tmp_path)
    assert proc.returncode == 2 and "t.csv: no truth rows" in proc.stderr, proc.stderr
    assert not (tmp_path / "x").exists()
