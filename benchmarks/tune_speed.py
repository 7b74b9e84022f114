"""`wfviz tune`: trials per minute with and without the front-end cache, and whether a study
started from the defaults beats them on clips it did not tune on.

    python benchmarks/tune_speed.py                  # both parts (~10 min on 2 cores)
    python benchmarks/tune_speed.py --only speed     # the 20-trial target study, cached and not
    python benchmarks/tune_speed.py --write-doc      # also update docs/tuning.md

**speed**: the issue's target study, 20 trials of the default GEWC space over two 640x512 clips
of 40 frames (``synth:fov70-maneuver:0``, ``synth:fov70-four-targets:0``) with ``--workers 2``,
timed as whole ``wfviz tune`` processes (start-up, reports and recordings included), once with
the front-end cache and once with ``--no-cache``; the two trials.csv must agree in every score.

**own**: tune on three of wfviz's own scenarios (full length) and validate on three others,
40 trials of the default space with ``--workers 2``: the validation scores of the defaults
(trial 0) and of the best trial.
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

DOC = Path(__file__).resolve().parents[1] / "docs" / "tuning.md"
SPEED_CLIPS = ["synth:fov70-maneuver:0", "synth:fov70-four-targets:0"]
OWN_TUNE = ["synth:fov70-maneuver:0", "synth:fov180-city-aircraft:0", "synth:uniform-50hz:0"]
OWN_VALIDATE = ["synth:fov70-four-targets:0", "synth:fov180-launches:0", "synth:long-1024:0"]


def _tune(args: list[str], cwd: Path) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "wfviz", "tune", *args], cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"wfviz tune failed: {proc.stderr.strip()}")
    return time.perf_counter() - t0


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def speed(tmp: Path, trials: int) -> str:
    common = [*SPEED_CLIPS, "--stop", "40", "--trials", str(trials), "--workers", "2", "--seed", "0"]
    cached = _tune([*common, "--out", "cached"], tmp)
    plain = _tune([*common, "--out", "plain", "--no-cache"], tmp)
    a = [{k: v for k, v in r.items() if k != "seconds"} for r in _rows(tmp / "cached" / "trials.csv")]
    b = [{k: v for k, v in r.items() if k != "seconds"} for r in _rows(tmp / "plain" / "trials.csv")]
    same = "identical" if a == b else "**differ**"
    per = {name: sum(float(r["seconds"]) for r in _rows(tmp / name / "trials.csv")) / trials
           for name in ("cached", "plain")}
    return "\n".join([
        f"Measured {time.strftime('%Y-%m-%d')} on {machine()}; `python benchmarks/tune_speed.py --only speed`.",
        "",
        f"{trials} trials of the default GEWC space, two 640×512 clips of 40 frames "
        f"({', '.join(SPEED_CLIPS)}), `--workers 2`, whole `wfviz tune` processes:",
        "",
        "| front end | wall time | trials per minute | mean trial (s, both clips) | target (< 180 s) |",
        "|---|---:|---:|---:|---|",
        f"| cached (default) | {cached:.1f} s | {60 * trials / cached:.1f} | {per['cached']:.2f} | "
        f"{'met' if cached < 180 else 'missed'} |",
        f"| `--no-cache` | {plain:.1f} s | {60 * trials / plain:.1f} | {per['plain']:.2f} | "
        f"{'met' if plain < 180 else 'missed'} |",
        "",
        f"Scores of the two studies: {same} in every trial. The cache saves "
        f"{100 * (1 - per['cached'] / per['plain']):.0f} % of a trial's time here (each worker "
        "prepares each clip once, in its first trial).",
    ])


def own(tmp: Path, trials: int) -> str:
    _tune([*OWN_TUNE, *sum((["--validate", v] for v in OWN_VALIDATE), []), "--out", "own",
           "--trials", str(trials), "--workers", "2", "--seed", "0", "--stop", "300"], tmp)
    got = _rows(tmp / "own" / "trials.csv")
    done = [r for r in got if r["state"] == "complete"]
    base = next(r for r in done if r["base"] == "1")
    best = max(done, key=lambda r: (float(r["tune_mota"]), -int(r["trial"])))
    other = max((r for r in done if r["base"] != "1"), key=lambda r: (float(r["tune_mota"]), -int(r["trial"])))
    lines = [
        f"Measured {time.strftime('%Y-%m-%d')}; `python benchmarks/tune_speed.py --only own`: "
        f"{trials} trials, default GEWC space, objective MOTA; tuned on {', '.join(OWN_TUNE)}, "
        f"validated on {', '.join(OWN_VALIDATE)} (`long-1024` cut to 300 frames).",
        "",
        "| trial | tune MOTA | tune FA/frame | validation MOTA | validation FA/frame |",
        "|---|---:|---:|---:|---:|",
        f"| {base['trial']} (defaults) | {float(base['tune_mota']):.3f} | {float(base['tune_fa']):.3f} | "
        f"{float(base['validate_mota']):.3f} | {float(base['validate_fa']):.3f} |",
        f"| {best['trial']} (best on the tune clips) | {float(best['tune_mota']):.3f} | {float(best['tune_fa']):.3f} | "
        f"{float(best['validate_mota']):.3f} | {float(best['validate_fa']):.3f} |",
        f"| {other['trial']} (best of the others) | {float(other['tune_mota']):.3f} | {float(other['tune_fa']):.3f} | "
        f"{float(other['validate_mota']):.3f} | {float(other['validate_fa']):.3f} |",
        "",
    ]
    gain = float(best["validate_mota"]) - float(base["validate_mota"])
    if best["trial"] == base["trial"]:
        lines.append("No trial beat the defaults on the tune clips: the defaults stay the best choice.")
    elif gain >= 0:
        lines.append(f"The tuned configuration holds on the validation clips ({gain:+.3f} MOTA against the defaults).")
    else:
        lines.append(f"The tuned configuration does **not** hold on the validation clips ({gain:+.3f} MOTA "
                     "against the defaults): it fitted the tune clips.")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("speed", "own"), nargs="+", default=["speed", "own"])
    ap.add_argument("--trials", type=int, default=20, help="trials of the speed study")
    ap.add_argument("--own-trials", type=int, default=40)
    ap.add_argument("--write-doc", action="store_true", help=f"update {DOC.name}")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if "speed" in a.only:
            block = speed(tmp, a.trials)
            print(block, "\n")
            if a.write_doc:
                write_block(DOC, "<!-- tune-speed:begin -->", "<!-- tune-speed:end -->", block)
        if "own" in a.only:
            block = own(tmp, a.own_trials)
            print(block)
            if a.write_doc:
                write_block(DOC, "<!-- tune-own:begin -->", "<!-- tune-own:end -->", block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
