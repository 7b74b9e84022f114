"""`wfviz tune --prune`: the trial time it saves on a study over the 24 real sequences, and
whether it chooses the same best trial.

    python benchmarks/tune_pruning.py                 # 12 trials each way, first 100 frames
    python benchmarks/tune_pruning.py --trials 16 --stop 0 --write-doc   # whole clips; the doc

Two seeded studies of the default GEWC space (objective MOTA, ``--gate 5``, ``--workers 1``,
seed 0, ``--stop 100``: the cached front end of all 24 clips then fits in the cache) tune on
every real sequence with truth under ../shared/data/real (no validation clip),
one without and one with ``--prune``, run one after the other as whole ``wfviz tune`` processes.
It reports the trials' summed wall time (``seconds`` in trials.csv) of each, the frames the
trials ran (a measure the machine's load does not change), the trials pruned and after how many
clips, and the best trial of each (number, MOTA, parameters).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_blocks import machine, write_block

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "tuning.md"
REAL = ROOT.parent / "shared" / "data" / "real"


def real_clips() -> list[Path]:
    """Every real sequence folder that holds its truth, sorted by set and name."""
    return sorted(p.parent for p in REAL.glob("*/*/truth.csv"))


def frames(clip: Path, stop: int | None = None) -> int:
    """The frames of a folder clip a study runs (before ``stop``)."""
    n = sum(1 for p in clip.iterdir() if p.suffix in (".png", ".tif", ".tiff", ".npy"))
    return min(n, stop) if stop else n


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def study(clips: list[Path], out: Path, trials: int, stop: int | None,
          prune: bool) -> tuple[list[dict[str, str]], float]:
    """Run one study; its trials.csv rows and the process's wall time."""
    args = [sys.executable, "-m", "wfviz", "tune", *map(str, clips), "--out", str(out), "--trials", str(trials),
            "--workers", "1", "--seed", "0", "--gate", "5", *(["--stop", str(stop)] if stop else []),
            *(["--prune"] if prune else [])]
    t0 = time.perf_counter()
    proc = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        sys.exit(f"wfviz tune failed: {proc.stderr.strip()}")
    return _rows(out / "trials.csv"), time.perf_counter() - t0


def summary(rows: list[dict[str, str]], clips: list[Path], stop: int | None) -> dict[str, object]:
    """Trial seconds, frames run, the pruned trials and the best completed trial."""
    n = {c.name: frames(c, stop) for c in clips}
    labels = {c.name: c.name for c in clips}  # a folder clip's label: its name (unique here)
    assert all(f"{label}_mota" in rows[0] for label in labels.values()), "a clip's column is missing"
    run = sum(n[c] for r in rows for c, label in labels.items() if r[f"{label}_mota"] != "")
    pruned = [r for r in rows if r["state"] == "pruned"]
    after = [sum(r[f"{label}_mota"] != "" for label in labels.values()) for r in pruned]
    done = [r for r in rows if r["state"] == "complete"]
    best = max(done, key=lambda r: (float(r["tune_mota"]), -int(r["trial"])))
    params = [k for k in rows[0] if "." in k and not k.endswith(("_mota", "_idf1", "_pd", "_fa", "_idsw"))]
    return {"seconds": sum(float(r["seconds"]) for r in rows), "frames": run,
            "all_frames": len(rows) * sum(n.values()), "pruned": len(pruned), "after": after,
            "best": int(best["trial"]), "best_mota": float(best["tune_mota"]),
            "best_params": {k: best[k] for k in params}}


def table(plain: dict, pruned: dict, walls: tuple[float, float], trials: int, stop: int | None,
          clips: list[Path]) -> str:
    saved = 1 - pruned["seconds"] / plain["seconds"]
    saved_frames = 1 - pruned["frames"] / plain["frames"]
    same = (plain["best"] == pruned["best"] and plain["best_params"] == pruned["best_params"])
    after = ", ".join(map(str, sorted(pruned["after"]))) or "–"
    return "\n".join([
        f"Measured {time.strftime('%Y-%m-%d')} on {machine()}; "
        f"`python benchmarks/tune_pruning.py --trials {trials} --stop {stop or 0}`.",
        "",
        f"{trials} trials of the default GEWC space, objective MOTA, `--gate 5`, `--workers 1`, seed 0, "
        f"tuned on the {len(clips)} real sequences"
        + (f" (their first {stop} frames" if stop else " (whole") + f": {sum(frames(c, stop) for c in clips)} frames a trial):",
        "",
        "| | trial time (s, summed) | frames run | pruned trials (after k clips) | best trial | its MOTA | wall time (s) |",
        "|---|---:|---:|---|---:|---:|---:|",
        f"| without `--prune` | {plain['seconds']:.0f} | {plain['frames']} | – | {plain['best']} | "
        f"{plain['best_mota']:.3f} | {walls[0]:.0f} |",
        f"| `--prune` | {pruned['seconds']:.0f} | {pruned['frames']} | {pruned['pruned']} ({after}) | "
        f"{pruned['best']} | {pruned['best_mota']:.3f} | {walls[1]:.0f} |",
        "",
        f"Pruning saves {100 * saved:.0f} % of the trials' time ({100 * saved_frames:.0f} % of the frames run; "
        f"target ≥ 40 %). The best trial is "
        + ("the same (same number and parameters)." if same else
           f"**not** the same: trial {plain['best']} without pruning, trial {pruned['best']} with it."),
    ])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=12)
    ap.add_argument("--stop", type=int, default=100, help="frames of each clip (0: all)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the two studies in this folder")
    ap.add_argument("--write-doc", action="store_true", help="update docs/tuning.md")
    args = ap.parse_args()
    clips = real_clips()
    if not clips:
        sys.exit(f"{REAL}: no real sequence with truth.csv")
    with tempfile.TemporaryDirectory() as tmp:
        base = args.keep or Path(tmp)
        stop = args.stop or None
        plain_rows, wall_plain = study(clips, base / "plain", args.trials, stop, prune=False)
        pruned_rows, wall_pruned = study(clips, base / "pruned", args.trials, stop, prune=True)
    text = table(summary(plain_rows, clips, args.stop or None), summary(pruned_rows, clips, args.stop or None),
                 (wall_plain, wall_pruned), args.trials, args.stop or None, clips)
    print(text)
    if args.write_doc:
        write_block(DOC, "<!-- tune-pruning:begin -->", "<!-- tune-pruning:end -->", text,
                    heading="## Pruning: measured on the real sequences")


if __name__ == "__main__":
    main()
