"""`wfviz compare`: several runs over one clip in one recording, their disagreements marked."""

from __future__ import annotations

import functools
import re
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from scipy.optimize import linear_sum_assignment

import wfviz.synth  # registers synth: clips with open_clip
from conftest import needs_vulkan, wfviz as run_wfviz
from wfviz.compare import Disagreements, parse_run
from wfviz.compare.session import compare
from wfviz.compare.differences import clusters
from wfviz.compare.parameters import flatten
from wfviz.config import load_config
from wfviz.evaluate import read_points
from wfviz.io.clip import open_clip
from wfviz.trackers import config_class

CLIP = "synth:fov70-four-targets:0"
STOP = "70"
REQUIRED = ("camera/detections", "camera/predictions", "camera/gates", "camera/tracks", "camera/truth",
            "timing/total", "config", "eval/cle", "eval/summary", "log")


wfviz = functools.partial(run_wfviz, timeout=600)


def _rows(path: Path) -> dict[str, list[tuple[int, object]]]:
    """entity -> [(frame, row of the first non-index column)] of every temporal chunk."""
    out: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        b = chunk.to_record_batch()
        if chunk.is_static or "frame" not in b.schema.names:
            out.setdefault(chunk.entity_path, [])
            continue
        data = [n for n in b.schema.names if ":" in n and not n.startswith("frame") and n not in ("time", "log_time", "log_tick")]
        col = next((n for n in data if n.endswith("positions") or n.endswith("scalars") or n.endswith("text")), None)
        frames = b.column("frame").to_pylist()
        values = b.column(col).to_pylist() if col else [None] * len(frames)
        out[chunk.entity_path] += list(zip(frames, values))
    return out


def _pairs(tracks: dict, truth: dict, gate: float = 3.0) -> dict[int, dict[int, int]]:
    """Per frame, {track: target} of a run's confirmed tracks (own assignment, for the test)."""
    out: dict[int, dict[int, int]] = {}
    for f, gt in truth.items():
        tr = tracks.get(f, [])
        if not gt or not tr:
            out[f] = {}
            continue
        d = np.hypot(*(np.array([p[1:] for p in gt])[:, None, :] - np.array([p[1:] for p in tr])[None]).transpose(2, 0, 1))
        r, c = linear_sum_assignment(np.where(d <= gate, d, 1e9))
        out[f] = {tr[j][0]: gt[i][0] for i, j in zip(r, c) if d[i, j] <= gate}
    return out


def _matched(tracks: dict, truth: dict, gate: float = 3.0) -> dict[int, set[int]]:
    """Per frame, the targets a run's confirmed tracks match (own assignment, for the test)."""
    return {f: set(m.values()) for f, m in _pairs(tracks, truth, gate).items()}


def _column(path: Path, entity: str, column: str) -> dict[int, list]:
    """frame -> the values of ``column`` (e.g. ``LineStrips2D:colors``) logged at ``entity``."""
    out: dict[int, list] = {}
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            for row in chunk.to_record_batch().to_pylist():
                out[row["frame"]] = row[column]
    return out


def _rgba(color: tuple[int, int, int]) -> int:
    """A colour as Rerun stores it (0xRRGGBBAA, opaque)."""
    r, g, b = color
    return r << 24 | g << 16 | b << 8 | 255


