"""A tracker on the three validation groups, scored separately: own scenarios, the independent
samples (../shared/data/independent) and every real sequence (../shared/data/real).

The real sequences are split into two declared halves, A and B: within each set and class,
sorted by name, sequences alternate A, B, A, ... (see :func:`real_half`). A rule or value is
chosen on one half and reported on the other. Run from the repository root:

    python benchmarks/validation.py                      # every group, default configuration
    python benchmarks/validation.py --groups real --half A --config my.toml
    python benchmarks/validation.py --write              # docs/accuracy.md validation block of the tracker
    python benchmarks/validation.py --json out.json      # every row, for comparisons
    python benchmarks/validation.py --starts 0 1 2 3 --json b.json   # each clip from four first frames:
    python benchmarks/validation_diff.py a.json b.json   # a change's effect against chance, clip by clip
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import os
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
DOC = ROOT / "docs" / "accuracy.md"
MARKERS = "<!-- validation-{}:begin -->", "<!-- validation-{}:end -->"  # per tracker
OWN = ("fov70-maneuver", "fov70-four-targets", "fov180-city-aircraft", "fov180-launches",
       "uniform-50hz", "long-1024")
INDEPENDENT = {"gewc": ("S1", "S2", "S3", "S4", "S7"), "fusion": ("S1", "S2", "S3", "S4", "S7"),
               "starfield": ("S5",), "tbd": ("S6",)}
GATES = {"own": 3.0, "independent": 3.0, "real": 5.0}
GOALS = {"independent": (0.85, 0.05), "real": (0.9, 0.1)}  # (Pd, FA per frame)


@dataclass(frozen=True)
class Job:
    group: str
    name: str
    source: str      # folder, or synth:NAME:SEED
    truth: str | None
    half: str = ""
    stop: int | None = None
    start: int = 0


def real_half(data: Path) -> dict[str, str]:
    """{set/sequence: 'A' or 'B'}: within each set, sorted by class then name, alternating (so
    each set and each class is split as evenly as it can be)."""
    out: dict[str, str] = {}
    for listing in sorted(data.glob("*/sequences.csv")):
        with open(listing, newline="", encoding="utf-8") as fh:
            rows = sorted(csv.DictReader(fh), key=lambda r: (r["class"], r["sequence"]))
        for i, r in enumerate(rows):
            out[f"{listing.parent.name}/{r['sequence']}"] = "AB"[i % 2]
    return out


def jobs(groups: list[str], tracker: str, seeds: list[int], long_frames: int, half: str | None,
         only: list[str] | None) -> list[Job]:
    out: list[Job] = []
    if "own" in groups:
        for name in OWN:
            for seed in seeds:
                out.append(Job("own", f"{name}:{seed}", f"synth:{name}:{seed}", None,
                               stop=long_frames if name == "long-1024" else None))
    if "independent" in groups:
        for s in INDEPENDENT.get(tracker, ()):
            d = SHARED / "independent" / s
            if (d / "frames").is_dir():
                out.append(Job("independent", s, str(d / "frames"), str(d / "truth.csv")))
    if "real" in groups:
        halves = real_half(SHARED / "real")
        for key, h in sorted(halves.items()):
            d = SHARED / "real" / key
            if half and h != half or not (d / "truth.csv").is_file():
                continue
            out.append(Job("real", key, str(d), str(d / "truth.csv"), h))
    if only:
        out = [j for j in out if any(o in j.name for o in only)]
    return out


def apply_patches(patches: list[str]) -> None:
    """``module.NAME=VALUE`` (a module constant, for ablations) set in this process."""
    import importlib

    for item in patches:
        name, _, value = item.partition("=")
        mod, _, const = name.rpartition(".")
        old = getattr(importlib.import_module(mod), const)
        new = value.strip().lower() in ("1", "true", "yes") if isinstance(old, bool) else type(old)(value)
        setattr(importlib.import_module(mod), const, new)


def load_with(tracker: str, config: str | None, settings: list[str]):
    """The tracker's configuration with ``section.key=value`` settings applied."""
    import tomllib

    from wfviz.config import load_config
    from wfviz.trackers import config_class, make_tracker

    cfg = load_config(config, config_class(tracker))
    for item in settings:
        key, _, value = item.partition("=")
        section, _, field = key.partition(".")
        sub = getattr(cfg, section)
        parsed = tomllib.loads(f"v = {value}")["v"]
        cfg = dataclasses.replace(cfg, **{section: dataclasses.replace(sub, **{field: parsed})})
    return make_tracker(tracker, cfg)


