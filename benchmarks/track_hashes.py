"""SHA-1 of the tracks CSV of every tracker on the own scenarios, the independent samples and
the real sequences in ../shared: the check that a restructuring changed no output.

    python benchmarks/track_hashes.py --out before.txt          # on the old commit
    python benchmarks/track_hashes.py --out after.txt           # on the new one
    diff before.txt after.txt                                   # nothing: outputs identical

``--trackers`` and ``--groups`` narrow the runs; ``--jobs`` runs clips in parallel processes.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
OWN = ("synth:fov70-maneuver:0", "synth:fov70-four-targets:0", "synth:fov180-city-aircraft:0",
       "synth:fov180-launches:0", "synth:starfield:0", "synth:lowsnr-tbd:0", "synth:uniform-50hz:0")
STOP = {"gewc": None, "fusion": None, "starfield": None, "tbd": 60}  # tbd is slow: its first 60 frames


def clips(groups: list[str]) -> list[str]:
    out: list[str] = []
    if "own" in groups:
        from wfviz.synth.scenarios import list_scenarios

        names = {i.name for i in list_scenarios()}
        out += [c for c in OWN if c.split(":")[1] in names]
    if "independent" in groups:
        out += sorted(str(p) for p in (SHARED / "independent").glob("S*/frames"))
    if "real" in groups:
        out += sorted(str(p.parent) for p in (SHARED / "real").glob("*/*/truth.csv"))
    return out


def one(job: tuple[str, str, int | None]) -> str:
    tracker, clip, stop = job
    import wfviz.synth  # noqa: F401 - registers synth: clips with open_clip
    from wfviz.io.clip import open_clip
    from wfviz.run import run
    from wfviz.trackers import make_tracker

    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.csv"
        try:
            run(open_clip(clip), make_tracker(tracker, None), tracks_csv=path, stop=stop)
            digest = hashlib.sha1(path.read_bytes()).hexdigest()
        except Exception as exc:  # noqa: BLE001 - a failure is a result too
            digest = f"error {type(exc).__name__}: {exc}"
    label = clip.replace(str(SHARED) + "/", "")
    return f"{tracker} {label} {digest}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trackers", nargs="+", default=["gewc", "fusion", "starfield", "tbd"])
    ap.add_argument("--groups", nargs="+", default=["own", "independent", "real"])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    jobs = [(t, c, STOP.get(t)) for t in args.trackers for c in clips(args.groups)]
    with ProcessPoolExecutor(args.jobs) as pool:
        lines = list(pool.map(one, jobs))
    text = "\n".join(lines) + "\n"
    if args.out:
        args.out.write_text(text)
    sys.stdout.write(text)


if __name__ == "__main__":
    main()
