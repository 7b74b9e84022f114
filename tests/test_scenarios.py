"""Tests for the scenario library (wfviz.synth.scenarios): geometry, truth, noise, output."""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from wfviz.io.frames import Clip
from wfviz.synth.camera import FisheyeCamera, az_el_to_dirs
from wfviz.synth.psf import add_gaussian_spot
from wfviz.synth.scenarios import (ScenarioClip, TruthRow, list_scenarios, make_scenario,
                                   write_scenario)

NAMES = ["fov70-maneuver", "fov70-four-targets", "fov180-city-aircraft", "fov180-launches",
         "starfield", "lowsnr-tbd", "uniform-50hz", "long-1024"]
_CACHE: dict[tuple, ScenarioClip] = {}


def _clip(name: str, **kw) -> ScenarioClip:
    key = (name, tuple(sorted(kw.items())))
    if key not in _CACHE:
        _CACHE[key] = make_scenario(name, **kw)
    return _CACHE[key]


def _by_frame(rows: list[TruthRow]) -> dict[int, list[TruthRow]]:
    out: dict[int, list[TruthRow]] = {}
    for r in rows:
        out.setdefault(r.frame, []).append(r)
    return out


def _truth_frames(clip: ScenarioClip, frames: list[int]) -> dict[int, list[TruthRow]]:
    rows = [r for r in clip.truth() if r.frame in set(frames)] if clip.n_frames < 1000 else \
        [r for f in frames for r in clip.truth_at(f)]
    return _by_frame(rows)


def test_list_and_unknown_name() -> None:
    infos = list_scenarios()
    assert [i.name for i in infos] == NAMES
    assert all(i.description and i.n_targets >= 1 and i.n_frames >= 30 for i in infos)
    with pytest.raises(ValueError, match=r"unknown scenario 'nope' \(available: fov70-maneuver, "):
        make_scenario("nope")


def test_camera_round_trip_and_models() -> None:
    cam = FisheyeCamera.circular(640, 512, 0.0, 25.0)
    assert cam.f_px == pytest.approx(cam.radius / (math.pi / 2))
    d = az_el_to_dirs(np.array([10.0, -60.0, 170.0, 0.0]), np.array([30.0, 5.0, 80.0, 0.0]))
    x, y, vis = cam.project(d)
    assert vis.all()
    assert np.allclose(cam.pixel_to_dir(x, y), d, atol=1e-12)
    assert np.hypot(x - cam.cx, y - cam.cy)[3] == pytest.approx(cam.f_px * math.radians(25.0))
    hz = cam.horizon()
    assert np.allclose(cam.pixel_to_dir(hz[:, 0], hz[:, 1])[:, 2], 0.0, atol=1e-9)
    assert FisheyeCamera.filling(640, 512, 70.0, 0.0, 20.0).circle is None


@pytest.mark.parametrize("name", NAMES)
def test_protocol_and_format(name: str) -> None:
    clip = _clip(name)
    info = clip.info
    assert isinstance(clip, Clip)
    assert clip.shape == (info.height, info.width) and clip.n_frames == info.n_frames
    frame = next(clip.frames(3, 4))
    assert frame.index == 3 and frame.time == pytest.approx(3 / clip.fps)
    assert frame.image.dtype == np.uint16 and frame.image.shape == clip.shape


@pytest.mark.parametrize("name", NAMES)
def test_truth_lies_on_rendered_spots(name: str) -> None:
    """Noise-free: spot centroid == truth (0.05 px); noisy: smoothed peak within 1 px."""
    clip = _clip(name, snr=8.0) if name == "lowsnr-tbd" else _clip(name)
    frames = list(np.linspace(0, min(clip.n_frames, 3000) - 1, 7).astype(int))
    truth = _truth_frames(clip, frames)
    dead = np.array(clip.meta()["dead_pixels"]).reshape(-1, 2)
    rows, cols = np.indices(clip.shape)
    checked = 0
    for f in frames:
        here = truth.get(f, [])
        bg = clip.background(f).astype(np.float64)
        clean = clip.render(f, noise=False) - bg
        noisy = cv2.GaussianBlur((clip.render(f) - bg).astype(np.float32), (0, 0), 1.0)
        for r in here:
            if not r.visible:
                continue
            half = 14 if name == "fov180-city-aircraft" else 6
            near = [o for o in here if o is not r and o.visible
                    and math.hypot(o.x - r.x, o.y - r.y) < 2 * half + 4]
            if (near or min(r.x, r.y) < half or r.x > clip.shape[1] - 1 - half
                    or r.y > clip.shape[0] - 1 - half
                    or (len(dead) and np.hypot(*(dead - (r.x, r.y)).T).min() < half + 2)):
                continue
            win = (abs(rows - r.y) <= half) & (abs(cols - r.x) <= half)
            w = clean[win]
            assert (w * cols[win]).sum() / w.sum() == pytest.approx(r.x, abs=0.05)
            assert (w * rows[win]).sum() / w.sum() == pytest.approx(r.y, abs=0.05)
            x0, y0 = round(r.x), round(r.y)
            patch = noisy[y0 - 3:y0 + 4, x0 - 3:x0 + 4]
            py, px = np.unravel_index(np.argmax(patch), patch.shape)
            assert math.hypot(x0 - 3 + px - r.x, y0 - 3 + py - r.y) <= 1.0
            checked += 1
    assert checked >= 5


