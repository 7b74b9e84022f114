"""Time the star-field tracker alone, per stage, on one core.

Frames are rendered into memory first (decoding and rendering are not timed); the tracker is
then run over them ``--runs`` times, a fresh tracker each run. For every frame and stage the
median over the runs is kept; the table reports, over the frames, the median, mean and 95th
percentile of each stage. A second table splits the segmentation into its steps (timed by
calling them directly on the same frames). Run from the repository root:

    python benchmarks/bench_starfield.py                    # starfield, seed 0, 5 runs
    python benchmarks/bench_starfield.py --seed 2 --runs 3
    python benchmarks/bench_starfield.py --config my.toml   # a starfield config file
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy / OpenCV load their thread pools
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from wfviz.trackers.starfield.config import StarfieldConfig
from wfviz.io.frames import Frame
from wfviz.trackers.starfield import segmentation as seg
from wfviz.trackers.starfield import StarfieldTracker

sys.path.insert(0, str(Path(__file__).resolve().parent))
from step_timing import bench_args, bench_frames, time_steps

STAGES = ["segment", "register", "candidates", "chains", "resegment", "total"]
PAPER_MS = 768.7  # the paper's mean per 1024x1024 frame (MATLAB-era, AMD dual core 2.3 GHz)


def segmentation_steps(frames: list[Frame], config: StarfieldConfig, runs: int) -> dict[str, np.ndarray]:
    """Median ms per frame of each segmentation step."""
    c = config.segmentation
    steps: dict[str, list[list[float]]] = {k: [] for k in ("background", "smooth + stats", "components")}
    for _ in range(runs):
        per = {k: [] for k in steps}
        for f in frames:
            t0 = time.perf_counter()
            img = f.image.astype(np.float32)
            residual = img - seg.estimate_background(img, c.background_block, c.background_sigma)
            t1 = time.perf_counter()
            smoothed = cv2.GaussianBlur(residual, (0, 0), c.smooth_sigma)
            level, sigma = seg.robust_stats(smoothed)
            binary = (smoothed > level + c.k_sigma * sigma).view(np.uint8)
            t2 = time.perf_counter()
            seg._components(binary, residual, smoothed, c.min_area, c.max_area, 0.0)
            t3 = time.perf_counter()
            per["background"].append((t1 - t0) * 1e3)
            per["smooth + stats"].append((t2 - t1) * 1e3)
            per["components"].append((t3 - t2) * 1e3)
        for k in steps:
            steps[k].append(per[k])
    return {k: np.median(v, axis=0) for k, v in steps.items()}


def main() -> None:
    args = bench_args(__doc__, "starfield", "starfield", 5)
    config, frames = bench_frames(args, StarfieldConfig)
    h, w = frames[0].image.shape
    t = time_steps(lambda: StarfieldTracker(config), frames, args.runs, STAGES, warmup=8)
    stages, wall = t.table, t.wall

    print(f"{args.scenario} seed {args.seed}: {len(frames)} frames {w}x{h}, {args.runs} runs, one core "
          f"({platform.machine()}, Python {platform.python_version()}, OpenCV {cv2.__version__}); "
          f"ms per frame, per-frame median over the runs")
    print(f"{'stage':16s} | {'median':>7s} {'mean':>7s} {'p95':>7s}")
    rows = [(s, stages[:, i]) for i, s in enumerate(STAGES)] + [("step (wall)", wall)]
    for name, v in rows:
        print(f"{name:16s} | {np.median(v):7.2f} {np.mean(v):7.2f} {np.percentile(v, 95):7.2f}")
    print(f"\nsegmentation steps (called directly, {len(frames)} frames):")
    for name, v in segmentation_steps(frames, config, args.runs).items():
        print(f"  {name:14s} | {np.median(v):7.2f} {np.mean(v):7.2f} {np.percentile(v, 95):7.2f}")
    print(f"\nmedian {np.median(wall):.1f} ms per frame = {PAPER_MS / np.median(wall):.0f}x faster than the "
          f"paper's {PAPER_MS} ms; budget 50 ms: {'met' if np.median(wall) <= 50 else 'NOT met'}")


if __name__ == "__main__":
    main()
