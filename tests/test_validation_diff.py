"""benchmarks/validation_diff.py: two validation runs compared clip by clip over their starts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "validation_diff.py"


def _row(name: str, half: str, start: int, pd: float, fa: float) -> dict:
    return dict(group="real", name=name, half=half, start=start, frames=100, pd=pd, pd_settled=pd, fa=fa,
                idsw=0, mota=pd - fa, idf1=pd, cle=1.0, ms=10.0, outside=0, wall=1.0, targets=[])


def _write(path: Path, rows: list[dict]) -> Path:
    path.write_text(json.dumps(rows), encoding="utf-8")
    return path


def _run(*args: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


def test_mean_change_per_clip_over_starts(tmp_path):
    # clip a: Pd 0.95 from both starts on the base, 0.85 and 0.95 on the candidate (goal lost from start 1);
    # clip b: FA 0.0 -> 0.2 from start 0 only
    base = [_row("a", "A", 0, 0.95, 0.0), _row("a", "A", 1, 0.95, 0.0),
            _row("b", "B", 0, 0.95, 0.0), _row("b", "B", 1, 0.95, 0.0)]
    cand = [_row("a", "A", 0, 0.95, 0.0), _row("a", "A", 1, 0.85, 0.0),
            _row("b", "B", 0, 0.95, 0.2), _row("b", "B", 1, 0.95, 0.0)]
    out = _run(_write(tmp_path / "base.json", base), _write(tmp_path / "cand.json", cand))
    assert out.returncode == 0, out.stderr
    lines = {ln.split("|")[1].strip(): ln for ln in out.stdout.splitlines() if ln.startswith("| real")}
    # per clip, means over the starts: a ΔPd -0.05, b ΔFA +0.1 (b misses the FA goal from start 0 only)
    assert "| real | 2 | -0.0250" in lines["real"] and "| +0.0500" in lines["real"]
    assert "2.00 → 1.00" in lines["real"]
    assert "| real half A | 1 | -0.0500 [–] |" in lines["real half A"]  # one clip: no interval
    assert "4 runs (2 clips from frames 0, 1), 2 with another Pd or FA" in out.stdout


def test_identical_runs_change_nothing(tmp_path):
    rows = [_row("a", "A", s, 0.9, 0.05) for s in range(3)] + [_row("b", "B", s, 0.7, 0.0) for s in range(3)]
    out = _run(_write(tmp_path / "x.json", rows), _write(tmp_path / "y.json", rows))
    assert out.returncode == 0, out.stderr
    assert "0 with another Pd or FA" in out.stdout
    assert "| real | 2 | +0.0000 [+0.0000, +0.0000] | +0.0000 [+0.0000, +0.0000] | 1.00 → 1.00" in out.stdout


def test_unreadable_file_is_named(tmp_path):
    good = _write(tmp_path / "good.json", [_row("a", "A", 0, 0.9, 0.0)])
    bad = tmp_path / "bad.json"
    bad.write_text("not json", encoding="utf-8")
    out = _run(good, bad)
    assert out.returncode != 0 and "bad.json: not a validation.py --json file" in out.stderr
