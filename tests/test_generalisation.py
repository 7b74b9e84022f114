"""Behaviour on scenes the trackers were not tuned on, default configuration (one default for
every camera): noise that varies over the frame, vignetted and gradient skies, a 180° view with
no horizon, a target that leaves the image. Built from numpy arrays, so each scene's truth is
exact."""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.io.frames import Frame
from wfviz.synth.psf import add_gaussian_spot
from wfviz.trackers import make_tracker
from wfviz.trackers.gewc import GEWCTracker

H, W = 256, 320


def run(tracker, frames: list[np.ndarray]) -> list:
    """Every frame through ``tracker``; the results."""
    return [tracker.step(Frame(i, i / 25.0, f)) for i, f in enumerate(frames)]


def to_u16(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img), 0, 65535).astype(np.uint16)


def mover(n: int, start: tuple[float, float], v: tuple[float, float]) -> np.ndarray:
    """(n, 2) positions of a constant-velocity target."""
    t = np.arange(n)[:, None]
    return np.asarray(start) + t * np.asarray(v)


def ramp_frames() -> list[np.ndarray]:
    rng = np.random.default_rng(1)
    sigma = np.linspace(3.0, 30.0, W)[None, :]
    return [to_u16(1000.0 + sigma * rng.standard_normal((H, W))) for _ in range(80)]


def leaving_frames() -> tuple[list[np.ndarray], np.ndarray]:
    rng = np.random.default_rng(4)
    truth = mover(60, (200.0, 120.0), (4.0, 0.5))
    frames = []
    for x, y in truth:
        img = np.full((H, W), 1000.0)
        add_gaussian_spot(img, x, y, 150.0, 0.8)
        frames.append(to_u16(img + 10.0 * rng.standard_normal(img.shape)))
    return frames, truth


def settled_hits(results: list, truth: np.ndarray, settle: int = 6, gate: float = 3.0) -> float:
    """Share of frames after the first ``settle`` with a confirmed track within ``gate`` px."""
    hits = [any(t.confirmed and np.hypot(t.x - x, t.y - y) <= gate for t in r.tracks)
            for r, (x, y) in zip(results[settle:], truth[settle:])]
    return float(np.mean(hits))


def false_confirmed(results: list, truth: np.ndarray | None, gate: float = 5.0) -> int:
    """Confirmed track rows farther than ``gate`` from the target (all of them without one)."""
    n = 0
    for i, r in enumerate(results):
        for t in r.tracks:
            if t.confirmed and (truth is None or np.hypot(t.x - truth[i, 0], t.y - truth[i, 1]) > gate):
                n += 1
    return n


@pytest.mark.parametrize("tracker_name", ["gewc", "fusion"])
def test_noise_ramp_gives_no_confirmed_track(tracker_name: str) -> None:
    """Noise σ growing 10x from left to right (a global threshold is too low on the right and
    too high on the left): no confirmed track, and the false detections spread evenly."""
    results = run(make_tracker(tracker_name), ramp_frames())
    assert false_confirmed(results, None) == 0
    left = sum(int((r.detections.xy[:, 0] < W / 2).sum()) for r in results[20:])
    right = sum(int((r.detections.xy[:, 0] >= W / 2).sum()) for r in results[20:])
    per_frame = (left + right) / 60
    assert per_frame < 10, per_frame
    assert right <= 3 * left + 30 and left <= 3 * right + 30, (left, right)


def test_vignetted_gradient_sky_target_is_tracked() -> None:
    """A sky brightening toward the bottom, vignetted at the rim (cos⁴), with shot noise, and
    one dim mover: tracked after confirmation, no false track."""
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    r = np.hypot(xx - W / 2, yy - H / 2) / np.hypot(W / 2, H / 2)
    sky = (2000.0 + 3000.0 * yy / H) * np.cos(np.arctan(1.2 * r)) ** 4
    truth = mover(70, (40.0, 60.0), (3.0, 1.2))
    frames = []
    for x, y in truth:
        img = sky.copy()
        add_gaussian_spot(img, x, y, 10.0 * np.sqrt(sky[int(y), int(x)] * 0.05 + 25.0), 0.8)
        frames.append(to_u16(img + np.sqrt(img * 0.05 + 25.0) * rng.standard_normal(img.shape)))
    results = run(GEWCTracker(), frames)
    assert settled_hits(results, truth) >= 0.9
    assert false_confirmed(results, truth) == 0


