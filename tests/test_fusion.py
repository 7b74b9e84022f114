"""The feature-fusion Kalman tracker (``--tracker fusion``): features, fused cost, tracking the
two-aircraft scenario, global re-detection and recovery, the recording and the config."""

from __future__ import annotations

import tomllib
from collections import defaultdict

import numpy as np
import pytest

from wfviz.config import ConfigError, config_from_dict, config_to_toml
from wfviz.io.frames import Frame
from wfviz.record_options import RecorderOptions
from wfviz.run import run
from wfviz.synth.psf import add_gaussian_spot
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers import TRACKERS, make_tracker
from wfviz.trackers.fusion import FusionTracker, fused_cost, min_area_rect, scalar_phi
from wfviz.trackers.fusion.config import FusionConfig

PLAIN = {"circle": {"enabled": False}, "horizon": {"enabled": False}}
# the paper's detection and confirmation (the defaults are the local-noise CFAR and the
# sequential test): for tests of the paper's thresholding, features and hit counting
PAPER = {"detection": {"mode": "global"}, "tracking": {"confirm": "hits"}}


def truth_points(clip):
    shown, hidden = defaultdict(list), defaultdict(list)
    for row in clip.truth():
        (shown if row.visible else hidden)[row.frame].append((row.target_id, row.x, row.y))
    return dict(shown), dict(hidden)


def blob_frame() -> tuple[np.ndarray, list[dict]]:
    """Flat background 500 with three blobs of known pixels and grey levels."""
    img = np.full((120, 160), 500, dtype=np.uint16)
    blobs = []
    # a 3x2 rectangle, level +100: area 6, residual sum 600, bbox centre (41, 30.5)
    img[30:32, 40:43] += 100
    blobs.append(dict(area=6, grey=600.0, raw=6 * 600.0, centre=(41.0, 30.5)))
    # an L of 4 pixels with different levels: bbox 2x3, centre (100.5, 71)
    for (y, x), v in zip([(70, 100), (71, 100), (72, 100), (72, 101)], [80, 120, 160, 200]):
        img[y, x] += v
    blobs.append(dict(area=4, grey=560.0, raw=4 * 500.0 + 560.0, centre=(100.5, 71.0)))
    # one pixel, +300
    img[90, 20] += 300
    blobs.append(dict(area=1, grey=300.0, raw=800.0, centre=(20.0, 90.0)))
    return img, blobs


@pytest.mark.parametrize("grey", ["residual", "raw"])
def test_global_detection_features_of_known_blobs(grey: str) -> None:
    """The paper's global mean + k·std threshold keeps every blob pixel of the noise-free frame
    (the default CFAR takes the frame's grey-level step of 20 as its noise floor and drops the
    L's faintest pixel, +80 = 4 steps), so the features are exact."""
    img, blobs = blob_frame()
    cfg = config_from_dict({**PLAIN, **PAPER, "defects": {"enabled": False}, "features": {"grey": grey}},
                           FusionConfig)
    r = FusionTracker(cfg).step(Frame(0, 0.0, img))
    assert r.global_detection and r.global_reason == "first frame"
    f = r.features
    assert len(f) == 3 and len(r.detections) == 3 and len(r.tracks) == 3  # every blob starts a track
    for b in blobs:
        j = int(np.argmin(np.hypot(*(f.centre - np.array(b["centre"])).T)))
        np.testing.assert_allclose(f.centre[j], b["centre"], atol=1e-9)
        assert f.area[j] == b["area"]
        assert f.grey[j] == pytest.approx(b[grey if grey == "raw" else "grey"])
        # the drawn rectangle is the bbox on pixel edges
        np.testing.assert_allclose(f.rects[j].mean(axis=0), b["centre"], atol=1e-9)


