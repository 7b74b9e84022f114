"""Where Pd went on every independent sample and real sequence in ../shared (default GEWC
tracker, or ``--tracker``): each clip's cause counts, its dominant miss cause and false-track
causes, and a check of the explanation against the outputs on every clip:

- every truth point has exactly one cause; ``matched`` equals the scorer's matches;
- ``not_detected`` has no detection within the gate (its ``det_dist`` is beyond it or empty);
- ``latency`` / ``not_confirmed`` have a tentative track row within the gate, the one named.

A second table says which confirmation test held the tentative tracks of the ``latency`` and
``not_confirmed`` points back (the explain file's ``test`` column), per clip and test: points,
and how far the statistic stayed from its level (median ``level - statistic``, and the median
statistic / level).

    python benchmarks/explain_causes.py                    # markdown tables on stdout
    python benchmarks/explain_causes.py --groups real --half A --jobs 2
    python benchmarks/explain_causes.py --only IR_BIRD_063 sequence1
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
import warnings
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MISS_ORDER = ("outside_circle", "outside_region", "not_detected", "lost", "not_associated", "latency",
              "not_confirmed")


def clips(groups: list[str]) -> list[tuple[str, str]]:
    """(clip, truth CSV) of the groups."""
    out: list[tuple[str, str]] = []
    if "independent" in groups:
        out += [(str(p / "frames"), str(p / "truth.csv")) for p in sorted((SHARED / "independent").glob("S*"))]
    if "real" in groups:
        out += [(str(p.parent), str(p)) for p in sorted((SHARED / "real").glob("*/*/truth.csv"))]
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def one(job: tuple[str, str, str, float]) -> dict:
    """Run ``tracker`` on ``clip`` with truth and --explain; the counts and the checks."""
    tracker, clip, truth, gate = job
    import wfviz.synth  # noqa: F401 - registers synth: clips with open_clip
    from wfviz.evaluate import matchable, read_truth
    from wfviz.io.clip import open_clip
    from wfviz.run import run
    from wfviz.trackers import make_tracker

    warnings.simplefilter("ignore")
    label = clip.replace(str(SHARED) + "/", "").removesuffix("/frames")
    with tempfile.TemporaryDirectory() as tmp:
        t, e = Path(tmp) / "t.csv", Path(tmp) / "e.csv"
        truth_points = read_truth(truth)
        summary = run(open_clip(clip), make_tracker(tracker, None), tracks_csv=t, truth=truth_points,
                      gate=gate, explain=e)
        ex, false = _rows(e), _rows(Path(tmp) / "e-false.csv")
        tracks: dict[int, list[dict[str, str]]] = {}
        for r in _rows(t):
            tracks.setdefault(int(r["frame"]), []).append(r)
    problems = []
    n = Counter(r["cause"] for r in ex)
    held = [(r["cause"], r["test"], _float(r["statistic"]), _float(r["level"])) for r in ex
            if r["cause"] in ("latency", "not_confirmed")]
    scores = summary.scores
    if scores is not None and n["matched"] != scores.matches:
        problems.append(f"matched {n['matched']} != scorer's {scores.matches}")
    for r in ex:
        x, y, f = float(r["x"]), float(r["y"]), int(r["frame"])
        if r["cause"] == "not_detected" and r["det_dist"] and float(r["det_dist"]) <= gate:
            problems.append(f"frame {f}: not_detected with a detection {r['det_dist']} px away")
        if r["cause"] in ("latency", "not_confirmed"):
            box = truth_points.boxes.get(f, {}).get(int(r["target_id"]))
            own = [t for t in tracks.get(f, []) if t["confirmed"] == "0" and t["track_id"] == r["track_id"]]
            xy = [[float(t["x"]), float(t["y"])] for t in own]
            if not matchable((int(r["target_id"]), x, y), xy, gate, box).any():
                problems.append(f"frame {f}: {r['cause']} without its tentative track within the gate")
    visible = sum(v for k, v in n.items() if k != "hidden")
    misses = {k: n[k] for k in MISS_ORDER if n[k]}
    return {"clip": label, "visible": visible, "matched": n["matched"], "causes": dict(n),
            "dominant": max(misses, key=lambda k: misses[k]) if misses else "-",
            "false": dict(Counter(r["cause"] for r in false)), "problems": problems, "held": held,
            "pd": scores.pd if scores is not None else math.nan}


def _float(v: str) -> float:
    return float(v) if v else math.nan


def held_table(results: list[dict]) -> list[str]:
    """Markdown rows: per clip and blocking test, the latency and not_confirmed points it held
    back, the median shortfall (level - statistic, in the test's units) and statistic / level;
    then the same over all clips."""
    import numpy as np

    def row(name: str, items: list[tuple[str, str, float, float]]) -> list[str]:
        out = []
        by: dict[str, list] = {}
        for it in items:
            by.setdefault(it[1] or "(none named)", []).append(it)
        for test, its in sorted(by.items(), key=lambda kv: -len(kv[1])):
            lat = sum(c == "latency" for c, *_ in its)
            val = np.array([v for _, _, v, _ in its])
            lev = np.array([lv for _, _, _, lv in its])
            ok = np.isfinite(val) & np.isfinite(lev)
            gap = f"{np.median(lev[ok] - val[ok]):.3g}" if ok.any() else "–"
            frac = ok & (lev != 0)
            ratio = f"{np.median(val[frac] / lev[frac]):.2f}" if frac.any() else "–"
            out.append(f"| {name} | {test} | {lat} | {len(its) - lat} | {gap} | {ratio} |")
        return out

    lines = ["| clip | held back by | latency | not confirmed | median level - statistic | median statistic / level |",
             "|---|---|---|---|---|---|"]
    every: list = []
    for r in results:
        lines += row(r["clip"], r["held"])
        every += r["held"]
    return lines + row("**all**", every)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracker", default="gewc")
    ap.add_argument("--groups", nargs="+", default=["independent", "real"], choices=["independent", "real"])
    ap.add_argument("--gate", type=float, default=3.0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--half", choices=["A", "B"], default=None, help="real sequences of one half only")
    ap.add_argument("--only", nargs="+", default=None, help="clips whose name contains one of these")
    a = ap.parse_args()
    picked = clips(a.groups)
    if a.half:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from validation import real_half

        halves = real_half(SHARED / "real")
        picked = [(c, t) for c, t in picked if "/real/" not in c
                  or halves.get(str(Path(c).relative_to(SHARED / "real"))) == a.half]
    if a.only:
        picked = [(c, t) for c, t in picked if any(o in c for o in a.only)]
    jobs = [(a.tracker, c, t, a.gate) for c, t in picked]
    with ProcessPoolExecutor(a.jobs) as pool:
        results = list(pool.map(one, jobs))
    head = ["clip", "visible", "Pd", *(c.replace("_", " ") for c in MISS_ORDER), "dominant", "false-track rows"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    total: Counter = Counter()
    bad = 0
    for r in results:
        total.update({k: v for k, v in r["causes"].items() if k != "hidden"})
        false = ", ".join(f"{k} {v}" for k, v in sorted(r["false"].items(), key=lambda kv: -kv[1])) or "0"
        print(f"| {r['clip']} | {r['visible']} | {r['pd']:.3f} | "
              + " | ".join(str(r["causes"].get(c, 0)) for c in MISS_ORDER) + f" | {r['dominant']} | {false} |")
        for p in r["problems"]:
            bad += 1
            print(f"  PROBLEM {r['clip']}: {p}", file=sys.stderr)
    v = sum(total.values())
    print(f"\nall clips: {v} visible truth points, " + ", ".join(
        f"{c} {100 * total[c] / max(v, 1):.1f} %" for c in ("matched", *MISS_ORDER)))
    print(f"consistency problems: {bad}")
    print()
    print("\n".join(held_table(results)))


if __name__ == "__main__":
    main()
