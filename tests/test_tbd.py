"""Multi-target particle-filter track-before-detect (``--tracker tbd``, METHODS.md section 4)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from collections import defaultdict
from dataclasses import replace

import numpy as np
import pytest

from wfviz.config import ConfigError, config_from_dict, config_to_toml
from wfviz.io.frames import Frame
from wfviz.synth.psf import add_gaussian_spot
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers import TRACKERS, make_tracker
from wfviz.trackers.tbd import TBDTracker
from wfviz.trackers.tbd.config import TBDConfig
from wfviz.trackers.tbd.model import likelihood, psf_patch

SIGMA, LEVEL = 20.0, 1000.0


def noise_clip(n: int, seed: int, shape=(64, 64), targets=()):
    """uint16 frames of Gaussian noise (sigma 20 on 1000) with point targets: each target is
    (first, last, x0, y0, vx, vy, peak SNR), PSF sigma 0.8 px (as lowsnr-tbd)."""
    g = np.random.default_rng(seed)
    frames, truth = [], defaultdict(list)
    for k in range(n):
        img = LEVEL + SIGMA * g.standard_normal(shape)
        for i, (first, last, x0, y0, vx, vy, snr) in enumerate(targets):
            if first <= k <= last:
                x, y = x0 + vx * (k - first), y0 + vy * (k - first)
                add_gaussian_spot(img, x, y, snr * SIGMA, 0.8)
                truth[k].append((i, x, y))
        frames.append(Frame(k, k / 10.0, np.clip(np.rint(img), 0, 65535).astype(np.uint16)))
    return frames, truth


def test_registered_and_config_round_trips():
    assert TRACKERS["tbd"][:2] == (TBDTracker, TBDConfig)
    text = config_to_toml(TBDConfig())
    assert config_from_dict(tomllib.loads(text), TBDConfig) == TBDConfig()
    with pytest.raises(ConfigError, match="tile_overlap"):
        config_from_dict({"regions": {"tile": 32, "tile_overlap": 32}}, TBDConfig)
    with pytest.raises(ConfigError, match="did you mean 'p_birth'"):
        config_from_dict({"filter": {"p_brith": 0.1}}, TBDConfig)


def test_cli_prints_a_loadable_config(tmp_path):
    out = subprocess.run([sys.executable, "-m", "wfviz", "config", "--tracker", "tbd"], capture_output=True,
                         text=True, timeout=120, check=True).stdout
    (tmp_path / "tbd.toml").write_text(out)
    assert config_from_dict(tomllib.loads(out), TBDConfig) == TBDConfig()
    assert "[filter]" in out and "max_targets = 3" in out


def test_overlapping_hypotheses_do_not_double_count_one_spot():
    """Two hypothesised targets on one spot explain it no better than one (cross terms B_jl):
    the likelihood of the pair is within the Occam penalty of the single target's, never the
    square of it."""
    y = np.zeros((21, 21))
    y[8:13, 8:13] = 6.0 * psf_patch(0.8, 2, 0.2, -0.3)
    one = np.array([[[10.2, 0, 9.7, 0]]])
    two = np.array([[[10.2, 0, 9.7, 0], [10.25, 0, 9.75, 0]]])
    lr1, m1, v1 = likelihood(y, one, np.full((1, 1), 4.0), np.full((1, 1), 9.0), 0.8, 2, 1.0)
    lr2, _, _ = likelihood(y, two, np.full((1, 2), 4.0), np.full((1, 2), 9.0), 0.8, 2, 1.0)
    assert lr1[0] > 20 and abs(m1[0, 0] - 6.0) < 0.5 and v1[0, 0] < 1.0
    assert lr2[0] < lr1[0] + 1.0
    far = np.array([[[3.0, 0, 3.0, 0]]])  # no signal there: the ratio is below 1
    assert likelihood(y, far, np.full((1, 1), 4.0), np.full((1, 1), 9.0), 0.8, 2, 1.0)[0][0] < 0


def test_single_target_at_snr5_found_within_5_frames_and_within_1px():
    appear = 3
    frames, truth = noise_clip(25, 7, targets=[(appear, 99, 20.3, 40.6, 0.45, -0.35, 5.0)])
    tracker = TBDTracker()
    found, ids = None, set()
    for f in frames:
        r = tracker.step(f)
        conf = [t for t in r.tracks if t.confirmed]
        if f.index < appear:
            continue
        (_, x, y), = truth[f.index]
        near = [t for t in conf if np.hypot(t.x - x, t.y - y) < 1.0]
        if found is None and near:
            found = f.index
        if found is not None:
            assert len(conf) == 1 and near, (f.index, conf, (x, y))
            ids.add(conf[0].track_id)
            assert r.count == 1 and r.p_count[1] > 0.9
    assert found is not None and found - appear <= 4, found
    assert len(ids) == 1


def test_empty_clip_keeps_p0_above_0_9():
    frames, _ = noise_clip(30, 11)
    tracker = TBDTracker()
    for f in frames:
        r = tracker.step(f)
        assert r.p_count[0] > 0.9, (f.index, r.p_count)
        assert r.count == 0 and not [t for t in r.tracks if t.confirmed]


def test_lowsnr_scenario_count_follows_truth_within_the_latency():
    """Targets appear (frames 3, 8, 13) and disappear (after 17, 22, 27) at peak SNR 3: the
    count estimate equals the true count of one of the last 5 frames in >= 90 % of frames,
    reaches every count 1..3 and is back to 0 at the end."""
    clip = make_scenario("lowsnr-tbd", seed=0, snr=3.0)
    true = np.zeros(clip.n_frames, dtype=int)
    for row in clip.truth():
        true[row.frame] += row.visible
    tracker = TBDTracker()
    est = np.array([tracker.step(f).count for f in clip.frames()])
    ok = [est[k] in set(true[max(0, k - 4):k + 1]) for k in range(len(true))]
    assert np.mean(ok) >= 0.9, (est, true)
    assert set(est[:3]) == {0} and est[-1] == 0
    assert {1, 2, 3} <= set(est.tolist())


def test_same_seed_same_output_other_seed_other_particles():
    frames, _ = noise_clip(8, 3, targets=[(0, 99, 30.0, 30.0, 0.3, 0.2, 4.0)])

    def run(seed: int):
        tr = TBDTracker(replace(TBDConfig(), filter=replace(TBDConfig().filter, seed=seed)))
        return [tr.step(f) for f in frames]

    a, b, c = run(0), run(0), run(1)
    for ra, rb in zip(a, b):
        assert ra.tracks == rb.tracks
        np.testing.assert_array_equal(ra.p_count, rb.p_count)
        np.testing.assert_array_equal(ra.particles, rb.particles)
    assert not np.array_equal(a[-1].particles, c[-1].particles)


def test_large_frames_run_over_candidate_windows_and_tiles():
    frames, truth = noise_clip(12, 5, shape=(160, 200), targets=[(0, 99, 120.4, 70.7, 0.5, 0.4, 8.0)])
    for mode in ("candidates", "tiles"):
        cfg = replace(TBDConfig(), regions=replace(TBDConfig().regions, mode=mode))
        tracker = make_tracker("tbd", cfg)
        for f in frames:
            r = tracker.step(f)
        (_, x, y), = truth[frames[-1].index]
        conf = [t for t in r.tracks if t.confirmed]
        assert len(conf) == 1 and np.hypot(conf[0].x - x, conf[0].y - y) < 1.0, (mode, conf)
        kinds = {g.kind for g in r.regions}
        assert kinds == {"window" if mode == "candidates" else "tile"}
        if mode == "tiles":
            assert len(r.regions) == 12  # 3 x 4 tiles of 64 px overlapping by 8 over 160 x 200
    auto = TBDTracker()
    auto.step(Frame(0, 0.0, frames[0].image))
    assert auto._mode == "candidates"  # 160 x 200 > regions.full_max_pixels


def test_recording_has_the_tbd_entities(tmp_path):
    from rerun.chunk import RrdReader

    from wfviz.record_options import RecorderOptions
    from wfviz.run import run

    clip = make_scenario("lowsnr-tbd", seed=0, snr=5.0, n_frames=12)
    shown, hidden = defaultdict(list), defaultdict(list)
    for row in clip.truth():
        (shown if row.visible else hidden)[row.frame].append((row.target_id, row.x, row.y))
    rrd, csv = tmp_path / "t.rrd", tmp_path / "t.csv"
    summary = run(clip, make_tracker("tbd"), tracks_csv=csv, recording=rrd,
                  recorder_options=RecorderOptions(source="lowsnr-tbd", config_text="", image_every=4),
                  truth=(dict(shown), dict(hidden)))
    assert summary.scores.pd > 0.5
    frames: dict[str, set] = defaultdict(set)
    texts = []
    for chunk in RrdReader(rrd).stream():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if "frame" in batch.schema.names:
            frames[chunk.entity_path].update(batch.column("frame").to_pylist())
        if chunk.entity_path == "/log":
            texts += [t for row in batch.column("TextLog:text").to_pylist() for t in (row or [])]
    every = set(range(12))
    for path in ["/tbd/particles", "/camera/predictions", "/camera/tracks", "/tbd/count", "/tbd/noise_sigma",
                 *[f"/tbd/p_count/{n}" for n in range(4)], "/timing/likelihood", "/timing/total"]:
        assert frames[path] == every, path
    assert frames["/suppressed/image"] == {0, 4, 8}
    assert any(p.startswith("/tbd/") and p.endswith("/amplitude") for p in frames)
    assert any("target count estimate 0 -> 1" in t for t in texts), texts
