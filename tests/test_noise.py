"""Local noise estimate and tail calibration (wfviz.stages.noise) on noise of known statistics."""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.stages.background import suppress_background
from wfviz.stages.noise import NoiseModel, TailCalibration, data_quantum, tile_statistics


def test_tile_sigma_follows_a_noise_ramp_and_ignores_a_bright_spot() -> None:
    rng = np.random.default_rng(0)
    h, w, tile = 256, 512, 32
    sigma = np.repeat(np.linspace(2.0, 20.0, w // tile), tile)[None, :]
    img = 100.0 + sigma * rng.standard_normal((h, w))
    img[100:103, 200:203] += 500.0  # a target: the tile's statistics must not see it
    level, sig, _, n = tile_statistics(img, np.ones((h, w), bool), tile)
    want = sigma[0, ::tile][None, :]
    ratio = sig / want  # 256 samples a tile: a few per cent of sampling error each
    assert np.all(np.abs(ratio - 1.0) < 0.2)
    assert abs(float(np.mean(ratio)) - 1.0) < 0.03
    assert np.all(np.abs(level - 100.0) < 0.3 * want)  # the median: 0.08 sigma of sampling error
    assert n.min() == (tile // 2) ** 2


def test_white_noise_significance_rate_is_near_gaussian() -> None:
    """The 5x5 top-hat residual of white Gaussian noise, standardised by the local estimate:
    the share above 4 is of the order of a Gaussian's 3.2e-5 (not 10x more or less)."""
    rng = np.random.default_rng(1)
    model = NoiseModel(tile=32, smoothing=0.0)
    exceed, total = 0, 0
    for _ in range(10):
        img = (1000.0 + 10.0 * rng.standard_normal((256, 320))).astype(np.float32)
        res = suppress_background(img, 5, "opening")
        valid = np.ones(res.shape, bool)
        z = model.update(res, valid).significance(res)
        exceed += int((z > 4.0).sum())
        total += z.size
    rate = exceed / total
    assert 3e-6 < rate < 3e-4, rate


def test_tail_calibration_is_one_for_gaussian_noise_and_more_for_a_heavy_tail() -> None:
    rng = np.random.default_rng(2)
    gauss, heavy = TailCalibration(32), TailCalibration(32)
    valid = np.ones((256, 256), bool)
    for _ in range(8):
        g = gauss.update(rng.standard_normal((256, 256)).astype(np.float32), valid)
        t = rng.standard_t(3, (256, 256)).astype(np.float32)  # Student t, 3 dof: heavy tail
        f = heavy.update(t, valid)
    assert np.median(g) == pytest.approx(1.0, abs=0.08)
    assert np.median(f) > 1.4


def test_tail_calibration_learns_as_fast_whatever_the_refresh() -> None:
    """Updated every 4th frame it reaches the every-frame factor after as many frames."""
    rng = np.random.default_rng(3)
    valid = np.ones((128, 128), bool)
    every, sparse = TailCalibration(32), TailCalibration(32, refresh=4)
    for i in range(8):
        t = rng.standard_t(3, (128, 128)).astype(np.float32)
        fe = every.update(t, valid)
        if i % 4 == 0:
            fs = sparse.update(t, valid)
    assert np.median(fs) > 1.3 and np.median(fe) > 1.3


def test_data_quantum_of_stretched_8_bit_data() -> None:
    img = (np.arange(16, dtype=np.uint8) * 17).reshape(4, 4)
    assert data_quantum(img) == 17.0
    assert data_quantum(np.array([[3, 4], [5, 9]], dtype=np.uint16)) == 1.0
    assert data_quantum(np.zeros((2, 2), np.float32)) == 0.0
    # signed data whose gaps exceed the type's range (an int8 difference of 200 wrapped to -56)
    assert data_quantum(np.array([[-100, 100]], np.int8)) == 200.0
    assert data_quantum(np.array([[-32768, 32767]], np.int16)) == 65535.0
    assert data_quantum(np.array([[-(2 ** 31), 2 ** 31 - 1]], np.int32)) == 2.0 ** 32 - 1
    assert data_quantum(np.array([[5, 5], [5, 5]], np.uint16)) == 1.0  # one grey level
    assert data_quantum(np.zeros((0, 3), np.uint16)) == 1.0


def test_quantised_flat_data_keeps_a_sigma_of_one_step() -> None:
    """Most pixels on one grey level (MAD 0): sigma is at least the data's step, so a single
    grey-level flicker is not a many-sigma detection."""
    img = np.full((64, 64), 50, np.uint8)
    img[::7, ::5] = 51
    model = NoiseModel(tile=32)
    est = model.update(img.astype(np.float32), np.ones(img.shape, bool), image=img)
    assert est.sigma.min() >= 1.0
    assert est.significance(img.astype(np.float32)).max() <= 1.5


@pytest.mark.parametrize("tile", [8, 9, 16, 32, 33])
@pytest.mark.parametrize("shape", [(100, 130), (64, 64), (97, 101), (512, 640)])
def test_tile_samples_equal_the_whole_frame_formula(tile: int, shape: tuple[int, int]) -> None:
    """The fast path (subsample the frame, then mask and pad) gives exactly the samples of masking
    and padding the whole frame and reading every 2nd row and column of each tile."""
    from wfviz.stages.noise import tile_samples

    rng = np.random.default_rng(tile * 1000 + shape[0])
    residual = rng.normal(0, 3, shape).astype(np.float32)
    valid = rng.random(shape) > 0.3
    h, w = shape
    ny, nx = -(-h // tile), -(-w // tile)
    padded = np.full((ny * tile, nx * tile), np.inf, dtype=np.float32)
    padded[:h, :w] = np.where(valid, residual, np.inf)
    want = padded.reshape(ny, tile, nx, tile)[:, ::2, :, ::2].transpose(0, 2, 1, 3).reshape(ny * nx, -1)
    np.testing.assert_array_equal(tile_samples(residual, valid, tile), want)


def test_nearest_tiles_equal_scipy_feature_transform_ties_included() -> None:
    """``nearest_tiles`` (the gap filling of the tile grids) returns SciPy's exact Euclidean
    feature transform, whose ties decide which tile a masked one copies."""
    from scipy import ndimage

    from wfviz.stages.noise import fill_missing, nearest_tiles

    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(400):
        h, w = rng.integers(1, 30, 2)
        bad = rng.random((h, w)) < rng.random() ** 0.3
        if bad.all() or not bad.any():
            continue
        want = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
        rows, cols = nearest_tiles(bad)
        assert np.array_equal(rows, want[0]) and np.array_equal(cols, want[1]), (h, w)
        checked += 1
    assert checked > 300
    grid = np.array([[np.nan, 2.0, np.nan], [np.nan, np.nan, np.nan], [5.0, np.nan, np.nan]])
    assert fill_missing(grid, 0.0).tolist() == [[2.0, 2.0, 2.0], [5.0, 2.0, 2.0], [5.0, 5.0, 5.0]]
    assert fill_missing(np.full((2, 2), np.nan), 7.0).tolist() == [[7.0, 7.0], [7.0, 7.0]]


def test_tile_sums_count_each_tile() -> None:
    """The tail calibration's per-tile pixel counts equal a count tile by tile, frames whose size
    is not a multiple of the tile included."""
    from wfviz.stages.noise import _tile_sums

    rng = np.random.default_rng(3)
    for h, w, tile in ((64, 96, 16), (50, 70, 16), (512, 640, 32), (33, 17, 8)):
        mask = rng.random((h, w)) < 0.3
        ny, nx = -(-h // tile), -(-w // tile)
        want = np.array([[mask[i * tile:(i + 1) * tile, j * tile:(j + 1) * tile].sum() for j in range(nx)]
                         for i in range(ny)])
        got = _tile_sums(mask, tile, ny, nx)
        assert got.dtype == np.int64 and np.array_equal(got, want)
        assert np.array_equal(_tile_sums(mask[::2, ::2], tile // 2, ny, nx),
                              np.array([[mask[::2, ::2][i * tile // 2:(i + 1) * tile // 2,
                                                        j * tile // 2:(j + 1) * tile // 2].sum()
                                         for j in range(nx)] for i in range(ny)]))
