"""`wfviz tune --constraint` and `--prune` through the CLI (issue 37, item 3): a constraint keeps
the trials that miss it from being chosen, a bad one is refused before anything is written, and
pruning stops a trial that is clearly worse while the study completes."""

from __future__ import annotations

import contextlib
import random
from pathlib import Path

import pytest

from conftest import invoke, rows

CLIPS = [f"synth:uniform-50hz:{i}" for i in range(6)]
# k_sigma up to 12 (40) loses the targets: a space where some values are terrible
SPACE = "[detection]\nk_sigma = {{ low = 3.0, high = {high} }}\n"


def _tune(root: Path, *args: str, high: float = 12.0) -> tuple[object, Path]:
    (root / "sp.toml").write_text(SPACE.format(high=high))
    with contextlib.chdir(root):
        r = invoke("tune", *args, "--out", "S", "--space", "sp.toml", "--workers", "1")
    return r, root / "S"


def _best(study: Path) -> int:
    """The trial number in best.toml's header."""
    head = (study / "best.toml").read_text().splitlines()[0]
    return int(head.split("trial ", 1)[1].split()[0])


def test_a_constraint_keeps_trials_that_miss_it_from_being_chosen(tmp_path: Path) -> None:
    r, study = _tune(tmp_path, *CLIPS[:2], "--stop", "10", "--trials", "8", "--constraint", "pd<=0.45")
    assert r.exit_code == 0, r.output
    trials = rows(study / "trials.csv")
    done = [t for t in trials if t["state"] == "complete"]
    for t in done:  # marked by the mean Pd over the tune clips
        assert t["feasible"] == str(int(float(t["tune_pd"]) <= 0.45)), t
    feasible = [t for t in done if t["feasible"] == "1"]
    outside = [t for t in done if t["feasible"] == "0"]
    assert feasible and outside
    best = max(feasible, key=lambda t: (float(t["tune_mota"]), -int(t["trial"])))
    assert _best(study) == int(best["trial"])
    # the constraint changed the choice: an excluded trial (the base among them) scores higher
    assert max(float(t["tune_mota"]) for t in outside) > float(best["tune_mota"])
    assert any(t["base"] == "1" for t in outside)
    assert f"{len(outside)} outside pd<=0.45: never chosen" in (study / "report.md").read_text()


@pytest.mark.parametrize("text, words", [
    ("fa_per_frame<0.1", ["use <= or >="]),
    ("fa_per_frams<=0.1", ["unknown metric", "did you mean 'fa_per_frame'"]),
    ("deta>=0.5", ["unknown metric", "pd, fa_per_frame, mota, idf1, hota, id_switches"]),
    ("fa_per_frame<=abc", ["'abc' is not a number"]),
    ("fa_per_frame<=nan", ["finite"]),
    ("fa_per_frame", ["expected METRIC<=VALUE"]),
])
def test_a_bad_constraint_is_one_line_exit_2_and_writes_nothing(tmp_path: Path, text: str,
                                                                words: list[str]) -> None:
    r, study = _tune(tmp_path, CLIPS[0], "--stop", "4", "--trials", "1", "--constraint", text)
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wfviz: error: --constraint"), r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert not study.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sp.toml"]


@pytest.mark.parametrize("args, message", [
    (["--constraint", "fa<=0.1", "--constraint", "fa_per_frame<=0.1"], "given twice"),
    (["--prune", "--objective", "pareto"], "--prune: needs one objective"),
])
def test_conflicting_constraint_or_prune_options_are_refused(tmp_path: Path, args: list[str],
                                                             message: str) -> None:
    r, study = _tune(tmp_path, CLIPS[0], "--stop", "4", "--trials", "1", *args)
    assert r.exit_code == 2 and message in r.stderr, r.output
    assert not study.exists()


def test_pruning_stops_a_clearly_worse_trial_and_the_study_completes(tmp_path: Path) -> None:
    r, study = _tune(tmp_path, *CLIPS, "--stop", "8", "--trials", "6", "--prune", "--seed", "0", high=40.0)
    assert r.exit_code == 0, r.output
    trials = rows(study / "trials.csv")
    assert len(trials) == 6 and trials[0]["state"] == "complete"  # the base runs every clip
    pruned = [t for t in trials if t["state"] == "pruned"]
    done = [t for t in trials if t["state"] == "complete"]
    assert pruned and done, [(t["state"], t["detection.k_sigma"]) for t in trials]
    labels = [c.split(":", 1)[1].replace(":", "-") for c in CLIPS]
    order = labels[:]
    random.Random(0).shuffle(order)  # the study's clip order (seeded, the same for every trial)
    best = max(done, key=lambda t: (float(t["tune_mota"]), -int(t["trial"])))
    for t in pruned:
        ran = [label for label in order if t[f"{label}_mota"] != ""]
        assert 4 <= len(ran) < len(order) and ran == order[: len(ran)], ran  # a prefix of the order
        assert t["tune_mota"] == "" and t["error"] == ""  # pruned: no score, no failure
        mine = [float(t[f"{label}_mota"]) for label in ran]
        theirs = [float(best[f"{label}_mota"]) for label in ran]
        assert all(a <= b for a, b in zip(mine, theirs)) and sum(mine) < sum(theirs)
        assert float(t["detection.k_sigma"]) > 6.0  # only terrible values are cut
    assert _best(study) == int(best["trial"])
    assert f"{len(pruned)} pruned" in (study / "report.md").read_text()
    assert f"{len(pruned)} pruned" in r.stdout


def test_a_resume_under_other_constraints_is_refused(tmp_path: Path) -> None:
    first, _ = _tune(tmp_path, CLIPS[0], "--stop", "4", "--trials", "1", "--constraint", "fa_per_frame<=0.1")
    assert first.exit_code == 0, first.output
    journal = (tmp_path / "S" / "study.journal").read_bytes()
    for other in (["--constraint", "fa_per_frame<=0.2"], []):  # another bound, or none
        r, _ = _tune(tmp_path, CLIPS[0], "--stop", "4", "--trials", "1", *other)
        assert r.exit_code == 2 and "constraints differ" in r.stderr, r.output
    assert (tmp_path / "S" / "study.journal").read_bytes() == journal
    again, _ = _tune(tmp_path, CLIPS[0], "--stop", "4", "--trials", "1", "--constraint", "fa<=0.1")
    assert again.exit_code == 0, again.output  # the same constraint (fa: fa_per_frame's short name)