def test_deterministic_per_seed_and_start() -> None:
    a = make_scenario("fov70-four-targets", seed=3, n_frames=8)
    b = make_scenario("fov70-four-targets", seed=3, n_frames=8)
    c = make_scenario("fov70-four-targets", seed=4, n_frames=8)
    fa = [f.image for f in a.frames()]
    assert all(np.array_equal(x, f.image) for x, f in zip(fa, b.frames(), strict=True))
    assert a.truth() == b.truth() and a.truth() == c.truth()
    assert np.array_equal(next(a.frames(start=5)).image, fa[5])
    assert not np.array_equal(fa[0], next(c.frames()).image)
    assert not np.array_equal(a.static_background, c.static_background)
    s1 = make_scenario("starfield", seed=1, n_frames=4)
    s2 = make_scenario("starfield", seed=2, n_frames=4)
    assert s1.meta()["jitter"] != s2.meta()["jitter"]


def _fit_peak(residual: np.ndarray, r: TruthRow, sigma: float) -> float:
    """Least-squares amplitude of a unit-peak pixel-integrated Gaussian at the truth."""
    t = np.zeros(residual.shape)
    add_gaussian_spot(t, r.x, r.y, 1.0, sigma)
    return float((residual * t).sum() / (t * t).sum())


def _local_sigma(residual: np.ndarray, r: TruthRow) -> float:
    x0, y0 = round(r.x), round(r.y)
    box = residual[max(y0 - 20, 0):y0 + 21, max(x0 - 20, 0):x0 + 21].copy()
    cy, cx = y0 - max(y0 - 20, 0), x0 - max(x0 - 20, 0)
    box[max(cy - 5, 0):cy + 6, max(cx - 5, 0):cx + 6] = np.nan
    return float(np.nanstd(box))


@pytest.mark.parametrize(("name", "snr"), [("fov70-maneuver", 11.0), ("fov70-maneuver", 6.0),
                                           ("lowsnr-tbd", 4.0), ("lowsnr-tbd", 2.0)])
def test_snr_sets_measured_peak(name: str, snr: float) -> None:
    clip = make_scenario(name, seed=5, snr=snr)
    sigma0 = clip.meta()["targets"][0]["sigma0"]
    frames = [60, 61, 62] if name == "fov70-maneuver" else list(range(clip.n_frames))
    ratios = []
    for f, rows in _truth_frames(clip, frames).items():
        residual = clip.render(f).astype(np.float64) - clip.background(f)
        for r in rows:
            if r.visible:
                assert r.peak_snr == pytest.approx(snr)
                ratios.append(_fit_peak(residual, r, sigma0) / _local_sigma(residual, r))
    assert np.mean(ratios) == pytest.approx(snr, rel=0.2)
    if name == "fov70-maneuver":  # one frame alone
        assert ratios[0] == pytest.approx(snr, rel=0.2)


