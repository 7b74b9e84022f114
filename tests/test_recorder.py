"""The recorder's fast paths log the same data as Rerun's own archetypes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

import wfviz.synth  # noqa: F401 - registers synth: clips with open_clip
from wfviz.io.clip import ClipError, open_clip
import pyarrow as pa

from wfviz.record.recorder import bar_chart_arrays, bar_chart_columns, class_ids, track_colors


def test_bar_chart_batches_equal_rerun_bar_chart():
    w = np.random.default_rng(0).random(8)
    ref = list(rr.BarChart(w, color=(12, 200, 7)).as_component_batches())
    columns = bar_chart_columns(w[None, :], np.array([(12, 200, 7)]))
    assert [c.component_descriptor() for c in columns] == [b.component_descriptor() for b in ref]
    for a, b in zip((c.component_batch for c in columns), ref):
        assert a.as_arrow_array().equals(b.as_arrow_array())


def test_bar_chart_column_rows_equal_rerun_bar_charts():
    rng = np.random.default_rng(1)
    values = rng.random((5, 8))
    colors = rng.integers(0, 256, (5, 3))
    tensor, rgba = bar_chart_arrays(values, colors)
    refs = [list(rr.BarChart(v, color=tuple(int(x) for x in c)).as_component_batches())
            for v, c in zip(values, colors)]
    assert tensor.equals(pa.concat_arrays([r[0].as_arrow_array() for r in refs]))
    assert rgba.equals(pa.concat_arrays([r[1].as_arrow_array() for r in refs]))


def test_class_ids_fit_16_bits_and_colours_are_rgba():
    ids = class_ids([1, 2, 65535, 65536, 1_000_000])
    assert ids.dtype == np.uint16 and ids.tolist()[:3] == [1, 2, 65535] and ids[3] == 1
    c = track_colors([3, 4], [True, False])
    assert c.shape == (2, 4) and c.dtype == np.uint8 and c[0, 3] == 255 and tuple(c[1]) == (150, 150, 150, 90)


def _scalars(rrd: Path, entity: str) -> dict[int, float]:
    out: dict[int, float] = {}
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            b = chunk.to_record_batch()
            for f, v in zip(b.column("frame").to_pylist(), b.column("Scalars:scalars").to_pylist()):
                out[f] = v[0]
    return out


def test_buffered_scalars_match_the_tracks_and_8_bit_previews(tmp_path):
    from wfviz.synth.demo import demo_clip
    frames = np.stack([f.image for f in demo_clip().frames(0, 70)])
    clip8 = tmp_path / "clip8.npy"
    lo, hi = np.percentile(frames[0], [0.1, 99.9])
    np.save(clip8, np.clip((frames - lo) * 255.0 / (hi - lo), 0, 255).astype(np.uint8))  # 8-bit source
    run = [sys.executable, "-m", "wfviz", "record", str(clip8)]
    for name, extra in (("raw", ["--exact-every", "1"]), ("jpeg", ["--jpeg-quality", "80"])):
        proc = subprocess.run(run + ["-o", str(tmp_path / f"{name}.rrd"), *extra], capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
    raw, jpeg = tmp_path / "raw.rrd", tmp_path / "jpeg.rrd"
    # 70 frames span more than one column flush (64 frames): every frame's count is there
    counts = _scalars(raw, "/detection/count")
    assert sorted(counts) == list(range(70))
    kinds = {(c.entity_path, n) for c in RrdReader(jpeg).stream() for n in c.to_record_batch().schema.names
             if c.entity_path in ("/camera/image", "/suppressed/image")}
    assert {("/camera/image", "EncodedImage:blob"), ("/suppressed/image", "EncodedImage:blob")} <= kinds, kinds
    assert jpeg.stat().st_size < 0.5 * raw.stat().st_size


def test_synthetic_input_is_lazy_and_checked():
    clip = open_clip("synth:lowsnr-tbd:3")
    assert clip.shape == (64, 64) and clip.n_frames == 30
    first = next(clip.frames(5, 6))
    assert first.index == 5 and first.image.shape == (64, 64)
    with pytest.raises(ClipError, match="unknown scenario 'nope'"):
        open_clip("synth:nope")
    with pytest.raises(ClipError, match="seed"):
        open_clip("synth:lowsnr-tbd:x")


def test_static_clutter_stage_is_logged(tmp_path: Path) -> None:
    """A textured 'ground' of fixed spots: the static-clutter stage marks them in the recording.

    The stage is an option (``clutter.enabled``), run here on the paper's global threshold:
    the default CFAR's tail calibration counts a frame crowded with fixed spots as heavy-tailed
    noise and detects almost none of them, leaving the stage nothing to mark."""
    rng = np.random.default_rng(3)
    spots = rng.uniform(8, 88, (14, 2))
    yy, xx = np.mgrid[0:96, 0:96]
    frames = np.full((24, 96, 96), 40.0) + rng.normal(0, 1.0, (24, 96, 96))
    for x, y in spots:
        frames += 30.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 1.5)
    clip = tmp_path / "ground.npy"
    np.save(clip, np.clip(frames, 0, 255).astype(np.uint8))
    cfg = tmp_path / "c.toml"
    cfg.write_text("[horizon]\nenabled = false\n[circle]\nenabled = false\n"
                   "[detection]\nmode = \"global\"\n"
                   "[clutter]\nenabled = true\nlag = 5\n"
                   "[tracking]\nconfirm_significance = 1.0\nconfirm_blobness = 0.3\n")
    rrd = tmp_path / "g.rrd"
    proc = subprocess.run([sys.executable, "-m", "wfviz", "record", str(clip), "--config", str(cfg),
                           "-o", str(rrd), "--no-images"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    static = _scalars(rrd, "/detection/static")
    counts = _scalars(rrd, "/detection/count")
    assert sorted(static) == list(range(24))
    assert all(static[f] == 0 for f in range(5))             # undecided before the lag
    assert all(static[f] == counts[f] >= 10 for f in range(10, 24))  # every fixed spot
    chunks = list(RrdReader(rrd).stream())
    assert any(c.entity_path == "/camera/clutter" for c in chunks)
    hover = [c.to_record_batch() for c in chunks if c.entity_path == "/camera/detections"]
    names = {n for b in hover for n in b.schema.names}
    assert {"significance", "blobness"} <= {n.split(":")[-1] for n in names}, names
    blob = [v for b in hover for n in b.schema.names if n.endswith("blobness")
            for row in b.column(n).to_pylist() if row for v in row]
    assert len(blob) >= 10 * 14 and min(blob) > 0.5  # round spots


def test_gewc_recording_logs_the_front_end_entities(tmp_path: Path) -> None:
    """Default GEWC config on a short synthetic clip: the shared front end's noise map and
    median σ, the camera motion and the sequential test's level are in the recording, each
    logged once a frame (the noise map with the images), and detections hover their change."""
    from wfviz.config import config_to_toml
    from wfviz.record_options import RecorderOptions
    from wfviz.run import run
    from wfviz.synth.scenarios import make_scenario
    from wfviz.trackers import make_tracker

    n = 10
    clip = make_scenario("uniform-50hz", seed=0, n_frames=n)
    trk = make_tracker("gewc")
    rrd = tmp_path / "g.rrd"
    run(clip, trk, recording=rrd,
        recorder_options=RecorderOptions(source="uniform-50hz", config_text=config_to_toml(trk.config), image_every=4,
                              exact_every=4))
    rows: dict[str, list[int]] = {}
    names: dict[str, set[str]] = {}
    noise_images = []
    for chunk in RrdReader(rrd).stream():
        b = chunk.to_record_batch()
        names.setdefault(chunk.entity_path, set()).update(b.schema.names)
        if not chunk.is_static and "frame" in b.schema.names:
            rows.setdefault(chunk.entity_path, []).extend(b.column("frame").to_pylist())
        if chunk.entity_path == "/suppressed/noise" and not chunk.is_static:  # static: its pixel-centre transform
            noise_images += zip(b.column("frame").to_pylist(), b.column("Image:buffer").to_pylist(),
                                b.column("Image:format").to_pylist())
    for path in ["/detection/noise_sigma", "/registration/dx", "/registration/dy",
                 "/registration/moving", "/tracks/confirm_level"]:
        assert sorted(rows.get(path, [])) == list(range(n)), path  # once a frame: no double logging
    assert sorted(rows["/suppressed/noise"]) == sorted(set(rows["/camera/image"])) == [0, 4, 8]
    sigma = _scalars(rrd, "/detection/noise_sigma")
    f16 = next(c for c in rr.Image(np.zeros((1, 1), np.float16)).as_component_batches()
               if str(c.component_descriptor()) == "Image:format").as_arrow_array().to_pylist()[0]
    h, w = clip.shape
    for frame, buf, fmt in noise_images:
        assert fmt[0]["channel_datatype"] == f16["channel_datatype"]
        assert (fmt[0]["height"], fmt[0]["width"]) == (h, w)
        img = np.frombuffer(bytes(buf[0]), dtype=np.float16).astype(np.float64)
        assert img.size == h * w and np.isfinite(img).all() and img.min() > 0
        assert np.median(img) == pytest.approx(sigma[frame], rel=0.5)
    assert all(v > 0 for v in sigma.values())
    level = _scalars(rrd, "/tracks/confirm_level")
    assert all(v > 0 for v in level.values())
    moving = _scalars(rrd, "/registration/moving")
    assert set(moving.values()) <= {0.0, 1.0}
    hover = {name.split(":")[-1] for name in names["/camera/detections"]}
    assert {"significance", "change"} <= hover, hover
    # geometry confidences, per update: the circle with the first mask, the horizon every
    # horizon.every frames (0, 10, ...: frame 0 only in 10 frames)
    assert sorted(rows["/geometry/circle_confidence"]) == [0]
    assert sorted(rows["/geometry/horizon_confidence"]) == [0]
    assert sorted(rows["/geometry/horizon_ground"]) == [0]
    for path in ("/geometry/circle_confidence", "/geometry/horizon_confidence", "/geometry/horizon_support",
                 "/geometry/horizon_separation", "/geometry/horizon_ground"):
        assert all(0.0 <= v <= 1.0 for v in _scalars(rrd, path).values()), path


# -- evidence: explanations, track tests, camera motion, defects, legend (issue 34) -------------

N_EVIDENCE = 12
HOT = [(5, 5), (10, 50), (20, 20), (40, 8), (50, 50), (58, 30), (33, 44), (12, 12)]  # (row, col)


def _evidence_clip(path: Path) -> Path:
    """64 x 64 frames of flat noise (no corners for the camera's flow), one dot moving 3 px a
    frame along row 30 and eight hot pixels (0.2 % of the frame: flagged, then replaced)."""
    rng = np.random.default_rng(0)
    frames = np.full((N_EVIDENCE, 64, 64), 1000.0) + rng.normal(0, 3, (N_EVIDENCE, 64, 64))
    for k in range(N_EVIDENCE):
        frames[k, 30:32, 10 + 3 * k:12 + 3 * k] += 300
    for r, c in HOT:
        frames[:, r, c] += 400
    np.save(path, frames.astype(np.uint16))
    return path


def _explanation(frame: int):
    """A hand-made explanation: T1 on the dot (latency, then matched, not detected on frame 8),
    T2 hidden, a false track on the first hot pixel from frame 3."""
    from wfviz.explain import Cause, FalseCause, FalseExplanation, FrameExplanation, TruthExplanation

    cause = Cause.LATENCY if frame < 6 else Cause.NOT_DETECTED if frame == 8 else Cause.MATCHED
    truth = (TruthExplanation(frame, 1, 11.5 + 3 * frame, 30.5, cause, f"detail {frame}", significance=10.0 + frame,
                              residual=10.0 + frame, change=5.0, threshold=4.0, det_dist=0.2, track_id=9),
             TruthExplanation(frame, 2, 40.0, 40.0, Cause.HIDDEN))
    false = (FalseExplanation(frame, 7, 5.0, 5.0, FalseCause.DEFECT, "on a flagged pixel"),) if frame >= 3 else ()
    return FrameExplanation(frame, truth, false)


@pytest.fixture(scope="module")
def evidence_rrd(tmp_path_factory) -> Path:
    """The evidence clip through GEWC's default configuration with a hand-made explanation
    published into each step's facts (as wfviz.explain's sink does) and recorded by a RecordingSink."""
    from wfviz.explain import FrameExplanation
    from wfviz.record_options import RecorderOptions
    from wfviz.run import SingleRun, drive
    from wfviz.sinks import BaseSink, RecordingSink, Step
    from wfviz.trackers import load_tracker

    class Explain(BaseSink):
        def publish(self, step: Step) -> None:
            step.facts.put(_explanation(step.frame.index))

    folder = tmp_path_factory.mktemp("evidence")
    clip = open_clip(_evidence_clip(folder / "clip.npy"))
    rrd = folder / "e.rrd"
    assert FrameExplanation  # the type the sink reads
    drive(clip, SingleRun(load_tracker("gewc", None)),
          [Explain(), RecordingSink(rrd, "gewc", clip, RecorderOptions(image_every=1))])
    return rrd


def _rows(rrd: Path, entity: str, column: str) -> dict[int, list]:
    """{frame: the values of ``column`` of a temporal entity's rows of that frame, in order}."""
    out: dict[int, list] = {}
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path == entity and not chunk.is_static:
            b = chunk.to_record_batch()
            if column in b.schema.names:
                for f, v in zip(b.column("frame").to_pylist(), b.column(column).to_pylist()):
                    out[f] = out.get(f, []) + (v if isinstance(v, list) else [v])
    return out


def _static(rrd: Path, entity: str, column: str) -> list:
    return [v for chunk in RrdReader(rrd).stream() if chunk.entity_path == entity and chunk.is_static
            for b in [chunk.to_record_batch()] if column in b.schema.names for v in b.column(column).to_pylist()]


def _labels(context: list) -> dict[int, str]:
    """{class id: label} of an AnnotationContext row."""
    return {c["class_id"]: c["class_description"]["info"]["label"] for c in context[0]}


def test_explanation_is_recorded_with_cause_classes(evidence_rrd: Path) -> None:
    from wfviz.explain import Cause

    causes = _labels(_static(evidence_rrd, "/camera/causes", "AnnotationContext:context")[0])
    assert len(causes) == len(Cause) and causes[1] == "matched" and causes[5] == "not detected"
    assert "latency" in causes[7] and "hidden" in causes[2]
    ids = _rows(evidence_rrd, "/camera/causes", "Points2D:class_ids")
    assert sorted(ids) == list(range(N_EVIDENCE))
    assert ids[0] == [7, 2] and ids[6] == [1, 2] and ids[8] == [5, 2]  # latency, matched, not detected; hidden
    labels = _rows(evidence_rrd, "/camera/causes", "Points2D:labels")
    assert labels[8][0] == "T1 not detected: detail 8"
    assert _rows(evidence_rrd, "/camera/causes", "detail")[8] == ["detail 8", ""]  # hover values
    misses = _rows(evidence_rrd, "/camera/misses", "Points2D:labels")
    assert misses[8] == ["T1 missed: not detected: detail 8"] and not misses.get(9)  # cleared after
    assert misses[0] == ["T1 missed: latency (its track is too young): detail 0"]
    false = _rows(evidence_rrd, "/camera/false_tracks", "Points2D:labels")
    assert false[3] == ["track 7 false track: sensor defect: on a flagged pixel"]
    assert "sensor defect" in _labels(_static(evidence_rrd, "/camera/false_tracks", "AnnotationContext:context")[0])[4]
    significance = _scalars(evidence_rrd, "/explain/T1/significance")
    assert significance == {f: 10.0 + f for f in range(N_EVIDENCE)}
    assert set(_scalars(evidence_rrd, "/explain/T1/threshold").values()) == {4.0}
    assert _static(evidence_rrd, "/explain/T1/significance", "SeriesLines:names") == [["T1 significance (σ)"]]
    legend = _rows(evidence_rrd, "/legend", "Points2D:labels") or {0: _static(evidence_rrd, "/legend", "Points2D:labels")[-1]}
    assert {"detection", "truth", "not detected", "missed (mark)"} <= set(next(iter(legend.values())))


def test_motion_lost_is_unknown_and_defects_are_counted(evidence_rrd: Path) -> None:
    """Flat noise has no corners for the flow: from frame 1 the shift is NaN (unknown, never
    0 = still), the confidence 0, one WARN line says so; the eight hot pixels, flagged on frame 4,
    are replaced from frame 5 (8 > 0.1 % of 4096 pixels: one WARN line)."""
    dx, dy = _scalars(evidence_rrd, "/registration/dx"), _scalars(evidence_rrd, "/registration/dy")
    assert sorted(dx) == sorted(dy) == list(range(N_EVIDENCE))
    assert dx[0] == 0.0 and all(np.isnan(dx[f]) and np.isnan(dy[f]) for f in range(1, N_EVIDENCE))
    confidence = _scalars(evidence_rrd, "/registration/confidence")
    assert confidence[0] == 1.0 and all(confidence[f] == 0.0 for f in range(1, N_EVIDENCE))
    assert sorted(_scalars(evidence_rrd, "/registration/corners")) == list(range(N_EVIDENCE))
    assert sorted(_scalars(evidence_rrd, "/registration/moving")) == list(range(N_EVIDENCE))
    text = _rows(evidence_rrd, "/log", "TextLog:text")
    level = _rows(evidence_rrd, "/log", "TextLog:level")
    lines = [(f, t, lv) for f in text for t, lv in zip(text[f], level[f])]
    lost = [(f, lv) for f, t, lv in lines if t.startswith("camera motion lost")]
    assert lost == [(1, "WARN")]
    count = _scalars(evidence_rrd, "/defects/count")
    assert sorted(count) == list(range(N_EVIDENCE)) and count[0] == 0 and count[N_EVIDENCE - 1] == len(HOT)
    warned = [(f, t, lv) for f, t, lv in lines if "replaced as sensor defects" in t]
    assert len(warned) == 1 and warned[0][2] == "WARN" and warned[0][1].startswith(f"{len(HOT)} pixels replaced")
    # the noise map on every exact frame (0 and 10 of 12), the search region once (it never changes)
    assert sorted(_rows(evidence_rrd, "/suppressed/noise", "Image:format")) == [0, 10]
    assert sorted(_rows(evidence_rrd, "/camera/search_region", "SegmentationImage:format")) == [0]


def test_confirmed_track_tests_are_series_against_their_levels(evidence_rrd: Path) -> None:
    """The dot's track is confirmed: each test of its rule is a series with its level, named
    after the track; tracks too young to be confirmed have none."""
    text = _rows(evidence_rrd, "/log", "TextLog:text")
    confirmed = [int(t.split()[1]) for f in text for t in text[f] if " confirmed after " in t]
    assert len(confirmed) == 1
    tid = confirmed[0]
    entities = {c.entity_path for c in RrdReader(evidence_rrd).stream()}
    tests = {e for e in entities if e.startswith(f"/tests/{tid}/")}
    assert {f"/tests/{tid}/persistence", f"/tests/{tid}/not_clutter", f"/tests/{tid}/motion_t2"} <= tests, tests
    persistence = _rows(evidence_rrd, f"/tests/{tid}/persistence", "Scalars:scalars")  # [value, level]
    assert len(persistence) >= N_EVIDENCE - 6 and all(len(v) == 2 for v in persistence.values())
    first = min(persistence)
    value, level = persistence[first + 1]
    assert value >= level > 0  # it passed the test it was confirmed by
    assert _static(evidence_rrd, f"/tests/{tid}/persistence", "SeriesLines:names") == [
        [f"track {tid}", f"track {tid} level"]]
    # besides the target, at most the eight hot pixels' tentative tracks are old enough to be
    # shown (with the clutter map a track may be confirmed in fewer hits than the motion test's 6)
    shown = {e.split("/")[2] for e in entities if e.startswith("/tests/")}
    assert str(tid) in shown and len(shown) <= 1 + 8, shown


def test_held_back_track_is_logged_once(tmp_path: Path) -> None:
    """A tentative track old enough to be confirmed, held back by the same test 25 frames in a
    row: one INFO line naming the test and its value against its level."""
    from wfviz.io.frames import Frame
    from wfviz.record.recorder import Recorder
    from wfviz.record_options import RecorderOptions
    from wfviz.stages.detection import Detections
    from wfviz.trackers.base import FrameResult
    from wfviz.tracking.decision import Decisions, Statistic, Verdicts
    from wfviz.tracking.tracks import TrackState

    none = Detections(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 4)),
                      np.zeros(0, np.int64), np.zeros((8, 8), np.int32), 1.0)
    tests = (Statistic("persistence", np.array([20.0]), 9.0, ">=", np.array([True])),
             Statistic("motion: steady progress", np.array([0.3]), 1.0, ">=", np.array([False]), unit="px"),
             Statistic("misses", np.array([0.0]), 3.0, ">=", np.array([False]), deletes=True))
    verdicts = Verdicts(np.array([7]), np.array([False]), Decisions(np.array([False]), np.array([False]), [""], tests),
                        np.array([False]), {}, "sprt", 6)
    rrd = tmp_path / "held.rrd"
    rec = Recorder(rrd, "gewc", RecorderOptions(image_every=0))
    for f in range(30):
        track = TrackState(7, 4.0, 4.0, 0.0, 0.0, False, False, 6 + f, 0)
        rec.log(Frame(f, f / 20, np.zeros((8, 8), np.uint8)),
                FrameResult(f, f / 20, (track,), (), none, (), {"total": 1.0}, verdicts))
    rec.close()
    text = _rows(rrd, "/log", "TextLog:text")
    held = [(f, t) for f in text for t in text[f] if "held back" in t]
    assert held == [(24, "track 7 held back 25 frames by motion: steady progress 0.3 px < 1")]
    assert _rows(rrd, "/log", "TextLog:level")[24] == ["INFO"]
    steady = _rows(rrd, "/tests/7/motion_steady_progress", "Scalars:scalars")
    assert sorted(steady) == list(range(30)) and set(map(tuple, steady.values())) == {(0.3, 1.0)}
    # of a tentative track, only the tests that held it back (not persistence, not the deletion test)
    assert {c.entity_path for c in RrdReader(rrd).stream() if c.entity_path.startswith("/tests/")} == {
        "/tests/7/motion_steady_progress"}


