"""Sky-ground line by multi-direction maximum gradient (GEWC paper, eqs. 2-3)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.config import HorizonConfig


@dataclass(frozen=True)
class Horizon:
    """Horizon row for every column (NaN where the column has no horizon); sky is above."""

    rows: np.ndarray

    def polyline(self, step: int = 4) -> np.ndarray:
        """(N, 2) array of (x, y) points along the horizon, every ``step`` columns."""
        xs = np.nonzero(np.isfinite(self.rows))[0]
        if xs.size == 0:
            return np.zeros((0, 2), dtype=np.float32)
        pick = np.unique(np.concatenate([xs[::step], xs[-1:]]))
        return np.column_stack([pick, self.rows[pick]]).astype(np.float32)


def max_gradient(image: np.ndarray, step: int) -> np.ndarray:
    """Eq. 2: Gmax = max(G0, G45, G90, G135) with differences ``step`` pixels apart.

    G0 = |f(i+n,j) - f(i-n,j)|, G45 = |f(i-n,j+n) - f(i+n,j-n)|, G90 = |f(i,j+n) - f(i,j-n)|,
    G135 = |f(i+n,j+n) - f(i-n,j-n)| with i = row, j = column, n = ``step``; borders replicate.
    """
    n = step
    f = cv2.copyMakeBorder(image.astype(np.float32, copy=False), n, n, n, n, cv2.BORDER_REPLICATE)
    h, w = image.shape

    def at(di: int, dj: int) -> np.ndarray:
        return f[n + di: n + di + h, n + dj: n + dj + w]

    g = np.abs(at(n, 0) - at(-n, 0))
    np.maximum(g, np.abs(at(-n, n) - at(n, -n)), out=g)
    np.maximum(g, np.abs(at(0, n) - at(0, -n)), out=g)
    np.maximum(g, np.abs(at(n, n) - at(-n, -n)), out=g)
    return g


def _median_abs(d: np.ndarray) -> float:
    """Median of |d|; integer data by a histogram (exact, and several times faster)."""
    if d.dtype.kind in "iu" and d.size:
        counts = np.bincount(np.abs(d).ravel())
        cdf = np.cumsum(counts)
        n = int(cdf[-1])
        lo, hi = np.searchsorted(cdf, [(n - 1) // 2 + 1, n // 2 + 1])
        return (float(lo) + float(hi)) / 2.0
    return float(np.median(np.abs(d)))


def noise_sigma(image: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Robust temporal-noise estimate: MAD of horizontal neighbour differences / sqrt(2)."""
    f = image.astype(np.int32) if image.dtype.kind in "iu" and image.itemsize <= 2 \
        else image.astype(np.float32, copy=False)
    d = f[:, 1:] - f[:, :-1]
    if valid is not None:
        d = d[valid[:, 1:] & valid[:, :-1]]
    if d.size == 0:
        return 1.0
    return max(1.4826 * _median_abs(d) / np.sqrt(2.0), 1e-6)


