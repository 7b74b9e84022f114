"""Peak memory of `wfviz track` and `wfviz record` against clip length, through the CLI.

    python benchmarks/memory.py                        # 2 000 and 20 000 frames (~1 h)
    python benchmarks/memory.py --frames 200 2000      # quicker
    python benchmarks/memory.py --write-doc            # also update docs/performance.md

Each run is a separate `wfviz` process on ``synth:long-1024`` (1024x1024, generated lazily
frame by frame, so no clip is held anywhere): `track` writing the tracks CSV, and `record`
with ``--image-every 100``. The peak RSS is the kernel's (``ru_maxrss`` from ``wait4``) for
that process alone; the RSS is also sampled every second from /proc to show it flat over
the run. Output files go to a temporary folder and their sizes are reported.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_blocks import write_block

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
BEGIN, END = "<!-- memory:begin -->", "<!-- memory:end -->"


def _rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def measure(args: list[str], env: dict[str, str]) -> dict:
    """Run ``args``; return peak RSS (MB), RSS samples (s, MB), wall seconds and exit code."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    samples: list[tuple[float, float]] = []
    done = threading.Event()

    def sample() -> None:
        while not done.wait(1.0):
            mb = _rss_mb(proc.pid)
            if mb is not None:
                samples.append((round(time.perf_counter() - t0, 1), round(mb, 1)))

    watcher = threading.Thread(target=sample, daemon=True)
    watcher.start()
    out = proc.stdout.read() if proc.stdout else ""
    _, status, usage = os.wait4(proc.pid, 0)
    done.set()
    watcher.join()
    proc.returncode = os.waitstatus_to_exitcode(status)
    return dict(peak_mb=usage.ru_maxrss / 1024, samples=samples, seconds=time.perf_counter() - t0,
                code=proc.returncode, output=out.strip().splitlines()[-4:])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[2000, 20000])
    ap.add_argument("--scenario", default="long-1024")
    ap.add_argument("--image-every", type=int, default=100)
    ap.add_argument("--commands", nargs="+", default=["track", "record"], choices=["track", "record"])
    ap.add_argument("--json", type=Path, help="save every run (with its RSS samples) here")
    ap.add_argument("--write-doc", action="store_true", help=f"update the table in {DOC.name}")
    args = ap.parse_args()

    wfviz = shutil.which("wfviz") or sys.exit("wfviz is not on PATH (pip install -e .)")
    env = dict(os.environ, OMP_NUM_THREADS="1")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.frames:
            for cmd in args.commands:
                out = Path(tmp) / f"{cmd}-{n}"
                argv = [wfviz, cmd, f"synth:{args.scenario}", "--stop", str(n)]
                if cmd == "track":
                    argv += ["--tracks", f"{out}.csv"]
                else:
                    argv += ["-o", f"{out}.rrd", "--tracks", f"{out}.csv", "--image-every", str(args.image_every)]
                print(" ".join(argv[1:]), flush=True)
                r = measure(argv, env)
                r.update(command=cmd, frames=n,
                         rrd_mb=os.path.getsize(f"{out}.rrd") / 2**20 if cmd == "record" else None,
                         csv_mb=os.path.getsize(f"{out}.csv") / 2**20)
                for f in Path(tmp).glob(f"{cmd}-{n}.*"):
                    f.unlink()
                rss = [mb for _, mb in r["samples"]]
                half = len(rss) // 2
                r["rss_first_half_max"] = max(rss[:half], default=None)
                r["rss_second_half_max"] = max(rss[half:], default=None)
                print(f"  exit {r['code']}, {r['seconds']:.0f} s, peak RSS {r['peak_mb']:.0f} MB, "
                      f"RSS max first/second half {r['rss_first_half_max']}/{r['rss_second_half_max']} MB",
                      flush=True)
                runs.append(r)
                if r["code"] != 0:
                    print("\n".join(r["output"]))
                    return 1
    if args.json:
        args.json.write_text(json.dumps(runs, indent=1))
    rows = ["| command | frames | wall time | peak RSS | RSS max, 1st / 2nd half of the run | outputs |",
            "|---|---:|---:|---:|---:|---|"]
    for r in runs:
        outs = f"CSV {r['csv_mb']:.0f} MB" + (f", .rrd {r['rrd_mb']:.0f} MB" if r["rrd_mb"] is not None else "")
        opt = f" --image-every {args.image_every}" if r["command"] == "record" else ""
        rows.append(f"| `{r['command']}`{opt} | {r['frames']:,} | {r['seconds'] / 60:.1f} min | "
                    f"**{r['peak_mb']:.0f} MB** | {r['rss_first_half_max']} / {r['rss_second_half_max']} MB | {outs} |")
    ratios = []
    for cmd in args.commands:
        peaks = [r["peak_mb"] for r in runs if r["command"] == cmd]
        if len(peaks) > 1:
            ratios.append(f"`{cmd}`: peak RSS of the longest over the shortest run = "
                          f"{max(peaks) / min(peaks):.3f}.")
    table = "\n".join(rows) + ("\n\n" + "\n".join(ratios) if ratios else "")
    print(table)
    if args.write_doc:
        write_block(DOC, BEGIN, END, table, heading="## Memory against clip length")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
