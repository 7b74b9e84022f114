"""Per-pixel background and noise of the track-before-detect likelihood, estimated from the data.

The likelihood of :mod:`wfviz.trackers.tbd.model` needs y = (z - b) / sigma with y ~ N(0, 1) where there
is no target. Neither b nor sigma is assumed:

* **background b** (per pixel): a running mean of the frames (rate 1/k over the first frames,
  then an exponential memory of ``memory`` frames). Each update moves b by the residual
  z - b clipped at +-``clip`` times its std, so a dim target passing over a pixel biases it
  little, and pixels near the filter's current targets (``hold``) are not updated at all. A
  fixed background of any structure (a sky gradient, cloud texture, fixed-pattern offsets, a
  hot pixel's constant excess) is learnt and removed; the spatial median of one frame is not
  enough when the background varies by more than the noise over the frame.
* **noise sigma** (per tile, hence signal dependent at the tile scale): 1.4826 MAD / sqrt(2) of
  the frame-to-frame difference z_k - z_k-1 over ``tile`` x ``tile`` tiles (the background
  cancels, a moving target barely moves a median), averaged over time in variance (rate 1/k,
  then ``noise_memory`` frames) and upsampled bilinearly to the pixels.
* **shrinkage to a smooth background**: the per-pixel mean b_t is a mean of finitely many
  frames, its error variance in units of sigma^2 is f_k = (1 - rho)^2 f_k-1 + rho^2. Where the
  background is flat, the tile medians of b_t (bilinearly upsampled, b_s) are far more
  precise. Both are combined by their variances (empirical Bayes): the spread of the true
  background about b_s, tau^2 = max(s^2 - f, 0) with s the robust std of (b_t - b_s) / sigma
  per tile, gives b = b_s + w (b_t - b_s), w = tau^2 / (tau^2 + f), whose error variance
  w f sigma^2 is added to the noise. That error is the same in every frame (until b is
  renewed), so a filter summing T frames of evidence sees it T times coherently (T^2 w f
  against T for the noise): y = (z - b) / (sigma sqrt(1 + T w f)), T = ``coherence``. Without
  it the noise of the first frames, learnt as background, looks like static dim targets. A flat sky gives
  w ~ 0 (b = the tile medians, as good as the frame median from the first frame); a
  structured background (S6: 45 DN of texture against 9 DN noise) gives w ~ 1.
* **hot (and dead) pixels**: a pixel whose background differs from its 3 x 3 neighbours'
  median by more than ``hot_k`` times the larger of sigma and the tile's robust spread of that
  difference (a textured background is not a field of hot pixels), from frame ``hot_after``
  on, carries no target evidence:
  its y is set to 0 (excluded from the matched filter and the likelihood sums a = sum h y).

On the first frame there is no noise estimate yet (a frame alone cannot tell texture from
noise): y = 0, no evidence. Pure numpy/OpenCV state,
no recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.stages.noise import upsample

_MAD = 1.4826


@dataclass(frozen=True)
class NoiseFrame:
    """One frame's normalisation: y, the median noise sigma (DN), the per-pixel sigma map
    (DN, including the background uncertainty), the background (DN) and the excluded pixels."""

    y: np.ndarray
    sigma: float
    sigma_map: np.ndarray
    background: np.ndarray
    excluded: np.ndarray


def _blocks(d: np.ndarray, tile: int) -> np.ndarray:
    """(ny, nx, tile * tile): the pixels of each ``tile`` x ``tile`` tile of ``d`` (the last
    row/column of tiles padded by reflection)."""
    rows, cols = d.shape
    ny, nx = -(-rows // tile), -(-cols // tile)
    pr, pc = ny * tile - rows, nx * tile - cols
    if pr or pc:
        d = np.pad(d, ((0, pr), (0, pc)), mode="reflect")
    return d.reshape(ny, tile, nx, tile).transpose(0, 2, 1, 3).reshape(ny, nx, tile * tile)


def tile_sigma(d: np.ndarray, tile: int) -> np.ndarray:
    """(ny, nx) robust std (1.4826 MAD about the median) of ``d`` over ``tile`` x ``tile`` tiles."""
    blocks = _blocks(d, tile)
    med = np.median(blocks, axis=-1, keepdims=True)
    return _MAD * np.median(np.abs(blocks - med), axis=-1)


class PixelBackground:
    """Running per-pixel background, per-tile noise and hot-pixel mask (see the module doc)."""

    def __init__(self, memory: float = 64.0, clip: float = 2.5, tile: int = 16, noise_memory: float = 32.0,
                 hot_k: float = 8.0, hot_after: int = 1, coherence: float = 10.0) -> None:
        self.coherence = float(coherence)
        self.memory, self.clip, self.tile = float(memory), float(clip), int(tile)
        self.noise_memory, self.hot_k, self.hot_after = float(noise_memory), float(hot_k), int(hot_after)
        self.b: np.ndarray | None = None
        self.f: float = 1.0
        self.prev: np.ndarray | None = None
        self.var: np.ndarray | None = None  # tile noise variance
        self.frames = 0

    def _upsample(self, grid: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Tile grid -> pixels, bilinear between tile centres (:func:`wfviz.stages.noise.upsample`)."""
        return np.ascontiguousarray(upsample(grid, shape, self.tile))

    @staticmethod
    def _coarse(grid: np.ndarray) -> np.ndarray:
        """Tile values averaged over each tile's 3 x 3 neighbourhood (a spread estimate of 256
        pixels is too noisy to subtract f from it)."""
        g = grid.astype(np.float32)
        return cv2.blur(g, (3, 3), borderType=cv2.BORDER_REPLICATE) if g.size > 1 else g

    def _sigma_map(self, shape: tuple[int, int]) -> np.ndarray:
        return self._upsample(np.sqrt(np.maximum(self.var, 1e-12)), shape)

    def _smooth(self, b: np.ndarray) -> np.ndarray:
        """b_s: the tile medians of ``b``, upsampled."""
        return self._upsample(np.median(_blocks(b, self.tile), axis=-1), b.shape)

    def step(self, image: np.ndarray, hold: np.ndarray | None = None) -> NoiseFrame:
        """Normalise ``image`` with the model of the previous frames, then update the model
        with it (``hold``: boolean mask of pixels whose background is not updated)."""
        z = image.astype(np.float32, copy=False)
        if self.b is None or self.b.shape != z.shape:
            self.b = z.copy()
            self.f = 1.0
            self.prev = z
            self.frames = 1
            s = _MAD * float(np.median(np.abs(z - np.median(z))))
            sig = np.full(z.shape, max(s, 1e-6), np.float32)
            return NoiseFrame(np.zeros(z.shape, np.float32), max(s, 1e-6), sig, self.b.copy(),
                              np.zeros(z.shape, bool))
        k = self.frames
        # noise: frame differences, per tile, averaged over time in variance
        v = (tile_sigma(z - self.prev, self.tile) ** 2) * 0.5
        v = np.maximum(v, 1e-6)
        rate = max(1.0 / k, 1.0 / self.noise_memory)
        self.var = v if self.var is None else (1.0 - rate) * self.var + rate * v
        sig = self._sigma_map(z.shape)
        total = sig * np.float32(np.sqrt(1.0 + self.f))  # of z - b_t
        res = z - self.b
        bs = self._smooth(self.b)
        spread = self._coarse(tile_sigma((self.b - bs) / sig, self.tile) ** 2)
        tau2 = np.maximum(spread - self.f, 0.0)
        w = self._upsample((tau2 / (tau2 + self.f)).astype(np.float32), z.shape)
        back = bs + w * (self.b - bs)
        scale = sig * np.sqrt(1.0 + w * np.float32(self.coherence * self.f))
        y = (z - back) / scale
        excluded = np.zeros(z.shape, bool)
        if k >= self.hot_after:
            d = self.b - cv2.medianBlur(self.b, 3) if min(z.shape) >= 3 else np.zeros_like(z)
            spread_d = self._upsample(tile_sigma(d, self.tile), z.shape)  # pixel-scale texture
            excluded = np.abs(d) > self.hot_k * np.maximum(sig, spread_d)
            y[excluded] = 0.0
        # background update (clipped residual, rate 1/(k+1) then 1/memory), not under targets
        rho = max(1.0 / (k + 1), 1.0 / self.memory)
        step = np.clip(res, -self.clip * total, self.clip * total) * np.float32(rho)
        if hold is not None and hold.any():
            step[hold] = 0.0
        self.b = self.b + step
        self.f = (1.0 - rho) ** 2 * self.f + rho ** 2
        self.prev = z
        self.frames += 1
        return NoiseFrame(y, float(np.median(sig)), scale, back, excluded)
