"""Replay confirmation rules offline on the hits of every track of a real GEWC run.

One GEWC run per real sequence (configs/real-gewc.toml) records, for every measured hit of
every track, its significance under several signal-to-clutter measures, its blobness, its
static-clutter label, its scene and image position and whether it lies within 5 px of a truth
point. A rule is then replayed on those hits: a track is confirmed at the first hit at which
the rule holds (4 hits, mean blobness ≥ 0.4, two decided clutter labels with a mean ≤ 0.5, as
in the real config) and scores as a detection on its on-target hits and as a false alarm on the
others from then on, until the clutter rule would delete it. The replay ignores what a
confirmation changes downstream (gates, births), so it approximates the real runs: with the
real rules it reproduces their Pd within 0.05 and their false alarms within 0.07 a frame
(docs/pipeline.md §9).

SCR measures (residual peak / a local std, window 31 px): ``frame`` (the one in use), ``hp1.5``
and ``hp3`` (the frame minus its Gaussian blur of that σ), ``suppressed`` (the
background-suppressed image), ``subwindow`` (the smallest std of 8 windows of 11 px around the
detection, 3 px away from it: an edge leaves some of them clean).

    python benchmarks/confirmation_replay.py                      # SCR measures, levels 4-10
    python benchmarks/confirmation_replay.py --mover              # frame SCR 4, or a mover
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from wfviz.clip import open_clip  # noqa: E402
from wfviz.detection import local_stats, sample_at  # noqa: E402
from wfviz.evaluate import read_truth  # noqa: E402
from wfviz.trackers import load_tracker  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "real"
WINDOW = 31
MEASURES = ("frame", "hp1.5", "hp3", "suppressed", "subwindow")


def _subwindow_std(image: np.ndarray, xy: np.ndarray, size: int = 11, gap: int = 3) -> np.ndarray:
    mean = cv2.blur(image, (size, size))
    std = np.sqrt(np.maximum(cv2.blur(image * image, (size, size)) - mean * mean, 1e-12))
    h, w = image.shape
    d = size // 2 + gap
    best = np.full(len(xy), np.inf)
    for dx, dy in ((-d, 0), (d, 0), (0, -d), (0, d), (-d, -d), (d, d), (-d, d), (d, -d)):
        x = np.clip(np.rint(xy[:, 0] + dx).astype(int), 0, w - 1)
        y = np.clip(np.rint(xy[:, 1] + dy).astype(int), 0, h - 1)
        best = np.minimum(best, std[y, x])
    return best


def record(seq: Path) -> dict:
    """Every measured hit of every track of a GEWC run on ``seq`` with its features."""
    truth, _ = read_truth(seq / "truth.csv")  # {frame: [(target_id, x, y)]}, visible points
    tracker = load_tracker("gewc", ROOT / "configs" / "real-gewc.toml")
    hits, frames = [], 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for frame in open_clip(seq).frames():
            frames += 1
            r = tracker.step(frame)
            d = r.detections
            if not len(d):
                continue
            img = frame.image.astype(np.float32)
            region = np.ones(img.shape, dtype=bool)
            std = {"frame": None}
            for s in (1.5, 3.0):
                std[f"hp{s:g}"] = local_stats(img - cv2.GaussianBlur(img, (0, 0), s), region, WINDOW)[1]
            std["suppressed"] = local_stats(r.suppressed, region, WINDOW)[1]
            scr = {"frame": d.significance}
            for k in ("hp1.5", "hp3", "suppressed"):
                scr[k] = d.peak / np.maximum(sample_at(std[k], d.xy), 1e-6)
            scr["subwindow"] = d.peak / np.maximum(_subwindow_std(img, d.xy), 1e-6)
            target = np.full(len(d), -1)
            if truth.get(frame.index):
                t = np.array([(x, y) for _, x, y in truth[frame.index]])
                dist = np.hypot(d.xy[:, 0, None] - t[None, :, 0], d.xy[:, 1, None] - t[None, :, 1])
                target = np.where(dist.min(1) < 5, dist.argmin(1), -1)
            shift = np.asarray(tracker._offset, dtype=float)
            labels = r.clutter if r.clutter is not None else np.zeros(len(d))
            for m in r.measurements:
                i = m.detection
                hits.append(dict(frame=frame.index, track=m.track_id, target=int(target[i]),
                                 image=d.xy[i].copy(), scene=d.xy[i] - shift, blob=float(d.blobness[i]),
                                 label=float(labels[i]), **{f"scr:{k}": float(v[i]) for k, v in scr.items()}))
    return dict(hits=hits, frames=frames, truth=sum(len(v) for v in truth.values()))


def replay(run: dict, measure: str, level: float, mover: float = 0.0) -> tuple[float, float]:
    """(Pd, false alarms a frame) when tracks are confirmed on a mean ``measure`` ≥ ``level``
    (or, with ``mover`` > 0, on a mean frame SCR ≥ 1 as a gapless straight mover)."""
    tracks: dict[int, list] = defaultdict(list)
    for h in run["hits"]:
        tracks[h["track"]].append(h)
    found, false = set(), 0
    for hs in tracks.values():
        n = np.arange(1, len(hs) + 1)
        mean = lambda key: np.cumsum([h[key] for h in hs]) / n  # noqa: E731
        lab = np.array([h["label"] for h in hs])
        known = np.cumsum(~np.isnan(lab))
        static = np.cumsum(np.nan_to_num(lab)) / np.maximum(known, 1)
        ok = mean(f"scr:{measure}") >= level
        if mover > 0:
            scene, image = np.array([h["scene"] for h in hs]), np.array([h["image"] for h in hs])
            moved = np.hypot(*(scene - scene[0]).T)
            path = np.r_[0.0, np.cumsum(np.hypot(*np.diff(scene, axis=0).T))]
            gapless = np.cumsum(np.r_[0, np.diff([h["frame"] for h in hs]) != 1]) == 0
            ok |= (gapless & (moved >= mover) & (np.hypot(*(image - image[0]).T) >= mover)
                   & (moved >= 0.8 * path) & (static <= 0.25) & (mean("scr:frame") >= 1.0))
        ok &= (n >= 4) & (mean("blob") >= 0.4) & (known >= 2) & (static <= 0.5)
        if not ok.any():
            continue
        k = int(np.argmax(ok))
        gone = np.nonzero((n > k) & (known >= 2) & (static > 0.8))[0]
        for h in hs[k:gone[0] if len(gone) else len(hs)]:
            if h["target"] >= 0:
                found.add((h["frame"], h["target"]))
            else:
                false += 1
    return len(found) / max(run["truth"], 1), false / max(run["frames"], 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", default="4,6,8,10", help="SCR levels to replay (comma-separated)")
    ap.add_argument("--mover", action="store_true", help="replay frame SCR 4 or a 6 px mover instead")
    args = ap.parse_args()
    seqs = sorted(p for p in DATA.glob("*/*/") if (p / "truth.csv").exists())
    if not seqs:
        sys.exit(f"no real sequences under {DATA}")
    levels = [float(v) for v in args.levels.split(",")]
    for seq in seqs:
        run = record(seq)
        name = seq.name
        if args.mover:
            cells = [f"frame SCR 4: {'%.2f / %.2f' % replay(run, 'frame', 4.0)}",
                     f"or a mover: {'%.2f / %.2f' % replay(run, 'frame', 4.0, mover=6.0)}"]
        else:
            cells = [f"{m} " + " ".join("%.2f/%.2f" % replay(run, m, v) for v in levels) for m in MEASURES]
        print(f"{name:18s} " + " | ".join(cells), flush=True)
    print(f"(Pd / false alarms a frame; levels {levels})")


if __name__ == "__main__":
    main()