def run_job(job: Job, tracker: str, config: str | None, settings: list[str] = (),
            patches: list[str] = (), backfill: bool = False) -> dict:
    """Track one clip in-process and score it (confirmed tracks, the group's gate; ``backfill``:
    every confirmed track from its first frame, as ``--backfill`` reports it)."""
    import numpy as np

    import wfviz.synth  # noqa: F401 - registers synth: clips with open_clip
    from wfviz.io.clip import open_clip
    from wfviz.evaluate import read_truth
    from wfviz.run import run

    apply_patches(list(patches))

    clip = open_clip(job.source)
    if job.truth is None:  # a synthetic scenario brings its own truth
        shown: dict = defaultdict(list)
        hidden: dict = defaultdict(list)
        for row in clip.truth():
            (shown if row.visible else hidden)[row.frame].append((row.target_id, row.x, row.y))
        truth = (dict(shown), dict(hidden))
    else:
        truth = read_truth(job.truth)
    rows: list[tuple[int, int, float, float]] = []

    def outside(frame, result) -> None:
        h, w = frame.image.shape
        for t in result.tracks:
            if not (-0.5 <= t.x <= w - 0.5 and -0.5 <= t.y <= h - 0.5):
                rows.append((frame.index, t.track_id, t.x, t.y))

    t0 = time.perf_counter()
    summary = run(clip, load_with(tracker, config, list(settings)), truth=truth, gate=GATES[job.group],
                  start=job.start, stop=job.stop, on_frame=outside, backfill=backfill)
    s = summary.scores
    if backfill:
        from wfviz.sinks import BackfilledScores

        filled = summary.facts.get(BackfilledScores)
        assert filled is not None
        s = filled.result

    def num(v: float) -> float | None:
        return None if v is None or not math.isfinite(v) else float(v)

    return dict(group=job.group, name=job.name, half=job.half, start=job.start, frames=summary.frames,
                pd=num(s.pd), pd_settled=num(s.pd_settled), fa=num(s.fa_per_frame), idsw=s.id_switches,
                mota=num(s.mota), idf1=num(s.idf1), cle=num(s.cle_rms), ms=summary.tracker_ms,
                outside=len(rows), wall=time.perf_counter() - t0,
                targets=[(p.target_id, p.frames, round(float(np.nan_to_num(p.p_d)), 3)) for p in s.per_target])


def meets(r: dict) -> bool | None:
    goal = GOALS.get(r["group"])
    if goal is None or r["pd"] is None:
        return None
    pd = r["pd_settled"] if r["group"] == "independent" else r["pd"]
    return (pd or 0.0) >= goal[0] and r["fa"] <= goal[1] and (r["group"] != "independent" or r["idsw"] == 0)


def fmt(v: float | None, spec: str) -> str:
    return "–" if v is None else format(v, spec)