def test_default_blueprint_hides_defects_and_names_views(evidence_rrd: Path) -> None:
    """The camera view keeps the sensor defects' entity but does not show it (visible = False);
    every GEWC bar panel is titled with its track; the legend view is there."""
    reader = RrdReader(evidence_rrd)
    stores = reader.blueprints()
    titles: set[str] = set()
    assert len(stores) == 2
    for store in stores:  # the first (written at the start) and the final one
        names: dict[str, str] = {}
        hidden: dict[str, list] = {}
        for chunk in reader.stream(store=store):
            b = chunk.to_record_batch()
            if "ViewBlueprint:display_name" in b.schema.names:
                names[chunk.entity_path] = b.column("ViewBlueprint:display_name").to_pylist()[0][0]
            if "EntityBehavior:visible" in b.schema.names:
                hidden[chunk.entity_path] = b.column("EntityBehavior:visible").to_pylist()
        camera = next(path for path, name in names.items() if name == "Camera + overlays")
        assert hidden == {f"{camera}/ViewContents/overrides/camera/bad_pixels/visualizers": [[False]]}, hidden
        assert "Legend" in names.values()
        titles |= set(names.values())
    text = _rows(evidence_rrd, "/log", "TextLog:text")
    tid = next(int(t.split()[1]) for f in text for t in text[f] if " confirmed after " in t)
    assert {f"GEWC weights, track {tid}", "Test: persistence", "Camera motion", "Truth T1 (σ)"} <= titles, titles


