"""``--backfill``: confirmed tracks reported from their first frame (their tentative rows
rewritten as confirmed when the run is complete), Pd printed both ways, ``wfviz eval`` reading
the column back."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from conftest import invoke, rows
from test_explain import SIGMA, _spot, scene


def _mover(tmp: Path) -> tuple[Path, Path]:
    """A bright target crossing a flat noisy frame at 1.5 px a frame, 30 frames."""
    def draw(k: int, f: np.ndarray) -> list:
        x = 20 + 1.5 * k
        _spot(f, x, 60, 15.0 * SIGMA)
        return [(1, x, 60, 1)]
    return scene(tmp, 30, draw)


def _by_track(rs: list[dict]) -> dict[int, list[dict]]:
    out: dict[int, list[dict]] = defaultdict(list)
    for r in rs:
        out[int(r["track_id"])].append(r)
    return out


def test_backfill_reports_a_confirmed_track_from_its_first_frame(tmp_path: Path) -> None:
    clip, truth = _mover(tmp_path)
    online, filled = tmp_path / "online.csv", tmp_path / "filled.csv"
    r0 = invoke("track", str(clip), "--tracks", str(online), "--truth", str(truth))
    r1 = invoke("track", str(clip), "--tracks", str(filled), "--truth", str(truth), "--backfill")
    assert r0.exit_code == 0 and r1.exit_code == 0, r0.output + r1.output
    assert "backfilled" not in online.read_text().splitlines()[0]  # the contract without the option
    a, b = rows(online), rows(filled)
    assert [(r["frame"], r["track_id"], r["x"], r["y"]) for r in a] == \
        [(r["frame"], r["track_id"], r["x"], r["y"]) for r in b]  # the same run, row for row
    confirmed_ids = {int(r["track_id"]) for r in a if r["confirmed"] == "1"}
    assert confirmed_ids, "the target's track must confirm"
    for tid, rs in _by_track(b).items():
        before = _by_track(a)[tid]
        if tid in confirmed_ids:  # every row confirmed; exactly the tentative ones marked
            assert all(r["confirmed"] == "1" for r in rs)
            assert [r["backfilled"] for r in rs] == ["1" if r["confirmed"] == "0" else "0" for r in before]
            assert any(r["backfilled"] == "1" for r in rs)
        else:  # a track never confirmed is left as it was
            assert all(r["confirmed"] == "0" and r["backfilled"] == "0" for r in rs)
    assert "with --backfill (confirmed tracks from their first frame): Pd" in r1.output
    assert "with --backfill" not in r0.output
    pd_online = float(r1.output.split("\nPd ")[1].split()[0])
    pd_filled = float(r1.output.split("with --backfill (confirmed tracks from their first frame): Pd ")[1].split()[0])
    assert pd_filled > pd_online  # the confirmation latency is reported back


def test_eval_scores_a_backfilled_csv_both_ways(tmp_path: Path) -> None:
    clip, truth = _mover(tmp_path)
    filled, online = tmp_path / "filled.csv", tmp_path / "online.csv"
    assert invoke("track", str(clip), "--tracks", str(filled), "--backfill").exit_code == 0
    assert invoke("track", str(clip), "--tracks", str(online)).exit_code == 0
    out = tmp_path / "scores.json"
    r = invoke("eval", str(filled), str(truth), "--json", str(out))
    assert r.exit_code == 0, r.output
    assert "online (backfilled rows as tentative): Pd" in r.output
    data = json.loads(out.read_text())
    plain = invoke("eval", str(online), str(truth), "--json", str(tmp_path / "plain.json"))
    assert plain.exit_code == 0 and "online (" not in plain.output
    same = json.loads((tmp_path / "plain.json").read_text())
    assert data["online"]["pd"] == same["pd"]  # the online score is the run's without the option
    assert data["pd"] > data["online"]["pd"]