@pytest.mark.parametrize("name", ["fov180-city-aircraft", "fov180-launches", "long-1024"])
def test_fisheye_180_dark_corners_and_horizon(name: str) -> None:
    clip, dark = _clip(name), 800.0
    meta, bg = clip.meta(), clip.static_background
    for patch in (bg[:6, :6], bg[:6, -6:], bg[-6:, :6], bg[-6:, -6:]):
        assert np.median(patch) < dark + 30
    assert np.median(bg[bg.shape[0] // 2 - 5:bg.shape[0] // 2 + 5]) > dark + 3000
    circle = meta["imaging_circle"]
    assert circle is not None and circle["radius"] < min(clip.shape) / 2
    hz = np.array(meta["horizon"])
    assert len(hz) > 50
    dist = np.hypot(hz[:, 0] - circle["cx"], hz[:, 1] - circle["cy"])
    assert dist.max() <= circle["radius"] + 0.01
    assert meta["camera"]["f_px"] == pytest.approx(circle["radius"] / (math.pi / 2))


@pytest.mark.parametrize("name", ["fov70-maneuver", "fov70-four-targets"])
def test_fov70_fills_frame(name: str) -> None:
    clip = _clip(name)
    bg, meta = clip.static_background, clip.meta()
    assert meta["imaging_circle"] is None and meta["camera"]["fov_deg"] == 70.0
    for patch in (bg[:6, :6], bg[:6, -6:], bg[-6:, :6], bg[-6:, -6:]):
        assert np.median(patch) > 3000
    assert meta["horizon"] is not None


def test_visible_targets_stay_inside_and_above_horizon() -> None:
    for name in ["fov70-maneuver", "fov70-four-targets", "fov180-city-aircraft", "uniform-50hz"]:
        assert all(r.visible for r in _clip(name).truth()), name
    launch = _clip("fov180-launches").truth()
    assert {r.frame for r in launch if r.target_id == 2} == set(range(70, 160))
    assert all(r.visible for r in launch if r.frame >= 80)


def test_starfield_jitter_matches_star_shift() -> None:
    clip = _clip("starfield")
    jitter = np.array(clip.meta()["jitter"])
    assert jitter.shape == (clip.n_frames, 2) and np.abs(jitter).max() <= 3.0
    assert len(clip.meta()["stars"]) >= 300
    win = cv2.createHanningWindow(clip.shape[::-1], cv2.CV_64F)
    imgs = {k: clip.render(k).astype(np.float64) - clip.static_background for k in (0, 1, 2, 7)}
    for a, b in [(0, 1), (1, 2), (2, 7)]:
        (dx, dy), _ = cv2.phaseCorrelate(imgs[a], imgs[b], win)
        assert dx == pytest.approx(jitter[b, 0] - jitter[a, 0], abs=0.1)
        assert dy == pytest.approx(jitter[b, 1] - jitter[a, 1], abs=0.1)
    hidden = [r.frame for r in clip.truth() if not r.visible]
    assert hidden == [20, 21, 22, 23, 24]


def test_four_target_pair_meets_and_crosses() -> None:
    truth = _clip("fov70-four-targets").truth()
    first = {t: min(r.frame for r in truth if r.target_id == t) for t in (1, 2, 3, 4)}
    assert first == {1: 0, 2: 0, 3: 17, 4: 46}
    p = {(r.frame, r.target_id): np.array([r.x, r.y]) for r in truth}
    close = [f for f in range(200) if np.linalg.norm(p[f, 1] - p[f, 2]) < 20]
    assert close == list(range(close[0], close[-1] + 1)) and 8 <= len(close) <= 14
    assert 68 <= close[0] <= 74
    before, after = p[close[0], 1] - p[close[0], 2], p[close[-1], 1] - p[close[-1], 2]
    assert before[0] * after[0] < 0  # they swap sides: a crossing, not a touch
    others = [np.linalg.norm(p[f, a] - p[f, b]) for f in range(200) for a, b in
              [(1, 3), (1, 4), (2, 3), (2, 4), (3, 4)] if (f, a) in p and (f, b) in p]
    assert min(others) > 20


def test_lowsnr_presence_intervals() -> None:
    clip = _clip("lowsnr-tbd")
    truth = clip.truth()
    spans = {t: sorted(r.frame for r in truth if r.target_id == t) for t in (1, 2, 3)}
    assert spans == {1: list(range(3, 28)), 2: list(range(8, 18)), 3: list(range(13, 23))}
    assert all(r.visible and r.peak_snr == pytest.approx(3.0) for r in truth)
    for t in (1, 2, 3):
        xy = np.array([[r.x, r.y] for r in truth if r.target_id == t])
        assert 0.1 < np.hypot(*np.diff(xy, axis=0).T).max() < 1.0
    meta = clip.meta()
    assert clip.shape == (64, 64) and meta["horizon"] is None and meta["imaging_circle"] is None


def test_write_scenario_round_trip(tmp_path: Path) -> None:
    clip = make_scenario("fov180-launches", seed=2, n_frames=5)
    out = write_scenario(clip, tmp_path / "out", avi=True)
    assert out == tmp_path / "out"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    for frame in clip.frames():
        png = cv2.imread(str(out / f"frame_{frame.index:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint16 and np.array_equal(png, frame.image)
    with (out / "truth.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["frame", "target_id", "x", "y", "peak_snr", "visible"]
    truth = clip.truth()
    assert len(rows) - 1 == len(truth) and rows[1][2] == f"{truth[0].x:.4f}"
    meta = json.loads((out / "meta.json").read_text())
    assert meta["seed"] == 2 and meta["fps"] == 25.0 and meta["camera"]["fov_deg"] == 180.0
    cap = cv2.VideoCapture(str(out / meta["avi"]["file"]))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    ok, first = cap.read()
    cap.release()
    scale = meta["avi"]
    expect = np.clip(np.rint((clip.render(0) - scale["offset"]) * scale["gain"]), 0, 255)
    tol = 0 if meta["avi"]["codec"] == "FFV1" else 12
    assert ok and np.abs(first[..., 0].astype(int) - expect).max() <= tol
    short = make_scenario("fov180-launches", seed=2, n_frames=3)
    write_scenario(short, out)
    names = sorted(p.name for p in out.glob("frame_*.png"))
    assert names == [f"frame_{i:06d}.png" for i in range(3)]
    assert json.loads((out / "meta.json").read_text())["n_frames"] == 3


def test_long_clip_is_lazy_and_fast() -> None:
    t0 = time.perf_counter()
    clip = make_scenario("long-1024", seed=1)
    assert time.perf_counter() - t0 < 3.0
    assert clip.n_frames == 20_000 and clip.shape == (1024, 1024)
    frame = next(clip.frames(19_999))
    assert frame.index == 19_999 and frame.image.dtype == np.uint16
    rows = clip.truth_at(19_999)
    assert len({r.target_id for r in rows}) == len(rows) and all(r.target_id > 4 for r in rows)