def _effective(path: Path, entity: str) -> dict[int, dict[str, object]]:
    """{frame: {component: value}} of ``entity``, its static components filling what a frame lacks."""
    static: dict[str, object] = {}
    rows: dict[int, dict[str, object]] = {}
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if ":" in n]
        if chunk.is_static:
            static.update({n: batch.column(n).to_pylist()[-1] for n in names})
            continue
        for i, f in enumerate(batch.column("frame").to_pylist()):
            row = rows.setdefault(f, {})
            row.update({n: v for n in names if (v := batch.column(n).to_pylist()[i]) is not None})
    return {f: {**static, **row} for f, row in rows.items()}


def test_instance_columns_equal_per_frame_archetypes(tmp_path: Path) -> None:
    """Overlays held and sent as columns (``ColumnBuffer.instances``, constant components static
    once) read back frame by frame as the archetypes logged each frame would: positions, labels,
    strips, hover values, and empty frames that clear the last one's instances."""
    from wfviz.record.recorder import ColumnBuffer

    rng = np.random.default_rng(4)
    counts = [3, 0, 5, 1, 0, 0, 7] * 3  # 21 frames: two flushes of 8 and a partial one
    frames = [(rng.random((n, 2)).astype(np.float32) * 100, [f"p{k}" for k in range(n)],
               [rng.random((k + 2, 2)).astype(np.float32) for k in range(n)], rng.random(n)) for n in counts]
    want, got = rr.RecordingStream("want"), rr.RecordingStream("got")
    want.save(tmp_path / "want.rrd")
    got.save(tmp_path / "got.rrd")
    cols = ColumnBuffer(got, instance_frames=8)
    got.log("points", rr.Points2D.from_fields(colors=(255, 0, 0), draw_order=3.0, show_labels=False), static=True)
    for f, (xy, labels, strips, value) in enumerate(frames):
        want.set_time("frame", sequence=f)
        want.set_time("time", duration=f * 0.05)
        want.log("points", rr.Points2D(xy, labels=labels, colors=(255, 0, 0), draw_order=3.0, show_labels=False),
                 *([rr.AnyValues(value=value)] if len(xy) else []))
        want.log("strips", rr.LineStrips2D(strips, class_ids=np.arange(len(strips), dtype=np.uint16)))
        cols.instances("points", f, f * 0.05, rr.Points2D, len(xy), positions=xy, labels=labels)
        if len(xy):
            cols.instances("points", f, f * 0.05, rr.AnyValues, len(xy), value=value)
        cols.instances("strips", f, f * 0.05, rr.LineStrips2D, len(strips), strips=strips,
                       class_ids=np.arange(len(strips), dtype=np.uint16))
        cols.end_frame()
    cols.flush()
    want.disconnect()
    got.disconnect()
    for entity in ("/points", "/strips"):
        a, b = _effective(tmp_path / "want.rrd", entity), _effective(tmp_path / "got.rrd", entity)
        assert sorted(a) == list(range(len(counts))) and a == b, entity
    assert _effective(tmp_path / "got.rrd", "/points")[1]["Points2D:positions"] == []  # an empty frame
