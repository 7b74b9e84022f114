"""Outputs never destroy inputs, temporary files are unique and cleaned up (issue 18, items 1-7)."""

from __future__ import annotations

import csv
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import WFVIZ, H, W, digest, invoke, noise, temporaries, write_folder
from wfviz import sinks
from wfviz.io import outputs

@pytest.fixture()
def scene(tmp_path: Path) -> Path:
    """An image folder of 20 frames with a truth file inside."""
    s = write_folder(tmp_path / "s", {f"frame_{i:06d}.png": noise() for i in range(20)})
    (s / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n")
    return s


@pytest.mark.parametrize("command, option, name", [
    ("track", "--tracks", "frame_000019.png"),
    ("record", "-o", "frame_000000.png"),
    ("track", "--tracks", "truth.csv"),
    ("record", "--tracks", "truth.csv"),
    ("track", "--tracks", "frame_000100.png"),  # not a frame yet, but it would become one
])
def test_outputs_into_the_input_folder_are_refused(scene: Path, command: str, option: str, name: str) -> None:
    before = digest(scene)
    args = [command, str(scene), option, str(scene / name)]
    if command == "record" and option == "--tracks":
        args += ["-o", str(scene.parent / "r.rrd")]
    if command == "track" or option != "--tracks":
        args += [] if command == "track" else ["--tracks", str(scene.parent / "t.csv")]
    r = invoke(*args)
    assert r.exit_code == 2, r.output
    assert "output would overwrite" in r.output and name in r.output
    assert digest(scene) == before and not temporaries(scene.parent)


def test_a_symlink_to_an_input_frame_is_refused(scene: Path, tmp_path: Path) -> None:
    link = tmp_path / "link.csv"
    link.symlink_to(scene / "frame_000003.png")
    before = digest(scene)
    r = invoke("track", str(scene), "--tracks", str(link))
    assert r.exit_code == 2 and "frame 3 of the input clip" in r.output
    assert digest(scene) == before


def test_truth_and_config_are_inputs_too(scene: Path, tmp_path: Path) -> None:
    truth = tmp_path / "truth.csv"
    truth.write_text("frame,target_id,x,y\n0,1,5,5\n")
    cfg = tmp_path / "my.toml"
    cfg.write_text("")
    for args, what in ((["--truth", str(truth), "--tracks", str(truth)], "the truth file"),
                       (["--config", str(cfg), "--tracks", str(cfg)], "the config file")):
        before = (truth.read_bytes(), cfg.read_bytes())
        r = invoke("track", str(scene), *args)
        assert r.exit_code == 2 and what in r.output, r.output
        assert (truth.read_bytes(), cfg.read_bytes()) == before


def test_eval_and_screenshot_do_not_replace_their_inputs(tmp_path: Path) -> None:
    tracks, truth = tmp_path / "t.csv", tmp_path / "truth.csv"
    tracks.write_text("frame,track_id,x,y,confirmed\n0,1,5,5,1\n")
    truth.write_text("frame,target_id,x,y\n0,1,5,5\n")
    before = truth.read_bytes()
    r = invoke("eval", str(tracks), str(truth), "--json", str(truth))
    assert r.exit_code == 2 and "the truth file" in r.output and truth.read_bytes() == before
    rrd = tmp_path / "x.rrd"
    rrd.write_bytes(b"not really a recording")
    r = invoke("screenshot", str(rrd), "-o", str(rrd))
    assert r.exit_code == 2 and "the recording" in r.output and rrd.read_bytes() == b"not really a recording"


def test_two_outputs_of_one_run_may_not_share_a_name(scene: Path, tmp_path: Path) -> None:
    r = invoke("record", str(scene), "-o", str(tmp_path / "a.rrd"), "--tracks", str(tmp_path / "a.rrd"))
    assert r.exit_code == 2 and "same name" in r.output


def test_tracks_named_like_the_recordings_old_temporary_file(tmp_path: Path) -> None:
    np.save(tmp_path / "c.npy", noise(shape=(8, H, W)))
    rrd, csv_path = tmp_path / "X.rrd", tmp_path / "X.rrd.part"
    r = invoke("record", str(tmp_path / "c.npy"), "-o", str(rrd), "--tracks", str(csv_path), "--no-images")
    assert r.exit_code == 0, r.output
    assert rrd.read_bytes()[:4] == b"RRF2" or rrd.stat().st_size > 100
    with open(csv_path, newline="") as fh:
        assert next(csv.reader(fh))[:5] == ["frame", "track_id", "x", "y", "confirmed"]
    assert not temporaries(tmp_path) or temporaries(tmp_path) == [csv_path]


def test_temporary_files_are_unique_per_run(tmp_path: Path) -> None:
    a, b = outputs.temp_path(tmp_path / "t.csv"), outputs.temp_path(tmp_path / "t.csv")
    assert a != b and a.exists() and b.exists()
    assert a.name.startswith(f".t.csv.{os.getpid()}.") and a.name.endswith(outputs.TEMP_SUFFIX)


def test_concurrent_runs_on_one_output_leave_one_whole_file(tmp_path: Path) -> None:
    alone = {}
    for name, n in (("a", 30), ("b", 45)):
        np.save(tmp_path / f"{name}.npy", noise(shape=(n, H, W)))
        assert invoke("track", str(tmp_path / f"{name}.npy"), "--tracks", str(tmp_path / f"{name}.csv")).exit_code == 0
        alone[name] = (tmp_path / f"{name}.csv").read_bytes()
    out = tmp_path / "t.csv"
    procs = [subprocess.Popen([*WFVIZ, "track", str(tmp_path / f"{name}.npy"), "--tracks", str(out)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name in ("a", "b")]
    for p in procs:
        _, stderr = p.communicate(timeout=120)
        assert p.returncode == 0, stderr
    assert out.read_bytes() in alone.values()  # one run's file, whole, never a mix
    assert not temporaries(tmp_path)


class _FullDisk:
    def write(self, text: str) -> int:
        raise OSError(28, "No space left on device")

    def close(self) -> None:
        raise OSError(28, "No space left on device")


@pytest.mark.parametrize("extra", [(), ("--backfill",)])
def test_a_full_disk_names_the_file_and_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       extra: tuple[str, ...]) -> None:
    np.save(tmp_path / "c.npy", noise(shape=(6, H, W)))
    real_init = sinks.TracksWriter.__init__

    def init(self, path: Path, *args: object, **kwargs: object) -> None:
        real_init(self, path, *args, **kwargs)
        self._fh.close()
        self._fh = _FullDisk()

    monkeypatch.setattr(sinks.TracksWriter, "__init__", init)
    r = invoke("track", str(tmp_path / "c.npy"), "--tracks", str(tmp_path / "t.csv"), *extra)
    assert r.exit_code == 2, r.output
    line = [ln for ln in r.output.splitlines() if "error" in ln]
    assert line and f"{tmp_path / 't.csv'}: cannot write (No space left on device)" in line[0]
    assert not (tmp_path / "t.csv").exists() and not temporaries(tmp_path)


def _dead_pid() -> int:
    pid = 999_999
    while True:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except PermissionError:
            pass
        pid -= 1


def test_stale_temporaries_of_killed_runs_are_removed(tmp_path: Path) -> None:
    np.save(tmp_path / "c.npy", noise(shape=(6, H, W)))
    stale = tmp_path / f".t.csv.{_dead_pid()}.abc123{outputs.TEMP_SUFFIX}"
    stale.write_text("half a run")
    stale_dir = tmp_path / f".scene.{_dead_pid()}.x9{outputs.TEMP_SUFFIX}"
    stale_dir.mkdir()
    live = tmp_path / f".t.csv.{os.getpid()}.def456{outputs.TEMP_SUFFIX}"  # a run still going
    live.write_text("in progress")
    mine = tmp_path / ".t.csv.part"  # not of wfviz's own naming: left alone
    mine.write_text("the user's")
    r = invoke("track", str(tmp_path / "c.npy"), "--tracks", str(tmp_path / "t.csv"))
    assert r.exit_code == 0, r.output
    assert not stale.exists() and not stale_dir.exists() and "removed" in r.output
    assert live.exists() and mine.exists()


def test_sigterm_to_synth_leaves_no_temporary_folder(tmp_path: Path) -> None:
    proc = subprocess.Popen([*WFVIZ, "synth", "long-1024", str(tmp_path / "out"), "--frames", "3000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not any(p.is_dir() and p.name.endswith(outputs.TEMP_SUFFIX) for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "terminated" in stderr
    assert [p.name for p in tmp_path.iterdir()] == []


# -- wrong answers without a word (items 8-10) ----------------------------------------------

def _truth(path: Path, text: str = "frame,target_id,x,y\n0,1,5,5\n1,1,6,5\n") -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_tracks_without_a_confirmed_column_need_all_rows(tmp_path: Path) -> None:
    truth = _truth(tmp_path / "truth.csv")
    tracks = tmp_path / "t.csv"
    tracks.write_text("frame,track_id,x,y\n0,7,5,5\n1,7,6,5\n1,8,40,40\n")
    r = invoke("eval", str(tracks), str(truth))
    assert r.exit_code == 2 and "no 'confirmed' column" in r.output and "--all-rows" in r.output
    r = invoke("eval", str(tracks), str(truth), "--all-rows")
    assert r.exit_code == 0, r.output
    assert "0.500" in r.output  # MOTA: 2 matches, 1 false positive over 2 truth points


@pytest.mark.parametrize("text, message", [
    ("frame,target_id,x,y\n", "no truth rows"),
    ("", "no truth rows"),
    ("frame,target_id,x,y\n-1,1,5,5\n", "truth.csv:2: column 'frame': -1 is negative"),
])
def test_empty_or_negative_truth_is_a_clear_error(tmp_path: Path, text: str, message: str) -> None:
    tracks = tmp_path / "t.csv"
    tracks.write_text("frame,track_id,x,y,confirmed\n0,7,5,5,1\n")
    r = invoke("eval", str(tracks), str(_truth(tmp_path / "truth.csv", text)))
    assert r.exit_code == 2 and message in r.output, r.output


def test_scoring_cost_follows_the_rows_not_the_frame_span(tmp_path: Path) -> None:
    truth = _truth(tmp_path / "truth.csv", "frame,target_id,x,y\n0,1,5,5\n100000000,1,5,5\n")
    tracks = tmp_path / "t.csv"
    tracks.write_text("frame,track_id,x,y,confirmed\n0,7,5,5,1\n100000000,7,5,5,1\n")
    t0 = time.perf_counter()
    r = invoke("eval", str(tracks), str(truth))
    assert r.exit_code == 0, r.output
    assert time.perf_counter() - t0 < 30  # 10^8 frames one by one would take hours
    assert "1.000" in r.output


def test_a_byte_order_mark_is_accepted(tmp_path: Path) -> None:
    truth = tmp_path / "truth.csv"
    truth.write_bytes(b"\xef\xbb\xbf" + b"frame,target_id,x,y\r\n0,1,5,5\r\n")
    tracks = tmp_path / "t.csv"
    tracks.write_bytes(b"\xef\xbb\xbf" + b"frame,track_id,x,y,confirmed\r\n0,7,5,5,1\r\n")
    r = invoke("eval", str(tracks), str(truth))
    assert r.exit_code == 0, r.output
    cfg = tmp_path / "c.toml"
    cfg.write_bytes(b"\xef\xbb\xbf" + b"[kalman]\ngate_sigma = 3.0\n")
    np.save(tmp_path / "c.npy", noise(shape=(4, H, W)))
    r = invoke("track", str(tmp_path / "c.npy"), "--config", str(cfg), "--tracks", str(tmp_path / "o.csv"))
    assert r.exit_code == 0, r.output


# -- messages (item 12) ---------------------------------------------------------------------

@pytest.mark.parametrize("name", ["run[test].npy", "a[/b.npy", "[bold]x.npy"])
def test_paths_are_printed_literally(tmp_path: Path, name: str) -> None:
    clip = tmp_path / name
    clip.parent.mkdir(exist_ok=True)
    np.save(clip, noise(shape=(4, H, W)))
    out = clip.with_name(f"out-{clip.stem}.csv")
    r = invoke("track", str(clip), "--tracks", str(out))
    assert r.exit_code == 0, r.output
    assert str(out) in r.output and out.exists()
    r = invoke("track", str(tmp_path / f"missing{name}"), "--tracks", str(out))
    assert r.exit_code == 2 and f"missing{name}" in r.output and "Traceback" not in r.output


def test_a_config_error_keeps_its_section_name(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text("[kalman]\nnot_a_key = 1\n")
    np.save(tmp_path / "c.npy", noise(shape=(4, H, W)))
    r = invoke("track", str(tmp_path / "c.npy"), "--config", str(cfg), "--tracks", str(tmp_path / "o.csv"))
    assert r.exit_code == 2 and "kalman" in r.output, r.output


# -- option errors (items 14, 15) -----------------------------------------------------------

@pytest.mark.parametrize("args, option", [
    (["track", "CLIP", "--fps", "0", "--tracks", "o.csv"], "--fps"),
    (["track", "CLIP", "--start", "-1", "--tracks", "o.csv"], "--start"),
    (["record", "CLIP", "--image-every", "0"], "--image-every"),
    (["bench", "CLIP", "--threads", str((os.cpu_count() or 1) + 1)], "--threads"),
])
def test_option_errors_are_one_line(tmp_path: Path, args: list[str], option: str) -> None:
    np.save(tmp_path / "c.npy", noise(shape=(4, H, W)))
    args = [str(tmp_path / "c.npy") if a == "CLIP" else a for a in args]
    proc = subprocess.run([*WFVIZ, *args], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wfviz: error:") and option in lines[0], proc.stderr


def test_screenshot_to_a_folder_and_synth_into_a_file_exit_2(tmp_path: Path) -> None:
    rrd = tmp_path / "x.rrd"
    rrd.write_bytes(b"x")
    r = invoke("screenshot", str(rrd), "-o", str(tmp_path))
    assert r.exit_code == 2 and "is a folder" in r.output
    (tmp_path / "file").write_text("mine")
    r = invoke("synth", "fov70-maneuver", str(tmp_path / "file"), "--frames", "2")
    assert r.exit_code == 2 and "is a file" in r.output and (tmp_path / "file").read_text() == "mine"


def test_a_multi_page_tiff_is_warned_about(tmp_path: Path) -> None:
    import cv2

    folder = tmp_path / "seq"
    folder.mkdir()
    for i in range(3):
        pages = [noise(np.uint8) for _ in range(2 if i == 1 else 1)]
        assert cv2.imwritemulti(str(folder / f"f{i}.tif"), pages)
    r = invoke("track", str(folder), "--tracks", str(tmp_path / "t.csv"))
    assert r.exit_code == 0, r.output
    assert "multi-page TIFF (2 pages)" in r.output and "f1.tif" in r.output


def test_synth_refuses_an_infinite_snr(tmp_path: Path) -> None:
    r = invoke("synth", "fov70-maneuver", str(tmp_path / "o"), "--snr", "inf", "--frames", "2")
    assert r.exit_code == 2 and "--snr" in r.output and not (tmp_path / "o").exists()


#: ``python -m wfviz ARGS`` that prints "ready" once wfviz's own SIGINT handler is installed, i.e. while
#: it imports numpy, OpenCV and the command line (a signal before that lands in Python's start-up)
_SPY_LOADING = """
import signal, sys
_real = signal.signal
def _spy(sig, handler):
    old = _real(sig, handler)
    if sig == signal.SIGINT and getattr(handler, "__name__", "") == "_exit_now":
        sys.stdout.write("ready\\n")
        sys.stdout.flush()
    return old
signal.signal = _spy
sys.argv[0] = "wfviz"
import runpy
runpy.run_module("wfviz", run_name="__main__", alter_sys=True)
"""


def test_ctrl_c_while_loading_is_one_line(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", _SPY_LOADING, "config"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 60)
    assert ready and proc.stdout.readline() == "ready\n"  # wfviz's handler is set, the rest still loading
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert stderr.strip() == "wfviz: error: interrupted"


# -- property: whatever the output names, inputs are untouched and nothing temporary remains --

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_NAME_PART = st.text(st.sampled_from(list("ab[]/ _-.é中🙂")), min_size=1, max_size=12).filter(
    lambda s: not s.startswith("/") and not s.endswith("/") and "//" not in s and s.strip(". /") != ""
    and all(part not in (".", "..") and part.strip() for part in s.split("/")))


@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(tracks=st.one_of(_NAME_PART, st.sampled_from(["s/frame_000001.png", "s/truth.csv", "truth.csv",
                                                        "cfg.toml", "s", "s/"])),
       rec=st.one_of(st.none(), _NAME_PART, st.sampled_from(["s/frame_000000.png", "truth.csv"])))
def test_any_output_names_leave_inputs_whole(tmp_path_factory: pytest.TempPathFactory, tracks: str,
                                              rec: str | None) -> None:
    root = tmp_path_factory.mktemp("p")
    s = write_folder(root / "s", {f"frame_{i:06d}.png": noise() for i in range(4)})
    (s / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n")
    (root / "truth.csv").write_text("frame,target_id,x,y\n0,1,5,5\n")
    (root / "cfg.toml").write_text("")
    before = digest(root)
    args = ["record", str(s), "--tracks", str(root / tracks), "--truth", str(root / "truth.csv"),
            "--config", str(root / "cfg.toml"), "--no-images"]
    args += ["-o", str(root / rec)] if rec is not None else ["-o", str(root / "out" / "r.rrd")]
    r = invoke(*args)
    after = digest(root)
    for name, sha in before.items():
        assert after.get(name) == sha, (name, args, r.output)  # no input changed or vanished
    assert not temporaries(root), (args, r.output)
    assert r.exit_code in (0, 2), r.output
    if r.exit_code == 2:
        assert r.output.count("\n") <= 2 and "wfviz: error:" in r.output


def test_a_recording_that_cannot_be_written_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from wfviz.record.recorder import Recorder

    np.save(tmp_path / "c.npy", noise(shape=(6, H, W)))

    def fail(self, *args, **kwargs) -> None:
        raise RuntimeError("File-writer thread shut down prematurely")  # what Rerun raises on a full disk

    monkeypatch.setattr(Recorder, "log", fail)
    r = invoke("record", str(tmp_path / "c.npy"), "-o", str(tmp_path / "r.rrd"), "--no-images")
    assert r.exit_code == 2, r.output
    assert f"{tmp_path / 'r.rrd'}: cannot write the recording" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "r.rrd").exists() and not (tmp_path / "r.csv").exists() and not temporaries(tmp_path)


def test_a_full_output_folder_is_refused_before_the_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil

    np.save(tmp_path / "c.npy", noise(shape=(6, H, W)))
    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10 << 20, 10 << 20, 4096))
    r = invoke("track", str(tmp_path / "c.npy"), "--tracks", str(tmp_path / "t.csv"))
    assert r.exit_code == 2 and "output folder is full (4 kB free)" in r.output


def test_outputs_get_the_usual_permissions(tmp_path: Path) -> None:
    np.save(tmp_path / "c.npy", noise(shape=(4, H, W)))
    assert invoke("track", str(tmp_path / "c.npy"), "--tracks", str(tmp_path / "t.csv")).exit_code == 0
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "t.csv").stat().st_mode & 0o777 == 0o666 & ~mask


def test_a_frame_that_is_a_symlink_protects_its_target(tmp_path: Path) -> None:
    real = write_folder(tmp_path / "real", {f"f{i}.png": noise() for i in range(4)})
    links = tmp_path / "links"
    links.mkdir()
    for i in range(4):
        (links / f"l{i}.png").symlink_to(real / f"f{i}.png")
    before = digest(real)
    r = invoke("track", str(links), "--tracks", str(real / "f2.png"))
    assert r.exit_code == 2 and "frame 2 of the input clip" in r.output, r.output
    assert digest(real) == before


def test_a_hard_link_to_the_truth_is_refused(tmp_path: Path) -> None:
    np.save(tmp_path / "c.npy", noise(shape=(4, H, W)))
    truth = _truth(tmp_path / "truth.csv")
    os.link(truth, tmp_path / "other.csv")
    r = invoke("track", str(tmp_path / "c.npy"), "--truth", str(truth), "--tracks", str(tmp_path / "other.csv"))
    assert r.exit_code == 2 and "the truth file" in r.output and truth.read_text().startswith("frame")
