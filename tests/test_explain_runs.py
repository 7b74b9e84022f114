"""Where Pd went in every run of `wfviz compare` and in every trial of `wfviz tune` (issue 34):
the causes of each run's misses printed, `compare --explain` files per run, the causes summed
per trial in the study's journal, trials.csv and report.md."""

from __future__ import annotations

import csv
import functools
from pathlib import Path
from types import SimpleNamespace

import pytest

import wfviz.synth  # registers synth: clips with open_clip

from conftest import one_line_error, rows, wfviz as run_wfviz
from wfviz.compare import parse_run
from wfviz.compare.session import compare
from wfviz.evaluate import evaluate_points, read_points
from wfviz.explain.report import read_explain
from wfviz.explain.types import MISSES, Cause
from wfviz.io.clip import open_clip

CLIP = "synth:fov70-maneuver:0"
STOP = 40
CONTRACT = ["frame", "target_id", "cause", "detail", "significance", "det_dist", "track_id"]
SHORT = ["circle", "region", "not_det", "lost", "not_assoc", "latency", "not_conf"]

wfviz = functools.partial(run_wfviz, timeout=300)


def _truth(stop: int = STOP):
    shown, hidden = open_clip(CLIP).truth_points()
    return ({f: v for f, v in shown.items() if f < stop}, {f: v for f, v in hidden.items() if f < stop})


def _causes_rows(stdout: str) -> dict[str, dict[str, str]]:
    """The "where Pd went" table of `wfviz compare`: run -> {column: cell}."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("where Pd went"))
    head = lines[start + 1].split()
    assert head[:len(SHORT) + 3] == ["run", *SHORT, "matched", "dominant"], head
    out = {}
    for line in lines[start + 2:]:
        if not line.strip():
            break
        cells = line.split(maxsplit=len(SHORT) + 3)
        out[cells[0]] = dict(zip(head[:len(SHORT) + 3] + ["false"], cells))
    return out


def test_compare_prints_each_runs_causes_and_writes_its_explain_files(tmp_path: Path) -> None:
    (tmp_path / "strict.toml").write_text("[detection]\nk_sigma = 6.5\n")
    proc = wfviz("compare", CLIP, "--run", "gewc", "--run", "strict=gewc:strict.toml", "--stop", str(STOP),
                 "--no-images", "-o", "c.rrd", "--explain", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    table = _causes_rows(proc.stdout)
    assert set(table) == {"gewc", "strict"}
    shown, hidden = _truth()
    for label in ("gewc", "strict"):
        why = tmp_path / f"c-{label}-explain.csv"
        false = tmp_path / f"c-{label}-explain-false.csv"
        assert f"explain {label}: {why.name}, {false.name}" in proc.stdout
        with open(why, newline="") as fh:
            assert next(csv.reader(fh))[:len(CONTRACT)] == CONTRACT
        assert next(csv.reader(open(false, newline="")))[:3] == ["frame", "track_id", "cause"]
        summary = read_explain(why)
        row = table[label]
        # the printed counts are the file's, and its matched points are the run's matches
        for short, cause in zip(SHORT, MISSES):
            assert int(row[short]) == summary.causes.get(cause, 0), (label, short)
        assert row["dominant"] == (summary.dominant or "-")
        scores = evaluate_points(read_points(tmp_path / f"c-{label}.csv", "track_id", True), shown, 3.0, hidden)
        assert int(row["matched"]) == summary.causes.get("matched", 0) == scores.matches, label
        assert summary.visible == scores.truth_points
        assert row["false"].split()[0] == str(sum(summary.false_causes.values()))


def test_compare_summary_causes_equal_each_runs_scores() -> None:
    """Through the API, no file written: every run's explain summary next to its scores."""
    runs = [parse_run("gewc"), parse_run("fusion")]
    summary = compare(open_clip(CLIP), runs, recording=None, tracks=[None, None], truth=_truth(), stop=STOP)
    for r in summary.runs:
        assert r.scores is not None and r.explain is not None and r.explain_csv is None
        assert r.explain.causes.get("matched", 0) == r.scores.matches, r.label
        assert r.explain.missed == r.scores.misses, r.label
    none = compare(open_clip(CLIP), runs, recording=None, tracks=[None, None], stop=3)
    assert all(r.explain is None and r.scores is None for r in none.runs)


def test_compare_explain_needs_truth(tmp_path: Path) -> None:
    import numpy as np

    np.save(tmp_path / "clip.npy", np.zeros((3, 64, 64), dtype=np.uint16))
    proc = wfviz("compare", "clip.npy", "--run", "gewc", "--run", "fusion", "-o", "c.rrd", "--explain",
                 cwd=tmp_path)
    one_line_error(proc, "--explain", "needs truth")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.npy"]
    with pytest.raises(ValueError, match="needs truth"):
        compare(open_clip(str(tmp_path / "clip.npy")), [parse_run("gewc"), parse_run("fusion")], recording=None,
                tracks=[None, None], explain=[tmp_path / "a.csv", None])


