"""Local background level and noise σ of the background-suppressed residual (not in the paper).

The paper thresholds the residual at one global ``mean + k·std`` (GEWC, Zhang et al. 2018,
§2.3). Real skies brighten toward the horizon, vignetting dims the rim, shot noise grows with
the signal and textured ground is rougher than sky, so one global level is too high in one
place and too low in another. Here the residual is described locally, tile by tile, with
robust statistics that ignore the few pixels a target or a clutter spot occupies:

- ``level``: the median of the tile's residual;
- ``sigma``: the standard deviation of the tile's residual within ``clip`` robust sigmas of
  that median (the robust sigma is 1.4826 × the median absolute deviation, at least one grey
  level ``quantum``, so that coarsely quantised data, where most pixels share one value, still
  gets a non-zero spread), corrected for the clipping.

The tile grids are smoothed in time (:class:`NoiseModel`) and interpolated bilinearly to
every pixel. A residual pixel's significance is ``(residual - level) / sigma``; under white
Gaussian noise the 5×5 top-hat residual standardised this way exceeds 4 in 1.0e-4 of the
pixels (40 frames of 256×320; a Gaussian: 3.2e-5): the top-hat's residual is skewed, which
the tail calibration (:class:`TailCalibration`) measures and corrects; ``tests/test_noise.py``
checks the order of magnitude.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from wfviz import normal

_MAD = 1.4826  # MAD -> sigma for Gaussian data
_Q99 = 2.3263  # 99th percentile of a unit Gaussian
MIN_SAMPLES = 32  # a tile with fewer valid samples takes its nearest neighbour's statistics
QUANTUM_FLOOR = 1.0  # sigma is at least this many grey levels (the data's step)


@dataclass(frozen=True)
class NoiseEstimate:
    """Per-pixel background ``level`` and noise ``sigma`` (float32, the frame's shape) of the
    residual, from the tile grids ``level_grid`` / ``sigma_grid`` (``tile`` px tiles)."""

    level: np.ndarray
    sigma: np.ndarray
    level_grid: np.ndarray
    sigma_grid: np.ndarray
    tile: int
    quantum: float
    _medians: dict[float | None, float] = field(default_factory=dict, init=False, repr=False, compare=False)

    def typical_threshold(self, k_sigma: float) -> float:
        """The typical "cfar" threshold (DN): the median over the tile grid of level + ``k_sigma``
        σ (inf when no tile is known); computed once per ``k_sigma`` (an estimate serves
        several frames and two stages)."""
        k = float(k_sigma)
        if k not in self._medians:
            grid = self.level_grid + k * self.sigma_grid
            self._medians[k] = float(np.nanmedian(grid)) if np.isfinite(grid).any() else float("inf")
        return self._medians[k]

    def typical_sigma(self) -> float:
        """The median σ over the tile grid (NaN when no tile is known), computed once."""
        if None not in self._medians:
            finite = np.isfinite(self.sigma_grid).any()
            self._medians[None] = float(np.nanmedian(self.sigma_grid)) if finite else float("nan")
        return self._medians[None]

    def significance(self, residual: np.ndarray) -> np.ndarray:
        """(residual - level) / sigma, float32."""
        z = np.subtract(residual, self.level, dtype=np.float32)
        return np.divide(z, self.sigma, out=z)

    def at(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(level, sigma) at the pixels nearest the points ``xy`` (N, 2) = (x, y)."""
        h, w = self.level.shape
        r = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
        c = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
        return self.level[r, c], self.sigma[r, c]


def data_quantum(image: np.ndarray) -> float:
    """The step between an integer image's grey levels: the greatest common divisor of the
    differences between its distinct values (1 for ordinary data; 17 for a frame whose 16
    levels were stretched over 0..255); 0 for float data."""
    if image.dtype.kind not in "iu":
        return 0.0
    if image.size == 0:
        return 1.0
    if image.itemsize <= 2:  # the values present, from a histogram: a sort's result, 10x sooner
        flat = image.ravel()
        # from 0 (unsigned data stays in its type: bincount counts it several times faster)
        shifted = flat - flat.min() if flat.dtype.kind == "u" else flat.astype(np.int64) - int(flat.min())
        values = np.flatnonzero(np.bincount(shifted))
    else:
        values = np.unique(image)
    if values.size < 2:
        return 1.0
    return float(np.gcd.reduce(np.diff(values.astype(np.int64))))  # in int64: no gap wraps


def tile_samples(residual: np.ndarray, valid: np.ndarray, tile: int, step: int = 2) -> np.ndarray:
    """The samples of each ``tile`` × ``tile`` tile, a row per tile (row-major tiles): the pixels
    on every ``step``-th row and column of the tile, float32, inf where not ``valid`` or beyond
    the frame."""
    h, w = residual.shape
    ny, nx = -(-h // tile), -(-w // tile)
    if tile % step == 0:  # those are every step-th row and column of the frame: take them first
        sub_r, sub_v = residual[::step, ::step], valid[::step, ::step]
        side = tile // step
        padded = np.full((ny * side, nx * side), np.inf, dtype=np.float32)
        np.copyto(padded[:sub_r.shape[0], :sub_r.shape[1]], sub_r, casting="unsafe", where=sub_v)  # one pass
        return padded.reshape(ny, side, nx, side).transpose(0, 2, 1, 3).reshape(ny * nx, -1)
    padded = np.full((ny * tile, nx * tile), np.inf, dtype=np.float32)
    padded[:h, :w] = np.where(valid, residual.astype(np.float32, copy=False), np.inf)
    return padded.reshape(ny, tile, nx, tile)[:, ::step, :, ::step].transpose(0, 2, 1, 3).reshape(ny * nx, -1)


def tile_statistics(residual: np.ndarray, valid: np.ndarray, tile: int, quantum: float = 0.0,
                    clip: float = 3.5, step: int = 2
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(level, sigma, tail, samples) grids of ``residual`` over ``tile`` × ``tile`` tiles, from
    the ``valid`` pixels on a grid of every ``step``-th row and column (:func:`tile_samples`;
    see the module docstring). ``tail``: the tile's 99th percentile in units of ``sigma`` above
    ``level``, divided by a Gaussian's (2.326). Tiles with fewer than :data:`MIN_SAMPLES` valid
    samples get NaN."""
    h, w = residual.shape
    ny, nx = -(-h // tile), -(-w // tile)
    samples = tile_samples(residual, valid, tile, step)
    n = np.isfinite(samples).sum(axis=1)
    # only the tiles with enough samples are measured (the others get NaN): an empty tile's
    # samples would only add NaN to the sorts, which are several times slower with them
    enough = np.flatnonzero(n >= MIN_SAMPLES)
    t, k = samples[enough], n[enough]
    rows = np.arange(len(enough))
    mid = (k - 1) // 2
    ordered = np.sort(t, axis=1)
    lv = ordered[rows, mid]
    with np.errstate(invalid="ignore"):
        dev = t - lv[:, None]
        mad = np.sort(np.abs(dev), axis=1)[rows, mid]
        s0 = np.maximum(_MAD * mad, quantum)
        inside = np.abs(dev) <= clip * s0[:, None]
    m = np.maximum(inside.sum(axis=1), 1)
    d = np.where(inside, dev, 0.0)
    mean = d.sum(axis=1) / m
    var = np.maximum((d * d).sum(axis=1) / m - mean * mean, 0.0)
    sg = np.sqrt(var) / _clipped_std(clip)
    sg = np.maximum(sg, max(QUANTUM_FLOOR * quantum, 1e-6))  # the grey levels' own spread
    q99 = ordered[rows, np.rint(0.99 * (k - 1)).astype(np.int64)]
    with np.errstate(invalid="ignore"):
        tl = (q99 - lv) / sg / _Q99
    level = np.full(len(n), np.nan, dtype=lv.dtype)
    sigma = np.full(len(n), np.nan, dtype=sg.dtype)
    tail = np.full(len(n), np.nan, dtype=tl.dtype)
    level[enough], sigma[enough], tail[enough] = lv, sg, tl
    return level.reshape(ny, nx), sigma.reshape(ny, nx), tail.reshape(ny, nx), n.reshape(ny, nx)


def _clipped_std(clip: float) -> float:
    """Standard deviation of a unit Gaussian truncated to ±clip."""
    from math import erf, exp, pi, sqrt

    p = erf(clip / sqrt(2.0))
    return sqrt(max(1.0 - 2.0 * clip * exp(-clip * clip / 2.0) / sqrt(2.0 * pi) / p, 1e-12))


def heavy_tail(tail: np.ndarray) -> np.ndarray:
    """How much heavier than a Gaussian's the residual's upper tail is, per tile: the median of
    the tile's and its 8 neighbours' 99th-percentile ratios (:func:`tile_statistics`), at least 1.
    Multiplying sigma by it makes a threshold of k sigma cut as far into the tail as it would in
    Gaussian noise, where compression blocks, fixed-pattern stripes or texture fatten it."""
    t = fill_missing(tail, 1.0)
    p = cv2.copyMakeBorder(t, 1, 1, 1, 1, cv2.BORDER_REPLICATE)  # edge-padded (np.pad is 10x slower)
    stack = np.stack([p[i:i + t.shape[0], j:j + t.shape[1]] for i in range(3) for j in range(3)])
    median = np.partition(stack, 4, axis=0)[4]  # the middle of 9: np.median's value, without its overhead
    return np.where(np.isfinite(tail), np.maximum(median, 1.0), np.nan)


def fill_missing(grid: np.ndarray, default: float) -> np.ndarray:
    """NaN tiles take the value of their nearest finite tile (``default`` if there is none)."""
    bad = ~np.isfinite(grid)
    if not bad.any():
        return grid
    if bad.all():
        return np.full_like(grid, default)
    return grid[_nearest_tiles_cached(bad.shape, np.packbits(bad).tobytes())]


@lru_cache(maxsize=32)
def _nearest_tiles_cached(shape: tuple[int, int], packed: bytes) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nearest_tiles` of a grid given packed: the same tiles are missing frame after frame
    (those the mask or the horizon cover), so each pattern is solved once (read-only results)."""
    bad = np.unpackbits(np.frombuffer(packed, dtype=np.uint8), count=shape[0] * shape[1]).reshape(shape)
    out = nearest_tiles(bad.astype(bool))
    for a in out:
        a.flags.writeable = False
    return out


def nearest_tiles(bad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the nearest tile not ``bad`` (Euclidean) for every tile of the 2-D grid
    ``bad`` (at least one tile not bad). Separable, as Maurer, Qi and Raghavan (2003, IEEE PAMI
    25, 265-270) and ``scipy.ndimage.distance_transform_edt``, with its ties: first the nearest
    good row within each column (the upper on a tie), then within each row the nearest of the
    columns' candidates (the left on a tie). The tile grid is small (20 x 16 at 640 x 512), so the
    second step compares every pair of columns; tested against SciPy's."""
    h, w = bad.shape
    good = ~bad
    rows = np.arange(h)
    far = 4 * (h + w) ** 2  # beyond any distance in the grid
    # each column: the nearest good row above (at or before) and below (at or after)
    above = np.maximum.accumulate(np.where(good, rows[:, None], -far), axis=0)
    below = np.minimum.accumulate(np.where(good, rows[:, None], far)[::-1], axis=0)[::-1]
    r1 = np.where(rows[:, None] - above <= below - rows[:, None], above, below)
    # each row: the nearest of the columns' candidates (columns without a good tile left out)
    cols = np.arange(w)
    d2 = (r1[:, None, :] - rows[:, None, None]) ** 2 + (cols[None, None, :] - cols[None, :, None]) ** 2
    d2[:, :, ~good.any(axis=0)] = np.iinfo(d2.dtype).max
    c2 = np.argmin(d2, axis=2)
    return r1[rows[:, None], c2], c2


def _tile_sums(mask: np.ndarray, tile: int, ny: int, nx: int) -> np.ndarray:
    """Number of set pixels of ``mask`` in each ``tile`` x ``tile`` tile (``ny`` x ``nx``, int64):
    each tile row's columns summed first (contiguous rows: 4x faster than counting over both
    axes of the tiled view)."""
    h, w = mask.shape
    if (h, w) != (ny * tile, nx * tile):
        mask = np.pad(mask, ((0, ny * tile - h), (0, nx * tile - w)))
    rows = np.ascontiguousarray(mask).view(np.uint8).reshape(ny, tile, nx * tile).sum(axis=1, dtype=np.int32)
    return rows.reshape(ny, nx, tile).sum(axis=2, dtype=np.int64)


def _quantile_bins(counts: np.ndarray, level: np.ndarray, first: int = 160) -> np.ndarray:
    """Per row of the histograms ``counts``, the first bin whose cumulative count reaches
    ``level`` (the number of bins below it). The cumulative sum is taken over the first
    ``first`` bins, and over all of them only for rows that need it."""
    cdf = np.cumsum(counts[:, :first], axis=1)
    idx = (cdf < level[:, None]).sum(axis=1)
    far = idx >= cdf.shape[1]
    if far.any():
        idx[far] = (np.cumsum(counts[far], axis=1) < level[far, None]).sum(axis=1)
    return idx


def upsample(grid: np.ndarray, shape: tuple[int, int], tile: int) -> np.ndarray:
    """Bilinear interpolation of a tile grid to every pixel (tile centres at their pixels)."""
    ny, nx = grid.shape
    big = cv2.resize(grid.astype(np.float32), (nx * tile, ny * tile), interpolation=cv2.INTER_LINEAR)
    return big[: shape[0], : shape[1]]


class NoiseModel:
    """Tile statistics of each frame's residual, smoothed in time, per zone.

    ``update`` takes the residual, the valid pixels and optional zones (masks that partition
    them, e.g. sky and ground below a confident horizon): each zone gets its own statistics, so
    a tile that straddles the horizon does not mix them. The grids are blended with the previous
    frame's (weight ``smoothing`` on the previous; ``sigma`` in the log domain) unless the
    frame size or the zones changed, or ``reset`` is set (a camera that moved).
    """

    def __init__(self, tile: int = 32, smoothing: float = 0.5, clip: float = 3.5) -> None:
        self.tile, self.smoothing, self.clip = tile, smoothing, clip
        self.quantum: float | None = None
        self._grids: list[tuple[np.ndarray, np.ndarray]] | None = None
        self._key: tuple | None = None

    def update(self, residual: np.ndarray, valid: np.ndarray, zones: list[np.ndarray] | None = None,
               image: np.ndarray | None = None, reset: bool = False) -> NoiseEstimate:
        """The noise estimate of this frame (``image``: the frame, for its grey-level step)."""
        if self.quantum is None or (self._key is not None and self._key[0] != residual.shape):
            self.quantum = data_quantum(image if image is not None else residual)
        parts = zones if zones else [valid]
        key = (residual.shape, len(parts))
        grids = []
        for z in parts:
            level, sigma, tail, _ = tile_statistics(residual, z, self.tile, self.quantum, self.clip)
            grids.append((level, sigma * heavy_tail(tail)))
        if self._grids is not None and self._key == key and not reset and self.smoothing > 0:
            a = self.smoothing
            blended = []
            for (lv, sg), (plv, psg) in zip(grids, self._grids):
                ok = np.isfinite(lv) & np.isfinite(plv)
                lv = np.where(ok, a * plv + (1 - a) * lv, np.where(np.isfinite(lv), lv, plv))
                sg = np.where(ok, np.exp(a * np.log(psg) + (1 - a) * np.log(np.where(ok, sg, 1.0))),
                              np.where(np.isfinite(sg), sg, psg))
                blended.append((lv, sg))
            grids = blended
        self._grids, self._key = grids, key
        return self._estimate(grids, parts, residual.shape)

    def _estimate(self, grids: list[tuple[np.ndarray, np.ndarray]], parts: list[np.ndarray],
                  shape: tuple[int, int]) -> NoiseEstimate:
        q = float(self.quantum or 0.0)
        floor = max(QUANTUM_FLOOR * q, 1e-6)
        level = sigma = None
        for (lv, sg), z in zip(grids, parts):
            lv_full = upsample(fill_missing(lv, 0.0), shape, self.tile)
            sg_full = upsample(fill_missing(sg, 1.0), shape, self.tile)
            if level is None:
                level, sigma = lv_full, sg_full
            else:
                level = np.where(z, lv_full, level)
                sigma = np.where(z, sg_full, sigma)
        lv0, sg0 = grids[0]
        # (sigma is this call's own array: upsampled or selected above)
        return NoiseEstimate(level, np.maximum(sigma, floor, out=sigma), lv0, sg0, self.tile, q)


SHARE = 0.75  # TailCalibration: a tail as heavy as that of this share of the tiles holds everywhere
TAIL_QUANTILE = 0.999  # TailCalibration: where the tail is measured
TAIL_FLOOR = 2.0  # TailCalibration: significances below it are not binned (below 0.999's 3.09)


@lru_cache(maxsize=4)
def _tile_index(shape: tuple[int, int], every: int, tile: int, nx: int) -> np.ndarray:
    """The tile (row-major index, ``nx`` tiles a row) of every pixel of an image of ``shape``
    sampled every ``every``-th row and column from a frame cut in ``tile``-px tiles (int64,
    read-only: shared by every calibration of that shape)."""
    rows = (np.arange(shape[0], dtype=np.int64) * every) // tile
    cols = (np.arange(shape[1], dtype=np.int64) * every) // tile
    out = rows[:, None] * nx + cols[None, :]
    out.flags.writeable = False
    return out


class TailCalibration:
    """How much heavier than a Gaussian's the upper tail of a clip's significance is, far out:
    the ``quantile`` of the significance of each ``tile`` × ``tile`` tile, pooled over frames (a
    histogram per tile blended with weight ``memory`` on the past), divided by a unit
    Gaussian's; the factor of a tile is the median of that over the tile and its 8 neighbours
    (a target fills few tiles), at least 1 (:attr:`grid`; tiles that have seen fewer than
    ``min_samples`` pixels take their nearest neighbour's). Compressed video clumps its noise
    into blobs that persist for a group of pictures, and textured clutter has more bright spots
    than noise would: both fatten the tail beyond the 99th percentile that :func:`heavy_tail`
    measures in one frame. Dividing the significance by the factor makes ``k_sigma`` cut as far
    into that tail as into Gaussian noise, place by place.

    ``refresh``: frames between updates; the past's weight per update is ``memory`` to that
    power and an update samples every pixel instead of every other row and column from 4 frames
    up, so that the calibration learns as fast in frames whatever the refresh."""

    def __init__(self, tile: int = 32, quantile: float | None = None, memory: float = 0.9,
                 lo: float = 0.0, hi: float = 40.0, step: float = 0.1, min_samples: float = 1000.0,
                 refresh: int = 1) -> None:
        quantile = TAIL_QUANTILE if quantile is None else quantile
        self.tile, self.quantile, self.min_samples = tile, quantile, min_samples
        self.memory = memory ** refresh
        self.stride = 1 if refresh >= 4 else 2
        self.lo, self.step = lo, step
        self.nbins = int(round((hi - lo) / step))
        self.counts: np.ndarray | None = None
        self.gauss = float(normal.quantile(quantile))
        self.grid: np.ndarray | None = None
        self._tiles: np.ndarray | None = None  # tile index x bins of each sampled pixel

    def update(self, z: np.ndarray, valid: np.ndarray, overall: bool = True) -> np.ndarray:
        """Add the significance map ``z`` (``valid`` pixels only); returns the factor of every
        pixel (float32, ``z``'s shape). ``overall``: at least the tail ratio that :data:`SHARE`
        of the tiles reach, everywhere.

        Only pixels at or above :data:`TAIL_FLOOR` are binned; the rest of a tile's pixels are
        counted in its lowest bin. The result is the same as binning all of them: a quantile
        that falls below the floor gives a ratio below 1, which the factor's floor of 1 (and
        the 3 x 3 median, and the :data:`SHARE` quantile, all order-preserving) replaces
        whatever its value."""
        h, w = z.shape
        t, every = self.tile, self.stride
        nx, ny = -(-w // t), -(-h // t)
        zs = z[::every, ::every]
        if self._tiles is None or self._tiles.shape != zs.shape:
            self._tiles = _tile_index(zs.shape, every, t, nx)
        keep = valid[::every, ::every] & np.isfinite(zs)
        with np.errstate(invalid="ignore"):  # NaN pixels are not kept
            high = np.flatnonzero(keep & (zs >= max(TAIL_FLOOR, self.lo)))
        b = np.minimum((zs.ravel()[high] - self.lo) * (1.0 / self.step), self.nbins - 1).astype(np.int64)
        tiles = self._tiles.ravel()
        if self.counts is None or self.counts.shape[0] != nx * ny:
            self.counts = np.zeros((nx * ny, self.nbins))
        self.counts *= self.memory
        hist = np.bincount(tiles[high] * self.nbins + b, minlength=nx * ny * self.nbins).reshape(-1, self.nbins)
        hist[:, 0] += _tile_sums(keep, t // every, ny, nx).ravel() - hist.sum(axis=1)
        self.counts += hist
        total = self.counts.sum(axis=1)
        enough = np.flatnonzero(total >= self.min_samples)  # the others are NaN: not searched
        tiles_ratio = np.full(len(total), np.nan)
        idx = _quantile_bins(self.counts[enough], self.quantile * total[enough])
        tiles_ratio[enough] = (self.lo + (idx + 1) * self.step) / self.gauss
        ratio = tiles_ratio.reshape(ny, nx)
        self.grid = heavy_tail(ratio)  # 3 x 3 median, at least 1
        seen = ratio[np.isfinite(ratio)]
        least = max(1.0, float(np.quantile(seen, SHARE))) if seen.size and overall else 1.0
        return upsample(np.maximum(fill_missing(self.grid, 1.0), least), (h, w), t)
