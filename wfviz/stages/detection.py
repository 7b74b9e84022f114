"""Track start points: adaptive threshold of the residual and connected components."""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from wfviz.config import DetectionConfig
from wfviz.stages.noise import NoiseEstimate


@dataclass(frozen=True)
class Detections:
    """Connected components above threshold, brightest first.

    ``xy`` (N, 2) intensity-weighted centroids (x, y) of the residual above threshold;
    ``area`` pixel counts; ``peak`` and ``flux`` residual maximum and sum; ``bbox`` (N, 4)
    x, y, width, height; ``component`` each detection's label in ``labels`` (the label image,
    0 = background); ``threshold`` the adaptive threshold used (its median for a local
    threshold, whose map is ``threshold_map``); ``significance`` the signal-to-clutter ratio of
    each detection and ``blobness`` its shape measure, when computed (:func:`signal_to_clutter`,
    :func:`blobness`); ``change`` the largest change significance among its pixels
    (:func:`detect`, NaN where unknown); ``linearity`` how much of it is part of a line or an
    edge (:func:`linearity`, 0..1) and ``max_linearity`` the level above which it is
    :meth:`line_like` (``detection.max_linearity``); ``multiframe`` the largest multi-frame
    significance among its pixels (:func:`detect`, NaN where none).
    """

    xy: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    flux: np.ndarray
    bbox: np.ndarray
    component: np.ndarray
    labels: np.ndarray
    threshold: float
    threshold_map: np.ndarray | None = None
    significance: np.ndarray | None = None
    blobness: np.ndarray | None = None
    change: np.ndarray | None = None
    linearity: np.ndarray | None = None
    max_linearity: float = 1.0
    multiframe: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def subset(self, keep: np.ndarray) -> "Detections":
        """The detections where ``keep`` (bool, N) holds, same label image and thresholds."""
        k = np.asarray(keep, dtype=bool)
        opt = {f: (None if getattr(self, f) is None else getattr(self, f)[k])
               for f in ("significance", "blobness", "change", "linearity", "multiframe")}
        return Detections(self.xy[k], self.area[k], self.peak[k], self.flux[k], self.bbox[k],
                          self.component[k], self.labels, self.threshold, self.threshold_map, **opt,
                          max_linearity=self.max_linearity)

    def line_like(self) -> np.ndarray:
        """Detections that are part of a line or an edge: ``linearity > max_linearity`` (none
        where it was not measured)."""
        if self.linearity is None:
            return np.zeros(len(self), dtype=bool)
        return self.linearity > self.max_linearity

    def thresholds(self) -> np.ndarray:
        """The threshold each detection passed (the local map at its position, if any)."""
        if self.threshold_map is None:
            return np.full(len(self), self.threshold, dtype=np.float64)
        return sample_at(self.threshold_map, self.xy)


