"""Evidence from the frames in which a track's gate holds no detection (not in the papers).

A miss says only that nothing crossed the threshold ``k`` in the gate; the value below it says
more. The track reads the change significance (σ, what is new at its place in the scene:
static clutter reads like noise there) at its prediction, the largest in a
(2 :data:`WINDOW` + 1)² window (:func:`read_at`), and scores it with the likelihood ratio of a
read given a miss (Wald's test on the joint outcome, :mod:`wfviz.tracking.confirmation`):

    L += ln((1 - P_D) / (1 - p_fa)) + ln f1(m | m < k) - ln f0(m | m < k)

f0: the same read at places with no target, measured on every frame (:class:`ReadNull`: the
window maxima and their centre pixels at random pixels of the searched region, so the null is
the scene's own, its smoothing and tails included; a Gaussian model adds :data:`PSEUDO` samples'
weight where few were measured). f1: a target missed this frame, its pixel the null's centre
value plus a significance uniform in [k - :data:`SPAN`, k] (a target just below the threshold,
the dim ones the multi-frame stage exists for), the largest of it and the window's other pixels.
Reads below the null's median count as the median (Huber's censoring). On Gaussian noise a dim
target read at 3 σ under k = 4 gains about 2.4 nats, noise read at its typical 1.4 σ (the median)
loses about 1.4: a dim target's track is not deleted between its detections, a track that lost its target is
deleted sooner, a static-clutter track gains nothing (its change is noise).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from wfviz import normal
from wfviz.tracking.confirmation import EVIDENCE_CAP

WINDOW = 1  #: half size (px) of the window a read takes the largest value of (3 × 3)
SAMPLES = 512  #: random pixels read for the null every EVERY frames
EVERY = 4  #: frames between the null's samples (a call's cost is mostly its overhead)
POOL = 4096  #: null reads kept (the last 32 frames at SAMPLES / EVERY a frame)
PSEUDO = 200.0  #: weight (samples) of the Gaussian model in the null's density
SPAN = 2.0  #: σ: a missed target's significance is taken uniform in [k - SPAN, k]
BAND = 0.25  #: σ: half width of the band the null's density is measured in
CAP = EVIDENCE_CAP  #: most one read may add to or take from a score (nats), as one hit's significance
_MU_STEPS = 21  #: steps of a missed target's significance in [k - SPAN, k]
_GAUSS_MEDIAN = 1.4457  #: median of the largest of 9 independent N(0, 1) values


def read_at(zmap: np.ndarray, xy: np.ndarray, half: int = WINDOW, mask: np.ndarray | None = None) -> np.ndarray:
    """The largest finite value of ``zmap`` in the (2 ``half`` + 1)² window about each point
    ``xy`` (N, 2) (rounded to the nearest pixel), among the pixels of ``mask`` (None: all; the
    searched region: a read where nothing was searched says nothing of a miss); NaN where the
    point lies outside the image or the window holds no such finite value. Never modifies
    ``zmap``."""
    out = np.full(len(np.asarray(xy).reshape(-1, 2)), np.nan)
    inside, v = _windows(zmap, xy, half, mask)
    if len(v):
        out[inside] = np.fmax.reduce(v, axis=1)  # NaN only where every pixel is
    return out


def _windows(zmap: np.ndarray, xy: np.ndarray, half: int,
             mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(which points ``xy`` lie in the image, the (2 ``half`` + 1)² values of ``zmap`` about each
    of those, row by row, NaN outside ``mask``; the window clipped to the image)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    h, w = zmap.shape[:2]
    c = np.rint(xy[:, 0])
    r = np.rint(xy[:, 1])
    with np.errstate(invalid="ignore"):
        inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)  # NaN compares false
    d = np.arange(-half, half + 1)
    rr = np.clip(r[inside].astype(np.int64)[:, None, None] + d[None, :, None], 0, h - 1)
    cc = np.clip(c[inside].astype(np.int64)[:, None, None] + d[None, None, :], 0, w - 1)
    size = (2 * half + 1) ** 2
    v = zmap[rr, cc].reshape(len(rr), size).astype(np.float64)  # any strides: no copy of the frame
    if mask is not None:
        v[~mask[rr, cc].reshape(len(rr), size).astype(bool)] = np.nan
    return inside, v


class NullReads:
    """The reads measured where no target is, for :func:`read_score`: each window's largest
    value (``values``) and its centre pixel's (``centre``), sorted on first use (most frames
    score no read); each distribution blended with its Gaussian model (weight :data:`PSEUDO`)."""

    def __init__(self, values: np.ndarray, centre: np.ndarray | None = None) -> None:
        self._raw = np.asarray(values, dtype=np.float64)
        self._centre = np.asarray(self._raw if centre is None else centre, dtype=np.float64)

    @cached_property
    def values(self) -> np.ndarray:
        """The window maxima, sorted."""
        return np.sort(self._raw)

    @cached_property
    def centre(self) -> np.ndarray:
        """The centre pixels' values, sorted."""
        return np.sort(self._centre)

    @cached_property
    def median(self) -> float:
        """The median window maximum (the Gaussian model's without reads)."""
        return float(np.median(self.values)) if len(self.values) else _GAUSS_MEDIAN

    def cdf(self, m: np.ndarray) -> np.ndarray:
        """P(read <= m) under the null (the Gaussian model: the largest of the window's
        independent N(0, 1) pixels)."""
        return _blend(self.values, m, (2 * WINDOW + 1) ** 2)

    def centre_cdf(self, x: np.ndarray) -> np.ndarray:
        """P(one pixel's value <= x) under the null (the Gaussian model: N(0, 1))."""
        return _blend(self.centre, x, 1)

    def target_cdf(self, m: np.ndarray, k: np.ndarray) -> np.ndarray:
        """P(read <= m) of a target missed at threshold ``k``: its pixel the null's centre value
        plus a significance uniform in [k - :data:`SPAN`, k], the window's other pixels the
        null's (their largest's CDF taken as ``cdf`` ** (8 / 9))."""
        m = np.asarray(m, dtype=np.float64)
        mu = np.asarray(k, dtype=np.float64)[..., None] - SPAN * np.linspace(0.0, 1.0, _MU_STEPS)
        own = self.centre_cdf(m[..., None] - mu).mean(axis=-1)
        n = (2 * WINDOW + 1) ** 2
        return own * self.cdf(m) ** ((n - 1) / n)

    def log_density(self, m: np.ndarray, k: np.ndarray, target: bool = False) -> np.ndarray:
        """ln f(m | m < k) of the null (or, ``target``, of a missed target): the density in a
        band of ± :data:`BAND` σ about ``m`` (clipped below ``k``) over the probability below ``k``."""
        m = np.asarray(m, dtype=np.float64)
        k = np.asarray(k, dtype=np.float64)
        hi = np.minimum(m + BAND, k)
        lo = hi - 2 * BAND
        F = (lambda x: self.target_cdf(x, k)) if target else self.cdf
        mass = np.maximum(F(hi) - F(lo), 1e-12) / (2 * BAND)
        return np.log(mass) - np.log(np.maximum(F(k), 1e-12))