def test_window_search_measures_the_same_features_as_global_detection() -> None:
    """Paper options: still blobs are confirmed by hits (the sequential test wants motion)."""
    img, blobs = blob_frame()
    cfg = config_from_dict({**PLAIN, **PAPER, "defects": {"enabled": False}, "fusion": {"detect_every": 0}},
                           FusionConfig)
    trk = FusionTracker(cfg)
    first = trk.step(Frame(0, 0.0, img))
    second = trk.step(Frame(1, 0.02, img))  # tentative tracks only: still global (acquisition)
    assert second.global_detection and second.global_reason == "no confirmed track"
    # confirm the three tracks, then the windows alone are searched
    for k in range(2, 8):
        r = trk.step(Frame(k, 0.02 * k, img))
    assert not r.global_detection and r.searched
    assert sum(t.confirmed for t in r.tracks) == 3
    order = lambda res: np.lexsort(res.features.centre.T)  # noqa: E731
    a, b = first.features, r.features
    np.testing.assert_allclose(a.centre[order(first)], b.centre[order(r)])
    np.testing.assert_array_equal(a.area[order(first)], b.area[order(r)])
    np.testing.assert_allclose(a.grey[order(first)], b.grey[order(r)])
    # the candidates lie in the searched crops; the residual is the full frame's all the same
    for x, y in b.centre:
        assert any(x0 <= x < x1 and y0 <= y < y1 for x0, y0, x1, y1 in r.searched), (x, y)
    np.testing.assert_array_equal(r.front.suppressed, first.front.suppressed)
    assert r.front.suppressed[30, 41] == 100


def test_window_search_uses_the_whole_region_threshold_in_global_mode() -> None:
    """A bright 3x3 blob with a faint wing pixel: found whole by global detection, and the same
    in its window, thresholded over the whole search region (the window's own mean + 4·std,
    inflated by the blob, would drop the wing)."""
    img = np.full((120, 160), 500, dtype=np.uint16)
    img[50:53, 70:73] += 200
    img[51, 73] += 40
    cfg = config_from_dict({**PLAIN, **PAPER, "defects": {"enabled": False}, "fusion": {"detect_every": 0}},
                           FusionConfig)
    trk = FusionTracker(cfg)
    results = [trk.step(Frame(k, 0.02 * k, img)) for k in range(8)]
    first, last = results[0], results[-1]
    assert first.features.area.tolist() == [10] and not last.global_detection
    assert last.detections.threshold == pytest.approx(first.detections.threshold)
    assert last.features.area.tolist() == [10]
    np.testing.assert_allclose(last.features.centre, first.features.centre)


def test_min_area_rect_of_a_diagonal_streak():
    xs = np.arange(10, 16, dtype=float)
    (cx, cy), corners = min_area_rect(xs, xs + 5)
    assert (cx, cy) == pytest.approx((12.5, 17.5), abs=1e-4)
    sides = np.linalg.norm(np.diff(np.vstack([corners, corners[:1]]), axis=0), axis=1)
    # rotated 45°: 6·√2 long and √2 wide (the pixel squares' corners), a third of the 6x6 box
    assert sorted(sides)[0] == pytest.approx(np.sqrt(2), rel=1e-3)
    assert sorted(sides)[-1] == pytest.approx(6 * np.sqrt(2), rel=1e-3)


def test_fused_cost_prefers_matching_features_over_the_nearest_candidate():
    pred, half = np.array([[50.0, 50.0]]), np.array([[6.0, 6.0]])
    ref_area, ref_grey = np.array([6.0]), np.array([600.0])
    centre = np.array([[50.5, 50.0], [53.0, 52.0]])  # a bright single pixel at the prediction
    area, grey = np.array([1, 6]), np.array([2000.0, 620.0])  # and the target 3.6 px away
    cost = fused_cost(pred, half, ref_area, ref_grey, centre, area, grey, 0.4, 0.3, 0.3)
    assert cost.shape == (1, 2) and cost[0, 1] < cost[0, 0]
    # position alone (beta = gamma = 0) picks the nearer one
    pos = fused_cost(pred, half, ref_area, ref_grey, centre, area, grey, 1.0, 0.0, 0.0)
    assert pos[0, 0] < pos[0, 1]
    # the scalar Φ can be blind: a larger, dimmer candidate has the same Φ as the reference
    phi = scalar_phi(np.array([[50.0, 50.0], [50.0, 50.0]]), np.array([6.0, 8.0]),
                     np.array([600.0, 400.0]), 6.0, 600.0, (100, 100), 0.4, 0.3, 0.3)
    assert phi[0] == pytest.approx(phi[1])


