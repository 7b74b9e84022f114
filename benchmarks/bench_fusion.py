"""Time the feature-fusion tracker alone, per stage, on one core.

Frames are rendered into memory first (decoding and rendering are not timed); the tracker is
then run over them ``--runs`` times, a fresh tracker each run. For every frame and stage the
median over the runs is kept; the table reports, over the frames, the median, mean and 95th
percentile of each stage, for all frames and separately for the frames that searched only the
windows and those that ran the global detection. Run from the repository root:

    python benchmarks/bench_fusion.py                       # uniform-50hz, seed 0, 7 runs
    python benchmarks/bench_fusion.py --scenario fov70-four-targets --runs 3
    python benchmarks/bench_fusion.py --config my.toml      # a fusion config file
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy / OpenCV load their thread pools
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import platform
import sys
from pathlib import Path

import cv2
import numpy as np

from wfviz.trackers.fusion.config import FusionConfig
from wfviz.trackers.fusion import FusionTracker

sys.path.insert(0, str(Path(__file__).resolve().parent))
from step_timing import bench_args, bench_frames, time_steps

STAGES = ["defects", "mask", "horizon", "windows", "suppress", "detect", "associate", "kalman", "total"]


def main() -> None:
    args = bench_args(__doc__, "fusion", "uniform-50hz", 7)
    config, frames = bench_frames(args, FusionConfig)
    h, w = frames[0].image.shape
    t = time_steps(lambda: FusionTracker(config), frames, args.runs, STAGES, warmup=20,
                   extra=lambda r: r.global_detection)
    stages, wall, cpu = t.table, t.wall, t.cpu
    glob = t.extra[0].astype(bool)
    if (t.extra != t.extra[0]).any():
        print("warning: runs differ in their global-detection frames")

    print(f"{args.scenario} seed {args.seed}: {len(frames)} frames {w}x{h}, {args.runs} runs, one core "
          f"({platform.machine()}, Python {platform.python_version()}, OpenCV {cv2.__version__}); "
          f"ms per frame, per-frame median over the runs")
    print(f"global detection on {int(glob.sum())} of {len(frames)} frames")
    groups = [("all frames", np.ones(len(frames), bool)), ("window frames", ~glob), ("global frames", glob)]
    header = f"{'stage':11s}" + "".join(f" | {name + ' median/mean/p95':>30s}" for name, _ in groups)
    print(header)
    print("-" * len(header))
    extra = {"step (wall)": wall, "step (CPU)": cpu}  # CPU time: robust when the machine is shared
    for j, s in enumerate(STAGES + list(extra)):
        col = extra[s] if s in extra else stages[:, j]
        cells = []
        for _, sel in groups:
            v = col[sel]
            cells.append(f"{np.median(v):8.3f} {np.mean(v):8.3f} {np.percentile(v, 95):8.3f}"
                         if v.size else f"{'–':>26s}")
        print(f"{s:11s}" + "".join(f" | {c:>30s}" for c in cells))


if __name__ == "__main__":
    main()
