"""The timing loop every tracker benchmark shares: repeated runs over in-memory frames."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from wfviz.config import load_config
from wfviz.io.frames import Frame
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers import Tracker


def bench_args(doc: str, tracker: str, scenario: str, runs: int, snr: bool = False) -> argparse.Namespace:
    """The options every tracker benchmark takes: scenario, seed, frames, runs, config (and
    ``--snr`` where the scenario has one)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--scenario", default=scenario)
    ap.add_argument("--seed", type=int, default=0)
    if snr:
        ap.add_argument("--snr", type=float, default=None, help="peak SNR of every target (lowsnr-tbd: 3)")
    ap.add_argument("--frames", type=int, default=None, help="frames (default: the whole scenario)")
    ap.add_argument("--runs", type=int, default=runs)
    ap.add_argument("--config", default=None, help=f"{tracker} TOML config (default: defaults)")
    return ap.parse_args()


def bench_frames(args: argparse.Namespace, config_type: type) -> tuple[Any, list[Frame]]:
    """OpenCV on one thread; the config from ``--config``; the scenario's frames in memory
    (rendering is not timed)."""
    cv2.setNumThreads(1)
    clip = make_scenario(args.scenario, seed=args.seed, n_frames=args.frames, snr=getattr(args, "snr", None))
    return load_config(args.config, config_type), list(clip.frames())


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
