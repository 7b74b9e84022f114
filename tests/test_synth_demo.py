"""Tests for the synthetic PSF and the built-in demo clip."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from wfviz.io.frames import Clip
from wfviz.synth import DemoClip, add_gaussian_spot, demo_clip, gaussian_spot_image, horizon_row
from wfviz.synth.demo import _disc_coverage


@pytest.fixture(scope="module")
def clip() -> DemoClip:
    return demo_clip()


def _track(clip: DemoClip, target_id: int) -> dict[int, np.ndarray]:
    return {p.frame: np.array([p.x, p.y]) for p in clip.truth() if p.target_id == target_id}


@pytest.mark.parametrize(
    ("x", "y", "sigma", "sigma_y"),
    [(20.0, 20.0, 0.9, None), (20.3, 17.71, 0.9, None), (19.5, 21.27, 1.7, None),
     (21.13, 18.42, 0.8, 1.3)],
)
def test_spot_flux_and_centroid(x: float, y: float, sigma: float, sigma_y: float | None) -> None:
    image = np.zeros((40, 40), dtype=np.float64)
    add_gaussian_spot(image, x, y, 250.0, sigma, sigma_y)
    sy = sigma if sigma_y is None else sigma_y
    assert image.sum() == pytest.approx(250.0 * 2 * math.pi * sigma * sy, rel=0.01)
    rows, cols = np.indices(image.shape)
    assert (image * cols).sum() / image.sum() == pytest.approx(x, abs=0.01)
    assert (image * rows).sum() / image.sum() == pytest.approx(y, abs=0.01)


def test_spot_patch_is_local_and_clipped_at_border() -> None:
    image = gaussian_spot_image((30, 30), 0.2, 29.6, 100.0, 1.0)
    assert image[:, 10:].sum() == 0 and image[:20, :].sum() == 0
    assert image[29, 0] > 0
    float32 = np.zeros((30, 30), dtype=np.float32)
    add_gaussian_spot(float32, 15.0, 15.0, 100.0, 1.0)
    assert float32.dtype == np.float32 and float32.max() > 0
    with pytest.raises(TypeError):
        add_gaussian_spot(np.zeros((5, 5), dtype=np.uint16), 2.0, 2.0, 1.0, 1.0)


def test_clip_protocol_and_format(clip: DemoClip) -> None:
    assert isinstance(clip, Clip)
    assert (clip.name, clip.fps, clip.n_frames, clip.shape) == ("demo", 20.0, 160, (512, 640))
    frame = next(clip.frames(start=5))
    assert frame.index == 5 and frame.time == pytest.approx(0.25)
    assert frame.image.dtype == np.uint16 and frame.image.shape == (512, 640)
    assert [f.index for f in clip.frames(157, 999)] == [157, 158, 159]


def test_truth_lies_on_rendered_spots(clip: DemoClip) -> None:
    """Brightest matched-filtered pixel near each resolvable target is within 1 px of it."""
    rows, cols = np.indices(clip.shape)
    for index in (0, 29, 30, 55, 74, 76, 77, 78, 80, 82, 110, 159):
        diff = clip.render(index).astype(np.float32) - clip.background
        diff = cv2.GaussianBlur(diff, (0, 0), 1.0)  # matched filter: PSF sigma ~ 1 px
        noise = 1.4826 * float(np.median(np.abs(diff)))  # robust std of filtered noise
        points = clip.truth_at(index)
        assert len(points) == (3 if index < 30 else 4)
        for p in points:
            if min(math.hypot(p.x - q.x, p.y - q.y) for q in points if q != p) < 4.0:
                continue  # merged with the other crossing target
            near = np.hypot(cols - p.x, rows - p.y) <= 2.0
            r, c = np.unravel_index(np.argmax(np.where(near, diff, -np.inf)), diff.shape)
            assert math.hypot(c - p.x, r - p.y) <= 1.0, (index, p)
            assert diff[r, c] > 6.0 * noise, (index, p)


def test_deterministic_per_seed() -> None:
    a, b = demo_clip(seed=3, n_frames=10), demo_clip(seed=3, n_frames=10)
    first = [f.image for f in a.frames()]
    assert all(np.array_equal(i, j) for i, j in zip(first, (f.image for f in a.frames())))
    assert all(np.array_equal(i, f.image) for i, f in zip(first[6:], b.frames(start=6)))
    assert np.array_equal(first[4], b.render(4))
    other = demo_clip(seed=4, n_frames=10).render(4)
    assert not np.array_equal(first[4], other)
    assert not np.array_equal(first[4], first[5])


def test_targets_1_and_2_cross(clip: DemoClip) -> None:
    t1, t2 = _track(clip, 1), _track(clip, 2)
    frames = sorted(set(t1) & set(t2))
    dist = np.array([np.linalg.norm(t1[f] - t2[f]) for f in frames])
    assert dist.min() < 3.0
    close = [f for f, d in zip(frames, dist) if d < 20.0]
    assert close == list(range(close[0], close[-1] + 1))  # one run of consecutive frames
    assert 6 <= len(close) <= 14 and 70 <= frames[int(dist.argmin())] <= 90
    f = frames[int(dist.argmin())]
    v1, v2 = t1[f + 1] - t1[f - 1], t2[f + 1] - t2[f - 1]
    angle = math.degrees(math.acos(v1 @ v2 / np.linalg.norm(v1) / np.linalg.norm(v2)))
    assert 90.0 <= angle <= 120.0


def test_target_presence_and_speed(clip: DemoClip) -> None:
    for target_id in (1, 2, 3, 4):
        track = _track(clip, target_id)
        first = 30 if target_id == 4 else 0
        assert sorted(track) == list(range(first, 160))
        steps = np.linalg.norm(np.diff(np.array(list(track.values())), axis=0), axis=1)
        assert steps.min() >= 1.5 and steps.max() <= 3.0
    assert all(len(clip.truth_at(f)) == 3 for f in range(30))


def test_truth_inside_circle_and_above_horizon(clip: DemoClip) -> None:
    cx, cy, radius = clip.circle
    xy = np.array([(p.x, p.y) for p in clip.truth()])
    assert (radius - np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) >= 20.0).all()
    assert (clip.horizon_row(xy[:, 0]) - xy[:, 1] >= 20.0).all()


def test_horizon_geometry_and_rendering(clip: DemoClip) -> None:
    cx, cy, radius = clip.circle
    focal = radius / (math.pi / 2)
    centre_row = cy + focal * math.radians(25.0)
    assert horizon_row(np.array([cx]))[0] == pytest.approx(centre_row, abs=1e-3)
    assert np.isnan(horizon_row(np.array([cx - radius - 1.0, cx + radius + 1.0]))).all()
    assert horizon_row(np.array([cx - radius + 0.01]))[0] == pytest.approx(cy, abs=0.5)
    bg = clip.background
    for col in (150, 230, 340, 480):
        row = int(round(horizon_row(np.array([float(col)]))[0]))
        assert bg[row - 3, col] < 7300.0 < 8000.0 < bg[row + 3, col]


def test_dark_outside_circle_bright_sky(clip: DemoClip) -> None:
    image = clip.render(12).astype(np.float64)
    cx, cy, radius = clip.circle
    rows, cols = np.indices(image.shape)
    dist = np.hypot(cols - cx, rows - cy)
    outside = image[dist > radius + 2]
    assert abs(outside.mean() - 800.0) < 5.0 and outside.std() < 40.0
    sky = image[(dist < radius - 5) & (rows < horizon_row(cols.astype(float)) - 10)]
    assert sky.min() > 4000.0 and 5000.0 < sky.mean() < 7000.0
    assert _disc_coverage().sum() == pytest.approx(math.pi * radius**2, rel=1e-4)


def test_save_writes_pngs_and_truth(clip: DemoClip, tmp_path: Path) -> None:
    clip.save(tmp_path, start=29, stop=31)
    for index in (29, 30):
        png = cv2.imread(str(tmp_path / f"frame_{index:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint16 and np.array_equal(png, clip.render(index))
    with (tmp_path / "truth.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["frame", "target_id", "x", "y", "peak"]
    assert [(int(r[0]), int(r[1])) for r in rows[1:]] == [(29, 1), (29, 2), (29, 3),
                                                        (30, 1), (30, 2), (30, 3), (30, 4)]
    truth = clip.truth_at(30)[3]
    assert float(rows[-1][2]) == pytest.approx(truth.x, abs=5e-5)
    assert rows[-1][3] == f"{truth.y:.4f}"
