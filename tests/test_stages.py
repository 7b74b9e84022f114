"""Each GEWC stage against synthetic frames with exact truth."""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.config import DetectionConfig, HorizonConfig
from wfviz.stages.background import suppress_background
from wfviz.stages.centroid import gewc_centroid, intensity_centroid, measure
from wfviz.stages.detection import blobness, detect
from wfviz.stages.horizon import find_horizon, horizon_confident, max_gradient
from wfviz.stages.imaging_circle import estimate_imaging_circle, non_imaging_mask, ImagingCircle
from wfviz.stages.noise import NoiseModel
from wfviz.synth.psf import add_gaussian_spot


def fisheye_frame(shape, cx, cy, r, rng, dark=800.0, sky=6000.0, noise=25.0):
    """Anti-aliased bright disc on a dark background, plus noise and a sky gradient."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w]
    cover = np.clip(r + 0.5 - np.hypot(xx - cx, yy - cy), 0.0, 1.0)
    img = dark + cover * (sky - dark + 3.0 * (yy - cy)) + rng.normal(0, noise, shape)
    return img.astype(np.float32)


@pytest.mark.parametrize("cx,cy,r,shape", [
    (319.3, 255.6, 236.4, (512, 640)),   # 180° lens, circle inside the frame
    (160.7, 127.2, 150.3, (256, 320)),   # circle clipped by the top and bottom edges
    (100.2, 90.8, 70.6, (180, 200)),
])
def test_imaging_circle_within_one_pixel(cx, cy, r, shape):
    rng = np.random.default_rng(1)
    c = estimate_imaging_circle(fisheye_frame(shape, cx, cy, r, rng))
    assert c is not None
    assert abs(c.cx - cx) < 1.0 and abs(c.cy - cy) < 1.0 and abs(c.radius - r) < 1.0


def test_full_frame_lens_has_no_circle_and_empty_mask():
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[:240, :320]
    img = 5000 + 10 * yy + rng.normal(0, 25, (240, 320))  # a 70° view: no dark corners
    img[150:] += 3000 + rng.normal(0, 300, (90, 320))      # bright textured ground
    assert estimate_imaging_circle(img) is None
    assert not non_imaging_mask(img.shape, None, 5.0).any()


def test_mask_margin_shrinks_the_circle():
    mask = non_imaging_mask((100, 100), ImagingCircle(50, 50, 40), margin=5)
    assert not mask[50, 50] and mask[50, 50 + 36] and not mask[50, 50 + 34] and mask[0, 0]


def horizon_scene(rng, with_cloud: bool):
    h, w = 300, 400
    yy, xx = np.mgrid[:h, :w]
    true_row = 200 - 40 * np.cos((np.arange(w) - 200) / 400 * np.pi) ** 2 + 0.0004 * (np.arange(w) - 200) ** 2
    sky = 4000.0 + 4.0 * yy
    if with_cloud:  # a bright, smooth cloud band with a sharp lower edge above the horizon
        sky = sky + 1500.0 * ((yy > 60) & (yy < 110))
    ground = 9000.0 + rng.normal(0, 400, (h, w))
    img = np.where(yy < true_row[None, :], sky, ground) + rng.normal(0, 20, (h, w))
    return img.astype(np.float32), true_row


@pytest.mark.parametrize("with_cloud", [False, True])
def test_horizon_median_row_error_below_two_pixels(with_cloud):
    rng = np.random.default_rng(3)
    img, true_row = horizon_scene(rng, with_cloud)
    hz = find_horizon(img, np.ones(img.shape, bool), HorizonConfig())
    assert hz is not None
    ok = np.isfinite(hz.rows)
    assert ok.mean() > 0.8
    edge = np.ceil(true_row) - 0.5  # between the last sky row and the first ground row
    assert np.median(np.abs(hz.rows[ok] - edge[ok])) < 2.0


def test_no_horizon_in_plain_sky():
    # find_horizon returns its best line with a confidence (None only when the imaging area
    # has no room for the windows); a plain sky gives a line nobody may use
    rng = np.random.default_rng(4)
    img = (5000 + 2.0 * np.mgrid[:200, :300][0] + rng.normal(0, 20, (200, 300))).astype(np.float32)
    hz = find_horizon(img, np.ones(img.shape, bool), HorizonConfig())
    assert not horizon_confident(hz)


def test_max_gradient_directions():
    img = np.zeros((9, 9), np.float32)
    img[4, 4] = 10.0
    g = max_gradient(img, 1)
    assert g[3, 4] == 10 and g[5, 4] == 10 and g[4, 3] == 10 and g[3, 3] == 10 and g[4, 4] == 0


def test_suppression_raises_target_snr():
    rng = np.random.default_rng(5)
    h, w = 128, 128
    yy, xx = np.mgrid[:h, :w]
    img = 6000 + 400 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + rng.normal(0, 20, (h, w))
    add_gaussian_spot(img, 64.3, 60.7, 120.0, 0.9)
    img = img.astype(np.float32)

    def snr(a):
        ring = np.hypot(xx - 64.3, yy - 60.7)
        bg = a[(ring > 6) & (ring < 20)]
        return (a[61, 64] - bg.mean()) / bg.std()

    res = suppress_background(img, 5)
    assert snr(res) > 2.0 * snr(img)
    assert res.min() >= 0


@pytest.mark.parametrize("mode", ["cfar", "global"])
def test_detect_finds_spots_at_their_positions(mode: str) -> None:
    """The default CFAR (with the residual's local noise estimate) and the paper's global
    mean + k·std both find the three spots, and nothing else, at their positions."""
    rng = np.random.default_rng(6)
    img = 1000 + rng.normal(0, 10, (100, 120))
    truth = [(20.3, 30.6), (80.8, 70.1), (50.5, 50.5)]
    for x, y in truth:
        add_gaussian_spot(img, x, y, 150.0, 1.0)
    res = suppress_background(img.astype(np.float32), 5)
    valid = np.ones(res.shape, bool)
    cfg = DetectionConfig(mode=mode, k_sigma=5.0)
    noise = NoiseModel().update(res, valid) if mode == "cfar" else None
    d = detect(res, valid, cfg, noise=noise)
    assert len(d) == len(truth)
    for x, y in truth:
        assert np.min(np.hypot(d.xy[:, 0] - x, d.xy[:, 1] - y)) < 0.5
    if mode == "cfar":  # each spot's significance: its peak in local noise σ, above k_sigma
        assert d.significance is not None and (d.significance > cfg.k_sigma).all()


def test_cfar_detection_needs_a_noise_estimate() -> None:
    res = np.zeros((20, 20), np.float32)
    with pytest.raises(ValueError, match="needs a noise estimate"):
        detect(res, np.ones(res.shape, bool), DetectionConfig())


def test_blobness_tells_round_spots_from_ridges():
    rng = np.random.default_rng(2)
    img = 100 + rng.normal(0, 1.0, (80, 120))
    add_gaussian_spot(img, 20.4, 30.7, 60.0, 1.0)       # a point target
    add_gaussian_spot(img, 50.0, 30.0, 60.0, 1.6)       # a wider one
    img[:, 90] += 60.0                                   # a one-pixel bright line (a reed, a wire)
    img[60, 10:70] += 60.0                               # and a horizontal one
    xy = np.array([[20.4, 30.7], [50.0, 30.0], [90.0, 40.0], [40.0, 60.0]])
    b = blobness(img, xy, 1.0)
    assert b[0] > 0.85 and b[1] > 0.85                  # λ₂ ≈ λ₁
    assert abs(b[2]) < 0.3 and abs(b[3]) < 0.3          # one curvature (the rest is noise)
    assert blobness(img, np.zeros((0, 2)), 1.0).shape == (0,)
    assert blobness(np.ones((2, 2)), xy[:1], 1.0).tolist() == [-1.0]  # too small to tell


def centroid_errors(snr: float, n: int = 200, seed: int = 7):
    rng = np.random.default_rng(seed)
    eg, ei = [], []
    for _ in range(n):
        x, y = 10 + rng.random(), 10 + rng.random()
        img = rng.normal(0, 1.0, (21, 21))
        add_gaussian_spot(img, x, y, snr, 1.0)
        res = np.maximum(img, 0).astype(np.float32)
        labels = np.ones(img.shape, np.int32)
        g = measure(res, labels, 1, (x, y), 9, 2.5, "gewc")
        i = measure(res, labels, 1, (x, y), 9, 2.5, "intensity")
        eg.append(np.hypot(g.x - x, g.y - y))
        ei.append(np.hypot(i.x - x, i.y - y))
    return float(np.sqrt(np.mean(np.square(eg)))), float(np.sqrt(np.mean(np.square(ei))))


@pytest.mark.parametrize("snr", [10.0, 20.0])
def test_gewc_centroid_sub_pixel_accuracy(snr, record_property):
    gewc_rms, intensity_rms = centroid_errors(snr)
    record_property("gewc_rms_px", gewc_rms)
    record_property("intensity_rms_px", intensity_rms)
    print(f"SNR {snr}: GEWC RMS {gewc_rms:.3f} px, intensity centroid RMS {intensity_rms:.3f} px")
    assert gewc_rms < 0.5          # well inside a pixel at these SNRs
    assert intensity_rms < gewc_rms  # the faithful GEWC is the less precise of the two


def test_gewc_noise_free_symmetric_spot_is_exact_and_weights_sum_to_one():
    patch = np.zeros((11, 11))
    add_gaussian_spot(patch, 5.0, 5.0, 100.0, 1.2)
    r = gewc_centroid(patch)
    assert abs(r.x - 5.0) < 1e-6 and abs(r.y - 5.0) < 1e-6
    assert r.weights.shape == (8,) and abs(r.weights.sum() - 1.0) < 1e-9
    assert np.allclose(r.weights[:4], r.weights[4:])  # a point-symmetric spot: opposite octants agree
    assert intensity_centroid(np.zeros((5, 5))) is None and gewc_centroid(np.zeros((5, 5))) is None


def test_measure_ignores_other_components_in_the_window():
    res = np.zeros((30, 30), np.float32)
    add_gaussian_spot(res, 12.2, 14.6, 100.0, 0.9)
    add_gaussian_spot(res, 17.0, 14.0, 100.0, 0.9)
    labels = np.zeros((30, 30), np.int32)
    labels[:, :15] = 1
    labels[:, 15:] = 2
    alone = np.where(labels == 1, res, 0)
    a = measure(res, labels, 1, (12, 14), 11, 0.0, "intensity")
    b = measure(alone, labels, 1, (12, 14), 11, 0.0, "intensity")
    assert abs(a.x - b.x) < 1e-9 and abs(a.y - b.y) < 1e-9


def test_pipeline_circle_and_horizon_on_the_demo_scene():
    """The tracker's own estimates against the demo's exact fisheye geometry."""
    from wfviz.synth.demo import demo_clip, horizon_row
    from wfviz.trackers import make_tracker

    clip = demo_clip(seed=3)
    trk = make_tracker("gewc")
    result = None
    for frame in clip.frames(0, 11):
        result = trk.step(frame)
    cx, cy, r = clip.circle
    c = trk.circle
    assert abs(c.cx - cx) < 1 and abs(c.cy - cy) < 1 and abs(c.radius - r) < 1
    truth = horizon_row(np.arange(clip.shape[1]))
    ok = np.isfinite(truth) & np.isfinite(result.front.horizon.rows)
    assert ok.sum() > 0.9 * np.isfinite(truth).sum()
    assert np.median(np.abs(result.front.horizon.rows[ok] - truth[ok])) < 2.0


def test_search_zones_exclude_ground_modes():
    from wfviz.stages.horizon import Horizon, search_zones
    valid = np.ones((40, 50), dtype=bool)
    horizon = Horizon(np.full(50, 20.0))
    sky_rows = np.nonzero(search_zones(valid, horizon, 2.0, "always", False)[0].any(axis=1))[0]
    assert sky_rows.max() < 18                       # the paper: deep sky only
    for mode, fisheye in (("auto", False), ("never", True)):
        region, zones = search_zones(valid, horizon, 2.0, mode, fisheye)
        assert region.all() and len(zones) == 2 and not (zones[0] & zones[1]).any()
    region, zones = search_zones(valid, horizon, 2.0, "auto", True)   # fisheye sky view
    assert zones is None and not region[30].any()
    region, zones = search_zones(valid, None, 2.0, "never", False)    # no horizon: one zone
    assert region.all() and zones is None


def _gewc_reference(patch: np.ndarray, bins: int = 32, iterations: int = 2) -> tuple[float, float]:
    """Eqs. 4-7 written out pixel by pixel (Zhang Shuai et al. 2018), for the vectorised one."""
    import math
    from collections import defaultdict

    gy, gx = np.gradient(patch.astype(np.float64))
    grad = np.hypot(gx, gy)
    gmax = grad.max()
    h, w = patch.shape
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    for _ in range(iterations):
        cells: dict = defaultdict(lambda: defaultdict(list))  # region -> level -> positions
        for y in range(h):
            for x in range(w):
                if grad[y, x] <= gmax * 1e-9:
                    continue
                level = min(int(grad[y, x] / gmax * bins), bins - 1)
                region = int((math.atan2(y - cy, x - cx) + math.pi) / (2 * math.pi / 8)) % 8
                cells[region][level].append((x, y))
        entropy, centre = {}, {}
        for r, levels in cells.items():
            n_r = sum(len(v) for v in levels.values())
            q = {g: len(v) / n_r for g, v in levels.items()}                       # eq. 4
            m = {g: np.mean(v, axis=0) for g, v in levels.items()}                   # eq. 5
            entropy[r] = -sum(p * math.log2(p) for p in q.values())                  # eq. 6
            centre[r] = sum(q[g] * m[g] for g in q)
        total = sum(entropy.values())
        weight = {r: (e / total if total > 0 else 1.0 / len(entropy)) for r, e in entropy.items()}
        cx, cy = (float(v) for v in sum(weight[r] * centre[r] for r in weight))      # eq. 7
    return cx, cy


def test_gewc_matches_a_pixel_by_pixel_reading_of_the_equations():
    """The one (batched) GEWC implementation against eqs. 4-7 written out with loops, on spots
    at sub-pixel offsets with noise, to 1e-9 px; single-patch calls are the batched one."""
    from wfviz.stages.centroid import gewc_centroids

    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:11, 0:11]
    patches = []
    for _ in range(12):
        x0, y0 = 5 + rng.uniform(-1.5, 1.5), 5 + rng.uniform(-1.5, 1.5)
        spot = 100 * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * rng.uniform(0.6, 1.6) ** 2))
        patches.append(np.maximum(spot + rng.normal(0, 3, spot.shape), 0))
    patches = np.array(patches)
    batched = gewc_centroids(patches)
    for p, b in zip(patches, batched):
        rx, ry = _gewc_reference(p)
        single = gewc_centroid(p)
        assert abs(b.x - rx) < 1e-9 and abs(b.y - ry) < 1e-9
        assert (single.x, single.y) == (b.x, b.y)
