"""The recorder's image cost a frame, apart from a run: `wfviz.record.images.ImageLog` logging
the demo's raw frame and background-suppressed image every frame (exact every 10th frame, JPEG
previews between) and three 640x512 value maps on the exact frames (noise and multi-frame score
in half precision, the clutter map in single), as `wfviz record` logs its images.

    taskset -c 1 python benchmarks/image_log.py [--rounds 5] [--frames 160]

CPU time of the process (Rerun's file-writer thread included) per frame, best of the rounds;
compare two versions by running it with each on `PYTHONPATH`, interleaved.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--frames", type=int, default=160)
    args = ap.parse_args()
    from wfviz.record.arrow import arrow_without_pandas
    arrow_without_pandas()
    import rerun as rr

    from wfviz.record.images import ImageLog
    from wfviz.stages.background import suppress_background
    from wfviz.synth.demo import demo_clip

    raw = [f.image for f in demo_clip(0, n_frames=args.frames).frames()]
    residual = [suppress_background(r) for r in raw]
    rng = np.random.default_rng(0)
    # the value maps of an exact frame, in the dtypes the recorder logs them in
    maps = [("suppressed/noise", rng.random(raw[0].shape).astype(np.float16)),
            ("suppressed/multiframe", rng.random(raw[0].shape).astype(np.float16)),
            ("clutter/map", rng.random(raw[0].shape).astype(np.float32))]
    rounds = []
    with tempfile.TemporaryDirectory() as d:
        rec = rr.RecordingStream("wfviz-image-log-benchmark")
        rec.save(Path(d) / "images.rrd")
        for _ in range(args.rounds):
            log = ImageLog(rec, threaded=False)
            t0 = time.process_time()
            for n, (r, s) in enumerate(zip(raw, residual)):
                if log.begin_frame(n, n, n / 25.0):
                    log.log("camera/image", r)
                    log.log("suppressed/image", s)
                    if log.exact:
                        for path, m in maps:
                            log.log(path, m, value_map=True)
            log.close()
            rec.flush()  # the file writer's work on this round's last chunks counts in this round
            rounds.append((time.process_time() - t0) / len(raw) * 1e3)
        rec.disconnect()
    print(f"ImageLog: {min(rounds):.3f} ms a frame (best of {len(rounds)}; rounds "
          f"{', '.join(f'{r:.3f}' for r in rounds)})")


if __name__ == "__main__":
    main()
