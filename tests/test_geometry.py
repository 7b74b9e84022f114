"""Scene geometry with confidences: the horizon detector and the imaging-circle estimate on
synthetic frames with exact truth (and, when present, on the independent samples S3/S4)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from wfviz.config import CircleConfig, HorizonConfig
from wfviz.stages.horizon import (CONFIDENT, SKY_BELOW_HIGH, SKY_BELOW_LOW, Horizon, HorizonTracker, blend,
                                  boundary_evidence, find_horizon, horizon_confident, search_zones, sky_below)
from wfviz.stages.imaging_circle import (ImagingCircle, ImagingMask, estimate_imaging_circle, non_imaging_mask,
                                  resolve_circle)

H, W = 240, 320
CFG = HorizonConfig()


def texture(rng: np.random.Generator, shape: tuple[int, int], amplitude: float) -> np.ndarray:
    """Ground-like texture: blurred noise at two scales, unit std times ``amplitude``."""
    t = cv2.GaussianBlur(rng.normal(0, 1, shape).astype(np.float32), (0, 0), 1.2)
    t += 0.5 * cv2.GaussianBlur(rng.normal(0, 1, shape).astype(np.float32), (0, 0), 4.0)
    return amplitude * t / t.std()


def sky(shape: tuple[int, int], rng: np.random.Generator, noise: float = 20.0) -> np.ndarray:
    """A smooth sky brightening toward the bottom, vignetted toward the corners, with noise."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    level = 3000.0 + 2500.0 * (yy / h) ** 2
    level *= 1.0 - 0.25 * (((xx - w / 2) / w) ** 2 + ((yy - h / 2) / h) ** 2)
    return level + rng.normal(0, noise, shape).astype(np.float32)