def _text(path: Path, entity: str) -> str:
    """The text of the static ``TextDocument`` at ``entity``."""
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity and chunk.is_static:
            return chunk.to_record_batch().column("TextDocument:text").to_pylist()[0][0]
    raise AssertionError(f"no {entity}")


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("compare")
    (d / "strict.toml").write_text("[detection]\nk_sigma = 6.5\n")
    proc = wfviz("compare", CLIP, "--run", "gewc", "--run", "strict=gewc:strict.toml", "--stop", STOP,
                 "-o", "out/cmp.rrd", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert "truth: the synthetic clip's own" in proc.stdout
    assert "gewc " in proc.stdout and "strict " in proc.stdout and "MOTA" in proc.stdout
    assert "where Pd went" in proc.stdout and "explain" not in proc.stdout  # files only with --explain
    assert re.search(r"^ +detection\.k_sigma +4\.0 +6\.5$", proc.stdout, re.M), proc.stdout
    return d


def test_two_runs_each_under_its_root_with_the_raw_frame_once(two_runs: Path) -> None:
    rows = _rows(two_runs / "out" / "cmp.rrd")
    for label in ("gewc", "strict"):
        for e in REQUIRED:
            assert f"/runs/{label}/{e}" in rows, (label, e)
        assert f"/runs/{label}/camera/image" not in rows  # the raw frame is shared
        for m in ("pd", "false_tracks", "cle", "tracks", "ms"):
            assert len(rows[f"/compare/metrics/{m}/{label}"]) == int(STOP), m
    assert {f for f, _ in rows["/camera/image"]} == set(range(int(STOP)))  # an image (exact or a preview) per frame
    # the second run shares the first's front end: its residual is the first's
    assert "/runs/gewc/suppressed/image" in rows and "/runs/strict/suppressed/image" not in rows
    assert "/compare/summary" in rows


def test_tracks_csvs_equal_single_runs(two_runs: Path) -> None:
    """Sharing the front end changes nothing: each CSV equals `wfviz track` of that config."""
    for label, extra in (("gewc", []), ("strict", ["--config", "strict.toml"])):
        proc = wfviz("track", CLIP, "--stop", STOP, "--tracks", f"{label}.csv", *extra, cwd=two_runs)
        assert proc.returncode == 0, proc.stderr
        assert (two_runs / f"{label}.csv").read_bytes() == (two_runs / "out" / f"cmp-{label}.csv").read_bytes()


def test_missed_marks_where_the_runs_match_different_targets(two_runs: Path) -> None:
    """compare/marks/missed has points exactly on the frames where the two runs' matched
    targets differ, computed here from the CSVs and the truth; each stretch starts with a
    log line naming the run that missed."""
    clip = open_clip(CLIP)
    shown, _ = clip.truth_points()
    shown = {f: v for f, v in shown.items() if f < int(STOP)}
    a = _matched(read_points(two_runs / "out" / "cmp-gewc.csv", "track_id", True), shown)
    b = _matched(read_points(two_runs / "out" / "cmp-strict.csv", "track_id", True), shown)
    expect = sorted(f for f in shown if a[f] != b[f])
    assert expect, "the two configurations never disagree: the test has nothing to check"
    rows = _rows(two_runs / "out" / "cmp.rrd")
    marked = sorted(f for f, pts in rows["/compare/marks/missed"] if pts)
    assert marked == expect
    onsets = [f for f in expect if f - 1 not in expect]
    log = rows["/compare/log"]
    assert {f for f, _ in log} >= set(onsets)
    text = " ".join(str(t) for _, t in log)
    assert "missed by" in text and ("strict" in text or "gewc" in text)


def test_tracks_coloured_by_the_target_they_match(two_runs: Path) -> None:
    """With truth, a confirmed track matched to a target is drawn in that target's colour in
    every run, whatever its id there; a track that has matched no target yet has a colour no
    target has."""
    from wfviz.record.colors import target_color

    shown, _ = open_clip(CLIP).truth_points()
    shown = {f: v for f, v in shown.items() if f < int(STOP)}
    targets = {tid for pts in shown.values() for tid, _, _ in pts}
    palette = {_rgba(target_color(t)) for t in targets}
    rrd = two_runs / "out" / "cmp.rrd"
    seen: dict[str, dict[int, set[int]]] = {}  # run -> target -> the track ids drawn in its colour
    for label in ("gewc", "strict"):
        pairs = _pairs(read_points(two_runs / "out" / f"cmp-{label}.csv", "track_id", True), shown)
        ids = _column(rrd, f"/runs/{label}/camera/tracks", "LineStrips2D:class_ids")
        colors = _column(rrd, f"/runs/{label}/camera/tracks", "LineStrips2D:colors")
        ever: set[int] = set()
        seen[label] = defaultdict(set)
        for f in sorted(shown):
            ever |= set(pairs[f])
            for tid, color in zip(ids[f], colors[f]):
                if tid in pairs[f]:
                    assert color == _rgba(target_color(pairs[f][tid])), (label, f, tid)
                    seen[label][pairs[f][tid]].add(tid)
                elif tid not in ever:
                    assert color not in palette, (label, f, tid)
    both = set(seen["gewc"]) & set(seen["strict"])
    assert len(both) >= 2, seen
    # the point of it: some target is another track in each run, yet has one colour
    assert any(seen["gewc"][t] != seen["strict"][t] for t in both), seen


def test_misses_drawn_over_the_defects_and_larger(two_runs: Path) -> None:
    """The missed marks are larger than the other marks and than the sensor defects' dots, drawn
    over both, in a colour apart from the defects'."""
    rrd = two_runs / "out" / "cmp.rrd"

    def first(entity: str, column: str) -> float:
        return next(v[0] for v in _column(rrd, entity, column).values() if v)

    bad = "/runs/gewc/camera/bad_pixels"
    assert any(_column(rrd, bad, "Points2D:positions").values()), "no defect flagged: nothing to check"
    miss_r, miss_order = first("/compare/marks/missed", "Points2D:radii"), first("/compare/marks/missed",
                                                                                 "Points2D:draw_order")
    assert miss_r >= 3 * first(bad, "Points2D:radii") and miss_order > first(bad, "Points2D:draw_order")
    for other in ("false_track", "switch"):
        assert miss_r > first(f"/compare/marks/{other}", "Points2D:radii")
        assert miss_order > first(f"/compare/marks/{other}", "Points2D:draw_order")
    rgb = [np.array([(c >> s) & 255 for s in (24, 16, 8)])
           for c in (first("/compare/marks/missed", "Points2D:colors"), first(bad, "Points2D:colors"))]
    assert np.abs(rgb[0] - rgb[1]).sum() > 100, rgb
    # each run's camera view keeps its defects' entity but hides it (a tick shows it)
    reader = RrdReader(rrd)
    names: dict[str, str] = {}
    hidden: dict[str, list] = {}
    for chunk in reader.stream(store=reader.blueprints()[0]):
        b = chunk.to_record_batch()
        if "ViewBlueprint:display_name" in b.schema.names:
            names[chunk.entity_path] = b.column("ViewBlueprint:display_name").to_pylist()[0][0]
        if "EntityBehavior:visible" in b.schema.names:
            hidden[chunk.entity_path] = b.column("EntityBehavior:visible").to_pylist()
    views = {name: path for path, name in names.items()}
    assert hidden == {f"{views[label]}/ViewContents/overrides/runs/{label}/camera/bad_pixels/visualizers": [[False]]
                      for label in ("gewc", "strict")}, hidden


def test_parameters_that_differ_in_the_summary_and_the_recording(tmp_path: Path) -> None:
    """Two configurations of one tracker differing in tracking.p_detect, and a run of another
    tracker: the summary and the recording list p_detect with both values, and nothing else;
    the other tracker's parameters are not compared."""
    (tmp_path / "a.toml").write_text("[tracking]\np_detect = 0.7\n")
    (tmp_path / "b.toml").write_text("[tracking]\np_detect = 0.95\n")
    proc = wfviz("compare", "synth:fov70-four-targets:0", "--run", "a=gewc:a.toml", "--run", "b=gewc:b.toml",
                 "--run", "fusion", "--stop", "12", "--no-images", "-o", "c.rrd", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "parameters that differ between the gewc runs:" in out, out
    block = out.split("parameters that differ between the gewc runs:")[1].split("\n\n")[0].splitlines()
    assert block[1].split() == ["parameter", "a", "b"]
    assert [line.split() for line in block[2:] if not line.startswith("different")] == [
        ["tracking.p_detect", "0.7", "0.95"]], block
    assert "different trackers, parameters not compared: fusion (fusion)" in out
    doc = _text(tmp_path / "c.rrd", "/compare/parameters")
    assert "| `tracking.p_detect` | `0.7` | `0.95` |" in doc, doc
    assert sum(line.startswith("| `") for line in doc.splitlines()) == 1, doc
    assert "**fusion**" in doc
    scores = _text(tmp_path / "c.rrd", "/compare/summary")
    assert re.search(r"tracking\.p_detect +0\.7 +0\.95", scores), scores


def test_disagreements_without_truth() -> None:
    d = Disagreements(["a", "b"], gate=3.0)
    same = d.update(0, [[(1, 10.0, 10.0)], [(7, 11.0, 10.0)]])
    assert same.marks == ()
    one = d.update(1, [[(1, 10.0, 10.0), (2, 50.0, 50.0)], [(7, 11.0, 10.0)]])
    assert [m.kind for m in one.marks] == ["unmatched"] and one.marks[0].runs == ("a",)
    assert one.began == one.marks and "not in b" in one.marks[0].text
    again = d.update(2, [[(1, 10.0, 10.0), (2, 50.0, 50.0)], [(7, 11.0, 10.0)]])
    assert again.began == () and len(again.marks) == 1  # it goes on: no new line
    done = d.update(3, [[(1, 10.0, 10.0)], [(7, 11.0, 10.0)]])
    assert done.marks == () and len(done.ended) == 1


def test_disagreements_with_truth_switch_and_false_track() -> None:
    d = Disagreements(["a", "b"], gate=3.0)
    truth = [(5, 100.0, 100.0)]
    d.update(0, [[(1, 100.0, 100.0)], [(3, 100.5, 100.0)]], truth)
    c = d.update(1, [[(2, 100.0, 100.0), (9, 20.0, 20.0)], [(3, 100.5, 100.0), (4, 20.5, 20.0)]], truth)
    kinds = sorted(m.kind for m in c.marks)
    assert kinds == ["switch"], c.marks  # the false tracks agree (within the gate)
    assert "track 1 -> 2" in c.marks[0].text
    c = d.update(2, [[(2, 100.0, 100.0), (9, 20.0, 20.0)], [(4, 60.0, 60.0)]], truth)
    assert sorted(m.kind for m in c.marks) == ["false_track", "false_track", "missed"]
    assert {m.text for m in c.marks if m.kind == "false_track"} == {
        "false track only in a 9, not in b", "false track only in b 4, not in a"}
    missed = next(m for m in c.marks if m.kind == "missed")
    assert missed.runs == ("b",) and "T5 missed by b (matched by a)" == missed.text
    assert c.runs[0].pd == 1.0 and c.runs[1].pd == 0.0 and c.runs[1].false_tracks == 1


def test_clusters_take_one_point_per_run() -> None:
    groups = clusters([[(1, 0.0, 0.0), (2, 1.0, 0.0)], [(3, 0.5, 0.0)]], gate=3.0)
    assert sorted(len(g) for g in groups) == [1, 2]
    assert all(len({r for r, _ in g}) == len(g) for g in groups)


def test_compare_api_keeps_nothing_on_error(tmp_path: Path) -> None:
    """A run failing mid-clip: no recording, no CSV, not even a temporary one."""
    class Boom(Exception):
        pass

    clip = open_clip("synth:lowsnr-tbd:0")
    runs = [parse_run("tbd"), parse_run("b=tbd")]

    def fail(n: int) -> None:
        if n == 3:
            raise Boom()

    with pytest.raises(Boom):
        compare(clip, runs, recording=tmp_path / "c.rrd", tracks=[tmp_path / "a.csv", tmp_path / "b.csv"],
                on_frame=fail)
    assert list(tmp_path.iterdir()) == []


def test_compare_without_truth_marks_unmatched_tracks(tmp_path: Path) -> None:
    frames = np.stack([f.image for f in open_clip("synth:fov70-four-targets:1").frames(0, 50)])
    np.save(tmp_path / "clip.npy", frames)
    proc = wfviz("compare", "clip.npy", "--run", "gewc", "--run", "fusion", "-o", "c.rrd", "--image-every", "10",
                 cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "MOTA" not in proc.stdout and "where Pd went" not in proc.stdout
    assert "frames with a disagreement" in proc.stdout
    rows = _rows(tmp_path / "c.rrd")
    assert len(rows["/camera/image"]) == 5
    assert "/compare/metrics/pd/gewc" not in rows and len(rows["/compare/metrics/tracks/fusion"]) == 50
    # fusion and gewc confirm at different frames: somewhere one has a track the other lacks
    assert any(pts for _, pts in rows["/compare/marks/unmatched"])
    assert (tmp_path / "c-gewc.csv").is_file() and (tmp_path / "c-fusion.csv").is_file()


@pytest.mark.parametrize("args, message", [
    (["--run", "nope", "--run", "gewc"], "unknown tracker 'nope'"),
    (["--run", "gewc:missing.toml", "--run", "gewc"], "missing.toml: no such config file"),
    (["--run", "gewc", "--run", "gewc"], "label 'gewc' given twice"),
    (["--run", "gewc"], "at least two runs"),
    (["--run", "a b=gewc", "--run", "gewc"], "label 'a b' must be"),
    (["--run", "gewc:", "--run", "tbd"], "no config file after ':'"),
    (["--study", "nowhere", "--run", "gewc"], "--study nowhere: no such folder"),
])
def test_bad_specs_are_one_line_errors(tmp_path: Path, args: list[str], message: str) -> None:
    proc = wfviz("compare", "synth:lowsnr-tbd:0", *args, "-o", "c.rrd", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not any(tmp_path.iterdir())


def test_study_top_trials_and_defaults(tmp_path: Path) -> None:
    proc = wfviz("tune", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--trials", "3", "--workers", "1",
                 "--out", "study", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = wfviz("compare", "synth:lowsnr-tbd:0", "--study", "study", "--top", "2", "-o", "c.rrd", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    # the trials' parameters against the defaults (the study samples them: they differ)
    head = re.search(r"^parameters that differ between the tbd runs:\n +parameter +(trial-\d+) +(trial-\d+) +defaults$",
                     proc.stdout, re.M)
    assert head, proc.stdout
    rows = {}
    for line in proc.stdout[head.end():].split("\n\n")[0].strip("\n").splitlines():
        key, *values = line.split()
        rows[key] = values
    best = flatten(load_config(tmp_path / "study" / "best.toml", config_class("tbd")))  # the first trial shown
    defaults = flatten(config_class("tbd")())
    assert rows and all(best[k] == v[0] and defaults[k] == v[2] for k, v in rows.items()), rows
    assert {k for k in best if best[k] != defaults[k]} <= set(rows)
    rows = _rows(tmp_path / "c.rrd")
    roots = {p.split("/")[2] for p in rows if p.startswith("/runs/")}
    assert "defaults" in roots and len(roots) == 3 and all(r == "defaults" or r.startswith("trial-") for r in roots)



@needs_vulkan
def test_screenshot_shows_both_runs_and_a_shared_plot(two_runs: Path) -> None:
    """The default blueprint in the real viewer: both runs' camera frames side by side above,
    and a metric plot below with a series in each run's colour."""
    from PIL import Image

    from wfviz.record.compare import run_color
    from wfviz.record.screenshot import render_screenshot

    png = render_screenshot(two_runs / "out" / "cmp.rrd", two_runs / "shot.png", frame=60, width=1400,
                            height=900, timeout=180)
    rgb = np.asarray(Image.open(png).convert("RGB")).astype(np.int32)
    h, w, _ = rgb.shape
    grey = rgb.mean(axis=2)
    for x0, x1 in ((0.02, 0.48), (0.52, 0.98)):  # each run's view: the fisheye frame, many grey levels
        view = grey[int(0.08 * h): int(0.55 * h), int(x0 * w): int(x1 * w)]
        assert view.std() > 20 and len(np.unique(view.astype(int))) > 60, (x0, view.std())
    plots = rgb[int(0.62 * h):, :]
    for i in range(2):
        near = np.abs(plots - np.array(run_color(i))).sum(axis=2) < 40
        assert near.sum() > 30, f"no series in run {i}'s colour in the plots"


def test_the_first_targets_have_colours_far_apart():
    """Golden-ratio hue steps: the first six targets' hues at least 0.09 of the circle apart
    (one step of 7 ids, as before, put targets 1 and 4 on the same yellow)."""
    import colorsys

    from wfviz.record.colors import target_color, track_color

    hues = [colorsys.rgb_to_hsv(*(c / 255 for c in target_color(t)))[0] for t in range(1, 7)]
    gaps = [min(abs(a - b), 1 - abs(a - b)) for i, a in enumerate(hues) for b in hues[i + 1:]]
    assert min(gaps) >= 0.09, gaps
    assert all(target_color(t) != track_color(t) for t in range(1, 7))
