"""`wfviz compare`: what two runs cost against one `wfviz record` of the same clip.

    python benchmarks/compare_cost.py               # ~2 min on 2 cores
    python benchmarks/compare_cost.py --write-doc   # also update docs/performance.md

The clip: ``synth:fov70-four-targets:0`` (640x512, 16-bit, 200 frames) written once as PNGs,
so that every process decodes files as a user's would. Timed as whole processes (start-up,
decoding, tracking, logging, the file), interleaved, ``--repeats`` times, median wall time:

- ``record``: ``wfviz record FRAMES`` (GEWC defaults, every image logged);
- ``compare, shared front end``: GEWC defaults against GEWC with ``detection.k_sigma = 5.5``
  (the stages before detection are the same: computed once);
- ``compare, two front ends``: GEWC defaults against GEWC with ``suppression.size = 9``
  (everything twice but the decoding and the raw frame);

each on both cores and pinned to one (``taskset -c 0``). Target: two runs cost at most 1.6x
one record.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_blocks import machine, write_block

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
CLIP = "fov70-four-targets"


def _wfviz(args: list[str], cwd: Path, pin: bool) -> float:
    cmd = [sys.executable, "-m", "wfviz", *args]
    if pin and shutil.which("taskset"):
        cmd = ["taskset", "-c", "0", *cmd]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"wfviz {args[0]} failed: {proc.stderr.strip()}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write-doc", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        subprocess.run([sys.executable, "-m", "wfviz", "synth", CLIP, "clip"], cwd=d, check=True, capture_output=True)
        (d / "k55.toml").write_text("[detection]\nk_sigma = 5.5\n")
        (d / "s9.toml").write_text("[suppression]\nsize = 9\n")
        cases = {
            "record": ["record", "clip", "-o", "r.rrd"],
            "compare, shared front end": ["compare", "clip", "--run", "gewc", "--run", "b=gewc:k55.toml", "-o", "c.rrd"],
            "compare, two front ends": ["compare", "clip", "--run", "gewc", "--run", "b=gewc:s9.toml", "-o", "c.rrd"],
        }
        times: dict[tuple[str, bool], list[float]] = {}
        for _ in range(args.repeats):
            for pin in (False, True):
                for name, cmd in cases.items():
                    times.setdefault((name, pin), []).append(_wfviz(cmd, d, pin))
        sizes = {"record": (d / "r.rrd").stat().st_size}
    lines = [f"Measured {time.strftime('%Y-%m-%d')} on {machine()}; `python benchmarks/compare_cost.py` "
             f"(200 frames of `{CLIP}` as 16-bit PNGs, whole processes, median of {args.repeats}).", "",
             "| process | 2 cores: s | × record | 1 core: s | × record |", "|---|---:|---:|---:|---:|"]
    for name in cases:
        cells = []
        for pin in (False, True):
            t = statistics.median(times[(name, pin)])
            base = statistics.median(times[("record", pin)])
            cells += [f"{t:.2f}", f"{t / base:.2f}"]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    block = "\n".join(lines)
    print(block)
    print(f"(record file {sizes['record'] / 2**20:.0f} MB)")
    if args.write_doc:
        write_block(DOC, "<!-- compare-cost:begin -->", "<!-- compare-cost:end -->", block,
                    heading="## `wfviz compare`: two runs against one record")


if __name__ == "__main__":
    main()