def skyline_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Sky over textured, brighter ground below a gently curved horizon, with one building
    (columns 120-169, 30 px tall) standing on it. Returns (frame, true boundary row per
    column, between the last sky row and the first ground row)."""
    x = np.arange(W)
    base = 160.0 + 0.0006 * (x - W / 2) ** 2
    top = base.copy()
    top[120:170] = np.floor(base[120:170]).min() - 30.0
    yy = np.arange(H)[:, None]
    ground = yy >= np.ceil(top)[None, :]
    img = sky((H, W), rng)
    img = np.where(ground, 7000.0 + texture(rng, (H, W), 300.0), img) + rng.normal(0, 20, (H, W))
    return img.astype(np.float32), np.ceil(top) - 0.5


def test_confident_horizon_follows_the_skyline_and_the_building_top():
    rng = np.random.default_rng(11)
    img, truth = skyline_scene(rng)
    hz = find_horizon(img, np.ones(img.shape, bool), CFG)
    assert horizon_confident(hz) and hz.confidence > 0.8
    err = np.abs(hz.rows - truth)
    assert np.median(err) < 1.5
    assert np.mean(err <= 3.0) > 0.9
    assert np.median(err[125:165]) < 2.0          # on the roof, not at the building's foot


def test_eight_bit_quantised_scene_is_confident_too():
    rng = np.random.default_rng(12)
    img, truth = skyline_scene(rng)
    img8 = np.clip((img - 2500.0) / 25.0, 0, 255).astype(np.uint8)   # few grey levels in the sky
    hz = find_horizon(img8, np.ones(img8.shape, bool), CFG)
    assert horizon_confident(hz)
    assert np.median(np.abs(hz.rows - truth)) < 2.0


@pytest.mark.parametrize("seed", [21, 22])
def test_pure_sky_with_gradient_and_vignetting_is_not_confident(seed):
    rng = np.random.default_rng(seed)
    img = sky((H, W), rng)
    img += 15.0 * rng.normal(0, 1, (1, W)).astype(np.float32)   # column fixed-pattern stripes
    for _ in range(20):                                            # stars
        y, x = rng.integers(5, H - 5), rng.integers(5, W - 5)
        img[y, x] += 800.0
    hz = find_horizon(img, np.ones(img.shape, bool), CFG)
    assert not horizon_confident(hz)
    assert hz is None or hz.confidence < 0.2


def test_cloud_bands_are_not_a_horizon():
    """Bright, smooth cloud bands with soft, wavy edges and clear sky between and below them
    (the paper's constraint (a): a cloud edge is smooth on both sides)."""
    rng = np.random.default_rng(23)
    img = sky((H, W), rng)
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    for centre, amp in ((50.0, 1500.0), (105.0, 1200.0), (160.0, 1800.0)):
        edge = centre + 6.0 * np.sin(xx / 37.0 + centre)
        img += amp * np.exp(-0.5 * ((yy - edge) / 9.0) ** 2)
    hz = find_horizon(img, np.ones(img.shape, bool), CFG)
    assert not horizon_confident(hz)


def cloud_band_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bright, textured cloud band (columns 80-239) with a sharp upper edge near row 60 that
    fades out by row 110, clear sky below and beside it, over textured ground near row 170;
    under the band a smooth warm gate (40 rows) gives the ground line there little evidence,
    so the cloud's upper edge is the stronger line in those columns (IR_HELICOPTER_036's case).
    Returns (frame, true ground boundary row per column, cloud edge row per column)."""
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    img = sky((H, W), rng)
    upper = 60.0 + 4.0 * np.sin(xx[0] / 23.0)
    band = (xx >= 80) & (xx < 240)
    cloud = np.clip((110.0 - yy) / 30.0, 0, 1) * (yy >= np.ceil(upper)[None, :]) * band
    img += cloud * (1500.0 + texture(rng, (H, W), 150.0))
    ground_row = 170.0 + 0.0004 * (xx[0] - W / 2) ** 2
    ground = yy >= np.ceil(ground_row)[None, :]
    img = np.where(ground, 7000.0 + texture(rng, (H, W), 300.0), img)
    img = np.where(ground & band & (yy < ground_row[None, :] + 40), 7000.0, img)   # the gate
    img += rng.normal(0, 20, (H, W))
    return img.astype(np.float32), np.ceil(ground_row) - 0.5, np.ceil(upper) - 0.5


def test_a_line_on_a_cloud_band_has_sky_below_it():
    """The measure behind the cloud doubt: under a line on the cloud's edge the column is sky
    again further down (sky below ≥ SKY_BELOW_HIGH, full doubt), under the ground line it is
    not (≤ SKY_BELOW_LOW)."""
    img, ground_row, cloud_row = cloud_band_scene(np.random.default_rng(31))
    valid = np.ones(img.shape, bool)
    ev = boundary_evidence(img, valid)
    x = np.arange(W)
    on_ground = (ground_row + 0.5).astype(np.int64)          # working row y: boundary at y - 0.5
    on_cloud = np.where((x >= 80) & (x < 240), (cloud_row + 0.5).astype(np.int64), on_ground)
    for path in (on_ground, on_cloud):
        share = sky_below(ev, valid, path)[path, x]
        assert np.all(share[:70] <= SKY_BELOW_LOW) and np.all(share[250:] <= SKY_BELOW_LOW)
    assert np.all(sky_below(ev, valid, on_ground)[on_ground, x][80:240] <= SKY_BELOW_LOW)
    assert np.all(sky_below(ev, valid, on_cloud)[on_cloud, x][85:235] >= SKY_BELOW_HIGH)


def test_cloud_band_edge_is_doubted_and_the_ground_line_found():
    """Without the doubt the path followed the cloud's edge over half the width (confidence
    1.0, the ground under it not searched); with it the line stays on or below the ground in
    the band's columns and the ground horizon keeps a high confidence."""
    img, ground_row, _ = cloud_band_scene(np.random.default_rng(31))
    hz = find_horizon(img, np.ones(img.shape, bool), CFG)
    assert hz is not None and horizon_confident(hz) and hz.confidence > 0.8
    assert hz.ground > 0.95
    assert np.all(hz.rows[80:240] >= ground_row[80:240] - 2.0)
    err = np.abs(hz.rows - ground_row)
    assert np.median(err[:70]) < 1.5 and np.median(err[250:]) < 1.5


def test_terrain_only_view_is_not_confident():
    rng = np.random.default_rng(24)
    img = 6000.0 + texture(rng, (H, W), 250.0)
    img[60:140, 40:300] -= 0.7 * texture(rng, (80, 260), 250.0)     # a smoother field
    img[140:150, :] += 900.0                                         # a bright road across
    img += rng.normal(0, 15, (H, W))
    hz = find_horizon(img.astype(np.float32), np.ones(img.shape, bool), CFG)
    assert not horizon_confident(hz)


def fisheye_scene(rng: np.random.Generator, cx=160.3, cy=120.6, r=112.4):
    """A 180° frame: dark corners, sky in the circle, textured ground below a horizon arc
    that bends up toward the rim (a circle through the rim below the centre)."""
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    inside = np.hypot(xx - cx, yy - cy) <= r
    horizon = cy + 25.0 - 0.004 * (xx - cx) ** 2          # row of the arc at each column
    img = np.where(yy >= np.ceil(horizon), 7500.0 + texture(rng, (H, W), 300.0), sky((H, W), rng))
    img = np.where(inside, img, 300.0) + rng.normal(0, 10, (H, W))
    return img.astype(np.float32), np.ceil(horizon[0]) - 0.5, (cx, cy, r)


