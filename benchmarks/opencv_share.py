"""How much of a tracker's step is spent inside OpenCV calls, which are compiled already.

Every function of the ``cv2`` namespace is wrapped with a timer before wfviz is imported, so
every call the tracker makes is counted (the trackers call OpenCV functions only, no OpenCV
object's methods). There is no profiler, so the step times stay close to
`wfviz bench`. The OpenCV share is a floor for the per-frame budget: compiling the NumPy and
Python between the calls cannot take it away. Only fewer or cheaper OpenCV passes can.

    taskset -c 1 python benchmarks/opencv_share.py [CLIP] [--tracker gewc] [--rounds 3] [--frames 160]
    taskset -c 1 python benchmarks/opencv_share.py synth:uniform-50hz --tracker fusion --frames 200

CLIP defaults to `demo`, the demo clip (160 frames of 640x512, as `wfviz demo` and
`benchmarks/performance.py` use); any clip `wfviz track` reads works. Frames are decoded first,
outside the timing. The best round by mean step time is printed, with the largest OpenCV calls.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

SPENT: defaultdict[str, float] = defaultdict(float)
CALLS: defaultdict[str, int] = defaultdict(int)


def _timed(name: str, f: Callable[..., Any]) -> Callable[..., Any]:
    def call(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return f(*args, **kwargs)
        finally:
            SPENT[name] += time.perf_counter() - t
            CALLS[name] += 1
    return call


def wrap_opencv() -> None:
    """Replace every OpenCV function in the ``cv2`` namespace by a timed one."""
    for name in dir(cv2):
        f = getattr(cv2, name)
        if type(f).__name__ == "builtin_function_or_method":
            setattr(cv2, name, _timed(name, f))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("clip", nargs="?", default="demo")
    ap.add_argument("--tracker", default="gewc")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=160)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    wrap_opencv()
    from wfviz.io.clip import open_clip  # after wrapping: every cv2 lookup finds the timed one
    from wfviz.synth.demo import demo_clip
    from wfviz.trackers import make_tracker

    frames = []
    clip = demo_clip(0) if args.clip == "demo" else open_clip(args.clip)
    for frame in clip.frames():
        frames.append(frame)
        if len(frames) >= args.frames:
            break
    best: tuple[float, str, dict[str, float], dict[str, int]] | None = None
    for r in range(args.rounds):
        tracker = make_tracker(args.tracker)
        SPENT.clear()
        CALLS.clear()
        step, inside = [], []
        for frame in frames:
            before = sum(SPENT.values())
            t = time.perf_counter()
            tracker.step(frame)
            step.append(time.perf_counter() - t)
            inside.append(sum(SPENT.values()) - before)
        s, cv = np.array(step) * 1e3, np.array(inside) * 1e3
        line = (f"step median {np.median(s):.2f} mean {s.mean():.2f} p95 {np.percentile(s, 95):.2f} ms; "
                f"inside OpenCV median {np.median(cv):.2f} mean {cv.mean():.2f} p95 {np.percentile(cv, 95):.2f} ms "
                f"({cv.mean() / s.mean():.0%} of the mean); the rest median {np.median(s - cv):.2f} "
                f"mean {(s - cv).mean():.2f} ms")
        print(f"round {r}: {line}", flush=True)
        if best is None or s.mean() < best[0]:
            best = (s.mean(), line, dict(SPENT), dict(CALLS))
    assert best is not None
    _, line, spent, calls = best
    n = len(frames)
    print(f"\n{args.tracker} on {args.clip}, {n} frames, best round: {line}")
    print("| OpenCV function | ms per frame | calls per frame |\n|---|---:|---:|")
    for name, v in sorted(spent.items(), key=lambda kv: -kv[1])[:12]:
        print(f"| `{name}` | {v / n * 1e3:.3f} | {calls[name] / n:.1f} |")


if __name__ == "__main__":
    main()
