"""Time the track-before-detect tracker alone, per stage, on one core.

Frames are rendered into memory first (rendering is not timed); the tracker is then run over
them ``--runs`` times, a fresh tracker (same seed) each run. For every frame and stage the
median over the runs is kept; the table reports, over the frames, the median, mean and 95th
percentile of each stage. Run from the repository root:

    python benchmarks/bench_tbd.py                          # lowsnr-tbd (64x64), SNR 3, 7 runs
    python benchmarks/bench_tbd.py --scenario fov70-four-targets --frames 60 --runs 3   # 640x512
    python benchmarks/bench_tbd.py --config my.toml         # a tbd config file
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

from wfviz.trackers.tbd.config import TBDConfig
from wfviz.trackers.tbd import STAGES, TBDTracker

sys.path.insert(0, str(Path(__file__).resolve().parent))
from step_timing import bench_args, bench_frames, time_steps

COLUMNS = list(STAGES) + ["total"]


def main() -> None:
    args = bench_args(__doc__, "tbd", "lowsnr-tbd", 7, snr=True)
    config, frames = bench_frames(args, TBDConfig)
    h, w = frames[0].image.shape
    t = time_steps(lambda: TBDTracker(config), frames, args.runs, COLUMNS, warmup=5,
                   extra=lambda r: len(r.regions))
    stages, wall, cpu = t.table, t.wall, t.cpu
    regions = t.extra[0]
    f = config.filter
    print(f"{args.scenario} seed {args.seed}: {len(frames)} frames {w}x{h}, {args.runs} runs, one core "
          f"({platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}, "
          f"OpenCV {cv2.__version__}); N_max {f.max_targets}, particles per PF_n "
          f"{f.birth_particles} + {f.continuation_particles} + {f.death_particles}; "
          f"regions per frame {np.median(regions):.0f} median, {regions.max():.0f} max")
    print("ms per frame, per-frame median over the runs")
    header = f"{'stage':12s} | {'median':>8s} {'mean':>8s} {'p95':>8s}"
    print(header)
    print("-" * len(header))
    extra = {"step (wall)": wall, "step (CPU)": cpu}  # CPU time: robust when the machine is shared
    for j, s in enumerate(COLUMNS + list(extra)):
        col = extra[s] if s in extra else stages[:, j]
        print(f"{s:12s} | {np.median(col):8.3f} {np.mean(col):8.3f} {np.percentile(col, 95):8.3f}")


if __name__ == "__main__":
    main()