def test_fisheye_horizon_inside_the_imaging_circle():
    rng = np.random.default_rng(31)
    img, truth, (cx, cy, r) = fisheye_scene(rng)
    circle = estimate_imaging_circle(img)
    assert circle is not None and circle.confidence > 0.9
    assert abs(circle.cx - cx) < 1 and abs(circle.cy - cy) < 1 and abs(circle.radius - r) < 1
    valid = ~non_imaging_mask(img.shape, circle, 6.0)
    hz = find_horizon(img, valid, CFG)
    assert horizon_confident(hz)
    cols = valid.any(axis=0)
    assert np.isnan(hz.rows[~cols]).all() and np.isfinite(hz.rows[cols]).all()
    # columns where the arc lies inside the imaging area (it bends up toward the rim)
    inside = cols & (np.abs(truth - cy) < np.sqrt(np.maximum((r - 8) ** 2 - (np.arange(W) - cx) ** 2, 0)))
    err = np.abs(hz.rows - truth)[inside]
    assert np.median(err) < 1.5 and np.mean(err <= 5.0) > 0.85


def test_circle_confidence_falls_with_a_ragged_low_contrast_rim():
    rng = np.random.default_rng(32)
    clean, _, _ = fisheye_scene(rng)
    good = estimate_imaging_circle(clean)
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    ang = np.arctan2(yy - 120.6, xx - 160.3)
    rim = 112.4 + 1.0 * np.sign(np.sin(9.0 * ang))            # a rim 1 px in and out
    dark, bright = 3000.0, 3600.0                              # 600 DN over noise 40: ~15 σ
    ragged = np.where(np.hypot(xx - 160.3, yy - 120.6) <= rim, bright, dark) + rng.normal(0, 40, (H, W))
    bad = estimate_imaging_circle(ragged.astype(np.float32))
    assert good.confidence > 0.9
    assert bad is not None and bad.confidence < 0.5 * good.confidence


def test_configured_circle_has_confidence_one():
    cfg = CircleConfig(center=(100.0, 90.0), radius=80.0)
    c = resolve_circle(np.zeros((180, 200), np.float32), cfg)
    assert c == ImagingCircle(100.0, 90.0, 80.0, 1.0)
    mask = ImagingMask(cfg)
    mask.update(np.zeros((180, 200), np.float32))
    assert mask.circle.confidence == 1.0


def test_tracker_confidence_follows_agreement_and_keeps_the_confident_rows():
    rng = np.random.default_rng(41)
    img, truth = skyline_scene(rng)
    valid = np.ones(img.shape, bool)
    trk = HorizonTracker(HorizonConfig(every=1))
    first, updated = trk.update(img, valid)
    second, _ = trk.update(img, valid)
    assert updated and horizon_confident(second)
    assert abs(second.confidence - first.confidence) < 0.1       # agreeing estimates: it holds
    blank = sky((H, W), rng)
    third, _ = trk.update(blank, valid)                           # the line vanishes
    assert third.confidence < second.confidence
    np.testing.assert_array_equal(third.rows, second.rows)        # the failed estimate keeps it
    for _ in range(4):
        last, _ = trk.update(blank, valid)
    assert not horizon_confident(last)                            # ... but not for ever


def test_blend_smooths_where_the_lines_agree_and_follows_a_moved_line():
    a = Horizon(np.full(50, 20.0), 0.9, 0.9, 1.0)
    moved = blend(a, Horizon(np.full(50, 40.0), 0.7, 0.7, 1.0), 0.5)     # the camera panned
    assert moved.confidence == pytest.approx(0.7) and np.all(moved.rows == 40.0)
    same = blend(a, Horizon(np.full(50, 21.0), 0.7, 0.7, 1.0), 0.5)      # agrees everywhere
    assert same.confidence == pytest.approx(0.8) and np.allclose(same.rows, 20.5)
    failed = blend(a, Horizon(np.full(50, 35.0), 0.1, 0.1, 0.2), 0.5)    # not confident
    assert failed.confidence == pytest.approx(0.5) and np.all(failed.rows == 20.0)
    assert blend(a, None, 0.5) is a


def test_an_unconfident_horizon_does_not_cut_the_search_region():
    valid = np.ones((40, 50), dtype=bool)
    weak = Horizon(np.full(50, 20.0), CONFIDENT - 0.1, 0.4, 1.0)
    region, zones = search_zones(valid, weak, 2.0, "always", False)
    assert region.all() and zones is None
    strong = Horizon(np.full(50, 20.0), CONFIDENT, 0.5, 1.0)
    region, _ = search_zones(valid, strong, 2.0, "always", False)
    assert not region[25:].any()


