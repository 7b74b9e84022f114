"""Two validation runs compared clip by clip: is a change's effect on accuracy larger than chance?

A tracker whose estimates are re-made periodically gives a slightly different result when the
same clip starts a frame later: the re-estimations fall on other frames of the scene. On the
short real sequences one false track more or less moves a clip's FA by 0.05 a frame, so a single
run cannot tell a change that moves estimates by a fraction of a pixel from a real loss. Run
both sides from several first frames (``validation.py --starts 0 1 2 3 --json X``), then:

    python benchmarks/validation_diff.py base.json candidate.json

For each group (and real half) it prints the mean change of Pd, FA per frame and goals met
(each clip averaged over its starts first, so a clip counts once), with a 95 % bootstrap
interval over the clips (the clips are the sample: the interval says how far the mean change
could be from zero by the luck of which clips changed), and how much the clips move with the
first frame alone (the baseline's spread over its starts: what "chance" is here).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from validation import meets

ROUNDS = 10_000  # bootstrap resamples


def load(path: Path) -> dict[tuple[str, str, int], dict]:
    """{(group, clip, start): row} of a ``validation.py --json`` file."""
    try:
        rows = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        sys.exit(f"{path}: not a validation.py --json file ({e})")
    return {(r["group"], r["name"], r.get("start", 0)): r for r in rows}


def per_clip(rows: dict[tuple[str, str, int], dict], keys: list[tuple[str, str, int]]) -> dict:
    """{(group, clip): (half, mean Pd, mean FA, mean goal met, Pd spread, FA spread)} over the starts in ``keys``."""
    by: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for k in keys:
        by[k[:2]].append(rows[k])
    out = {}
    for clip, rs in by.items():
        pd = np.array([r["pd"] or 0.0 for r in rs])
        fa = np.array([r["fa"] or 0.0 for r in rs])
        met = np.array([float(bool(meets(r))) for r in rs])
        out[clip] = (rs[0]["half"], pd.mean(), fa.mean(), met.mean(), pd.std(), fa.std())
    return out


def interval(d: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    """95 % bootstrap interval of the mean of ``d`` (resampling its entries)."""
    if len(d) < 2:
        return float("nan"), float("nan")
    means = d[rng.integers(0, len(d), size=(ROUNDS, len(d)))].mean(axis=1)
    lo, hi = np.quantile(means, [0.025, 0.975])
    return float(lo), float(hi)


def span(lo: float, hi: float, digits: int) -> str:
    """``[lo, hi]`` signed, or ``[–]`` where one clip gives no interval."""
    return "[–]" if np.isnan(lo) else f"[{lo:+.{digits}f}, {hi:+.{digits}f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", type=Path)
    ap.add_argument("candidate", type=Path)
    ap.add_argument("--top", type=int, default=8, help="clips with the largest changes listed")
    args = ap.parse_args()
    a, b = load(args.base), load(args.candidate)
    keys = sorted(set(a) & set(b))
    if not keys:
        sys.exit(f"{args.candidate}: no clip and start in common with {args.base}")
    if len(keys) < max(len(a), len(b)):
        print(f"({max(len(a), len(b)) - len(keys)} runs only on one side left out)")
    starts = sorted({k[2] for k in keys})
    ca, cb = per_clip(a, keys), per_clip(b, keys)
    rng = np.random.default_rng(0)
    groups: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for clip, v in ca.items():
        groups[clip[0]].append(clip)
        if v[0]:
            groups[f"{clip[0]} half {v[0]}"].append(clip)
    changed = sum(a[k]["pd"] != b[k]["pd"] or a[k]["fa"] != b[k]["fa"] for k in keys)
    print(f"{len(keys)} runs ({len(ca)} clips from frames {', '.join(map(str, starts))}), "
          f"{changed} with another Pd or FA")
    print("| group | clips | ΔPd [95 %] | ΔFA/frame [95 %] | goals met base → candidate [95 % of Δ] | "
          "base spread over starts: Pd, FA |")
    print("|---|---:|---|---|---|---|")
    for g in sorted(groups):
        clips = groups[g]
        dpd = np.array([cb[c][1] - ca[c][1] for c in clips])
        dfa = np.array([cb[c][2] - ca[c][2] for c in clips])
        dmet = np.array([cb[c][3] - ca[c][3] for c in clips])
        n = len(clips)
        (pl, ph), (fl, fh), (ml, mh) = (interval(d, rng) for d in (dpd, dfa, dmet * n))
        print(f"| {g} | {n} | {dpd.mean():+.4f} {span(pl, ph, 4)} | {dfa.mean():+.4f} {span(fl, fh, 4)} | "
              f"{sum(ca[c][3] for c in clips):.2f} → {sum(cb[c][3] for c in clips):.2f} "
              f"{span(ml, mh, 2)} | {np.mean([ca[c][4] for c in clips]):.4f}, "
              f"{np.mean([ca[c][5] for c in clips]):.4f} |")
    moved = sorted(ca, key=lambda c: -(abs(cb[c][1] - ca[c][1]) + abs(cb[c][2] - ca[c][2])))[:args.top]
    print("\nlargest changes (mean over the starts):")
    for c in moved:
        print(f"  {c[0]:11s} {c[1]:34s} Pd {ca[c][1]:.3f} → {cb[c][1]:.3f}  FA {ca[c][2]:.3f} → {cb[c][2]:.3f}  "
              f"goal {ca[c][3]:.2f} → {cb[c][3]:.2f}")


if __name__ == "__main__":
    main()
