"""A run as a pipeline of threads (``--threads``): frames decoded ahead
(:func:`wfviz.io.frames.read_ahead`), the stages before detection run ahead of the tracker
(:class:`PrepareAhead`), the tracker on the calling thread, and the sinks (tracks CSV, recording,
scores) behind it (:class:`SinkThread`). NumPy and OpenCV release the GIL in their loops, so the
threads share the cores. Every thread does the same work in the same order as a run on one
thread, so the outputs are identical (tests/test_pipeline.py); only the times differ.

Measured (docs/performance.md): on the 2-vCPU machine of the benchmarks two independent
CPU-bound processes run 1.5-1.8x as fast at once as in turn, and ``track`` and ``record`` run
1.1-1.3x as fast on both as on one: the tracker's and the recorder's Python share the GIL. The
front end in a child process instead of a thread (no shared GIL) was tried and ran slower: the
prepared frames (3-8 MB each) cost more to send than the GIL did."""

from __future__ import annotations

import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from wfviz.io.frames import Frame, read_ahead

#: frames a stage may run ahead of the next one (bounds the memory held in the queues)
DEPTH = 2


def default_threads() -> int:
    """``--threads`` by default: the cores this process may run on (at most 4, one per stage)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, 4))


class PrepareAhead:
    """A :class:`~wfviz.stages.front_end.PreparedSource` whose frames are prepared by a tracker's
    own :class:`~wfviz.stages.front_end.Preparer` in a background thread, up to :data:`DEPTH`
    frames ahead of the tracker. Only for a front end that does not depend on the tracks
    (:func:`prepare_ahead` checks), so the frames are those the tracker would prepare itself.
    Each stage's time (that thread's CPU time, so that waiting for the GIL while the tracker runs
    is not counted as the stage's) is handed to the tracker's timer with the frame."""

    def __init__(self, stages: Any) -> None:
        self.stages = stages
        self._ready: deque[tuple[Any, Any, list[tuple[str, float]]]] = deque()
        self._circle = None
        #: ms the stages took (in their thread) on the last frame handed out
        self.last_ms = 0.0

    @property
    def circle(self) -> Any:
        """The imaging circle as of the last frame handed out."""
        return self._circle

    def feed(self, frames: Iterator[Frame]) -> Iterator[Frame]:
        """``frames`` in order, each prepared (in a background thread) by the time it is
        yielded; closing the iterator stops that thread."""

        def prepared() -> Iterator[tuple[Frame, Any, list[tuple[str, float]]]]:
            try:
                for frame in frames:
                    laps: list[tuple[str, float]] = []
                    t0 = [time.thread_time()]

                    def lap(stage: str) -> None:  # this thread's CPU time: not the waits for the GIL
                        t1 = time.thread_time()
                        laps.append((stage, (t1 - t0[0]) * 1e3))
                        t0[0] = t1

                    yield frame, self.stages.prepare(frame.image, lap), laps
            finally:
                getattr(frames, "close", lambda: None)()

        stream = read_ahead(prepared(), DEPTH)
        try:
            for frame, p, laps in stream:
                self._ready.append((frame.image, p, laps))
                yield frame
        finally:
            stream.close()

    def prepare(self, raw: Any, lap: Callable[..., None], whole: bool = True,
                update_horizon: bool = True) -> Any:
        """The prepared frame of ``raw`` (the next frame fed); its stage times go to ``lap``."""
        if not self._ready or self._ready[0][0] is not raw or not (whole and update_horizon):
            raise RuntimeError("PrepareAhead: frames must be stepped in the order they were fed, searched whole")
        _, p, laps = self._ready.popleft()
        self._circle = p.circle
        self.last_ms = sum(ms for _, ms in laps)
        for stage, ms in laps:
            lap(stage, ms)
        return p


def prepare_ahead(tracker: Any) -> PrepareAhead | None:
    """Give ``tracker`` a :class:`PrepareAhead` source around its own stages when its front end
    is its own, searches whole frames and does not depend on the tracks (GEWC in "cfar" mode;
    not fusion, whose windows follow its tracks, nor the trackers without the front end);
    None (nothing changed) otherwise."""
    front = getattr(tracker, "front", None)
    preparer = getattr(front, "preparer", None)
    if preparer is None or front.source is not preparer or not getattr(tracker, "searches_whole_frames", False):
        return None
    if not front.independent_of_tracks(front.config):
        return None
    ahead = PrepareAhead(preparer)
    front.source = ahead
    return ahead


def restore(tracker: Any, ahead: PrepareAhead | None) -> None:
    """Undo :func:`prepare_ahead` (the tracker prepares its frames itself again)."""
    if ahead is not None:
        tracker.front.source = ahead.stages


class SinkThread:
    """The sinks' :meth:`publish` and :meth:`step` of each step, in order, in a background thread
    (at most :data:`DEPTH` steps behind). An error a sink raises (a KeyboardInterrupt too)
    comes back from the next :meth:`send` or from :meth:`drain`."""

    def __init__(self, sinks: Sequence[Any]) -> None:
        self.sinks = sinks
        self._items: queue.Queue = queue.Queue(maxsize=DEPTH)
        self._error: BaseException | None = None
        self._failed = False
        self._thread = threading.Thread(target=self._serve, name="wfviz-sinks", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while True:
            step = self._items.get()
            if step is None:
                return
            if self._failed:
                continue  # a sink failed: the steps after it are dropped (the run is stopping)
            try:
                deliver(self.sinks, step)
            except BaseException as exc:  # noqa: BLE001 - handed back to the loop
                self._error, self._failed = exc, True

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def send(self, step: Any) -> None:
        """Queue ``step`` for the sinks (waits while :data:`DEPTH` steps are queued)."""
        self._raise()
        self._items.put(step)

    def drain(self, deliver: bool = True) -> None:
        """Wait until every queued step is delivered (``deliver`` False: dropped, the run is
        failing); raise a sink's error."""
        if not deliver:
            self._failed = True
        if self._thread.is_alive():
            self._items.put(None)
            self._thread.join()
        self._raise()


def deliver(sinks: Sequence[Any], step: Any) -> None:
    """``step`` published by every sink, then to every sink (:mod:`wfviz.sinks`)."""
    for sink in sinks:
        sink.publish(step)
    for sink in sinks:
        sink.step(step)
