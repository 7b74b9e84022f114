"""The timing loop every tracker benchmark shares: repeated runs over in-memory frames."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from wfviz.frames import Frame
from wfviz.trackers import Tracker


@dataclass(frozen=True)
class StepTimes:
    """Per frame, the median over the runs of each stage's ms (``stages`` columns), of the
    step's wall and CPU (thread) ms; ``extra`` (runs, frames) holds ``extra(result)``."""

    stages: list[str]
    table: np.ndarray
    wall: np.ndarray
    cpu: np.ndarray
    extra: np.ndarray


def time_steps(make: Callable[[], Tracker], frames: list[Frame], runs: int,
               stages: list[str] | None = None, warmup: int | None = None,
               extra: Callable[[object], float] | None = None) -> StepTimes:
    """Run a fresh tracker from ``make()`` over ``frames`` ``runs`` times, after a warm-up run
    over the first ``warmup`` frames (all of them when None). ``stages`` defaults to the
    stages the tracker reports, ``total`` left out."""
    warm = make()
    for f in frames[:warmup]:
        result = warm.step(f)
        stages = stages or [s for s in result.timings if s != "total"]
    tables, walls, cpus, extras = [], [], [], []
    for _ in range(runs):
        tracker = make()
        table = np.zeros((len(frames), len(stages or [])))
        wall, cpu, ex = np.zeros(len(frames)), np.zeros(len(frames)), np.zeros(len(frames))
        for i, f in enumerate(frames):
            c0, t0 = time.thread_time(), time.perf_counter()
            result = tracker.step(f)
            wall[i] = (time.perf_counter() - t0) * 1e3
            cpu[i] = (time.thread_time() - c0) * 1e3
            table[i] = [result.timings.get(s, 0.0) for s in stages or []]
            ex[i] = extra(result) if extra is not None else 0.0
        tables.append(table)
        walls.append(wall)
        cpus.append(cpu)
        extras.append(ex)
    return StepTimes(list(stages or []), np.median(tables, axis=0), np.median(walls, axis=0),
                     np.median(cpus, axis=0), np.array(extras))