def test_two_aircraft_at_50hz_tracked_without_identity_switch():
    clip = make_scenario("uniform-50hz", seed=0)
    summary = run(clip, make_tracker("fusion"), truth=truth_points(clip))
    s = summary.scores
    print(f"fusion uniform-50hz: MOTA {s.mota:.3f} IDF1 {s.idf1:.3f} switches {s.id_switches} "
          f"CLE RMS {s.cle_rms:.3f} FA/frame {s.fa_per_frame:.3f}")
    assert s.mota >= 0.95 and s.id_switches == 0 and s.fa_per_frame == 0
    assert len(summary.confirmed) == 2


def jump_clip(jump: tuple[float, float], n: int = 50, at: int = 30, seed: int = 0) -> tuple[list[Frame], list]:
    """Two targets on a noisy background; target 1 jumps by ``jump`` px at frame ``at``."""
    rng = np.random.default_rng(seed)
    frames, truth = [], []
    for k in range(n):
        img = 1000.0 + rng.normal(0.0, 5.0, (140, 200))
        x1, y1 = 30.0 + 1.0 * k, 40.0 + 0.5 * k
        if k >= at:
            x1, y1 = x1 + jump[0], y1 + jump[1]
        x2, y2 = 170.0 - 0.8 * k, 110.0 - 0.3 * k
        add_gaussian_spot(img, x1, y1, 120.0, 0.8)
        add_gaussian_spot(img, x2, y2, 100.0, 0.8)
        frames.append(Frame(k, k / 50.0, np.clip(img, 0, 65535).astype(np.uint16)))
        truth.append(((x1, y1), (x2, y2)))
    return frames, truth


def nearest(tracks, xy, gate=2.0):
    best = min(tracks, key=lambda t: np.hypot(t.x - xy[0], t.y - xy[1]), default=None)
    return best if best is not None and np.hypot(best.x - xy[0], best.y - xy[1]) <= gate else None


@pytest.mark.parametrize("confirm", [
    "hits",
    "sprt",
])
def test_target_leaving_its_window_triggers_global_detection_and_the_track_recovers(confirm: str) -> None:
    """Both the paper's hits rule and the default sequential test ("sprt")."""
    frames, truth = jump_clip((22.0, 9.0))  # beyond gate_max = 15 px
    trk = FusionTracker(config_from_dict({**PLAIN, "fusion": {"detect_every": 0},
                                          "tracking": {"confirm": confirm}}, FusionConfig))
    results = [trk.step(f) for f in frames]
    before = nearest([t for t in results[29].tracks if t.confirmed], truth[29][0])
    other = nearest([t for t in results[29].tracks if t.confirmed], truth[29][1])
    assert before is not None and other is not None
    # frames 6..29: windows only
    assert not any(r.global_detection for r in results[8:30])
    r = results[30]
    assert r.global_detection and str(before.track_id) in r.global_reason
    kinds = {(e.kind, e.track_id) for e in r.events}
    assert ("window_lost", before.track_id) in kinds and ("recovered", before.track_id) in kinds
    assert ("deleted", before.track_id) not in kinds  # a recovered track lives on
    m = next(m for m in r.matches if m.track_id == before.track_id)
    assert m.recovered and np.hypot(m.x - truth[30][0][0], m.y - truth[30][0][1]) < 1.5
    # the same track follows the target from then on, in its windows again, and the other is undisturbed
    for k in range(31, len(frames)):
        t1 = nearest(results[k].tracks, truth[k][0])
        t2 = nearest(results[k].tracks, truth[k][1])
        assert t1 is not None and t1.track_id == before.track_id and t1.confirmed, k
        assert t2 is not None and t2.track_id == other.track_id, k
    assert not any(r.global_detection for r in results[32:])