INDEPENDENT = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "independent"


def _truth_rows(polyline: list, width: int) -> np.ndarray:
    rows = np.full(width, np.nan)
    p = np.asarray(polyline, float)
    for a, b in zip(p[:-1], p[1:]):
        q = a + np.linspace(0, 1, int(np.ceil(np.hypot(*(b - a)) / 0.25)) + 1)[:, None] * (b - a)
        c = np.rint(q[:, 0]).astype(int)
        ok = (c >= 0) & (c < width)
        np.fmin.at(rows, c[ok], q[ok, 1])
    return rows


@pytest.mark.parametrize("name,floor_cover,max_median", [("S3", 0.65, 3.0), ("S4", 0.7, 3.5)])
def test_independent_fisheye_samples(name, floor_cover, max_median):
    """S3 (city skyline) and S4 (flare, clouds), frame 0: measured cover 0.73 / 0.79, median
    2.1 / 2.6 px, confidence 0.80 / 0.75, circle centre error 0.48 / 0.42 px, confidence 1.0
    (benchmarks/geometry.py); the floors are a little below."""
    folder = INDEPENDENT / name
    if not (folder / "meta.json").exists():
        pytest.skip(f"{folder} not found (the independent samples live beside the repository)")
    meta = json.loads((folder / "meta.json").read_text())
    img = cv2.imread(str(folder / "frames" / "frame_000000.png"), cv2.IMREAD_UNCHANGED)
    circle = estimate_imaging_circle(img)
    assert circle is not None and circle.confidence > 0.9
    assert np.hypot(circle.cx - meta["circle_center"][0], circle.cy - meta["circle_center"][1]) < 1.0
    assert abs(circle.radius - meta["circle_radius"]) < 1.0
    valid = ~ImagingMask(CircleConfig()).update(img)[0]
    hz = find_horizon(img, valid, CFG)
    assert horizon_confident(hz) and hz.confidence > 0.6
    truth = _truth_rows(meta["horizon_polyline"], img.shape[1])
    err = np.abs(hz.rows - truth)[np.isfinite(truth)]
    err = np.where(np.isfinite(err), err, np.inf)
    assert np.median(err) <= max_median
    assert np.mean(err <= 5.0) >= floor_cover


@pytest.mark.parametrize("cross", [True, False])
def test_a_confirmed_track_is_followed_below_the_horizon(cross):
    """A target descending from the sky across the skyline into the ground: its confirmed
    track's gate is searched below the horizon too, so the track follows it there; without
    that (the search region only) the track is lost at the line. No track starts on the
    textured ground either way."""
    from wfviz.io.frames import Frame
    from wfviz.synth.psf import add_gaussian_spot
    from wfviz.trackers.gewc import GEWCConfig, GEWCTracker

    rng = np.random.default_rng(5)
    background, boundary = skyline_scene(rng)
    config = GEWCConfig()
    trk = GEWCTracker(replace(config, detection=replace(config.detection, gates_cross_horizon=cross)))
    below = 0
    for k in range(40):
        x, y = 40.0 + 1.5 * k, 110.0 + 2.0 * k
        img = background + rng.normal(0, 20, (H, W)).astype(np.float32)
        add_gaussian_spot(img, x, y, 4000.0, 1.0, 1.0)
        r = trk.step(Frame(k, k / 25, np.clip(img, 0, 65535).astype(np.uint16)))
        on_ground = y > boundary[int(round(x))] + 4
        for t in r.tracks:
            if t.confirmed and t.y > boundary[int(round(t.x))] + 4:
                assert np.hypot(t.x - x, t.y - y) < 3.0  # only the target, never the ground
                below += on_ground
    assert (below >= 8) if cross else (below == 0)


def test_sky_below_when_the_sky_above_lies_only_on_skipped_rows():
    """The sky above the path is sampled on every other pixel; where it lies only on the rows or
    columns that skips, the statistics are taken on all of it (it crashed before)."""
    from wfviz.stages.horizon import BoundaryEvidence, sky_below

    h, w = 40, 64
    rng = np.random.default_rng(0)
    ev = BoundaryEvidence(evidence=np.zeros((h, w), np.float32),
                          texture=rng.random((h, w)).astype(np.float32),
                          level=rng.random((h, w)).astype(np.float32), floor=0.01)
    valid = np.zeros((h, w), bool)
    valid[1, 1:33:2] = True                      # 16 imaging pixels above the path, odd row and columns
    valid[8:] = True
    path = np.full(w, 8)
    out = sky_below(ev, valid, path)
    assert out.shape == (h, w) and np.isfinite(out).all()