def test_tune_counts_causes_per_trial_and_reports_base_against_best(tmp_path: Path) -> None:
    """A base that detects almost nothing (k_sigma 8) against one trial of a lower threshold:
    the report shows the not_detected misses the search removed."""
    (tmp_path / "space.toml").write_text("[detection]\nk_sigma = { low = 3.0, high = 8.0 }\n")
    (tmp_path / "base.toml").write_text("[detection]\nk_sigma = 8.0\n")
    proc = wfviz("tune", CLIP, "--validate", "synth:uniform-50hz:0", "--out", "st", "--space", "space.toml",
                 "--config", "base.toml", "--stop", "16", "--workers", "1", "--trials", "2", "--seed", "1",
                 cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    from wfviz.tune.study import load_journal

    trials = load_journal(tmp_path / "st" / "study.journal").get_trials(deepcopy=False)
    table = {r["trial"]: r for r in rows(tmp_path / "st" / "trials.csv")}
    for t in trials:
        causes = t.user_attrs["causes"]
        for role in ("tune", "validate"):
            c = causes[role]["causes"]
            visible = sum(c.values())
            assert set(c) == {"matched", *(m.value for m in MISSES)}
            # one clip per role: its Pd is matched / visible
            assert c["matched"] / visible == pytest.approx(t.user_attrs[role]["pd"]), (t.number, role)
            dominant = max(((n, k) for k, n in c.items() if k != "matched" and n), default=(0, ""))[1]
            assert table[str(t.number)][f"{role}_dominant_miss"] == dominant
    report = (tmp_path / "st" / "report.md").read_text()
    part = report[report.index("## Where Pd went"):]
    assert "### Tune clips" in part and "### Validation clips" in part
    assert "| cause | trial 0 (base) | trial 1 (best) | 1 (best) − 0 (base) |" in part
    assert "| **matched** |" in part and "| latency |" in part and "| dominant miss cause | not_detected |" in part
    assert part.count("Trial 1 has ") == 2 and "fewer `not_detected` misses than the base" in part


def _trial(number: int, causes: dict | None, base: bool = False) -> SimpleNamespace:
    attrs: dict = {"base": True} if base else {}
    if causes is not None:
        attrs["causes"] = {"tune": {"causes": causes, "false": {"unknown": 2 * number}, "hidden": 0}}
    return SimpleNamespace(number=number, user_attrs=attrs)


def test_report_table_shows_a_trial_without_causes_as_a_dash() -> None:
    """A study resumed from before causes were counted: its trials show "-"; the change and
    the sentence name the cause the best trial reduced."""
    from wfviz.tune.report import causes_table, reduced

    zero = {"matched": 0, **{m.value: 0 for m in MISSES}}
    base = _trial(0, zero | {"matched": 30, "latency": 6, "not_detected": 4}, base=True)
    best = _trial(3, zero | {"matched": 35, "latency": 2, "not_detected": 3})
    old = _trial(1, None)
    lines = causes_table([base, best], "tune", best)
    assert lines[0] == "| cause | trial 0 (base) | trial 3 (best) | 3 (best) − 0 (base) |"
    assert "| latency | 6 (15.0 %) | 2 (5.0 %) | -4 |" in lines
    assert "| **matched** | 30 (75.0 %) | 35 (87.5 %) | +5 |" in lines
    assert "| false-track rows | 0 | 6 | +6 |" in lines and "| false: unknown | 0 | 6 (100.0 %) | +6 |" in lines
    assert reduced(base, best, "tune").startswith("Trial 3 has 4 fewer `latency` misses than the base (6 → 2)")
    lines = causes_table([old, best], "tune", best)
    assert "| latency | - | 2 (5.0 %) |" in lines and "| dominant miss cause | - | not_detected |" in lines
    assert reduced(old, best, "tune") == ""


def test_compare_explain_file_over_an_input_is_refused(tmp_path: Path) -> None:
    """A run's explain file is an output like its tracks CSV: one that would replace the truth
    file (or collide with another output) is refused before anything is written."""
    from wfviz.tune.clips import synth_truth

    truth = tmp_path / "c-gewc-explain-false.csv"
    truth.write_text(synth_truth(CLIP, 5))
    before = truth.read_bytes()
    proc = wfviz("compare", CLIP, "--run", "gewc", "--run", "fusion", "--stop", "5", "-o", "c.rrd",
                 "--truth", truth.name, "--explain", cwd=tmp_path)
    one_line_error(proc, "c-gewc-explain-false.csv", "would overwrite the truth file")
    assert truth.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [truth.name]
    proc = wfviz("compare", CLIP, "--run", "gewc", "--run", "gewc-explain=gewc", "--stop", "5", "-o", "c.rrd",
                 "--explain", cwd=tmp_path)
    one_line_error(proc, "c-gewc-explain.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == [truth.name]


def test_tune_resumes_a_study_whose_trials_have_no_causes(tmp_path: Path) -> None:
    """A study begun before trials counted causes (its journal without the `causes` attribute)
    resumes; its old trial shows "-" in report.md and empty dominant causes in trials.csv."""
    (tmp_path / "space.toml").write_text("[detection]\nk_sigma = { low = 3.0, high = 8.0 }\n")
    (tmp_path / "base.toml").write_text("[detection]\nk_sigma = 8.0\n")
    args = ["tune", CLIP, "--out", "st", "--space", "space.toml", "--config", "base.toml", "--stop", "12",
            "--workers", "1", "--seed", "1", "--trials"]
    assert wfviz(*args, "1", cwd=tmp_path).returncode == 0
    journal = tmp_path / "st" / "study.journal"
    lines = journal.read_text().splitlines(keepends=True)
    old = [line for line in lines if '"user_attr":{"causes"' not in line]
    assert len(old) == len(lines) - 1
    journal.write_text("".join(old))
    proc = wfviz(*args, "2", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    got = {r["trial"]: r for r in rows(tmp_path / "st" / "trials.csv")}
    new = got["1"]["tune_dominant_miss"]  # whichever cause dominates the new trial, it is counted
    assert got["0"]["tune_dominant_miss"] == "" and new in {c.value for c in Cause}, new
    report = (tmp_path / "st" / "report.md").read_text()
    assert "| cause | trial 0 (base) | trial 1 (best) |\n" in report
    assert "| not_detected | - | " in report and f"| dominant miss cause | - | {new} |" in report
