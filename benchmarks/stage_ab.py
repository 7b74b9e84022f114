"""Per-stage cost of the code now against an older commit, measured the same minutes, interleaved.

    python benchmarks/stage_ab.py --base HEAD~3                 # GEWC on the demo clip, 5 rounds
    python benchmarks/stage_ab.py --base 7b5a90d --tracker fusion --clip synth:uniform-50hz

Each round runs ``wfviz bench`` (one core: ``taskset -c 1`` where it exists, OpenCV on one
thread, decoding apart) once with the old code and once with the new, by ``PYTHONPATH``: the
old commit is checked out into a temporary ``git worktree`` (or ``--base`` names a folder that
holds the old code). This machine's speed drifts by more than most single changes save, so a
change is judged by the stage table of both sides in the same rounds, never by one number
against a figure from another day: the output is each stage's median, mean and p95 on both
sides (median over the rounds) and the new side's difference, with the spread of the
differences over the rounds. A stage whose mean moves by less than its spread has not
measurably changed. ``benchmarks/track_hashes.py`` says whether the outputs did.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROW = re.compile(r"^(\S+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s*$")


def bench_table(code: Path, clip: str, tracker: str) -> dict[str, tuple[float, float, float]]:
    """``wfviz bench`` with the wfviz under ``code``: stage -> (median, mean, p95) in ms."""
    pin = ["taskset", "-c", "1"] if shutil.which("taskset") and os.cpu_count() and os.cpu_count() > 1 else []
    env = dict(os.environ, PYTHONPATH=str(code))
    r = subprocess.run([*pin, sys.executable, "-m", "wfviz", "bench", clip, "--tracker", tracker, "--threads", "1"],
                       capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    if r.returncode != 0:
        raise SystemExit(f"stage_ab: wfviz bench failed with {code}: {r.stderr.strip().splitlines()[-1:]}")
    table = {}
    for line in r.stdout.splitlines():
        m = ROW.match(line)
        if m:
            table[m.group(1)] = (float(m.group(2)), float(m.group(3)), float(m.group(4)))
    return table


def old_code(base: str, keep: list[Path]) -> Path:
    """A folder holding the wfviz of ``base`` (a folder as it is, or a commit checked out into a
    temporary worktree, recorded in ``keep`` for removal)."""
    if Path(base).is_dir() and (Path(base) / "wfviz").is_dir():
        return Path(base)
    tmp = Path(tempfile.mkdtemp(prefix="wfviz-base-"))
    r = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tmp), base],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"stage_ab: cannot check out {base!r}: {r.stderr.strip()}")
    keep.append(tmp)
    return tmp


def demo_npy(folder: Path) -> str:
    """The demo clip (160 frames of 640x512) as a .npy stack, written once."""
    import numpy as np

    from wfviz.synth.demo import demo_clip

    path = folder / "demo.npy"
    np.save(path, np.stack([f.image for f in demo_clip(0).frames()]))
    return str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the old code: a commit (checked out into a worktree) or a folder")
    ap.add_argument("--clip", default=None, help="clip for wfviz bench (default: the demo clip as a .npy)")
    ap.add_argument("--tracker", default="gewc")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    keep: list[Path] = []
    work = Path(tempfile.mkdtemp(prefix="wfviz-ab-"))
    try:
        base = old_code(args.base, keep)
        clip = args.clip or demo_npy(work)
        sides: dict[str, list[dict[str, tuple[float, float, float]]]] = {"base": [], "new": []}
        for r in range(args.rounds):
            for side, code in (("base", base), ("new", ROOT)):
                sides[side].append(bench_table(code, clip, args.tracker))
            print(f"round {r + 1} of {args.rounds}: total mean base {sides['base'][-1]['total'][1]:.2f}, "
                  f"new {sides['new'][-1]['total'][1]:.2f} ms", file=sys.stderr, flush=True)
        stages = [s for s in sides["new"][0] if all(s in t for t in sides["base"] + sides["new"])]
        print(f"{args.tracker} on {args.clip or 'the demo clip'}: base {args.base}, new {ROOT}, "
              f"{args.rounds} interleaved rounds, ms a frame (median over the rounds)\n")
        print("| stage | base median / mean / p95 | new median / mean / p95 | mean: new − base (spread) | p95: new − base |")
        print("|---|---|---|---|---|")
        for s in stages:
            b = [statistics.median(t[s][k] for t in sides["base"]) for k in range(3)]
            n = [statistics.median(t[s][k] for t in sides["new"]) for k in range(3)]
            d = [nt[s][1] - bt[s][1] for bt, nt in zip(sides["base"], sides["new"])]
            d95 = statistics.median(nt[s][2] - bt[s][2] for bt, nt in zip(sides["base"], sides["new"]))
            print(f"| {s} | {b[0]:.2f} / {b[1]:.2f} / {b[2]:.2f} | {n[0]:.2f} / {n[1]:.2f} / {n[2]:.2f} | "
                  f"{statistics.median(d):+.2f} ({min(d):+.2f} to {max(d):+.2f}) | {d95:+.2f} |")
    finally:
        for tmp in keep:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tmp)], capture_output=True)
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
