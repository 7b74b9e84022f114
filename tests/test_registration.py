"""Camera motion (wfviz.stages.registration): the flow, its phase-correlation fallback, and
"unknown" (never "still") when neither measures the shift; the tracker's rules then do not take
static ground for movers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rerun.chunk import RrdReader

from wfviz.io.frames import Frame
from wfviz.stages.registration import CameraMotion, CameraState
from wfviz.trackers import make_tracker

H, W = 128, 160  # frame size


def ground(seed: int = 0, texture: float = 0.0, spots: int = 60, size: tuple[int, int] = (400, 700)) -> np.ndarray:
    """A scene larger than the frame: grey 1000, a smooth random texture of RMS ``texture``
    (Gaussian-blurred noise, 10 px) and ``spots`` bright point-like spots (peak 200, σ 0.8 px)."""
    rng = np.random.default_rng(seed)
    h, w = size
    g = cv2.GaussianBlur(rng.normal(0.0, 1.0, size).astype(np.float32), (0, 0), 10.0)
    g = 1000.0 + texture * g / g.std()
    yy, xx = np.mgrid[-4:5, -4:5]
    for x, y in rng.uniform((5, 5), (w - 5, h - 5), (spots, 2)):
        x0, y0 = int(x), int(y)
        g[y0 - 4:y0 + 5, x0 - 4:x0 + 5] += 200.0 * np.exp(-((xx + x0 - x) ** 2 + (yy + y0 - y) ** 2) / (2 * 0.8 ** 2))
    return g.astype(np.float32)


def pan(scene: np.ndarray, steps: list[tuple[float, float]], seed: int = 1, noise: float = 10.0
        ) -> tuple[list[np.ndarray], np.ndarray]:
    """Frames of a camera whose view moves over ``scene`` by ``steps`` (px a frame; the scene
    moves the other way in the image), with sensor noise; and the true offsets (a scene point of
    the first frame is at xy + offset)."""
    rng = np.random.default_rng(seed)
    start = pos = np.array([20.0, 100.0])
    frames, offsets = [], []
    for k in range(len(steps) + 1):
        if k:
            pos = pos + steps[k - 1]
        f = cv2.getRectSubPix(scene, (W, H), (float(pos[0] + W / 2), float(pos[1] + H / 2)))
        frames.append(np.clip(f + rng.normal(0.0, noise, f.shape), 0, 65535).astype(np.uint16))
        offsets.append(start - pos)
    return frames, np.array(offsets)


#: slow pans, a re-pointing (two jumps), a faster pan
REPOINT = [(1.0, 0.0)] * 15 + [(2.0, 0.5)] * 10 + [(25.0, 5.0), (20.0, -4.0)] + [(3.0, 0.0)] * 12


def states(frames: list[np.ndarray]) -> list[CameraState]:
    cam = CameraMotion()
    return [cam.update(f) for f in frames]


def test_the_fallback_measures_jumps_the_flow_cannot_follow() -> None:
    """Textured ground; the view jumps 46 px, then back: the flow loses its corners on the
    second jump, phase correlation measures it, the offset stays within 0.5 px of the truth
    (jumps of more than about a third of the frame are unknown: the frame's halves no longer
    overlap enough to agree)."""
    steps = [(1.0, 0.5)] * 6 + [(45.0, 10.0), (2.5, 1.5), (-45.0, 10.0)] + [(2.5, 1.5)] * 6
    frames, truth = pan(ground(texture=12.0, spots=300, size=(500, 800)), steps, noise=4.0)
    got = states(frames)
    assert all(s.reliable for s in got)
    assert "phase" in [s.method for s in got[7:10]]
    assert all(s.method == "flow" for s in got[:7])  # the key frame's corners, until the jump
    np.testing.assert_allclose([s.offset for s in got], truth, atol=0.5)
    assert got[-1].moving


def test_spots_on_flat_sky_are_measured_or_unknown_never_still() -> None:
    """A few bright spots on flat noise (too few corners for the flow): each frame's shift is
    measured within 1 px of the truth, or unknown (NaN residual, 0 confidence, shift 0 and
    method "none"); a frame measured after unknown ones carries their motion too (the key
    frame is kept), so the offset stays the truth's; most of the frames the flow lost are
    measured by phase correlation."""
    frames, truth = pan(ground(texture=0.0, spots=60), REPOINT)
    got = states(frames)
    truth = np.asarray(truth, dtype=np.float64)
    last = 0  # the last frame whose motion was measured
    for k, s in enumerate(got[1:], start=1):
        if s.reliable:
            assert np.hypot(*(np.array(s.shift) - (truth[k] - truth[last]))) < 1.0, (k, s, truth[k] - truth[last])
            last = k
        else:
            assert s.method == "none" and s.shift == (0.0, 0.0) and s.confidence == 0.0 and np.isnan(s.residual)
    methods = [s.method for s in got]
    assert methods.count("phase") > 2 * methods.count("none")


def test_a_target_over_featureless_sky_is_not_the_camera_shift() -> None:
    """A still camera on flat noise and one bright extended target crossing it at 3 px a frame:
    nothing the camera carries, so the fallback measures no shift, or about 0, never the
    target's motion (which the frames' phase correlation peaks at, response 1.1). (The flow may:
    noise corners near the target follow it in the coarse pyramid levels.)"""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:H, 0:W]
    frames = []
    for k in range(20):
        x, y = 30.0 + 3.0 * k, 40.0 + 1.5 * k
        f = 1000.0 + rng.normal(0.0, 10.0, (H, W)) + 400.0 * np.exp(-((xx - x) ** 2 / 8.0 + (yy - y) ** 2 / 4.5))
        frames.append(f.astype(np.uint16))
    got = states(frames)
    assert sum(s.method == "none" for s in got) >= 15  # the flow's few corners rarely agree
    assert all(s.method != "phase" or np.hypot(*s.shift) < 0.5 for s in got)  # the target is not the camera


def _confirmed(frames: list[np.ndarray]) -> set[int]:
    trk = make_tracker("gewc")
    out: set[int] = set()
    for k, f in enumerate(frames):
        out |= {t.track_id for t in trk.step(Frame(k, k / 25.0, f)).tracks if t.confirmed}
    return out


@pytest.mark.parametrize("forget", [True, False])
def test_scene_positions_are_not_compared_across_frames_of_unknown_motion(monkeypatch, forget: bool) -> None:
    """Static spots on textured ground under a pan of 1.5 px a frame; from frame 8 the camera's
    motion is lost (unknown, the camera known to move). The tracks are not moved, so the spots
    slide through them; the motion test compares no scene positions across the lost frames, the
    change stage compares nothing with the scene's past (and forgets it), and no spot is
    confirmed. Without these rules (``forget`` False) they are confirmed as movers."""
    from wfviz.tracking import TrackManager

    update = CameraMotion.update

    def lost_after_8(self: CameraMotion, image: np.ndarray) -> CameraState:
        s = update(self, image)
        self.frames = getattr(self, "frames", 0) + 1
        if self.frames <= 8:
            return s
        return CameraState(self.offset_at_8, (0.0, 0.0), True, 0, False, 0.0, float("nan"), "none")

    def remember(self: CameraMotion, image: np.ndarray) -> CameraState:
        s = lost_after_8(self, image)
        if self.frames == 8:
            self.offset_at_8 = s.offset
        return s

    monkeypatch.setattr(CameraMotion, "update", remember)
    if not forget:
        monkeypatch.setattr(TrackManager, "motion_unknown", lambda self: None)
        monkeypatch.setattr(CameraState, "lost", property(lambda self: False))
    frames, _ = pan(ground(texture=30.0, spots=120), [(1.5, 0.0)] * 40)
    confirmed = _confirmed(frames)
    assert (not confirmed) if forget else confirmed


def _log(rrd: Path) -> list[tuple[int, str, str]]:
    """(frame, text, level) of every TextLog line at ``/log``."""
    out = []
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path == "/log" and not chunk.is_static:
            b = chunk.to_record_batch()
            for f, texts, levels in zip(b.column("frame").to_pylist(), b.column("TextLog:text").to_pylist(),
                                        b.column("TextLog:level").to_pylist()):
                out += [(f, t, lv) for t, lv in zip(texts, levels)]
    return out


def test_a_camera_re_pointing_over_spotted_ground_gives_no_track_and_warns(tmp_path: Path) -> None:
    """GEWC on spots-only ground seen by a camera that pans and re-points (too few corners for
    the flow most of the time): no static spot is confirmed, and the recording says when phase
    correlation took over (a WARN line) and marks those frames in ``registration/fallback``."""
    from wfviz.io.clip import open_clip
    from wfviz.run import run

    frames, _ = pan(ground(texture=0.0, spots=60), REPOINT)
    np.save(tmp_path / "clip.npy", np.stack(frames))
    trk = make_tracker("gewc")
    rrd = tmp_path / "r.rrd"
    run(open_clip(tmp_path / "clip.npy"), trk, recording=rrd)
    assert not trk.manager.confirmed_ids and not any(
        "confirmed after" in t for _, t, _ in _log(rrd))
    warned = [(f, lv) for f, t, lv in _log(rrd) if t.startswith("camera motion measured by phase correlation")]
    assert warned and all(lv == "WARN" for _, lv in warned)
    fallback = {}
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path == "/registration/fallback" and not chunk.is_static:
            b = chunk.to_record_batch()
            col = [n for n in b.schema.names if n.startswith("Scalars")][0]
            fallback.update(zip(b.column("frame").to_pylist(), [v[0] for v in b.column(col).to_pylist()]))
    assert sorted(fallback) == list(range(len(frames)))
    assert set(fallback.values()) == {0.0, 1.0} and fallback[warned[0][0]] == 1.0


def test_the_change_stage_forgets_the_past_when_the_motion_is_lost() -> None:
    from wfviz.stages.background import TemporalBackground

    tb = TemporalBackground(lag=4)
    img = np.ones((16, 16), np.float32)
    assert tb.update(img, (0.0, 0.0), moving=True) is None      # no past on the first frame
    assert tb.update(img, (1.0, 0.0), moving=True) is not None
    tb.forget()
    assert tb.update(img, (2.0, 0.0), moving=True) is None      # a new history, as on the first frame
    assert CameraState((0.0, 0.0), (0.0, 0.0), True, 0, False).lost
    assert not CameraState((0.0, 0.0), (0.0, 0.0), False, 0, False).lost   # still camera: nothing to lose


def test_the_shift_s_standard_error() -> None:
    flow = CameraState((0.0, 0.0), (1.0, 0.0), True, 16, True, 0.5, 0.4, "flow")
    assert flow.error == pytest.approx(0.1)          # the corners' spread over √16
    phase = CameraState((0.0, 0.0), (1.0, 0.0), True, 3, True, 0.2, 0.3, "phase")
    assert phase.error == pytest.approx(0.3)         # the halves' disagreement
    assert np.isnan(CameraState((0.0, 0.0), (0.0, 0.0), True, 0, False).error)
