"""Per-stage timing of a tracker on a clip: decoding and each stage measured separately."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from wfviz.io.frames import Clip
from wfviz.trackers import Tracker


@dataclass(frozen=True)
class StageTiming:
    """Milliseconds per frame for one stage: median, mean, 95th percentile."""

    stage: str
    median: float
    mean: float
    p95: float


@dataclass(frozen=True)
class BenchResult:
    """Frames timed, the decoding cost and each tracker stage's cost (``total`` last)."""

    frames: int
    shape: tuple[int, int]
    decode: StageTiming
    stages: tuple[StageTiming, ...]


def _timing(stage: str, values: list[float]) -> StageTiming:
    a = np.asarray(values, dtype=np.float64)
    return StageTiming(stage, float(np.median(a)), float(a.mean()), float(np.percentile(a, 95)))


def bench(clip: Clip, tracker: Tracker, start: int = 0, stop: int | None = None,
          warmup: int = 3) -> BenchResult:
    """Run ``tracker`` over ``clip`` once, timing decoding and every stage it reports."""
    decode: list[float] = []
    per_stage: dict[str, list[float]] = {}
    frames = clip.frames(start, stop)
    n = 0
    shape = (0, 0)
    while True:
        t0 = time.perf_counter()
        frame = next(frames, None)
        t_decode = (time.perf_counter() - t0) * 1e3
        if frame is None:
            break
        result = tracker.step(frame)
        n += 1
        shape = frame.image.shape
        if n <= warmup:
            continue
        decode.append(t_decode)
        for stage, ms in result.timings.items():
            per_stage.setdefault(stage, []).append(ms)
    if not decode:
        raise ValueError(f"{clip.name}: need more than {warmup} frames to time (got {n})")
    order = [s for s in per_stage if s != "total"] + (["total"] if "total" in per_stage else [])
    return BenchResult(len(decode), shape, _timing("decode", decode),
                       tuple(_timing(s, per_stage[s]) for s in order))


def format_bench(result: BenchResult, tracker: str) -> str:
    """A plain-text table: one row per stage, decoding first."""
    h, w = result.shape
    rows = [f"{tracker} on {w}x{h} frames, {result.frames} frames timed (ms per frame)",
            f"{'stage':<12}{'median':>9}{'mean':>9}{'p95':>9}"]
    for t in (result.decode, *result.stages):
        rows.append(f"{t.stage:<12}{t.median:9.3f}{t.mean:9.3f}{t.p95:9.3f}")
    total = result.stages[-1] if result.stages and result.stages[-1].stage == "total" else None
    if total is not None and total.mean > 0:
        rows.append(f"tracking alone: {1e3 / total.mean:.0f} frames/s (mean); with decoding: "
                    f"{1e3 / (total.mean + result.decode.mean):.0f} frames/s")
    return "\n".join(rows)
