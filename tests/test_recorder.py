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
        if chunk.entity_path == "/suppressed/noise":
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
    for path in ("/geometry/circle_confidence", "/geometry/horizon_confidence"):
        assert all(0.0 <= v <= 1.0 for v in _scalars(rrd, path).values()), path
