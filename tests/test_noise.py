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


def test_quantised_flat_data_keeps_a_sigma_of_one_step() -> None:
    """Most pixels on one grey level (MAD 0): sigma is at least the data's step, so a single
    grey-level flicker is not a many-sigma detection."""
    img = np.full((64, 64), 50, np.uint8)
    img[::7, ::5] = 51
    model = NoiseModel(tile=32)
    est = model.update(img.astype(np.float32), np.ones(img.shape, bool), image=img)
    assert est.sigma.min() >= 1.0
    assert est.significance(img.astype(np.float32)).max() <= 1.5


def _tile_statistics_reference(residual, valid, tile, quantum=0.0, clip=3.5, step=2):
    """The tile statistics as first written: the frame masked and padded whole, then every
    step-th row and column of each tile read (the fast path must give exactly this)."""
    h, w = residual.shape
    ny, nx = -(-h // tile), -(-w // tile)
    padded = np.full((ny * tile, nx * tile), np.inf, dtype=np.float32)
    padded[:h, :w] = np.where(valid, residual.astype(np.float32, copy=False), np.inf)
    t = padded.reshape(ny, tile, nx, tile)[:, ::step, :, ::step].transpose(0, 2, 1, 3).reshape(ny * nx, -1)
    return _stats_of_table(t, ny, nx, quantum, clip)


def _stats_of_table(t, ny, nx, quantum, clip):
    from wfviz.stages.noise import MIN_SAMPLES, QUANTUM_FLOOR, _MAD, _Q99, _clipped_std

    n = np.isfinite(t).sum(axis=1)
    rows = np.arange(t.shape[0])
    mid = np.maximum((n - 1) // 2, 0)
    ordered = np.sort(t, axis=1)
    level = ordered[rows, mid]
    with np.errstate(invalid="ignore"):
        dev = t - level[:, None]
        mad = np.sort(np.abs(dev), axis=1)[rows, mid]
        s0 = np.maximum(_MAD * mad, quantum)
        inside = np.abs(dev) <= clip * s0[:, None]
    m = np.maximum(inside.sum(axis=1), 1)
    d = np.where(inside, dev, 0.0)
    mean = d.sum(axis=1) / m
    var = np.maximum((d * d).sum(axis=1) / m - mean * mean, 0.0)
    sigma = np.maximum(np.sqrt(var) / _clipped_std(clip), max(QUANTUM_FLOOR * quantum, 1e-6))
    q99 = ordered[rows, np.maximum(np.rint(0.99 * (n - 1)).astype(np.int64), 0)]
    with np.errstate(invalid="ignore"):
        tail = (q99 - level) / sigma / _Q99
    few = n < MIN_SAMPLES
    level, sigma, tail = (np.where(few, np.nan, a) for a in (level, sigma, tail))
    return level.reshape(ny, nx), sigma.reshape(ny, nx), tail.reshape(ny, nx), n.reshape(ny, nx)


@pytest.mark.parametrize("tile", [8, 9, 16, 32, 33])
@pytest.mark.parametrize("shape", [(100, 130), (64, 64), (97, 101), (512, 640)])
def test_tile_statistics_equal_the_whole_frame_formula(tile: int, shape: tuple[int, int]) -> None:
    """The fast path (subsample, then mask and pad) gives exactly the statistics of masking and
    padding the whole frame and reading every 2nd row and column of each tile."""
    from wfviz.stages.noise import tile_statistics

    rng = np.random.default_rng(tile * 1000 + shape[0])
    residual = rng.normal(0, 3, shape).astype(np.float32)
    valid = rng.random(shape) > 0.3
    got = tile_statistics(residual, valid, tile, 1.0)
    want = _tile_statistics_reference(residual, valid, tile, 1.0)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
