"""Speed on one core: every tracker per stage, `track` against `record`, decoding, and peers.

    python benchmarks/performance.py                   # everything (~5 min), prints the tables
    python benchmarks/performance.py --write-doc       # also updates docs/performance.md
    python benchmarks/performance.py --only trackers record --runs 3

One core means: the process is pinned to one CPU (``sched_setaffinity``; Rerun's writer
threads share it), ``OMP_NUM_THREADS=1`` and ``cv2.setNumThreads(1)``. Frames are rendered
into memory first, so decoding is not in the tracker times; decoding is timed on its own from
the same frames written as files. Each tracker runs ``--runs`` times over the clip (a fresh
tracker each time); per frame and stage the median over the runs is kept, then the table
gives the median, mean and 95th percentile over the frames.

``record`` and ``track`` are timed through :func:`wfviz.run.run` (what the CLI calls) on the
in-memory frames: ``track`` writes the tracks CSV, ``record`` also the recording with every
stage and (by default) every frame's raw and residual image. Their cost is the wall time of
the whole run (writer threads and the final flush included) divided by the frames.

Peers (``--only peers``, needs ``pip install -e ".[bench]"``): trackpy ``locate`` + ``link``
and photutils ``DAOStarFinder`` on a ``Background2D``-subtracted frame, on the same 640x512
frames as the GEWC tracker.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy / OpenCV start their pools
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import importlib.metadata as md
import sys
import tempfile
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from wfviz.config import config_to_toml
from wfviz.io.clip import open_clip
from wfviz.io.frames import Frame
from wfviz.synth.clip import MemoryClip
from wfviz.record_options import RecorderOptions
from wfviz.run import run
from wfviz.synth.demo import demo_clip
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers import make_tracker

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_blocks import machine, write_block
from step_timing import time_steps

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
SECTIONS = ("trackers", "record", "startup", "cores", "decode", "peers")
PACKAGES = ("numpy", "opencv-python-headless", "scipy", "rerun-sdk")  # versions in the table heads
# tracker -> (clip, budget: median ms per frame from issue #38)
TRACKER_CASES = {
    "gewc": ("demo (640x512, 180°, 4 targets)", 3.0),
    "fusion": ("uniform-50hz (480x320)", 2.0),
    "starfield": ("starfield (1024x1024)", 50.0),
    "tbd": ("lowsnr-tbd (64x64)", 20.0),
}


def case_frames(tracker: str) -> MemoryClip:
    """The clip each tracker's budget is stated on, rendered into memory."""
    if tracker == "gewc":
        clip = demo_clip(0)
    else:
        clip = make_scenario({"fusion": "uniform-50hz", "starfield": "starfield", "tbd": "lowsnr-tbd"}[tracker])
    return MemoryClip(clip.name, list(clip.frames()), clip.fps)


def one_core() -> str:
    """Pin this process to one CPU and OpenCV to one thread; describe the CPU."""
    cpu = sorted(os.sched_getaffinity(0))[-1]
    os.sched_setaffinity(0, {cpu})
    cv2.setNumThreads(1)
    return f"CPU {cpu}"


def stats(values: np.ndarray) -> tuple[float, float, float]:
    return float(np.median(values)), float(np.mean(values)), float(np.percentile(values, 95))


