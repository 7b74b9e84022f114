"""Interrupted runs: SIGINT/SIGTERM finish the current frame and leave complete, verified
outputs holding exactly the frames reported; the previous signal handlers come back."""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from conftest import verify
from wfviz.io.clip import open_clip
from wfviz.record_options import RecorderOptions
from wfviz.run import run
from wfviz.trackers import make_tracker

N_FRAMES = 300
#: The CLI with every tracker step slowed down (15 ms), so a signal lands inside a frame.
SLOW_CLI = """
import sys, time
from wfviz.trackers.gewc import GEWCTracker
step = GEWCTracker.step
def slow_step(self, frame):
    time.sleep(0.015)
    return step(self, frame)
GEWCTracker.step = slow_step
from wfviz.cli import main
sys.argv[0] = "wfviz"
main()
"""


def moving_spot(path: Path, n: int = N_FRAMES, size: int = 64) -> Path:
    rng = np.random.default_rng(3)
    stack = rng.normal(1000, 5, (n, size, size)).astype(np.uint16)
    for t in range(n):
        stack[t, 20 + (t // 12) % 30, 10 + (t // 7) % 40] += 300
    np.save(path, stack)
    return path


def rrd_frames(path: Path) -> tuple[dict[str, set[int]], list[str]]:
    """{entity: frames with data} and every text of the ``log`` entity."""
    frames: dict[str, set[int]] = {}
    logs: list[str] = []
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        if "frame" in batch.schema.names:
            frames.setdefault(chunk.entity_path, set()).update(batch.column("frame").to_pylist())
        if chunk.entity_path == "/log":
            logs += [t for row in batch.column("TextLog:text").to_pylist() for t in row]
    return frames, logs


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_leaves_a_complete_recording_of_the_frames_done(tmp_path: Path, sig: int, code: int) -> None:
    clip = moving_spot(tmp_path / "clip.npy")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_CLI, "record", str(clip), "-o", str(out / "r.rrd")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + 60
    def temp() -> Path | None:
        found = list(out.glob(".r.rrd.*.wfviz-part")) if out.exists() else []
        return found[0] if found else None

    while temp() is None or temp().stat().st_size == 0:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.02)
    time.sleep(0.4)  # some frames in (at 15+ ms each), far from the end
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, stdout + stderr
    name = signal.Signals(sig).name
    n = int(re.search(rf"interrupted by {name}: (\d+) frames", stdout).group(1))
    assert 0 < n < N_FRAMES and f"recording: {out / 'r.rrd'} ({n} frames, 0-{n - 1})" in stdout
    assert sorted(p.name for p in out.iterdir()) == ["r.csv", "r.rrd"]  # no temporary file left
    verify(out / "r.rrd")
    frames, logs = rrd_frames(out / "r.rrd")
    assert frames["/camera/image"] == set(range(n)) == frames["/timing/total"]
    assert set().union(*frames.values()) == set(range(n))
    assert f"interrupted by {name} after {n} frames" in logs
    with open(out / "r.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and max(int(r["frame"]) for r in rows) == n - 1


def test_a_complete_run_verifies(tmp_path: Path) -> None:
    clip = open_clip(moving_spot(tmp_path / "clip.npy", n=20, size=48))
    summary = run(clip, make_tracker("gewc"), recording=tmp_path / "r.rrd",
                  recorder_options=RecorderOptions(source="test", config_text=""))
    assert summary.frames == 20 and not summary.interrupted
    verify(tmp_path / "r.rrd")
    assert set().union(*rrd_frames(tmp_path / "r.rrd")[0].values()) == set(range(20))


def test_handlers_stop_between_frames_and_are_restored(tmp_path: Path) -> None:
    clip = open_clip(moving_spot(tmp_path / "clip.npy", n=40, size=48))
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def on_frame(frame, result) -> None:
        if frame.index == 5:
            os.kill(os.getpid(), signal.SIGTERM)  # handled at once, in this thread

    summary = run(clip, make_tracker("gewc"), tracks_csv=tmp_path / "t.csv", on_frame=on_frame)
    assert (summary.frames, summary.signal, summary.interrupted) == (6, signal.SIGTERM, True)
    assert (summary.first, summary.last) == (0, 5)
    assert {s: signal.getsignal(s) for s in before} == before
    assert not list(tmp_path.glob(".t.csv.*"))
    with open(tmp_path / "t.csv", newline="") as fh:
        assert max(int(r["frame"]) for r in csv.DictReader(fh)) == 5
