"""Multi-frame detection (issue 36): the DP track-before-detect score of the change
significance finds a dim mover on frames where no single frame does, static structure gains
nothing from it, pure noise gives no confirmed track, and its hits carry no evidence of their own."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from wfviz.config import load_config
from wfviz.io.frames import Frame
from wfviz.stages.multiframe import MotionIntegrator
from wfviz.trackers import config_class, make_tracker

H, W = 128, 160
SIGMA = 10.0


def _spot(frame: np.ndarray, x: float, y: float, amplitude: float, width: float = 0.8) -> None:
    yy, xx = np.mgrid[0:frame.shape[0], 0:frame.shape[1]]
    frame += amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * width ** 2))


def _clip(n: int, draw, background: np.ndarray | None = None, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    base = np.full((H, W), 1000.0) if background is None else background
    out = []
    for k in range(n):
        f = base.copy()
        draw(k, f)
        f += rng.normal(0.0, SIGMA, f.shape)
        out.append(np.clip(f, 0, 65535).astype(np.uint16))
    return out


def _heads_near(frames: list[np.ndarray], where, config=None) -> tuple[list[bool], list[bool], list]:
    """Per frame: a detection within 2 px of ``where(k)`` found by the multi-frame stage only
    (its own significance below the threshold), one found by the single frame, and the results."""
    trk = make_tracker("gewc", config)
    multi, single, results = [], [], []
    for k, f in enumerate(frames):
        r = trk.step(Frame(k, k / 25.0, f))
        results.append(r)
        d = r.detections
        x, y = where(k)
        near = np.hypot(d.xy[:, 0] - x, d.xy[:, 1] - y) <= 2.0 if len(d) else np.zeros(0, bool)
        k_sigma = trk.config.detection.k_sigma
        sig = d.significance if d.significance is not None else np.zeros(len(d))
        multi.append(bool((near & (sig < k_sigma)).any()))
        single.append(bool((near & (sig >= k_sigma)).any()))
    return multi, single, results


def test_a_path_gains_and_a_fixed_point_does_not() -> None:
    """The integrator itself: 1 σ a frame along a path moving 1 px a frame approaches
    1 / (1 − λ); the same at one fixed pixel gains only through neighbours it must leave."""
    lam = 0.85
    mi = MotionIntegrator(memory=lam, clip=3.0)
    fixed = MotionIntegrator(memory=lam, clip=3.0)
    for k in range(60):
        c = np.zeros((20, 80), np.float32)
        c[10, 5 + k] = 1.0
        a = mi.update(c)
        s = np.zeros((20, 80), np.float32)
        s[10, 40] = 1.0
        b = fixed.update(s)
    assert a[10, 64] == pytest.approx(1.0 / (1.0 - lam), rel=0.01)
    assert b[10, 40] == pytest.approx(1.0 / (1.0 - lam * lam), rel=0.01)  # every other frame only
    clipped = MotionIntegrator(clip=3.0).update(np.full((4, 4), 50.0, np.float32))
    assert float(clipped.max()) == 3.0  # a bright target lends at most the clip
    nan = MotionIntegrator().update(np.full((4, 4), np.nan, np.float32))
    assert not np.isnan(nan).any() and float(np.abs(nan).max()) == 0.0  # unknown: no evidence


@pytest.mark.parametrize("speed", [0.7, 1.5])
def test_a_dim_mover_is_found_by_the_multi_frame_stage(speed: float) -> None:
    """Peak 4 σ of the sensor noise (about 2–3 σ in the residual), moving at ``speed`` px a
    frame: after the score settles, the multi-frame stage finds it on most frames the single
    frame misses, and the tracker keeps a track on it."""
    x0, y = 20.0, 64.0
    frames = _clip(80, lambda k, f: _spot(f, x0 + speed * k, y, 4.0 * SIGMA))
    base = load_config(None, config_class("gewc"))  # the stage alone: no sub-threshold reads
    base = replace(base, tracking=replace(base.tracking, read_misses=False))
    multi, single, results = _heads_near(frames, lambda k: (x0 + speed * k, y), base)
    late = range(30, 80)
    found = [multi[k] or single[k] for k in late]
    assert sum(found) >= 0.6 * len(late), (sum(multi[30:]), sum(single[30:]))
    assert sum(multi[k] and not single[k] for k in late) >= 0.3 * len(late)  # what it adds
    off = replace(base, detection=replace(base.detection, multi_memory=0.0))
    m_off, s_off, r_off = _heads_near(frames, lambda k: (x0 + speed * k, y), off)
    assert not any(m_off)  # off: no multi-frame detection
    assert sum(found) > sum(s_off[k] for k in late)

    def tracked(rs: list) -> int:  # frames with a confirmed track within 3 px of the target
        return sum(any(t.confirmed and np.hypot(t.x - x0 - speed * k, t.y - y) <= 3.0 for t in rs[k].tracks)
                   for k in late)
    assert tracked(results) >= tracked(r_off) + 10, (tracked(results), tracked(r_off))


def test_static_structure_gains_nothing() -> None:
    """A fixed point of the same brightness on textured ground: it never changes at its place in
    the scene, so no path head forms on it."""
    rng = np.random.default_rng(5)
    ground = 1000.0 + cv2.GaussianBlur(rng.normal(0.0, 40.0, (H, W)), (0, 0), 2.0)
    frames = _clip(60, lambda k, f: _spot(f, 80.0, 70.0, 4.0 * SIGMA), background=ground)
    multi, _, results = _heads_near(frames, lambda k: (80.0, 70.0))
    assert not any(multi[10:])
    m = results[-1].front.multiframe
    assert m is not None and float(np.max(m[66:75, 76:85])) < 4.0


def test_pure_noise_with_a_gradient_gives_no_confirmed_track() -> None:
    """100 frames of σ noise on a sloping background: whatever the multi-frame stage finds,
    no track is confirmed (its hits carry no evidence of their own)."""
    ramp = 1000.0 + np.linspace(0.0, 400.0, W)[None, :] + np.linspace(0.0, 200.0, H)[:, None]
    frames = _clip(100, lambda k, f: None, background=ramp, seed=3)
    _, _, results = _heads_near(frames, lambda k: (-100.0, -100.0))
    assert not any(t.confirmed for r in results for t in r.tracks)


def test_fusion_has_no_multi_frame_stage_by_default() -> None:
    assert load_config(None, config_class("fusion")).detection.multi_memory == 0.0
    assert load_config(None, config_class("gewc")).detection.multi_memory > 0.0
