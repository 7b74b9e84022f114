"""Soak run: many frames through the `wfviz track` code path, watching memory and warnings.

    python benchmarks/soak.py                          # 20 000 frames of long-1024 (~15 min)
    python benchmarks/soak.py --frames 2000 --every 100 --json soak.json
    python benchmarks/soak.py --config my.toml                  # e.g. with optional stages on

Runs :func:`wfviz.run.run` (what `wfviz track` calls) on the lazily generated scenario with a
tracks CSV, samples every ``--every`` frames the live tracks, the tracks the manager keeps, the
points in their histories, Python's object count and the process RSS, and records every warning
(Python and numpy). Exits 1 when a warning was emitted or memory grew in the second half.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

from wfviz.run import run
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers import load_tracker, make_tracker

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_blocks import machine


def rss_mb() -> tuple[float, float]:
    """(current, peak) resident set size of this process in MB, from /proc."""
    fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
    return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="long-1024")
    ap.add_argument("--frames", type=int, default=20_000)
    ap.add_argument("--every", type=int, default=500, help="sample every N frames")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, help="write the samples and summary here")
    ap.add_argument("--config", type=Path, help="GEWC config file (default: the defaults)")
    args = ap.parse_args()

    clip = make_scenario(args.scenario, seed=args.seed, n_frames=args.frames)
    tracker = load_tracker("gewc", args.config) if args.config else make_tracker("gewc")
    samples: list[dict] = []
    t0 = time.perf_counter()

    def sample(frame, result) -> None:
        i = frame.index + 1
        if i % args.every and i != 1 and i != args.frames:
            return
        rss, peak = rss_mb()
        kept = tracker.manager
        samples.append(dict(frame=frame.index, seconds=round(time.perf_counter() - t0, 1),
                            live=len(result.tracks), confirmed=sum(t.confirmed for t in result.tracks),
                            kept=len(kept), history=int(kept.history_len.sum()),
                            objects=len(gc.get_objects()), rss_mb=round(rss, 1), peak_mb=round(peak, 1)))
        s = samples[-1]
        print(f"frame {s['frame']:6d}  {s['seconds']:7.1f} s  live {s['live']:4d} (confirmed {s['confirmed']:3d})"
              f"  kept {s['kept']:4d}  history {s['history']:6d}  objects {s['objects']:7d}"
              f"  RSS {s['rss_mb']:7.1f} MB  peak {s['peak_mb']:7.1f} MB", flush=True)

    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        csv_path = Path(tmp) / "tracks.csv"
        summary = run(clip, tracker, tracks_csv=csv_path, on_frame=sample)
        csv_mb = csv_path.stat().st_size / 2**20
    seconds = time.perf_counter() - t0

    half = [s for s in samples if s["frame"] >= args.frames // 2]
    first_half = [s for s in samples if s["frame"] < args.frames // 2 and s["frame"] > 0] or samples[:1]
    grew = {key: max(s[key] for s in half) > 1.2 * max(s[key] for s in first_half) + slack
            for key, slack in (("kept", 20), ("history", 1000), ("objects", 5000), ("rss_mb", 50))}
    result = dict(
        machine=machine(), scenario=args.scenario, seed=args.seed, frames=summary.frames,
        config=str(args.config) if args.config else "defaults",
        seconds=round(seconds, 1), ms_per_frame=round(seconds * 1e3 / max(summary.frames, 1), 2),
        tracker_ms_per_frame=round(summary.tracker_ms, 2), confirmed_ids=len(summary.confirmed),
        tracks_csv_mb=round(csv_mb, 1), max_live=max(s["live"] for s in samples),
        max_kept=max(s["kept"] for s in samples),
        rss_mb={"start": samples[0]["rss_mb"], "middle": first_half[-1]["rss_mb"], "end": samples[-1]["rss_mb"]},
        peak_mb={"start": samples[0]["peak_mb"], "middle": first_half[-1]["peak_mb"], "end": samples[-1]["peak_mb"]},
        warnings=[f"{w.category.__name__}: {w.message} ({Path(w.filename).name}:{w.lineno})" for w in caught],
        growth=grew, samples=samples)
    print(json.dumps({k: v for k, v in result.items() if k != "samples"}, indent=2))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 1 if result["warnings"] or any(grew.values()) else 0


if __name__ == "__main__":
    raise SystemExit(main())