def find_horizon(image: np.ndarray, valid: np.ndarray, cfg: HorizonConfig) -> Horizon | None:
    """Detect the sky-ground line in ``image`` inside ``valid`` (the imaging area).

    Candidate per column: the strongest Gmax point whose ground side (below) has a local
    standard deviation of at least ``ground_std_min`` noise sigmas (constraint (a), the
    V_g-Th test that rejects cloud edges). The candidates are fitted by a robust polynomial;
    the fit is accepted when the inliers' position std is at most ``position_std_max`` px
    (constraint (b), V_L-Th) and they cover at least ``min_coverage`` of the valid columns.
    The result follows the measured skyline where it agrees with the fit or stands up to
    ``max_rise`` px above it, and the fit elsewhere across the imaging area.
    """
    h, w = image.shape
    f = image.astype(np.float32, copy=False)
    sigma = noise_sigma(image, valid)
    smooth = cv2.blur(f, (cfg.smooth, cfg.smooth)) if cfg.smooth > 1 else f
    g = max_gradient(smooth, cfg.step)
    pad = cfg.step + cfg.smooth // 2 + 1
    inner = cv2.erode(valid.astype(np.uint8), np.ones((2 * pad + 1, 2 * pad + 1), np.uint8)) > 0
    win = cfg.variance_window
    mean = cv2.blur(f, (win, win))
    std = np.sqrt(np.maximum(cv2.blur(f * f, (win, win)) - mean * mean, 0.0))
    below = np.full_like(std, 0.0)
    off = win // 2 + cfg.step + 1
    below[: h - off] = std[off:]
    g[~inner | (below < cfg.ground_std_min * sigma)] = 0.0
    # topmost strong edge per column: ground-side texture below it must not win
    peak = g.max(axis=0)
    first = np.argmax(g >= 0.5 * peak[None, :], axis=0)
    cols = np.nonzero(peak > 8.0 * sigma / cfg.smooth)[0]
    # sub-pixel: centroid of the edge response over the rows the first strong edge spans
    span = 2 * cfg.step + cfg.smooth
    rr = np.clip(first[cols][None, :] + np.arange(span + 1)[:, None], 0, h - 1)
    resp = g[rr, cols[None, :]]
    resp = np.where(resp >= 0.5 * peak[cols][None, :], resp, 0.0)
    rows = np.zeros(w)
    rows[cols] = (resp * rr).sum(axis=0) / np.maximum(resp.sum(axis=0), 1e-12)
    valid_cols = int(inner.any(axis=0).sum())
    if valid_cols == 0 or cols.size < max(8, cfg.min_coverage * valid_cols):
        return None
    x, y = cols.astype(np.float64), rows[cols]
    keep = np.ones(x.size, dtype=bool)
    scale = max(w / 2.0, 1.0)
    for _ in range(4):
        if keep.sum() <= cfg.degree + 1:
            return None
        coef = np.polyfit((x[keep] - scale) / scale, y[keep], cfg.degree)
        resid = y - np.polyval(coef, (x - scale) / scale)
        mad = 1.4826 * float(np.median(np.abs(resid[keep])))
        keep = np.abs(resid) <= max(3.0 * mad, 2.0)
    if keep.sum() < cfg.min_coverage * valid_cols or float(np.std(resid[keep])) > cfg.position_std_max:
        return None
    # the fit fills gaps and reaches the rim; measured skyline points are kept where they
    # agree with it or stand above it (buildings, trees: up to max_rise px)
    span = np.nonzero(valid.any(axis=0))[0]
    out = np.full(w, np.nan)
    out[span] = np.polyval(coef, (span - scale) / scale)
    use = keep | ((resid < 0) & (resid > -cfg.max_rise))
    out[cols[use]] = y[use]
    return Horizon(out)


def search_region(valid: np.ndarray, horizon: Horizon | None, margin: float) -> np.ndarray:
    """Deep-sky search region: inside ``valid`` and more than ``margin`` px above the horizon.

    The limit is the lowest horizon row within ``margin`` columns either side, so narrow
    dips of the skyline (a missed column on a rooftop) do not open the ground to detection.
    """
    if horizon is None:
        return valid
    rows = np.where(np.isfinite(horizon.rows), horizon.rows, np.inf)
    k = int(np.ceil(margin))
    if k > 0:
        padded = np.pad(rows, k, mode="edge")
        rows = np.min(np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1), axis=1)
    yy = np.arange(valid.shape[0])[:, None]
    return valid & (yy < (rows - margin)[None, :])


def search_zones(valid: np.ndarray, horizon: Horizon | None, margin: float, exclude_ground: str,
                 fisheye: bool) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Where to detect, and the zones that get their own threshold (None: one threshold).

    ``exclude_ground``: "always" searches only the deep sky above the horizon (the paper);
    "never" also the ground; "auto" excludes the ground only in a fisheye sky view
    (``fisheye``: an imaging circle was found), since a narrow view may show targets over the
    ground. When the ground is searched it is its own zone, so its clutter does not raise the
    sky's threshold.
    """
    sky = search_region(valid, horizon, margin)
    exclude = exclude_ground == "always" or (exclude_ground == "auto" and fisheye)
    if exclude or horizon is None:
        return sky, None
    return valid, [sky, valid & ~sky]


class HorizonTracker:
    """Re-estimates the horizon every ``cfg.every`` frames and smooths it over time.

    Each new estimate is blended per column with the previous one (weight ``cfg.smoothing``
    on the previous rows); a failed estimate keeps the previous horizon.
    """

    def __init__(self, cfg: HorizonConfig) -> None:
        self.cfg = cfg
        self.horizon: Horizon | None = None
        self._count = 0

    def update(self, image: np.ndarray, valid: np.ndarray) -> tuple[Horizon | None, bool]:
        """Return (current horizon, whether it was re-estimated on this call)."""
        due = self._count % self.cfg.every == 0
        self._count += 1
        if not self.cfg.enabled or not due:
            return self.horizon, False
        new = find_horizon(image, valid, self.cfg)
        if new is not None and self.horizon is not None:
            old = self.horizon.rows
            a = self.cfg.smoothing
            both = np.isfinite(old) & np.isfinite(new.rows)
            rows = new.rows.copy()
            rows[both] = a * old[both] + (1 - a) * new.rows[both]
            new = Horizon(rows)
        if new is not None:
            self.horizon = new
        return self.horizon, True