def _blend(sorted_values: np.ndarray, x: np.ndarray, n: int) -> np.ndarray:
    """Empirical CDF of ``sorted_values`` at ``x`` blended with Φ(x) ** ``n`` (weight :data:`PSEUDO`)."""
    x = np.asarray(x, dtype=np.float64)
    count = len(sorted_values)
    emp = np.searchsorted(sorted_values, x, side="right") / max(count, 1)
    return (count * emp + PSEUDO * normal.cdf(x) ** n) / (count + PSEUDO)


class ReadNull:
    """The null reads of :func:`read_at` at :data:`SAMPLES` random pixels of the searched
    region every :data:`EVERY` frames, the last :data:`POOL` kept (seeded: a run is reproducible)."""

    def __init__(self, seed: int = 0) -> None:
        self._rng = np.random.default_rng(seed)
        self._pool = np.empty((POOL, 2))  # (window maximum, centre pixel)
        self._n = 0
        self._at = 0
        self._frames = 0

    def update(self, zmap: np.ndarray | None, region: np.ndarray) -> None:
        """Read ``zmap`` (None: not known this frame, nothing read) at random pixels of
        ``region`` on every :data:`EVERY` th frame it is known (the first included)."""
        if zmap is None:
            return
        self._frames += 1
        if (self._frames - 1) % EVERY:
            return
        h, w = region.shape[:2]
        r = self._rng.integers(0, h, 2 * SAMPLES)
        c = self._rng.integers(0, w, 2 * SAMPLES)
        ok = region[r, c].astype(bool)
        _, win = _windows(zmap, np.column_stack([c[ok], r[ok]])[:SAMPLES], WINDOW, region)
        v = np.column_stack([np.fmax.reduce(win, axis=1), win[:, win.shape[1] // 2]])
        v = v[np.isfinite(v).all(axis=1)]
        for chunk in (v[: POOL - self._at], v[POOL - self._at:]):
            if not len(chunk):
                continue
            self._pool[self._at:self._at + len(chunk)] = chunk
            self._at = (self._at + len(chunk)) % POOL
            self._n = min(self._n + len(chunk), POOL)

    def snapshot(self) -> NullReads:
        """The reads kept so far (none: the Gaussian model alone)."""
        return NullReads(self._pool[: self._n, 0].copy(), self._pool[: self._n, 1].copy())


def read_score(m: np.ndarray, k: float | np.ndarray, null: NullReads) -> np.ndarray:
    """ln f1(m | m < k) - ln f0(m | m < k) of each read ``m`` (σ) of a missed track whose gate
    was searched at ``k`` (σ), bounded to ± :data:`CAP`; 0 where ``m`` is NaN (not read). A read
    below the null's median counts as the median (Huber's censoring: far below typical noise
    both models fail, e.g. where the camera's registration left a hole, and it says no more
    than typical noise does)."""
    m = np.asarray(m, dtype=np.float64)
    k = np.broadcast_to(np.asarray(k, dtype=np.float64), m.shape)
    ok = np.isfinite(m) & np.isfinite(k)
    out = np.zeros(m.shape)
    if ok.any():
        kk = k[ok]
        mm = np.clip(m[ok], np.minimum(null.median, kk), kk)
        out[ok] = np.clip(null.log_density(mm, kk, target=True) - null.log_density(mm, kk), -CAP, CAP)
    return out