def sample_at(values: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``values`` at the pixels nearest the points ``xy`` (N, 2) = (x, y), clipped to the frame."""
    r = np.clip(np.round(xy[:, 1]).astype(np.int64), 0, values.shape[0] - 1)
    c = np.clip(np.round(xy[:, 0]).astype(np.int64), 0, values.shape[1] - 1)
    return values[r, c]


def adaptive_threshold(residual: np.ndarray, region: np.ndarray, k_sigma: float) -> float:
    """Threshold = mean + k * std of the residual inside ``region``."""
    mask = np.asarray(region, dtype=bool).view(np.uint8)
    n = cv2.countNonZero(mask)
    if not n:
        return float("inf")
    # sums in double precision: twice as fast as cv2.meanStdDev with a mask
    if residual.dtype in (np.uint8, np.uint16, np.int16, np.float32):
        inside = cv2.multiply(residual, mask, dtype=cv2.CV_32F)
    else:
        inside = residual.astype(np.float64) * mask
    mean = cv2.sumElems(inside)[0] / n
    var = cv2.norm(inside, cv2.NORM_L2SQR) / n - mean * mean
    return float(mean + k_sigma * max(np.sqrt(max(var, 0.0)), 1e-6))


def local_stats(residual: np.ndarray, region: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std of the residual over ``window`` x ``window`` boxes, inside ``region`` only."""
    res = residual.astype(np.float32, copy=False)
    m = region.astype(np.float32)
    n = cv2.blur(m, (window, window)) + 1e-6
    mean = cv2.blur(res * m, (window, window)) / n
    var = cv2.blur(res * res * m, (window, window)) / n - mean * mean
    return mean, np.sqrt(np.maximum(var, 1e-12))


def _component_stats(lab: np.ndarray, xs: np.ndarray, ys: np.ndarray, n: int) -> np.ndarray:
    """cv2-style stats (x, y, width, height, area) of labels 0..n-1 from their pixels (lab, xs, ys)."""
    stats = np.zeros((n, 5), dtype=np.int64)
    big = np.iinfo(np.int64).max
    x0, y0 = np.full(n, big), np.full(n, big)
    x1, y1 = np.full(n, -1), np.full(n, -1)
    np.minimum.at(x0, lab, xs), np.minimum.at(y0, lab, ys)
    np.maximum.at(x1, lab, xs), np.maximum.at(y1, lab, ys)
    area = np.bincount(lab, minlength=n)
    ok = area > 0
    stats[ok, 0], stats[ok, 1] = x0[ok], y0[ok]
    stats[ok, 2], stats[ok, 3] = x1[ok] - x0[ok] + 1, y1[ok] - y0[ok] + 1
    stats[:, 4] = area
    return stats


def signal_to_clutter(image: np.ndarray, region: np.ndarray, xy: np.ndarray, peak: np.ndarray,
                      window: int) -> np.ndarray:
    """SCR of each detection: residual peak / std of the image over ``window`` x ``window``
    around it (inside ``region``); textured clutter has a large std, so its spots score low."""
    if len(xy) == 0:
        return np.zeros(0)
    _, std = local_stats(image, region, window)
    return peak / np.maximum(sample_at(std, xy), 1e-6)


def score_detections(dets: Detections, image: np.ndarray, region: np.ndarray, cfg: DetectionConfig,
                     significance: bool, shape: bool, residual: np.ndarray | None = None) -> Detections:
    """``dets`` with their signal-to-clutter ratio (``significance``: :func:`signal_to_clutter`
    over ``cfg.local_window``) and blobness (``shape``: :func:`blobness` at ``cfg.blob_sigma``)
    in ``image``, as the confirmation tests and the recording's hover values need them, and
    (with the background-suppressed ``residual``, unless ``cfg.max_linearity`` is 1: off) their
    :func:`linearity` there."""
    if significance:
        dets = replace(dets, significance=signal_to_clutter(image, region, dets.xy, dets.peak,
                                                            cfg.local_window))
    if shape:
        dets = replace(dets, blobness=blobness(image, dets.xy, cfg.blob_sigma))
    if residual is not None and cfg.max_linearity < 1.0:
        dets = replace(dets, linearity=linearity(residual, dets), max_linearity=cfg.max_linearity)
    return dets


def blobness(image: np.ndarray, xy: np.ndarray, sigma: float) -> np.ndarray:
    """Shape of each detection (not in the paper): λ₂/λ₁, the ratio of the smaller to the larger
    eigenvalue of the negative Hessian of ``image`` smoothed by a Gaussian of ``sigma`` px, at
    the best of the 3x3 pixels around the detection. About 1 for a round spot, 0 for a ridge
    (a lit edge, a reed, a wire), negative for a saddle; -1 where no pixel is a local maximum
    in any direction (λ₁ ≤ 0)."""
    n = len(xy)
    if n == 0:
        return np.zeros(0)
    h, w = image.shape
    if h < 3 or w < 3:
        return np.full(n, -1.0)
    g = cv2.GaussianBlur(np.asarray(image, dtype=np.float32), (0, 0), sigma)
    x0 = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
    y0 = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
    d = np.arange(-1, 2)
    x = np.clip(x0[:, None, None] + d[None, None, :], 1, w - 2)  # (N, 3, 3) candidates
    y = np.clip(y0[:, None, None] + d[None, :, None], 1, h - 2)
    c = g[y, x].astype(np.float64)
    a = 2 * c - g[y, x - 1] - g[y, x + 1]   # -d²/dx²
    b = 2 * c - g[y - 1, x] - g[y + 1, x]   # -d²/dy²
    e = -(g[y + 1, x + 1] + g[y - 1, x - 1] - g[y + 1, x - 1] - g[y - 1, x + 1]) / 4.0  # -d²/dxdy
    mean, half = (a + b) / 2, np.sqrt(((a - b) / 2) ** 2 + e ** 2)
    l1, l2 = mean + half, mean - half
    ratio = np.where(l1 > 0, l2 / np.where(l1 > 0, l1, 1.0), -1.0)
    return ratio.reshape(n, -1).max(axis=1)


#: the strips :func:`linearity` reads on each side of a detection's peak: ``LINE_LENGTH`` px
#: along a direction from beyond its component (at least ``LINE_NEAR``, at most ``LINE_REACH`` px
#: from the peak: a longer component is a line itself), 3 px wide, in ``LINE_DIRECTIONS``
#: directions over 180°
LINE_NEAR, LINE_REACH, LINE_LENGTH, LINE_DIRECTIONS = 4, 16, 5, 16
_THETA = np.arange(2 * LINE_DIRECTIONS) * np.pi / LINE_DIRECTIONS  # + sides, then - sides
_ALONG = np.stack([np.cos(_THETA), np.sin(_THETA)], axis=1)  # (2D, 2) unit (x, y)
_ACROSS = np.stack([-np.sin(_THETA), np.cos(_THETA)], axis=1)
_STEPS = np.repeat(np.arange(LINE_LENGTH, dtype=np.float64), 3)  # (S,) px beyond the strip's start
_OFFSETS = np.tile(np.arange(-1.0, 2.0), LINE_LENGTH)  # (S,) px across
# each strip pixel's offset from the strip's start, x and y: (2D, S)
_STRIP_X = _STEPS * _ALONG[:, 0, None] + _OFFSETS * _ACROSS[:, 0, None]
_STRIP_Y = _STEPS * _ALONG[:, 1, None] + _OFFSETS * _ACROSS[:, 1, None]
_UP, _DOWN = _ALONG > 1e-9, _ALONG < -1e-9  # (2D, 2): the ray's sense along x and y
_SAFE_ALONG = np.where(_UP | _DOWN, _ALONG, 1.0)
_PERP_SECTOR = np.arange(-(LINE_DIRECTIONS // 12), LINE_DIRECTIONS // 12 + 1)  # within ~30° of 90°
_AROUND = np.arange(-2, 3)


def peak_pixels(residual: np.ndarray, dets: Detections) -> np.ndarray:
    """(N, 2) integer (x, y) of each detection's brightest pixel of its own component within
    2 px of its rounded centroid (the brightest pixel there when none of it is)."""
    n = len(dets)
    h, w = residual.shape
    x0 = np.rint(dets.xy[:, 0]).astype(np.int64)
    y0 = np.rint(dets.xy[:, 1]).astype(np.int64)
    x = np.minimum(np.maximum(x0[:, None, None] + _AROUND[None, None, :], 0), w - 1).reshape(n, -1)
    y = np.minimum(np.maximum(y0[:, None, None] + _AROUND[None, :, None], 0), h - 1).reshape(n, -1)
    flat = y * w + x
    v = residual.ravel()[flat].astype(np.float64)
    own = dets.labels.ravel()[flat] == dets.component[:, None]
    v[own.any(axis=1)[:, None] & ~own] = -np.inf
    k = np.argmax(v, axis=1)
    r = np.arange(n)
    return np.column_stack([x[r, k], y[r, k]])


def _row_medians(a: np.ndarray) -> np.ndarray:
    """The median of each row's values that are not NaN (0 for a row with none); np.nanmedian
    is ten times slower on small rows."""
    k = (~np.isnan(a)).sum(axis=1)
    srt = np.sort(a, axis=1)  # NaN last
    r = np.arange(len(a))
    lo = srt[r, np.maximum((k - 1) // 2, 0)]
    hi = srt[r, np.minimum(k // 2, a.shape[1] - 1)]
    return np.where(k > 0, (lo + hi) / 2, 0.0)


def linearity(residual: np.ndarray, dets: Detections) -> np.ndarray:
    """How much of each detection is part of a line or an edge (not in the paper), in [0, 1]:
    how far the residual carries on beyond it on both sides along its best direction, as a
    share of its threshold's height (a line goes on at about the height where its detected
    piece was cut off; beyond a target there is only background).

    Around each detection's peak (:func:`peak_pixels`) strips 3 px wide (each step along one
    takes the largest of its 3 pixels across, on a thin line however it falls between them,
    and so does the background) and ``LINE_LENGTH`` px
    long run on both sides in ``LINE_DIRECTIONS`` directions over 180°, each from where the ray
    from the peak leaves the component's bounding box (at least ``LINE_NEAR``, at most
    ``LINE_REACH`` px out): what lies beyond the detection, so that a target's own parts (a
    drone's arms, a wing) do not count while a road goes on beyond any piece of it (a component
    reaching farther on both sides is a line itself). The best direction is the one whose weaker side
    has the larger mean; the background is the median of the strips within 30° of the
    perpendicular (beside a line, not on it). Linearity is the weaker side's mean above the
    background over the threshold's height above it (:meth:`Detections.thresholds`), clipped to
    [0, 1]: about 1 for a road, wire, lit edge or skyline, about 0 for a point, a blob or a
    larger target, and for an area (it carries on across too: its background is its own level;
    0 where the background is above the threshold). Strip pixels outside the frame are left out;
    where one side has none (a line leaving the frame) the other side decides alone."""
    n = len(dets)
    if n == 0:
        return np.zeros(0)
    h, w = residual.shape
    px = peak_pixels(residual, dets)
    # where each ray leaves the component's box [x0 - 0.5, x1 + 0.5] x [y0 - 0.5, y1 + 0.5]
    lo = dets.bbox[:, :2].astype(np.float64) - 0.5 - px  # (N, 2), <= 0 when the peak is inside
    hi = dets.bbox[:, :2] + dets.bbox[:, 2:] - 0.5 - px
    t = np.where(_UP, hi[:, None, :] / _SAFE_ALONG, np.where(_DOWN, lo[:, None, :] / _SAFE_ALONG, np.inf))
    start = np.minimum(np.maximum(np.minimum(t[:, :, 0], t[:, :, 1]), LINE_NEAR - 1.0), LINE_REACH - 1.0) + 1.0
    xs = np.rint((px[:, 0, None] + start * _ALONG[:, 0])[:, :, None] + _STRIP_X).astype(np.int64)  # (N, 2D, S)
    ys = np.rint((px[:, 1, None] + start * _ALONG[:, 1])[:, :, None] + _STRIP_Y).astype(np.int64)
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)  # + sides, then - sides
    vals = residual.ravel()[np.where(inside, ys * w + xs, 0)].astype(np.float64)
    vals[~inside] = np.nan
    across = vals.reshape(n, 2 * LINE_DIRECTIONS, LINE_LENGTH, 3)
    vals = np.fmax(np.fmax(across[..., 0], across[..., 1]), across[..., 2])  # (N, 2D, L)
    known = ~np.isnan(vals)
    with np.errstate(divide="ignore", invalid="ignore"):
        side = np.where(known, vals, 0.0).sum(axis=2) / known.sum(axis=2)  # NaN where none is known
    both = np.fmin(side[:, :LINE_DIRECTIONS], side[:, LINE_DIRECTIONS:])  # (N, D); one side: it
    both[np.isnan(both)] = -np.inf
    best = np.argmax(both, axis=1)
    r = np.arange(n)[:, None]
    perp = (best[:, None] + LINE_DIRECTIONS // 2 + _PERP_SECTOR[None, :]) % LINE_DIRECTIONS
    beside = np.concatenate([vals[r, perp], vals[r, perp + LINE_DIRECTIONS]], axis=1).reshape(n, -1)
    base = _row_medians(beside)
    height = dets.thresholds() - base
    along = both[r[:, 0], best] - base
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(height > 0, along / height, 0.0)
    out[~np.isfinite(out)] = 0.0
    return np.minimum(np.maximum(out, 0.0), 1.0)


def path_heads(multi: np.ndarray, k: float | np.ndarray, region: np.ndarray,
               found: np.ndarray | None = None, apart: int = 2) -> np.ndarray:
    """uint8 mask (1) of the pixels of ``region`` where ``multi`` (a multi-frame significance)
    exceeds ``k`` (σ; a number or a per-pixel map) and is the largest within 2 px: the head of a
    path, not its trail (each step behind it lower by the integrator's λ); without those within
    ``apart`` px of a pixel of ``found`` (what this frame detected on its own: the head adds
    nothing there, and would widen that detection)."""
    above = np.asarray(cv2.compare(multi, k, cv2.CMP_GT)) & np.asarray(region, dtype=bool).view(np.uint8)
    idx = np.flatnonzero(above.view(bool))  # 0/1: numpy's fast path for bool
    if len(idx):
        h, w = multi.shape
        r, c = idx // w, idx % w
        rr = np.clip(r[:, None, None] + _AROUND[None, :, None], 0, h - 1)
        cc = np.clip(c[:, None, None] + _AROUND[None, None, :], 0, w - 1)
        best = multi[rr, cc].reshape(len(idx), -1).max(axis=1)
        drop = multi.ravel()[idx] < best
        if found is not None:
            a = np.arange(-apart, apart + 1)
            fr = np.clip(r[:, None, None] + a[None, :, None], 0, h - 1)
            fc = np.clip(c[:, None, None] + a[None, None, :], 0, w - 1)
            drop |= found[fr, fc].reshape(len(idx), -1).any(axis=1)
        above.ravel()[idx[drop]] = 0
    return above


def detect(residual: np.ndarray, region: np.ndarray, cfg: DetectionConfig,
           zones: list[np.ndarray] | None = None, noise: NoiseEstimate | None = None,
           change: np.ndarray | None = None, k_map: np.ndarray | None = None,
           multi: np.ndarray | None = None) -> Detections:
    """Threshold ``residual`` inside ``region`` and label 8-connected components.

    ``cfg.mode``: "cfar" thresholds at ``level + k_sigma · sigma`` of the local ``noise``
    estimate (:mod:`wfviz.stages.noise`) and gives each detection its significance, the peak's
    ``(residual - level) / sigma``; "global" at mean + k·std of the whole region (the paper),
    where ``zones`` (masks partitioning the region, e.g. sky and ground) each get their own
    threshold; "local" at the mean + k·std of a ``local_window`` box.

    ``change`` (cfar only): the change significance of every pixel (what is new at its place
    in the scene, in its own noise σ; NaN where unknown). A pixel above ``k_sigma`` in either
    map is detected, a component's significance is the larger of the two, its ``change`` the
    largest change significance among its pixels, and its centroid weighs each pixel by how far
    the larger of the two exceeds ``k_sigma``. ``k_map`` (cfar only; float32, the frame's
    shape): the threshold in σ of every pixel instead of ``k_sigma`` (lower in the gates of
    confirmed tracks, :func:`wfviz.tracking.confirmation.gate_threshold`).

    ``multi`` (cfar only, with ``change``): the multi-frame significance
    (:mod:`wfviz.stages.multiframe`): its path heads above the threshold (:func:`path_heads`)
    are detected too (in the centroid a head weighs only where no pixel of this frame's own
    is above the threshold: a component found by this frame keeps its own centroid), but a
    component's significance and change stay
    this frame's own (below the threshold for a component only the multi-frame evidence
    found: the tracks score each frame's own evidence, never the integrated one twice); its
    ``multiframe`` is the largest multi-frame significance among its pixels.
    """
    res = residual
    z_of = None  # (level, sigma) maps when significance comes from the noise estimate
    if cfg.mode == "cfar":
        if noise is None:
            raise ValueError("detection.mode 'cfar' needs a noise estimate")
        res = residual.astype(np.float32, copy=False)
        thr_map = (cv2.scaleAdd(noise.sigma, float(cfg.k_sigma), noise.level) if k_map is None
                   else cv2.add(cv2.multiply(noise.sigma, k_map), noise.level))
        thr = noise.typical_threshold(cfg.k_sigma)  # for the record
        excess = cv2.subtract(res, thr_map)
        z_of = (noise.level, noise.sigma)
    elif cfg.mode == "global" and zones:
        res = residual.astype(np.float32, copy=False)
        thr_map = np.full(res.shape, np.inf, dtype=np.float32)
        for z in zones:
            thr_map[z] = adaptive_threshold(residual, z, cfg.k_sigma)
        thr = adaptive_threshold(residual, zones[0], cfg.k_sigma)
        excess = res - thr_map
    elif cfg.mode == "local":
        res = residual.astype(np.float32, copy=False)
        lmean, lstd = local_stats(res, region, cfg.local_window)
        thr_map: np.ndarray | None = lmean + cfg.k_sigma * lstd
        thr = float(np.median(thr_map[region])) if region.any() else float("inf")
        excess = res - thr_map
    else:
        thr_map = None
        thr = adaptive_threshold(residual, region, cfg.k_sigma)
        excess = None  # one threshold: compare in the residual's own type, no float copy
    if excess is None:
        src = residual if residual.dtype in (np.uint8, np.uint16, np.float32) else residual.astype(np.float32)
        binary = cv2.compare(src, float(thr), cv2.CMP_GT) if np.isfinite(thr) else np.zeros(src.shape, np.uint8)
        binary &= np.asarray(region, dtype=bool).view(np.uint8)  # 255 & 1: a 0/1 mask
    else:
        binary = cv2.compare(excess, 0.0, cv2.CMP_GT)
        if change is not None:  # NaN compares false
            binary |= cv2.compare(change, float(cfg.k_sigma) if k_map is None else k_map, cv2.CMP_GT)
            if multi is not None:
                binary |= path_heads(multi, float(cfg.k_sigma) if k_map is None else k_map, region,
                                     binary, max(2, cfg.merge_gap + 1))
        binary &= np.asarray(region, dtype=bool).view(np.uint8)
    # labels without cv2's stats (10x faster on sparse masks); stats from the few pixels below
    if cfg.merge_gap > 0:  # one target split by gaps of up to merge_gap px stays one component
        k = 2 * cfg.merge_gap + 1
        grown = cv2.dilate(binary, np.ones((k, k), np.uint8))
        n, labels = cv2.connectedComponents(grown, connectivity=8, ltype=cv2.CV_32S)
        labels *= binary  # keep labels on the pixels above threshold only
    else:
        n, labels = cv2.connectedComponents(binary, connectivity=8, ltype=cv2.CV_32S)
    idx = np.flatnonzero(binary.view(bool))  # bool: numpy's fast path
    lab = labels.ravel()[idx]
    raw = res.ravel()[idx].astype(np.float32)
    val = raw - np.float32(thr) if excess is None else excess.ravel()[idx]
    zval = zc = zm = None
    if z_of is not None:
        zval = ((raw - z_of[0].ravel()[idx]) / z_of[1].ravel()[idx]).astype(np.float64)
        if change is not None:
            zc = np.nan_to_num(change.ravel()[idx].astype(np.float64), nan=-np.inf)
            k_here = cfg.k_sigma if k_map is None else k_map.ravel()[idx]
            own = np.maximum(zval, zc) - k_here
            if multi is not None:  # a path head weighs only where nothing of this frame's own is above
                zm = np.nan_to_num(multi.ravel()[idx].astype(np.float64), nan=-np.inf)
                own = np.where(own > 0, own, 1e-3 * np.maximum(zm - k_here, 0.0))
            val = own.astype(np.float32)
    w = residual.shape[1]
    ix, iy = idx % w, idx // w
    stats = _component_stats(lab, ix, iy, n)
    xs, ys = ix.astype(np.float64), iy.astype(np.float64)
    flux = np.bincount(lab, weights=val, minlength=n)[1:]
    total = np.bincount(lab, weights=raw, minlength=n)[1:]
    safe = np.where(flux > 0, flux, 1.0)
    cx = np.bincount(lab, weights=val * xs, minlength=n)[1:] / safe
    cy = np.bincount(lab, weights=val * ys, minlength=n)[1:] / safe
    peak = np.zeros(n)
    np.maximum.at(peak, lab, raw)
    peak = peak[1:]
    sig = changed = multiple = None
    if zval is not None:  # significance of each component: its largest (r - level) / sigma
        sig = np.full(n, -np.inf)
        np.maximum.at(sig, lab, zval if zc is None else np.maximum(zval, zc))
        sig = sig[1:]
        if zc is not None:
            changed = np.full(n, -np.inf)
            np.maximum.at(changed, lab, zc)
            changed = np.where(np.isfinite(changed[1:]), changed[1:], np.nan)
        if zm is not None:
            multiple = np.full(n, -np.inf)
            np.maximum.at(multiple, lab, zm)
            multiple = np.where(np.isfinite(multiple[1:]), multiple[1:], np.nan)
    area = stats[1:, cv2.CC_STAT_AREA]
    keep = np.nonzero((area >= cfg.min_area) & (area <= cfg.max_area))[0]
    rank = peak if sig is None else sig
    keep = keep[np.argsort(-rank[keep], kind="stable")][: cfg.max_detections]

    return Detections(
        xy=np.column_stack([cx[keep], cy[keep]]),
        area=area[keep].astype(np.int64),
        peak=peak[keep],
        flux=total[keep],
        bbox=stats[1:, :4][keep].astype(np.int64),
        component=keep + 1,
        labels=labels,
        threshold=thr,
        threshold_map=thr_map,
        significance=None if sig is None else sig[keep],
        change=None if changed is None else changed[keep],
        multiframe=None if multiple is None else multiple[keep],
    )


def no_detections(shape: tuple[int, int], threshold: float = float("nan")) -> Detections:
    """A :class:`Detections` with no component (a frame a tracker thresholds nothing in, as the
    track-before-detect does)."""
    z = np.zeros(0)
    zi = np.zeros(0, dtype=np.int64)
    return Detections(np.zeros((0, 2)), zi, z, z, np.zeros((0, 4), dtype=np.int64), zi,
                      np.zeros(shape, dtype=np.int32), threshold)
