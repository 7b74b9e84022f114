"""Per-stage timing of a tracker on a clip: the drive loop (:func:`wfviz.run.drive`) without
read-ahead, so decoding and each stage are measured separately, and nothing written."""

from __future__ import annotations

from dataclasses import dataclass

from wfviz.io.frames import Clip
from wfviz.run import SingleRun, drive
from wfviz.sinks import StageTiming, TimingSink
from wfviz.trackers.base import Tracker


@dataclass(frozen=True)
class BenchResult:
    """Frames timed, the decoding cost and each tracker stage's cost (``total`` last); the
    signal that stopped the run early (None: it ran to the end)."""

    frames: int
    shape: tuple[int, int]
    decode: StageTiming
    stages: tuple[StageTiming, ...]
    signal: int | None = None


def bench(clip: Clip, tracker: Tracker, start: int = 0, stop: int | None = None,
          warmup: int = 3) -> BenchResult:
    """Run ``tracker`` over ``clip`` once, timing decoding and every stage it reports (the
    first ``warmup`` frames left out)."""
    timing = TimingSink(warmup)
    summary = drive(clip, SingleRun(tracker), [timing], start=start, stop=stop, ahead=False)
    if not timing.decode:
        if summary.signal is not None:  # stopped before a frame was timed: nothing to show
            raise KeyboardInterrupt
        raise ValueError(f"{clip.name}: need more than {warmup} frames to time (got {timing.seen})")
    decode, stages = timing.timings()
    return BenchResult(len(timing.decode), timing.shape, decode, stages, summary.signal)


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
