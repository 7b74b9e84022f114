"""Tests for wfviz.io.frames.read_ahead (decoding in a background thread) and the CLIP/frames layout."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import write_folder
from test_clip import ramp
from wfviz.cli import app
from wfviz.io.clip import open_clip
from wfviz.io.frames import Frame, read_ahead


def numbered(n: int, fail_at: int | None = None, closed: list[bool] | None = None):
    """Frames 0..n-1 (raising at ``fail_at``); appends True to ``closed`` when closed."""
    try:
        for i in range(n):
            if i == fail_at:
                raise ValueError(f"bad frame {i}")
            yield Frame(i, i / 25.0, np.full((4, 4), i, np.uint8))
    finally:
        if closed is not None:
            closed.append(True)


def readers() -> int:
    return sum(t.name == "wfviz-read-ahead" for t in threading.enumerate())


def test_frames_arrive_in_order_and_whole() -> None:
    got = list(read_ahead(numbered(50), depth=3))
    assert [f.index for f in got] == list(range(50))
    assert all(int(f.image[0, 0]) == f.index for f in got)
    assert readers() == 0


def test_an_error_arrives_where_its_frame_would() -> None:
    seen = []
    with pytest.raises(ValueError, match="bad frame 7"):
        for f in read_ahead(numbered(20, fail_at=7)):
            seen.append(f.index)
    assert seen == list(range(7))
    assert readers() == 0


def test_leaving_early_stops_the_reader_and_closes_the_source() -> None:
    closed: list[bool] = []
    stream = read_ahead(numbered(10_000, closed=closed), depth=2)
    for f in stream:
        if f.index == 3:
            break
    stream.close()
    assert closed == [True]
    deadline = time.monotonic() + 5
    while readers() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert readers() == 0


def test_scene_folder_with_a_frames_subfolder(tmp_path: Path) -> None:
    scene = tmp_path / "S9"
    scene.mkdir()
    write_folder(scene / "frames", {f"frame_{i:06d}.png": ramp(10 + i) for i in range(3)})
    (scene / "truth.csv").write_text("frame,target_id,x,y\n")
    clip = open_clip(scene)
    assert clip.name == "S9" and clip.n_frames == 3
    r = CliRunner().invoke(app, ["track", str(scene), "--tracks", str(tmp_path / "t.csv")])
    assert r.exit_code == 0, r.output
    assert "reading" in r.output and (tmp_path / "t.csv").exists()


def test_a_folder_with_images_of_its_own_is_read_itself(tmp_path: Path) -> None:
    write_folder(tmp_path / "seq", {f"a{i}.png": ramp(i) for i in range(2)})
    write_folder(tmp_path / "seq" / "frames", {f"b{i}.png": ramp(i) for i in range(5)})
    assert open_clip(tmp_path / "seq").n_frames == 2