def test_no_recovery_beyond_the_recovery_radius():
    frames, truth = jump_clip((60.0, 0.0))
    trk = FusionTracker(config_from_dict({**PLAIN, "fusion": {"detect_every": 0, "recover_radius": 40.0}},
                                         FusionConfig))
    results = [trk.step(f) for f in frames]
    lost_id = nearest(results[29].tracks, truth[29][0]).track_id
    assert not any(e.kind == "recovered" for r in results for e in r.events)
    assert any(e.kind == "deleted" and e.track_id == lost_id for r in results[30:34] for e in r.events)
    # the target is found again by global detection and tracked under a new id
    late = nearest([t for t in results[-1].tracks if t.confirmed], truth[-1][0])
    assert late is not None and late.track_id != lost_id


def test_recording_logs_the_fusion_entities(tmp_path):
    from rerun.chunk import RrdReader

    clip = make_scenario("uniform-50hz", seed=0, n_frames=24)
    trk = make_tracker("fusion")
    rrd = tmp_path / "f.rrd"
    run(clip, trk, recording=rrd, truth=truth_points(clip),
        recorder_options=RecorderOptions(source="uniform-50hz", config_text=config_to_toml(trk.config), image_every=0))
    frames, cols, texts = defaultdict(set), defaultdict(set), []
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        cols[chunk.entity_path].update(batch.schema.names)
        if not chunk.is_static and "frame" in batch.schema.names:
            frames[chunk.entity_path].update(batch.column("frame").to_pylist())
        if chunk.entity_path == "/log":
            texts += [t for row in batch.column("TextLog:text").to_pylist() for t in (row or [])]
    every = set(range(24))
    for path in ["/camera/detections", "/camera/gates", "/camera/predictions", "/camera/tracks",
                 "/camera/rects", "/camera/measurements", "/detection/global", "/timing/total",
                 "/timing/suppress", "/timing/noise", "/timing/detect", "/timing/associate",
                 # the shared front end's (wfviz/stages/front_end.py) and the sequential test's
                 "/detection/noise_sigma", "/registration/dx", "/registration/dy",
                 "/registration/moving", "/tracks/confirm_level"]:
        assert frames[path] == every, path
    assert ({"grey", "phi", "cost", "track", "area", "flux", "significance", "change"}
            <= cols["/camera/detections"])
    phi = [p for p in frames if p.startswith("/fusion/") and p.endswith("/phi")]
    cost = [p for p in frames if p.startswith("/fusion/") and p.endswith("/cost")]
    assert len(phi) == 2 and len(cost) == 2 and all(len(frames[p]) >= 15 for p in phi + cost)
    assert sum(p.startswith("/kalman/") and p.endswith("/innovation") for p in frames) == 2
    assert any("global detection (periodic" in t for t in texts)
    assert "/suppressed/image" not in frames and "/suppressed/noise" not in frames  # image_every=0


def test_registered_and_config_round_trips():
    assert TRACKERS["fusion"][:2] == (FusionTracker, FusionConfig)
    cfg = FusionConfig()
    assert (cfg.fusion.alpha, cfg.fusion.beta, cfg.fusion.gamma) == (0.4, 0.3, 0.3)
    assert config_from_dict(tomllib.loads(config_to_toml(cfg)), FusionConfig) == cfg
    with pytest.raises(ConfigError, match="fusion.cost"):
        config_from_dict({"fusion": {"cost": "product"}}, FusionConfig)
    with pytest.raises(ConfigError, match="must be positive"):
        config_from_dict({"fusion": {"alpha": 0.0, "beta": 0.0, "gamma": 0.0}}, FusionConfig)


@pytest.mark.parametrize("key", ["confirm_moving = 6.0", "meeting_misses = true"])
def test_gewc_only_tracking_options_are_refused(key: str) -> None:
    with pytest.raises(ConfigError, match=f"tracking.{key.split()[0]} is not supported by the fusion"):
        config_from_dict(tomllib.loads(f"[tracking]\n{key}\n"), FusionConfig)