def test_fisheye_without_horizon() -> None:
    """A 180° view of sky only (dark outside the imaging circle, no ground): the circle is
    found, no horizon is trusted, the whole disc is searched and the target is tracked."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    inside = np.hypot(xx - W / 2, yy - H / 2) < 0.47 * H
    base = np.where(inside, 3000.0, 200.0)
    truth = mover(60, (110.0, 200.0), (2.0, -2.0))
    frames = []
    for x, y in truth:
        img = base.copy()
        add_gaussian_spot(img, x, y, 120.0, 0.8)
        frames.append(to_u16(img + 10.0 * rng.standard_normal(img.shape)))
    tracker = GEWCTracker()
    results = run(tracker, frames)
    assert results[-1].front.circle is not None
    hz = results[-1].front.horizon
    assert hz is None or hz.confidence < 0.5
    assert settled_hits(results, truth) >= 0.9
    assert false_confirmed(results, truth) == 0


@pytest.mark.parametrize("tracker_name", ["gewc", "fusion"])
def test_target_leaving_the_image_leaves_no_row_outside(tracker_name: str) -> None:
    """A target that flies out of the right edge: its track never reports a position outside
    the image (x in [-0.5, W - 0.5], y in [-0.5, H - 0.5]) and is gone within a few frames."""
    frames, _ = leaving_frames()  # leaves the image at about frame 30
    results = run(make_tracker(tracker_name), frames)
    outside = [(r.index, t.x, t.y) for r in results for t in r.tracks
               if not (-0.5 <= t.x <= W - 0.5 and -0.5 <= t.y <= H - 0.5)]
    assert outside == []
    assert any(t.confirmed for r in results[15:25] for t in r.tracks)  # it was tracked
    assert not any(t.confirmed for r in results[40:] for t in r.tracks)  # and is gone


# -- the same scenes through the command line (`wfviz track STACK.npy`, default configuration) --

def cli_tracks(tmp_path, frames: list[np.ndarray]) -> list[dict]:
    """``wfviz track`` on the frames saved as a .npy stack; the tracks CSV's rows."""
    import csv
    import subprocess
    import sys

    stack = tmp_path / "clip.npy"
    np.save(stack, np.stack(frames))
    out = tmp_path / "tracks.csv"
    p = subprocess.run([sys.executable, "-m", "wfviz", "track", str(stack), "--tracks", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    with out.open(newline="") as f:
        return list(csv.DictReader(f))


def test_cli_noise_ramp_gives_no_confirmed_track(tmp_path) -> None:
    rows = cli_tracks(tmp_path, ramp_frames())
    assert [r for r in rows if r["confirmed"] == "1"] == []


def test_cli_track_leaving_the_image_is_deleted_and_no_row_lies_outside(tmp_path) -> None:
    frames, truth = leaving_frames()
    rows = cli_tracks(tmp_path, frames)
    outside = [r for r in rows if not (-0.5 <= float(r["x"]) <= W - 0.5 and -0.5 <= float(r["y"]) <= H - 0.5)]
    assert outside == []
    confirmed = [r for r in rows if r["confirmed"] == "1"]
    near = [r for r in confirmed if np.hypot(float(r["x"]) - truth[int(r["frame"]), 0],
                                            float(r["y"]) - truth[int(r["frame"]), 1]) < 3]
    assert any(15 <= int(r["frame"]) < 25 for r in near)  # it was tracked
    assert not any(int(r["frame"]) >= 40 for r in confirmed)  # and deleted once it left