def table(results: list[dict]) -> list[str]:
    lines = ["| group | clip | half | frames | Pd | Pd (settled) | FA/frame | ID sw | MOTA | ms/frame | goal |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        ok = meets(r)
        lines.append(f"| {r['group']} | {r['name']} | {r['half'] or '–'} | {r['frames']} | {fmt(r['pd'], '.3f')} | "
                     f"{fmt(r['pd_settled'], '.3f')} | {fmt(r['fa'], '.3f')} | {r['idsw']} | "
                     f"{fmt(r['mota'], '.3f')} | {r['ms']:.2f} | {'' if ok is None else ('yes' if ok else 'no')} |")
    return lines


def summary(results: list[dict]) -> list[str]:
    """One line per group (and real half): goals met, mean Pd and FA."""
    out = []
    keys: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in results:
        keys[(r["group"], "")].append(r)
        if r["half"]:
            keys[(r["group"], r["half"])].append(r)
    for (g, h), rs in keys.items():
        pds = [r["pd"] or 0.0 for r in rs]
        fas = [r["fa"] for r in rs if r["fa"] is not None]
        motas = [r["mota"] for r in rs if r["mota"] is not None]
        ok = [meets(r) for r in rs]
        met = f", goal met on {sum(bool(o) for o in ok)} of {len(rs)}" if ok and ok[0] is not None else ""
        out.append(f"- {g}{' half ' + h if h else ''}: {len(rs)} clips, mean Pd {sum(pds) / len(pds):.3f}, "
                   f"mean FA/frame {sum(fas) / max(len(fas), 1):.3f} (worst {max(fas, default=0):.2f}), "
                   f"min MOTA {min(motas, default=float('nan')):.3f}, ID switches {sum(r['idsw'] for r in rs)}, "
                   f"rows outside the image {sum(r['outside'] for r in rs)}{met}")
    return out


def by_start(results: list[dict]) -> list[str]:
    """With runs from several first frames: per group (and real half), goals met, mean Pd and FA
    from each (how far these figures move by chance alone); nothing with one start."""
    starts = sorted({r["start"] for r in results})
    if len(starts) < 2:
        return []
    out = []
    keys: dict[tuple[str, str], dict[int, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in results:
        keys[(r["group"], "")][r["start"]].append(r)
        if r["half"]:
            keys[(r["group"], r["half"])][r["start"]].append(r)
    for (g, h), per in keys.items():
        met = [sum(bool(meets(r)) for r in per[s]) for s in starts]
        pds = [sum(r["pd"] or 0.0 for r in per[s]) / len(per[s]) for s in starts]
        fas = [sum(r["fa"] or 0.0 for r in per[s]) / len(per[s]) for s in starts]
        goal = (f"goal met on {', '.join(map(str, met))} of {len(per[starts[0]])} (mean {sum(met) / len(met):.2f}), "
                if meets(per[starts[0]][0]) is not None else "")
        out.append(f"- {g}{' half ' + h if h else ''}: {goal}mean Pd {', '.join(f'{v:.3f}' for v in pds)}, "
                   f"mean FA/frame {', '.join(f'{v:.3f}' for v in fas)}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracker", default="gewc")
    ap.add_argument("--config", default=None)
    ap.add_argument("--groups", nargs="+", default=["own", "independent", "real"],
                    choices=["own", "independent", "real"])
    ap.add_argument("--half", choices=["A", "B"], default=None, help="real sequences of one half only")
    ap.add_argument("--only", nargs="+", default=None, help="clips whose name contains one of these")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--starts", type=int, nargs="+", default=[0],
                    help="first frames to track from: each clip runs once from each (the periodic "
                         "re-estimations then fall on other frames of the scene; benchmarks/validation_diff.py "
                         "compares two such runs clip by clip)")
    ap.add_argument("--long-frames", type=int, default=300)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--set", nargs="+", default=[], metavar="SECTION.KEY=VALUE",
                    help="configuration settings over --config (TOML values)")
    ap.add_argument("--patch", nargs="+", default=[], metavar="MODULE.NAME=VALUE",
                    help="module constants, for ablations")
    ap.add_argument("--write", action="store_true", help="write the table into docs/accuracy.md")
    ap.add_argument("--backfill", action="store_true",
                    help="score every confirmed track from its first frame (wfviz --backfill: offline)")
    args = ap.parse_args()
    if args.write and 0 not in args.starts:
        ap.error("--write tables the runs from frame 0: --starts must include 0")
    todo = [dataclasses.replace(j, start=s) for s in args.starts
            for j in jobs(args.groups, args.tracker, args.seeds, args.long_frames, args.half, args.only)]
    if not todo:
        sys.exit("nothing to run (is ../shared/data there?)")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = [pool.submit(run_job, j, args.tracker, args.config, args.set, args.patch, args.backfill)
                   for j in todo]
        results = []
        for f in futures:
            r = f.result()
            results.append(r)
            ok = meets(r)
            name = r["name"] + (f" @{r['start']}" if r["start"] else "")
            print(f"{r['group']:11s} {name:34s} {r['half'] or '-'} Pd {fmt(r['pd'], '.3f')} "
                  f"settled {fmt(r['pd_settled'], '.3f')} FA {fmt(r['fa'], '.3f')} IDsw {r['idsw']} "
                  f"MOTA {fmt(r['mota'], '.3f')} out {r['outside']} {r['ms']:.1f} ms"
                  f"{'' if ok is None else ('  ok' if ok else '  MISS')}", flush=True)
    starts = sorted({r["start"] for r in results})
    for s in starts:
        if len(starts) > 1:
            print(f"from frame {s}:")
        print("\n".join(summary([r for r in results if r["start"] == s])))
    if len(starts) > 1:  # each group's figures side by side
        print(f"from frames {', '.join(map(str, starts))}:")
        print("\n".join(by_start(results)))
    print(f"({time.perf_counter() - t0:.0f} s)")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    if args.write:
        first = [r for r in results if r["start"] == 0]
        started = ["", f"The same clips tracked from frames {', '.join(map(str, starts))} (the periodic "
                       "re-estimations then fall on other frames of each scene; the table below is from frame 0):",
                   *by_start(results)] if len(starts) > 1 else []
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from doc_blocks import write_block

        argv = sys.argv[1:]
        if "--json" in argv:  # where a copy went is no part of how the table was made
            i = argv.index("--json")
            argv = argv[:i] + argv[i + 2:]
        cmd = " ".join(["python benchmarks/validation.py", *argv]).replace(" --write", "")
        block = "\n".join([f"Generated by `{cmd}` (tracker `{args.tracker}`, "
                           f"{'configuration ' + args.config if args.config else 'default configuration'}; "
                           f"confirmed tracks only; match gate 3 px for own and independent clips, 5 px for "
                           f"real ones; 'Pd (settled)' leaves out each target's first 6 visible frames).",
                           "", *summary(first), *started, "", *table(first)])
        begin, end = (m.format(args.tracker) for m in MARKERS)
        write_block(DOC, begin, end, block, heading=f"### Validation: {args.tracker}")


if __name__ == "__main__":
    main()