def panning_clip(n: int = 16, step: int = 2, seed: int = 0) -> tuple[list[Frame], list[tuple[float, float]]]:
    """A textured scene panning left by ``step`` px a frame (the camera turns right), with one
    target moving in it by (1, 0.5) px a frame; returns the frames and the target's image
    positions."""
    rng = np.random.default_rng(seed)
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w + step * n]
    scene = 1000.0 + np.zeros(xx.shape)
    for x, y in rng.uniform((0, 0), (w + step * n, h), (120, 2)):  # bright, corner-rich blobs
        scene += 60.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 8.0)
    frames, truth = [], []
    for k in range(n):
        img = scene[:, step * k: step * k + w] + rng.normal(0.0, 3.0, (h, w))
        x, y = 50.0 + 1.0 * k, 60.0 + 0.5 * k
        add_gaussian_spot(img, x, y, 200.0, 0.8)
        frames.append(Frame(k, k / 50.0, np.clip(img, 0, 65535).astype(np.uint16)))
        truth.append((x, y))
    return frames, truth


@pytest.mark.parametrize("motion", ["auto", "off"])
def test_fusion_accepts_and_runs_with_reacquire_and_compensate_motion(motion: str) -> None:
    """``tracking.reacquire`` (a GEWC stage; the fusion tracker recovers by global detection)
    and ``tracking.compensate_motion`` (the shared front end's camera motion) are accepted:
    "auto" measures the pan, "off" assumes a still camera."""
    text = f'[tracking]\nreacquire = 30.0\ncompensate_motion = "{motion}"\n'
    cfg = config_from_dict({**tomllib.loads(text), **PLAIN}, FusionConfig)
    assert (cfg.tracking.reacquire, cfg.tracking.compensate_motion) == (30.0, motion)
    frames, truth = panning_clip()
    trk = FusionTracker(cfg)
    results = [trk.step(f) for f in frames]
    if motion == "off":
        assert all(r.front.camera is None for r in results)
    else:
        cams = [r.front.camera for r in results[1:]]
        assert all(c is not None and c.reliable for c in cams)
        np.testing.assert_allclose([c.shift for c in cams], np.tile([-2.0, 0.0], (len(cams), 1)), atol=0.2)
        assert results[-1].front.camera.moving
        assert results[-1].front.camera.offset[0] == pytest.approx(-2.0 * (len(frames) - 1), abs=1.0)
    # the target is detected near its position on every frame
    for r, (x, y) in zip(results, truth):
        assert len(r.detections) and np.min(np.hypot(*(r.detections.xy - (x, y)).T)) < 1.5


def _spot_and_ridge(n: int = 12, seed: int = 0):
    """A round spot (peak 100, σ 1 px) at (40, 40) and a ridge (a 1 px line of 11 px, +100) at
    y = 80, both still, on a background of 500 with noise σ 3."""
    rng = np.random.default_rng(seed)
    for k in range(n):
        img = 500.0 + rng.normal(0, 3.0, (120, 160))
        add_gaussian_spot(img, 40.0, 40.0, 100.0, 1.0)
        img[80, 95:106] += 100.0
        yield Frame(k, 0.02 * k, np.clip(img, 0, 65535).astype(np.uint16))


@pytest.mark.parametrize("tests,confirmed", [({}, {(40, 40), (100, 80)}),
                                             ({"confirm_blobness": 0.4, "confirm_significance": 4.0},
                                              {(40, 40)})])
def test_fusion_confirmation_tests_drop_the_ridge(tests: dict, confirmed: set) -> None:
    """Paper options (global threshold, hits) plus the blobness and significance (SCR) tests:
    both still objects are confirmed by hits, and the tests drop the ridge."""
    cfg = config_from_dict({**PLAIN, "defects": {"enabled": False}, "detection": PAPER["detection"],
                            "tracking": {**PAPER["tracking"], **tests}}, FusionConfig)
    trk = FusionTracker(cfg)
    seen = set()
    for f in _spot_and_ridge():
        r = trk.step(f)
        seen |= {(round(t.x), round(t.y)) for t in r.tracks if t.confirmed}
    assert seen == confirmed
    d = r.detections
    if tests:  # computed per candidate, window search included: hover values of the recording
        j = int(np.argmin(np.hypot(d.xy[:, 0] - 40, d.xy[:, 1] - 40)))
        assert d.significance[j] >= 4.0 and d.blobness[j] > 0.8
    else:
        assert d.significance is None and d.blobness is None
