"""``--threads``: the run as a pipeline of threads (:mod:`wfviz.pipeline`) gives the same outputs
as one thread; a sink's error or interrupt still stops the run as it does on one thread."""

from __future__ import annotations

import hashlib
from collections import defaultdict
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from conftest import wfviz
from wfviz.pipeline import PrepareAhead, prepare_ahead, restore
from wfviz.run import SingleRun, drive, run
from wfviz.sinks import BaseSink
from wfviz.synth.demo import demo_clip
from wfviz.trackers import make_tracker

#: recorded per run, not per frame's content: stage times and the recording's start time
TIMED = ("/timing/", "/__properties")


def _content(path: Path) -> dict[tuple[str, str], list[str]]:
    """(entity, column) -> digests of its chunks' values, for every entity but the timed ones."""
    out: dict[tuple[str, str], list[str]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        entity = str(chunk.entity_path)
        if entity.startswith(TIMED):
            continue
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.startswith("rerun.controls") or name in ("log_time", "log_tick"):
                continue
            out[(entity, name)].append(hashlib.sha1(str(batch.column(name).to_pylist()).encode()).hexdigest())
    return {k: sorted(v) for k, v in out.items()}


@pytest.fixture(scope="module")
def clip_folder(tmp_path_factory) -> Path:
    cwd = tmp_path_factory.mktemp("clip")
    proc = wfviz("demo", "--frames", "36", "--no-images", "--save-clip", "clip", "-o", "d/demo.rrd", cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    return cwd / "clip"


def test_record_with_threads_writes_what_one_thread_writes(clip_folder: Path, tmp_path: Path) -> None:
    outs = {}
    for threads in ("1", "3"):
        d = tmp_path / f"t{threads}"
        proc = wfviz("record", str(clip_folder), "--truth", str(clip_folder / "truth.csv"), "-o", str(d / "r.rrd"),
                     "--explain", str(d / "why.csv"), "--threads", threads, "--exact-every", "4")
        assert proc.returncode == 0, proc.stderr
        outs[threads] = d
    one, many = outs["1"], outs["3"]
    for name in ("r.csv", "why.csv", "why-false.csv"):
        assert (one / name).read_bytes() == (many / name).read_bytes(), name
    a, b = _content(one / "r.rrd"), _content(many / "r.rrd")
    assert a and set(a) == set(b)
    assert [k for k in a if a[k] != b[k]] == []
    assert any(e.startswith("/camera/tracks") or "tracks" in e for e, _ in a)  # the check sees the tracks


def test_the_front_end_runs_ahead_only_where_it_does_not_depend_on_the_tracks() -> None:
    gewc = make_tracker("gewc")
    ahead = prepare_ahead(gewc)
    assert isinstance(ahead, PrepareAhead) and gewc.front.source is ahead
    restore(gewc, ahead)
    assert gewc.front.source is gewc.front.preparer
    assert prepare_ahead(make_tracker("fusion")) is None  # its windows follow its tracks
    assert prepare_ahead(make_tracker("tbd")) is None  # no shared front end


class _Fails(BaseSink):
    def __init__(self, at: int, error: BaseException) -> None:
        self.at, self.error, self.seen, self.aborted = at, error, 0, False

    def step(self, step) -> None:
        self.seen += 1
        if step.frame.index == self.at:
            raise self.error

    def abort(self) -> None:
        self.aborted = True


@pytest.mark.parametrize("threads", [1, 2])
def test_a_sink_error_stops_the_run_and_aborts_the_sinks(threads: int) -> None:
    sink = _Fails(5, OSError("disk full"))
    with pytest.raises(OSError, match="disk full"):
        drive(demo_clip(n_frames=20), SingleRun(make_tracker("gewc")), [sink], threads=threads)
    assert sink.aborted and sink.seen == 6  # no step after the failing one reached it


@pytest.mark.parametrize("threads", [1, 2])
def test_an_interrupt_from_a_sink_ends_the_run_with_the_frames_done(threads: int) -> None:
    sink = _Fails(7, KeyboardInterrupt())
    summary = drive(demo_clip(n_frames=20), SingleRun(make_tracker("gewc")), [sink], threads=threads)
    assert summary.interrupted and not sink.aborted
    assert sink.seen == 8 and 8 <= summary.frames <= 8 + 3  # the tracker may be up to the queue's depth ahead


def test_stage_times_come_from_the_front_end_thread(tmp_path: Path) -> None:
    clip = demo_clip(n_frames=12)
    times: list[dict[str, float]] = []
    run(clip, make_tracker("gewc"), threads=2, on_frame=lambda f, r: times.append(r.timings))
    assert len(times) == 12
    assert all(t["camera"] > 0 and t["suppress"] > 0 and t["detect"] > 0 for t in times[1:])
    # the total is the frame's whole work, the stages timed in the front end's thread included
    assert all(t["total"] >= sum(v for k, v in t.items() if k != "total") - 1e-6 for t in times)
