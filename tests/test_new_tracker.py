"""A new tracker is one package, one recorder adapter and one registry line: a toy tracker
(the brightest pixel is the one track) registered with the base Recorder as its adapter runs
through `wfviz record` and `wfviz bench` with nothing else changed."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from wfviz.cli import app
from wfviz.io.frames import Frame
from wfviz.stages.detection import no_detections
from wfviz.trackers import TRACKERS, TrackerEntry
from wfviz.trackers.base import FrameResult, StageTimer, min_side
from wfviz.tracking import TrackState


@dataclass(frozen=True)
class BrightestTracking:
    trail_length: int = 10


@dataclass(frozen=True)
class BrightestConfig:
    tracking: BrightestTracking = BrightestTracking()


class BrightestTracker:
    """Track 1 is the brightest pixel of every frame."""

    name = "brightest"

    def __init__(self, config: BrightestConfig | None = None) -> None:
        self.config = config or BrightestConfig()

    def min_frame_side(self) -> int:
        return min_side()  # no windows of its own: the pipeline's minimum

    def step(self, frame: Frame) -> FrameResult:
        timer = StageTimer()
        y, x = np.unravel_index(int(np.argmax(frame.image)), frame.image.shape[:2])
        timer.lap("argmax")
        track = TrackState(1, float(x), float(y), 0.0, 0.0, True, False, frame.index + 1, 0)
        return FrameResult(frame.index, frame.time, (track,), (), no_detections(frame.image.shape[:2]), (),
                           timer.done())


@pytest.fixture
def registered(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(TRACKERS, "brightest", TrackerEntry(BrightestTracker, BrightestConfig,
                                                           "wfviz.record.recorder:Recorder"))


def test_a_registered_tracker_records_and_benches(registered: None, tmp_path: Path) -> None:
    rrd, tracks = tmp_path / "b.rrd", tmp_path / "b.csv"
    r = CliRunner().invoke(app, ["record", "synth:lowsnr-tbd:0", "--tracker", "brightest", "--stop", "6",
                                 "-o", str(rrd), "--tracks", str(tracks)])
    assert r.exit_code == 0, r.output
    with tracks.open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(row["frame"]) for row in rows] == list(range(6)) and {row["track_id"] for row in rows} == {"1"}
    paths = {chunk.entity_path for chunk in RrdReader(rrd).stream()}
    assert "/camera/image" in paths and "/camera/tracks" in paths, sorted(paths)
    r = CliRunner().invoke(app, ["bench", "synth:lowsnr-tbd:0", "--tracker", "brightest", "--stop", "8"])
    assert r.exit_code == 0 and "argmax" in r.output, r.output
    r = CliRunner().invoke(app, ["config", "--tracker", "brightest"])
    assert r.exit_code == 0 and "trail_length = 10" in r.output, r.output
