"""`wfviz tune` and `wfviz compare` never destroy a user's files (issue 32, items 1-3, 5, 7,
14, 15, 18): inputs out of reach of the study's files, the study folder apart from the clips,
only the study's own files replaced or deleted, one study process per folder, signals and
resumes that behave as documented."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import digest, invoke, noise, one_line_error, rows, temporaries, write_folder
from test_tune import wfviz

CLIP = "synth:fov70-maneuver:0"
SPACE = """
[detection]
k_sigma = { low = 3.0, high = 6.0 }
[tracking]
p_detect = { low = 0.6, high = 0.98 }
"""


@pytest.fixture()
def scene(tmp_path: Path) -> Path:
    """A folder clip of 6 noise frames with truth.csv inside."""
    s = write_folder(tmp_path / "clip", {f"frame_{i:06d}.png": noise() for i in range(6)})
    (s / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n1,1,6,5\n")
    return s


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """A finished 2-trial study."""
    cwd = tmp_path_factory.mktemp("study")
    (cwd / "space.toml").write_text(SPACE)
    proc = wfviz("tune", CLIP, "--out", "S", "--space", "space.toml", "--stop", "8", "--workers", "1",
                 "--trials", "2", cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    return cwd / "S"


# -- 1. every input out of reach of every file tune writes ---------------------------------------

@pytest.mark.parametrize("name, option", [("best.toml", "--config"), ("report.md", "--space"),
                                          ("trials.csv", "truth")])
def test_an_input_named_like_a_study_file_in_the_study_folder_is_refused(tmp_path: Path, scene: Path,
                                                                        name: str, option: str) -> None:
    s = tmp_path / "S"
    s.mkdir()
    text = {"--config": "[detection]\nk_sigma = 4.5\n", "--space": SPACE,
            "truth": "frame,target_id,x,y\n0,1,5,5\n"}[option]
    (s / name).write_text(text)
    before = digest(tmp_path)
    args = ["tune", f"{scene}={s / name}" if option == "truth" else str(scene), "--out", str(s),
            "--trials", "1", "--workers", "1"]
    if option != "truth":
        args += [option, str(s / name)]
    proc = wfviz(*args, cwd=tmp_path)
    one_line_error(proc, str(s / name))
    assert digest(tmp_path) == before


# -- 2. the study folder apart from the clip folders ---------------------------------------------

@pytest.mark.parametrize("where", ["clip", "clip/sub", "parent"])
def test_a_study_folder_in_around_or_as_a_clip_folder_is_refused(tmp_path: Path, scene: Path, where: str) -> None:
    out = {"clip": scene, "clip/sub": scene / "sub", "parent": tmp_path}[where]
    before = digest(tmp_path)
    proc = wfviz("tune", str(scene), "--out", str(out), "--trials", "1", "--workers", "1", cwd=tmp_path)
    one_line_error(proc, "--out")
    assert digest(tmp_path) == before
    assert not (scene / "sub").exists()
    ok = wfviz("track", str(scene), "--tracks", str(tmp_path / "t.csv"), cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr  # the clip still reads


# -- 3. compare never replaces a study's files -----------------------------------------------------

@pytest.mark.parametrize("name", ["study.journal", "trials.csv", "best.toml"])
def test_compare_output_over_a_study_file_is_refused(study: Path, tmp_path: Path, name: str) -> None:
    before = digest(study)
    proc = wfviz("compare", CLIP, "--study", str(study), "--top", "1", "--stop", "4", "-o", str(study / name),
                 cwd=tmp_path)
    one_line_error(proc, str(study / name))
    assert digest(study) == before
    again = wfviz("compare", CLIP, "--study", str(study), "--top", "1", "--stop", "4", "--no-images",
                  "-o", str(tmp_path / "c.rrd"), cwd=tmp_path)
    assert again.returncode == 0, again.stderr


def test_a_broken_journal_is_named(study: Path, tmp_path: Path) -> None:
    broken = tmp_path / "B"
    broken.mkdir()
    (broken / "study.journal").write_bytes(b"\x00RRF not a journal\n")
    for args in (["compare", CLIP, "--study", str(broken), "--stop", "4", "-o", str(tmp_path / "c.rrd")],
                 ["tune", CLIP, "--out", str(broken), "--trials", "1", "--stop", "4"]):
        proc = wfviz(*args, cwd=tmp_path)
        one_line_error(proc, str(broken / "study.journal"))
    assert (broken / "study.journal").read_bytes() == b"\x00RRF not a journal\n"


# -- 5. only what the study wrote is replaced or deleted ---------------------------------------------

def test_a_users_work_folder_and_files_survive_a_study(tmp_path: Path) -> None:
    p = tmp_path / "P"
    (p / "work").mkdir(parents=True)
    (p / "work" / "thesis.tex").write_text("chapter 1")
    (p / "notes.md").write_text("mine")
    proc = wfviz("tune", CLIP, "--out", "P", "--trials", "2", "--workers", "1", "--stop", "6",
                 "--objective", "pareto", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (p / "work" / "thesis.tex").read_text() == "chapter 1"
    assert (p / "notes.md").read_text() == "mine"
    assert list(p.glob("best-*.toml")) and not temporaries(p)


def test_files_with_study_names_the_study_did_not_write_are_refused(tmp_path: Path) -> None:
    p = tmp_path / "P"
    p.mkdir()
    (p / "best-3.toml").write_text("# my own\n")
    before = digest(tmp_path)
    proc = wfviz("tune", CLIP, "--out", "P", "--trials", "1", "--workers", "1", "--stop", "6",
                 "--objective", "pareto", cwd=tmp_path)
    one_line_error(proc, "best-3.toml")
    assert digest(tmp_path) == before


# -- 7, 14: one study process per folder; signals -----------------------------------------------

def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "wfviz", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_rows(path: Path, n: int, proc: subprocess.Popen, seconds: float = 240) -> None:
    deadline = time.time() + seconds
    while time.time() < deadline and proc.poll() is None and (not path.is_file() or len(rows(path)) < n):
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()


def test_a_second_study_on_a_folder_in_use_is_refused_and_sigterm_exits_143(tmp_path: Path) -> None:
    (tmp_path / "space.toml").write_text(SPACE)
    args = ["tune", CLIP, "--out", "L", "--space", "space.toml", "--stop", "16", "--workers", "1",
            "--trials", "200"]
    first = _start(args, tmp_path)
    try:
        _wait_rows(tmp_path / "L" / "trials.csv", 1, first)
        second = wfviz(*args, cwd=tmp_path)
        one_line_error(second, "in use")
        assert first.poll() is None  # the first goes on
        first.send_signal(signal.SIGTERM)
        out, err = first.communicate(timeout=120)
    finally:
        first.kill()
    assert first.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err and "interrupted by SIGTERM" in out
    got = rows(tmp_path / "L" / "trials.csv")
    assert got[0]["trial"] == "0" and got[0]["base"] == "1" and got[0]["state"] == "complete"


def test_a_resumed_study_runs_the_trials_of_an_uninterrupted_one(tmp_path: Path) -> None:
    (tmp_path / "space.toml").write_text(SPACE)
    common = ["--space", "space.toml", "--stop", "80", "--workers", "1", "--seed", "5", "--trials", "5"]
    whole = wfviz("tune", CLIP, "--out", "W", *common, cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    cut = _start(["tune", CLIP, "--out", "C", *common], tmp_path)
    try:
        _wait_rows(tmp_path / "C" / "trials.csv", 2, cut)
        deadline = time.time() + 120  # until the third trial writes its tracks: it is running
        while time.time() < deadline and cut.poll() is None and not list((tmp_path / "C").glob(".work.*/.trial-2-*")):
            time.sleep(0.01)
        cut.send_signal(signal.SIGINT)
        cut.communicate(timeout=120)
    finally:
        cut.kill()
    assert cut.returncode == 130
    resumed = wfviz("tune", CLIP, "--out", "C", *common, cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr

    def params(folder: str) -> list[tuple[str, str]]:
        return [(r["detection.k_sigma"], r["tracking.p_detect"]) for r in rows(tmp_path / folder / "trials.csv")
                if r["state"] == "complete"]
    numbers = [int(r["trial"]) for r in rows(tmp_path / "C" / "trials.csv") if r["state"] == "complete"]
    assert numbers != list(range(5)), "the signal fell between trials: no trial was cut"
    assert params("C") == params("W")


def test_a_signal_while_recording_the_best_trials_is_not_done(tmp_path: Path) -> None:
    proc = _start(["tune", CLIP, "--out", "R", "--trials", "1", "--workers", "1", "--stop", "120",
                   "--record-best", "1"], tmp_path)
    recs = tmp_path / "R" / "recordings"
    try:
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None and not (recs.is_dir() and temporaries(recs)):
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, (out, err)
    assert out.startswith("interrupted by SIGINT"), out
    assert not temporaries(tmp_path)


# -- 15. no more worker processes than trials and cores -------------------------------------------

def test_workers_are_capped_by_trials_and_cores(tmp_path: Path) -> None:
    proc = _start(["tune", CLIP, "--out", "K", "--trials", "2", "--workers", "40", "--stop", "12"], tmp_path)
    most = 0
    while proc.poll() is None:
        kids = os.popen(f"pgrep -f spawn_main -P {proc.pid}").read().split()  # the worker processes
        most = max(most, len(kids))
        time.sleep(0.1)
    out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert most <= min(2, os.cpu_count() or 1)  # not 40 (one core: the trials run in this process)
    assert "--workers 40:" in err


# -- property: whatever the study folder and the compare output, inputs stay whole ----------------

_NAME = st.text(st.sampled_from(list("ab _-.é")), min_size=1, max_size=6).filter(
    lambda s: s.strip(". ") != "" and s.strip() == s)


@settings(max_examples=12, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(out=st.one_of(_NAME, st.sampled_from([".", "s", "s/sub", "v", "cfg.toml", "truth.csv", "sp.toml",
                                              "sub/s", "s/frames"])),
       ext=st.sampled_from(["", "/x"]))
def test_any_study_folder_leaves_inputs_whole(tmp_path_factory: pytest.TempPathFactory, out: str, ext: str) -> None:
    root = tmp_path_factory.mktemp("t")
    s = write_folder(root / "s", {f"frame_{i:06d}.png": noise() for i in range(4)})
    v = write_folder(root / "v", {f"frame_{i:06d}.png": noise() for i in range(4)})
    (root / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n")
    (v / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n")
    (root / "cfg.toml").write_text("[detection]\nk_sigma = 4.0\n")
    (root / "sp.toml").write_text(SPACE)
    before = digest(root)
    r = invoke("tune", f"{s}={root / 'truth.csv'}", "--validate", str(v), "--out", str(root / (out + ext)),
               "--config", str(root / "cfg.toml"), "--space", str(root / "sp.toml"), "--trials", "1",
               "--workers", "1")
    after = digest(root)
    for name, sha in before.items():
        assert after.get(name) == sha, (name, out + ext, r.output)
    assert not temporaries(root), (out + ext, r.output)
    assert r.exit_code in (0, 2), (r.output, r.exception)


@settings(max_examples=12, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(name=st.one_of(_NAME, st.sampled_from(["S/study.journal", "S/trials.csv", "S/best.toml", "S/report.md",
                                              "S/truth/fov70-maneuver-0.csv", "s/frame_000001.png",
                                              "truth.csv", "cfg.toml", "S", "s"])))
def test_any_compare_output_leaves_inputs_whole(study: Path, tmp_path_factory: pytest.TempPathFactory,
                                                name: str) -> None:
    import shutil

    root = tmp_path_factory.mktemp("c")
    shutil.copytree(study, root / "S")
    s = write_folder(root / "s", {f"frame_{i:06d}.png": noise() for i in range(4)})
    (root / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n")
    (root / "cfg.toml").write_text("[detection]\nk_sigma = 4.0\n")
    before = digest(root)
    r = invoke("compare", str(s), "--study", str(root / "S"), "--top", "1", "--run", f"gewc:{root / 'cfg.toml'}",
               "--truth", str(root / "truth.csv"), "--no-images", "-o", str(root / name))
    after = digest(root)
    for f, sha in before.items():
        assert after.get(f) == sha, (f, name, r.output)
    assert not temporaries(root), (name, r.output)
    assert r.exit_code in (0, 2), (r.output, r.exception)


# -- issue 37, 1: a refused command changes nothing -----------------------------------------------

STOP = "8"
STALE = ".trials.csv.999999999.x.wfviz-part"  # a temporary of a killed run (no such process)


def snapshot(folder: Path) -> dict[str, tuple[bytes | None, int]]:
    """Every file and folder under ``folder``, itself included: relative path -> (bytes, or None
    for a folder; mtime_ns). A file written again with the same bytes, or a folder where a file
    was made and removed, shows in the times."""
    out: dict[str, tuple[bytes | None, int]] = {".": (None, folder.stat().st_mtime_ns)}
    for p in sorted(folder.rglob("*")):
        st = p.lstat()
        out[str(p.relative_to(folder))] = (None if p.is_dir() else p.read_bytes(), st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def resumable(tmp_path_factory) -> Path:
    """A folder holding a finished 2-trial study ``S`` (paths relative to the folder, so that a
    copy of the folder resumes it) and its space file."""
    root = tmp_path_factory.mktemp("resumable")
    (root / "sp.toml").write_text(SPACE)
    r = _tune_in(root)
    assert r.exit_code == 0, r.output
    return root


def _tune_in(root: Path, *extra: str, clips: tuple[str, ...] = (CLIP,)) -> Any:
    """``wfviz tune`` run in ``root`` as the resumable study was made, with ``extra`` options
    (later options win)."""
    import contextlib

    with contextlib.chdir(root):
        return invoke("tune", *clips, "--out", "S", "--space", "sp.toml", "--stop", STOP, "--workers", "1",
                      "--trials", "2", *extra)


def _refusal(root: Path, reason: str, value: int) -> tuple[tuple[str, ...], tuple[str, ...], str]:
    """Set up ``root`` (a copy of the resumable study) for one reason to refuse: the extra
    options, the clips and a word the error must hold."""
    s = root / "S"
    clips: tuple[str, ...] = (CLIP,)
    if reason == "stop":
        return ("--stop", str(int(STOP) + value)), clips, "stop differ"
    if reason == "tracker":
        return ("--tracker", "fusion"), clips, "tracker"  # (its configuration takes the space)
    if reason == "clips":
        return (), (CLIP, f"synth:fov70-maneuver:{value}"), "clips differ"
    if reason == "validate":
        return ("--validate", f"synth:fov70-maneuver:{value}"), clips, "clips differ"
    if reason == "space":
        (root / "sp2.toml").write_text(SPACE.replace("high = 6.0", f"high = {6 + value}.5"))
        return ("--space", "sp2.toml"), clips, "space differ"
    if reason == "objective":
        return ("--objective", ["idf1", "pareto"][value % 2]), clips, "objective differ"
    if reason == "seed":
        return ("--seed", str(value)), clips, "seed differ"
    if reason == "gate":
        return ("--gate", f"{3 + value}.5"), clips, "gate differ"
    if reason == "config":
        (root / "cfg.toml").write_text(f"[tracking]\nmax_misses = {10 + value}\n")
        return ("--config", "cfg.toml"), clips, "base differ"
    if reason == "foreign":  # names of files the study has not written (yet)
        name = ["best-3.toml", "pareto.csv", "truth/mine.csv", "recordings/trial-1-x.rrd"][value % 4]
        (s / name).parent.mkdir(exist_ok=True)
        (s / name).write_text("mine\n")
        return (), clips, "not written by this study"
    if reason == "input inside":  # the study's own best.toml, or a file in its truth folder
        name = ["best.toml", "truth/cfg.toml"][value % 2]
        if name != "best.toml":
            (s / name).write_text("[detection]\nk_sigma = 4.0\n")
        return ("--config", f"S/{name}"), clips, "lies where the study"
    if reason == "journal":
        (s / "study.journal").write_bytes(b"{not a journal\n"[: 4 + value % 10])
        return (), clips, "study.journal"
    if reason == "ray":
        return ("--ray", "local"), clips, "needs Ray"
    if reason == "constraint":  # a resume with a constraint the study was not run under
        return ("--constraint", f"fa_per_frame<={value / 10:g}"), clips, "constraints differ"
    if reason == "bad constraint":
        return ("--constraint", ["fa_per_frame<0.1", "speed<=3", "pd>=x"][value % 3]), clips, "--constraint"
    assert reason == "locked"
    return (), clips, "in use"


REASONS = ["stop", "tracker", "clips", "validate", "space", "objective", "seed", "gate", "config", "foreign",
           "input inside", "journal", "ray", "locked", "constraint", "bad constraint"]


def _ray_missing() -> bool:
    import importlib.util

    return importlib.util.find_spec("ray") is None


def test_the_same_command_resumes_and_leaves_the_truth_as_it_was(resumable: Path,
                                                                 tmp_path_factory: pytest.TempPathFactory) -> None:
    """The control of the refusals below: without a reason the command is accepted (and a
    resume that adds no trial keeps the truth and the journal as they were)."""
    import shutil

    root = tmp_path_factory.mktemp("same")
    shutil.copytree(resumable, root, dirs_exist_ok=True)
    before = snapshot(root / "S")
    r = _tune_in(root)
    assert r.exit_code == 0, r.output
    after = snapshot(root / "S")
    for kept in ("truth/fov70-maneuver-0.csv", "study.journal", "best.toml"):
        assert after[kept] == before[kept], kept


@pytest.mark.parametrize("reason", REASONS)
@settings(max_examples=2, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(value=st.integers(1, 9))
def test_a_refused_tune_changes_no_file(resumable: Path, tmp_path_factory: pytest.TempPathFactory,
                                       reason: str, value: int) -> None:
    """Whatever refuses the command (a resume with other settings, files with the study's names
    it did not write, an input where the study writes, an unreadable journal, a missing Ray, a
    folder in use): exit 2, one line naming the problem, and every file and folder of the study
    as it was: the same bytes, the same times, none added or removed (a killed run's temporary
    too: it is cleared only once a command is accepted)."""
    import fcntl
    import shutil

    if reason == "ray" and not _ray_missing():
        return
    root = tmp_path_factory.mktemp("refused")
    shutil.copytree(resumable, root, dirs_exist_ok=True)
    (root / "S" / STALE).write_text("")
    extra, clips, word = _refusal(root, reason, value)
    before = snapshot(root)
    fd = os.open(root / "S", os.O_RDONLY | os.O_DIRECTORY)
    try:
        if reason == "locked":  # as a running study holds it
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        r = _tune_in(root, *extra, clips=clips)
    finally:
        os.close(fd)
    assert r.exit_code == 2, (reason, r.output)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wfviz: error: ") and word in lines[0], (reason, r.stderr)
    after = snapshot(root)
    assert after.keys() == before.keys(), (reason, after.keys() ^ before.keys())
    for name, was in before.items():
        assert after[name] == was, (reason, name)


@pytest.mark.skipif(not _ray_missing(), reason="Ray is installed: --ray is not refused")
def test_a_refused_tune_into_a_new_folder_leaves_no_folder(tmp_path: Path) -> None:
    before = snapshot(tmp_path)
    r = invoke("tune", CLIP, "--out", str(tmp_path / "new" / "deep" / "S"), "--stop", STOP, "--trials", "1",
               "--workers", "1", "--ray", "local")
    assert r.exit_code == 2 and "needs Ray" in r.stderr, r.output
    assert snapshot(tmp_path) == before and not (tmp_path / "new").exists()


@pytest.mark.parametrize("case", ["windows", "output a folder", "no trial"])
def test_a_refused_compare_of_a_study_changes_none_of_its_files(study: Path, tmp_path: Path, case: str) -> None:
    """compare --study refused after its study and its clip were read (frames too small for a
    run's windows, an output that is a folder, a study with no finished trial): nothing in the
    study's folder changes, not even a killed run's temporary beside the output."""
    import shutil

    s = tmp_path / "S"
    shutil.copytree(study, s)
    (s / STALE).write_text("")
    clip, output, run = CLIP, s / "c.rrd", []
    if case == "windows":
        clip = str(write_folder(tmp_path / "tiny", {f"frame_{i:06d}.png": noise(shape=(18, 18)) for i in range(3)}))
        (tmp_path / "big.toml").write_text("[suppression]\nsize = 25\n")
        run = ["--run", f"big=gewc:{tmp_path / 'big.toml'}"]
        word = "smaller than the processing windows"
    elif case == "output a folder":
        output, word = s / "truth", "is a folder"
    else:  # a study whose first trial was cut short
        import optuna
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend

        from wfviz.tune.study import STUDY_NAME, load_journal

        settings_attr = load_journal(s / "study.journal").user_attrs["settings"]
        (s / "study.journal").unlink()
        journal = JournalStorage(JournalFileBackend(str(s / "study.journal")))
        cut = optuna.create_study(study_name=STUDY_NAME, storage=journal)
        cut.set_user_attr("settings", settings_attr)
        cut.ask()
        word = "no finished trial"
    before = snapshot(tmp_path)
    r = invoke("compare", clip, "--study", str(s), "--top", "1", *run, "--stop", "3", "--no-images",
               "-o", str(output))
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0], r.stderr
    assert snapshot(tmp_path) == before