# -- trackers ---------------------------------------------------------------------------------
def trackers_section(runs: int) -> str:
    out = ["### Trackers, per stage (ms per frame, one core, decoding excluded)", ""]
    summary = ["| tracker | clip | frames | median | mean | p95 | frames/s (mean) | budget | met |",
               "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    detail = []
    for name, (desc, budget) in TRACKER_CASES.items():
        clip = case_frames(name)
        t = time_steps(lambda: make_tracker(name), list(clip.frames()), runs)  # warm-up: one run
        stages, table, step = t.stages, t.table, t.wall
        med, mean, p95 = stats(step)
        summary.append(f"| {name} | {desc} | {len(step)} | **{med:.2f}** | {mean:.2f} | {p95:.2f} | "
                       f"{1e3 / mean:,.0f} | {budget:g} | {'yes' if med <= budget else 'no'} |")
        rows = [f"**{name}** on {desc}:", "", "| stage | median | mean | p95 |", "|---|---:|---:|---:|"]
        for j, s in enumerate(stages):
            rows.append("| {} | {:.3f} | {:.3f} | {:.3f} |".format(s, *stats(table[:, j])))
        rows.append("| step (whole) | {:.3f} | {:.3f} | {:.3f} |".format(med, mean, p95))
        detail += rows + [""]
        print(summary[-1], flush=True)
    return "\n".join(out + summary + [""] + detail)


# -- track against record ---------------------------------------------------------------------
def time_once(clip: MemoryClip, record: dict | None, tmp: Path, stop: int | None = None) -> tuple[float, float]:
    """(CPU ms of all threads for one whole run over frames [0, stop), .rrd MB per frame) for
    `track` (``record`` None) or `record` with the given recorder options."""
    n = clip.n_frames if stop is None else stop
    tracker = make_tracker("gewc")
    csv, rrd = tmp / "t.csv", tmp / "r.rrd"
    options = None
    if record is not None:
        options = RecorderOptions(source=clip.name, config_text=config_to_toml(tracker.config), **record)
    t0 = time.process_time()
    run(clip, tracker, tracks_csv=csv, recording=rrd if record is not None else None,
        recorder_options=options, stop=stop)
    total = (time.process_time() - t0) * 1e3
    size = 0.0
    if record is not None:
        size = rrd.stat().st_size / 1e6 / n
        rrd.unlink()
    csv.unlink()
    return total, size


def time_runs(clip: MemoryClip, runs: int, cases: list[dict | None], tmp: Path, stop: int | None = None
              ) -> list[tuple[float, float]]:
    """:func:`time_once` of every case (None: `track`), the cases interleaved within each of
    ``runs`` rounds after one warm-up round (this machine's speed drifts over minutes): the
    median ms and the .rrd MB per frame of each."""
    totals: list[list[float]] = [[] for _ in cases]
    sizes = [0.0] * len(cases)
    for r in range(runs + 1):
        for k, case in enumerate(cases):
            total, sizes[k] = time_once(clip, case, tmp, stop)
            if r:
                totals[k].append(total)
    return [(float(np.median(t)), mb) for t, mb in zip(totals, sizes)]


def record_section(runs: int) -> str:
    clip16 = case_frames("gewc")
    lo, hi = np.percentile(clip16.frames().__next__().image, [0.1, 99.9])
    clip8 = MemoryClip("demo-8bit", [Frame(f.index, f.time, np.clip((f.image - lo) * 255.0 / (hi - lo), 0, 255)
                                            .astype(np.uint8)) for f in clip16.frames()], clip16.fps)
    n = clip16.n_frames
    half = n // 2
    rows = ["### `track` against `record` (GEWC, demo clip, one core, decoding excluded)", "",
            f"Whole runs through `wfviz.run.run` (what the CLI calls), writer threads and the final "
            f"flush included, in CPU time of all threads (this one core's time, not the wall clock, "
            f"which another virtual machine's load stretches); the cases interleaved, median of {runs} "
            f"rounds. *Per frame*: the run's time over its {n} frames. "
            f"*Frames {half}–{n - 1}*: the extra time of a {n}-frame run over a {half}-frame one, per "
            "extra frame, i.e. without the fixed cost of opening and closing the recording (about "
            "0.1 s), which a long clip spreads thin.", "",
            f"| source | command | ms per frame | over `track` | frames {half}–{n - 1}: ms per frame | "
            "over `track` | .rrd MB per frame |",
            "|---|---|---:|---:|---:|---:|---:|"]
    cases = [("`record` (default: exact images every 10th frame, JPEG previews between)", dict()),
             ("`record --exact-every 1` (every image exact)", dict(exact_every=1)),
             ("`record --image-every 10` (exact images every 10th frame only)", dict(image_every=10)),
             ("`record --no-images`", dict(image_every=0))]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for clip in (clip16, clip8):
            bits = "16-bit" if clip is clip16 else "8-bit"
            options: list[dict | None] = [None, *(o for _, o in cases)]
            full = time_runs(clip, runs, options, tmp)
            part = time_runs(clip, runs, options, tmp, stop=half)
            base, base_m = full[0][0] / n, (full[0][0] - part[0][0]) / (n - half)
            rows.append(f"| {bits} | `track` | {base:.2f} | | {base_m:.2f} | | |")
            for (label, _), (r_full, mb), (r_half, _) in zip(cases, full[1:], part[1:]):
                ms, ms_m = r_full / n, (r_full - r_half) / (n - half)
                rows.append(f"| {bits} | {label} | {ms:.2f} | {ms - base:+.2f} | {ms_m:.2f} | "
                            f"**{ms_m - base_m:+.2f}** | {mb:.3f} |")
                print(rows[-1], flush=True)
    rows += ["", *whole_processes(runs, demo_clip(0, n_frames=600))]
    return "\n".join(rows)


def whole_processes(runs: int, clip: MemoryClip) -> list[str]:
    """`wfviz track` and `wfviz record` as whole processes on this one core (start-up, imports,
    PNG decoding and writing included) on the clip saved as a 16-bit PNG folder: the commands
    interleaved within each round (this machine's speed drifts over minutes), wall-clock and CPU
    time (the child's user + system time: what another virtual machine's load does not stretch)."""
    import resource
    import subprocess

    cpu = str(sorted(os.sched_getaffinity(0))[0])
    n = clip.n_frames
    rows = [f"### Whole processes (the {n} demo frames as a 16-bit PNG folder, `taskset -c {cpu}`, "
            f"commands interleaved, median of {runs} rounds after a warm-up)", "",
            "| command | seconds | CPU seconds | CPU ms per frame | over `track` (CPU) | .rrd MB per frame |",
            "|---|---:|---:|---:|---:|---:|"]
    commands = (("`wfviz track`", ["track", "{folder}", "--tracks", "{tmp}/t.csv"]),
                ("`wfviz record` (defaults)", ["record", "{folder}", "-o", "{tmp}/r.rrd"]),
                ("`wfviz record --exact-every 1`", ["record", "{folder}", "-o", "{tmp}/r.rrd", "--exact-every", "1"]),
                ("`wfviz record --no-images`", ["record", "{folder}", "-o", "{tmp}/r.rrd", "--no-images"]))
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        folder = tmp / "png16"
        folder.mkdir()
        for f in clip.frames():
            cv2.imwrite(str(folder / f"{f.index:05d}.png"), f.image)
        wall: list[list[float]] = [[] for _ in commands]
        cpu_s: list[list[float]] = [[] for _ in commands]
        mb = [0.0] * len(commands)
        for r in range(runs + 1):  # round 0 warms the disk cache and is not counted
            for k, (_, args) in enumerate(commands):
                for p in [*tmp.glob("r*.rrd"), *tmp.glob("*.csv")]:
                    p.unlink()
                argv = [a.format(folder=folder, tmp=tmp) for a in args]
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                subprocess.run(["taskset", "-c", cpu, sys.executable, "-m", "wfviz", *argv], check=True,
                               capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
                elapsed = time.perf_counter() - t0
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                if r:
                    wall[k].append(elapsed)
                    cpu_s[k].append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
                if (tmp / "r.rrd").exists():
                    mb[k] = (tmp / "r.rrd").stat().st_size / 1e6 / n
        base = None
        for k, (label, _) in enumerate(commands):
            sec, cpu_sec = float(np.median(wall[k])), float(np.median(cpu_s[k]))
            ms = cpu_sec * 1e3 / n
            over = "" if base is None else f"{ms - base:+.2f}"  # the first row is `track` itself
            base = ms if base is None else base
            size = f"{mb[k]:.3f}" if mb[k] else ""
            rows.append(f"| {label} | {sec:.2f} | {cpu_sec:.2f} | {ms:.2f} | {over} | {size} |")
            print(rows[-1], flush=True)
    return rows


# -- start-up ----------------------------------------------------------------------------------
def _wfviz() -> list[str]:
    """The `wfviz` console script beside this interpreter (what a user runs), else ``-m wfviz``."""
    script = Path(sys.executable).with_name("wfviz")
    return [str(script)] if script.exists() else [sys.executable, "-m", "wfviz"]


def _timed(args: list[str], runs: int, cpus: str, cwd: Path) -> float:
    """Median wall seconds of the command ``args`` as a whole process on ``cpus`` (taskset)."""
    import subprocess

    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(["taskset", "-c", cpus, *args], check=True, capture_output=True, cwd=cwd,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def startup_section(runs: int) -> str:
    """Whole-process times of the commands a user starts most, on one core: what they import
    before the first frame (`wfviz track` imports no Rerun, pandas, Optuna or matplotlib)."""
    import compileall

    import wfviz

    # an installed package has its bytecode; a working copy may not (or PYTHONDONTWRITEBYTECODE
    # keeps it stale), and compiling changed modules on every start is no part of start-up
    compileall.compile_dir(str(Path(wfviz.__file__).parent), quiet=1)
    cpu = str(sorted(os.sched_getaffinity(0))[0])
    exe = _wfviz()
    rows = [f"### Start-up (whole processes, `taskset -c {cpu}`, median of {runs + 2})", "",
            "| command | seconds |", "|---|---:|"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rng = np.random.default_rng(0)
        np.save(tmp / "two.npy", (1000 + rng.normal(0, 10, (2, 512, 640))).astype(np.uint16))
        cases = [("`python -c pass` (the interpreter alone)", [sys.executable, "-c", "pass"]),
                 ("`python -c 'import numpy, cv2'`", [sys.executable, "-c", "import numpy, cv2"]),
                 ("`wfviz --help`", [*exe, "--help"]),
                 ("`wfviz track` on a 2-frame 640x512 clip (start-up and 2 frames)",
                  [*exe, "track", "two.npy", "--tracks", "t.csv"]),
                 ("`wfviz record` on the same clip", [*exe, "record", "two.npy", "-o", "r.rrd"])]
        for label, args in cases:
            sec = _timed(args, runs + 2, cpu, tmp)
            rows.append(f"| {label} | {sec:.2f} |")
            print(rows[-1], flush=True)
        outside = _outside_frames([*exe, "track", "two.npy", "--tracks", "t.csv"], runs + 2, cpu, tmp)
        rows.append(f"| `wfviz track` on that clip before its first frame and after its last (the whole process "
                    f"less the run's own time, which it prints: imports, command line, opening the clip, exit) "
                    f"| {outside:.2f} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


def _outside_frames(args: list[str], runs: int, cpus: str, cwd: Path) -> float:
    """Median wall seconds of the command ``args`` (a `wfviz track`) outside its frames: the
    whole process less the run's time that it prints (``done: N frames in S s``)."""
    import re
    import subprocess

    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        r = subprocess.run(["taskset", "-c", cpus, *args], check=True, capture_output=True, text=True, cwd=cwd,
                           env={**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "200"})
        wall = time.perf_counter() - t0
        m = re.search(r"frames in ([\d.]+) s", r.stdout + r.stderr)
        if m is None:
            raise RuntimeError(f"no 'frames in S s' in the output of {' '.join(args)}")
        times.append(wall - float(m.group(1)))
    return float(np.median(times))


# -- one core against two ---------------------------------------------------------------------
_BUSY = ("import time, numpy as np, cv2; cv2.setNumThreads(1); "
         "a = np.random.default_rng(0).random((512, 640), dtype=np.float32); t0 = time.perf_counter()\n"
         "for _ in range(300): b = cv2.GaussianBlur(a, (0, 0), 2.0); c = np.sort(b[::4], axis=1)\n"
         "print(time.perf_counter() - t0)")


def cores_section(runs: int, n_frames: int = 600) -> str:
    """`wfviz track` and `wfviz record` end to end (16-bit PNG decoding included) on one core and
    on two, default ``--threads``; and what two cores give two independent CPU-bound processes
    on this machine (the ceiling for any parallel run here)."""
    import subprocess

    cpus = sorted(os.sched_getaffinity(0) | set(range(os.cpu_count() or 1)))
    if len(cpus) < 2:
        return "### One core against two\n\n(this machine has one core)"
    one, two = str(cpus[-1]), f"{cpus[0]},{cpus[1]}"
    clip = demo_clip(0, n_frames=n_frames)
    rows = [f"### One core against two (the demo clip, {n_frames} frames of 640x512 as a 16-bit PNG folder, "
            f"whole processes, median of {runs})", "",
            "| command | one core: s (ms/frame) | two cores: s (ms/frame) | two over one |", "|---|---:|---:|---:|"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        folder = clip.save(tmp / "png16")
        exe = _wfviz()
        for label, args in (("`wfviz track`", [*exe, "track", str(folder), "--tracks", "t.csv"]),
                            ("`wfviz record`", [*exe, "record", str(folder), "-o", "r.rrd"])):
            a = _timed(args, runs, one, tmp)
            b = _timed(args, runs, two, tmp)
            rows.append(f"| {label} | {a:.2f} ({a * 1e3 / n_frames:.1f}) | {b:.2f} ({b * 1e3 / n_frames:.1f}) | "
                        f"**{a / b:.2f}x** |")
            print(rows[-1], flush=True)
        alone = float(subprocess.run(["taskset", "-c", one, sys.executable, "-c", _BUSY], check=True,
                                     capture_output=True, text=True).stdout)
        pair = [subprocess.Popen(["taskset", "-c", two, sys.executable, "-c", _BUSY], stdout=subprocess.PIPE,
                                 text=True) for _ in range(2)]
        both = max(float(p.communicate()[0]) for p in pair)
        rows.append(f"| two independent CPU-bound processes (NumPy and OpenCV work) | {2 * alone:.2f} (in turn) | "
                    f"{both:.2f} (at once) | {2 * alone / both:.2f}x |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


# -- decoding ---------------------------------------------------------------------------------
def decode_section(runs: int) -> str:
    clip = demo_clip(0)
    rows = ["### Decoding (the demo clip, 160 frames of 640x512, ms per frame, one core)", "",
            "| source | ms per frame |", "|---|---:|"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        folder = clip.save(tmp / "png16")
        frames8 = [cv2.normalize(f.image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U) for f in clip.frames()]
        np.save(tmp / "stack.npy", np.stack([f.image for f in clip.frames()]))
        cases = [("16-bit PNG folder", folder), (".npy stack (16-bit)", tmp / "stack.npy")]
        for codec in ("FFV1", "MJPG"):
            path = tmp / f"clip-{codec}.avi"
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), 25.0, frames8[0].shape[::-1], isColor=False)
            if writer.isOpened():
                for f in frames8:
                    writer.write(f)
                writer.release()
                cases.append((f"8-bit AVI ({codec})", path))
        for label, path in cases:
            times = []
            for _ in range(runs):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    src = open_clip(path)
                t0 = time.perf_counter()
                n = sum(1 for _ in src.frames())
                times.append((time.perf_counter() - t0) * 1e3 / n)
            rows.append(f"| {label} | {np.median(times):.2f} |")
            print(rows[-1], flush=True)
    return "\n".join(rows)


# -- peers ------------------------------------------------------------------------------------
def peers_section(runs: int, n_frames: int) -> str:
    try:
        import pandas as pd
        import trackpy as tp
        from astropy.stats import SigmaClip
        from photutils.background import Background2D, MedianBackground
        from photutils.detection import DAOStarFinder
    except ImportError as exc:
        return f"### Peers\n\nskipped: {exc} (pip install -e \".[bench]\")"
    tp.quiet()
    clip = demo_clip(0, n_frames=n_frames)
    frames = list(clip.frames())
    images = [f.image.astype(np.float32) for f in frames]
    truth = [np.array([(t.x, t.y) for t in clip.truth_at(f.index)]).reshape(-1, 2) for f in frames]

    def recall(found: list[np.ndarray]) -> float:
        """Share of the truth targets with a detection within 1.5 px."""
        hits = [np.hypot(*(t[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)).min(axis=1) <= 1.5
                for t, xy in zip(truth, found) if len(t) and len(xy)]
        return float(np.concatenate(hits).mean()) if hits else 0.0

    def ours() -> list[np.ndarray]:
        tracker = make_tracker("gewc")
        return [tracker.step(f).detections.xy for f in frames]

    # parameters: the loosest that still find the four targets (trackpy's minmass is 0.8x
    # the faintest target's mass on these frames); the clutter then yields many features
    def trackpy_run() -> list[np.ndarray]:  # locate (band-pass + refine) per frame, then link
        feats = [tp.locate(im, diameter=5, minmass=150, separation=3).assign(frame=i)
                 for i, im in enumerate(images)]
        tp.link(pd.concat(feats, ignore_index=True), search_range=5, memory=3, adaptive_stop=1.0,
                adaptive_step=0.8)  # adaptive: dense clutter makes oversize subnets
        return [f[["x", "y"]].to_numpy() for f in feats]

    def false_per_frame(found: list[np.ndarray]) -> float:
        """Detections farther than 1.5 px from every target, per frame."""
        n = [int((np.hypot(*(xy[:, None, :] - t[None, :, :]).transpose(2, 0, 1)).min(axis=1) > 1.5).sum())
             if len(t) else len(xy) for t, xy in zip(truth, found) if len(xy)]
        return float(np.sum(n)) / len(found)

    def trackpy_with(minmass: float, percentile: float = 64.0, threshold: float | None = None) -> list[np.ndarray]:
        feats = [tp.locate(im, diameter=5, minmass=minmass, separation=3, percentile=percentile,
                           threshold=threshold, characterize=False).assign(frame=i)
                 for i, im in enumerate(images)]
        table = pd.concat(feats, ignore_index=True)
        if len(table):  # a minmass above every spot finds nothing to link
            tp.link(table, search_range=5, memory=3, adaptive_stop=1.0, adaptive_step=0.8)
        return [f[["x", "y"]].to_numpy() for f in feats]

    # tuned to the scene: a grid over minmass, percentile (the intensity percentile a local
    # maximum must exceed) and threshold (band-passed level clipped to zero), characterize off
    # (its extra columns are not used); taken: the
    # fewest false detections among the settings within 0.02 of the best recall, so that it
    # finds the targets and as little else as it can
    sweep = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        grid = [(mm, 64.0, None) for mm in (150, 165, 180, 200, 250)]
        grid += [(150, 99.0, None), (150, 99.9, None)]
        grid += [(mm, 64.0, th) for mm in (150, 200) for th in (30.0, 60.0, 120.0)]
        for mm, pc, th in grid:
            found = trackpy_with(mm, pc, th)
            sweep.append(((mm, pc, th), recall(found), false_per_frame(found)))
            print(f"trackpy minmass {mm} percentile {pc} threshold {th}: recall {sweep[-1][1]:.2f}, "
                  f"false/frame {sweep[-1][2]:.1f}", flush=True)
    best = max(r for _, r, _ in sweep)
    tuned_mm, tuned_pc, tuned_th = min((s for s in sweep if s[1] >= best - 0.02), key=lambda s: s[2])[0]

    def trackpy_tuned() -> list[np.ndarray]:
        return trackpy_with(tuned_mm, tuned_pc, tuned_th)

    def photutils_run() -> list[np.ndarray]:  # background-subtracted DAOStarFinder per frame
        found = []
        for im in images:
            bkg = Background2D(im, (32, 32), filter_size=(3, 3), sigma_clip=SigmaClip(sigma=3.0),
                               bkg_estimator=MedianBackground())
            src = DAOStarFinder(fwhm=2.5, threshold=3.0 * float(bkg.background_rms_median))(im - bkg.background)
            found.append(np.zeros((0, 2)) if src is None else
                         np.column_stack([np.asarray(src["x_centroid"]), np.asarray(src["y_centroid"])]))
        return found

    results = []
    for label, fn in (("wfviz GEWC (whole tracker: detection, centroid, Kalman, tracks)", ours),
                      ("trackpy `locate` (diameter 5, minmass 150) + `link` (search range 5, adaptive)", trackpy_run),
                      (f"trackpy tuned to the scene: `locate` (diameter 5, minmass {tuned_mm}, percentile {tuned_pc:g}, "
                       f"threshold {tuned_th}, characterize off) + `link`", trackpy_tuned),
                      ("photutils `Background2D` (32 px boxes) + `DAOStarFinder` (FWHM 2.5, 3σ)", photutils_run)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fn()  # warm-up (imports, caches)
            times, found = [], []
            for _ in range(runs):
                t0 = time.perf_counter()
                found = fn()
                times.append((time.perf_counter() - t0) * 1e3 / len(frames))
        results.append((label, float(np.median(times)), np.mean([len(x) for x in found]), recall(found),
                        false_per_frame(found)))
        print(label, f"{results[-1][1]:.2f} ms/frame", flush=True)
    with tempfile.TemporaryDirectory() as d:  # decoding, timed apart: the same frames as 16-bit PNG
        paths = [Path(d) / f"{f.index:05d}.png" for f in frames]
        for path, f in zip(paths, frames):
            cv2.imwrite(str(path), f.image)
        decode = []
        for _ in range(runs):
            t0 = time.perf_counter()
            for path in paths:
                cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            decode.append((time.perf_counter() - t0) * 1e3 / len(paths))
    ref = results[0][1]
    tuned_ms = next(ms for lab, ms, *_ in results if lab.startswith("trackpy tuned"))
    rows = [f"### Peers on the same frames ({len(frames)} demo frames, 640x512, one core)", "",
            "Frames decoded beforehand: every time is the method's own, beyond decoding. Decoding the "
            f"same frames from 16-bit PNG costs {np.median(decode):.2f} ms a frame (cv2.imread), "
            f"for every method alike. Tuned trackpy / wfviz: **{tuned_ms / ref:.1f}×**.", "",
            "| method | ms per frame | detections per frame | false detections per frame | targets found (≤ 1.5 px) | time / wfviz |",
            "|---|---:|---:|---:|---:|---:|"]
    rows += [f"| {lab} | {ms:.2f} | {k:.0f} | {fa:.1f} | {rec:.0%} | **{ms / ref:.1f}×** |"
             for lab, ms, k, rec, fa in results]
    rows += ["", "trackpy's grid on these frames (minmass/percentile/threshold: targets found, false "
             "detections per frame): " + "; ".join(f"{mm}/{pc:g}/{th}: {r:.0%}, {f:.0f}" for (mm, pc, th), r, f in sweep)
             + f". Tuned: minmass {tuned_mm}, percentile {tuned_pc:g}, threshold {tuned_th}."]
    vers = ", ".join(f"{p} {md.version(p)}" for p in ("trackpy", "photutils", "astropy") if _installed(p))
    rows += ["", f"({vers}.)"]
    return "\n".join(rows)


def _installed(pkg: str) -> bool:
    try:
        md.version(pkg)
        return True
    except md.PackageNotFoundError:
        return False


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--peer-frames", type=int, default=40, help="demo frames for the peer comparison")
    ap.add_argument("--write-doc", action="store_true", help=f"update {DOC.name}")
    args = ap.parse_args()
    pinned = one_core()
    head = (f"Measured {time.strftime('%Y-%m-%d')} on {machine(PACKAGES)}; one core ({pinned}), "
            f"`python benchmarks/performance.py --runs {args.runs}`.")
    print(head, flush=True)
    blocks = {"trackers": lambda: trackers_section(args.runs), "record": lambda: record_section(args.runs),
              "startup": lambda: startup_section(args.runs), "cores": lambda: cores_section(args.runs),
              "decode": lambda: decode_section(args.runs),
              "peers": lambda: peers_section(args.runs, args.peer_frames)}
    for name in args.only:
        text = blocks[name]()
        print(text, flush=True)
        if args.write_doc:
            write_block(DOC, f"<!-- perf-{name}:begin -->", f"<!-- perf-{name}:end -->", head + "\n\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
