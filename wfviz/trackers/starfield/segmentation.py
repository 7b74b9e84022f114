"""Star-field segmentation (Gao Jianwei et al. 2012: "segment, label connected components").

Per frame: a smooth background (coarse block medians, stars clipped, Gaussian-blurred on a
downsampled grid) is subtracted; the residual is smoothed with a Gaussian of the PSF's size
(a matched filter for point sources); pixels above ``level + k_sigma * sigma`` of the smoothed
map (``level`` and ``sigma`` its median and MAD-based std, robust against the stars) form
8-connected components, one star point each, with the intensity-weighted centroid of the
unsmoothed residual over the component.

A point whose brightest residual pixel carries more than ``SHARP_FRACTION`` of the light in the
5x5 box around it is *sharp*: no optical point source does that (a Gaussian PSF of sigma >= 0.5 px puts at most
~47 % of its light in one pixel, the 1.15 px PSF of a telescope ~12 %), a single-pixel sensor
event does (hot pixel, cosmic-ray hit: ~100 %). Sharp points stand still on the sensor while
the sky jitters, so they are kept out of the star pairing (a registration voting on them
locks onto the sensor, displacement 0) and out of the candidates (:class:`Segmentation`'s
``sharp``).

:func:`resegment` re-thresholds a small window around a prediction with a threshold computed
from that window alone (the paper's "re-segmentation with a new, lower threshold").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.stages.detection import Detections
from wfviz.stages.noise import fill_missing, tile_statistics, upsample
from wfviz.trackers.starfield.config import StarSegmentationConfig

_SAMPLE = 8  # every 8th row and column for the robust statistics
DEAD_SIGMA = 5.0  # a pixel this many robust stds below its 3x3 median is a dead pixel
SHARP_FRACTION = 0.5  # share of a component's flux in its brightest pixel above which it is sharp


@dataclass(frozen=True)
class Segmentation:
    """One frame's star points and the maps they came from.

    ``points`` are all components (stars, targets, noise, defects), brightest ``flux`` first;
    ``residual`` is the frame minus its background, ``smoothed`` the detection map,
    ``level`` and ``sigma`` its robust median and std (the median of the local noise map
    when there is one); ``points.threshold`` = level + k_sigma * sigma; ``sharp`` (N,) bool:
    the point is a single-pixel event (module docstring), not an optical point source;
    ``level_map``/``sigma_map``: the local level and noise of ``smoothed`` per pixel
    (:func:`local_noise`; None with ``noise_tile`` 0), against which pixels were thresholded.
    """

    points: Detections
    residual: np.ndarray
    smoothed: np.ndarray
    level: float
    sigma: float
    sharp: np.ndarray | None = None
    level_map: np.ndarray | None = None
    sigma_map: np.ndarray | None = None


def noise_at(sigma_map: np.ndarray | None, sigma: float, x: float, y: float) -> float:
    """``sigma_map`` at image position (x, y), clamped to the frame (``sigma`` without a map)."""
    if sigma_map is None:
        return sigma
    h, w = sigma_map.shape
    return float(sigma_map[min(max(int(round(y)), 0), h - 1), min(max(int(round(x)), 0), w - 1)])


@dataclass(frozen=True)
class Resegmentation:
    """A local re-segmentation: the window (x0, y0, w, h), its threshold, the point found
    nearest the prediction (x, y, flux, area, peak of the smoothed map) or None."""

    x0: int
    y0: int
    w: int
    h: int
    threshold: float
    found: tuple[float, float, float, int, float] | None


def robust_stats(a: np.ndarray, step: int = _SAMPLE) -> tuple[float, float]:
    """Median and 1.4826 * MAD of ``a`` sampled every ``step`` rows and columns."""
    sub = a[::step, ::step] if a.ndim == 2 and min(a.shape) >= 4 * step else a
    sub = np.asarray(sub, dtype=np.float32).ravel()
    med = float(np.median(sub))
    return med, max(float(np.median(np.abs(sub - med))) * 1.4826, 1e-6)


def estimate_background(image: np.ndarray, block: int, sigma: float, clip: float = 2.5) -> np.ndarray:
    """Smooth background of a star field (float32, full size).

    Pixels more than ``DEAD_SIGMA`` robust stds below the median of their 3x3 neighbourhood
    (dead pixels: single-pixel low events) are first raised to that level. Left in, a dead
    pixel of 0 DN on a 1600 DN sky pulled the blurred background ~15 DN down over a few px
    around it: a ring of +4 sigma in the residual that segmented as points standing still on
    the sensor. (Clipping all low outliers against the block guess instead, or taking the
    background of the 3x3 median image, changes it over dark or fine extended structure: the
    synth scenario long-1024 lost 0.05-0.2 MOTA.) A first guess is the 3x3 median of ``block`` x ``block`` block means (a block
    holding a bright star is an outlier among its neighbours); pixels more than ``clip``
    robust stds above it (the stars) are clipped to that level, and the result is
    Gaussian-blurred with ``sigma`` px on a grid downsampled by ``max(1, sigma // 2)``.
    """
    img = image.astype(np.float32, copy=False)
    med = cv2.medianBlur(img, 3)
    _, sd = robust_stats(img - med)
    img = cv2.max(img, med - np.float32(DEAD_SIGMA * sd))  # dead pixels raised to their neighbours
    h, w = img.shape
    bw, bh = max(1, w // block), max(1, h // block)
    small = cv2.medianBlur(cv2.resize(img, (bw, bh), interpolation=cv2.INTER_AREA), 3)
    first = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    _, sd = robust_stats(img - first)
    clipped = cv2.min(img, first + np.float32(clip * sd))
    down = max(1, int(sigma // 2))
    if down > 1 and min(h, w) >= 8 * down:
        sm = cv2.resize(clipped, (w // down, h // down), interpolation=cv2.INTER_AREA)
        sm = cv2.GaussianBlur(sm, (0, 0), sigma / down)
        return cv2.resize(sm, (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.GaussianBlur(clipped, (0, 0), sigma)


def _components(binary: np.ndarray, residual: np.ndarray, smoothed: np.ndarray,
                min_area: int, max_area: int, threshold: float,
                labels_out: bool = True) -> Detections:
    """Connected components of ``binary`` with intensity-weighted centroids of ``residual``.

    Labels without OpenCV's statistics (which cost ~10x the labelling on a sparse
    megapixel mask); area, box, flux, peak and centroid come from the labelled pixels sorted
    by label."""
    n, labels = cv2.connectedComponents(binary, connectivity=8, ltype=cv2.CV_32S)
    nz = cv2.findNonZero(binary)
    if n <= 1 or nz is None:
        z = np.zeros(0)
        return Detections(np.zeros((0, 2)), z.astype(np.int64), z, z, np.zeros((0, 4), np.int64),
                          z.astype(np.int64), labels if labels_out else np.zeros((0, 0), np.int32),
                          threshold)
    nz = nz.reshape(-1, 2)
    xs, ys = nz[:, 0], nz[:, 1]
    lab = labels[ys, xs]
    order = np.argsort(lab, kind="stable")
    lab, xs, ys = lab[order], xs[order], ys[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])  # one per label 1..n-1
    area = np.diff(np.r_[starts, len(lab)])
    val = residual[ys, xs].astype(np.float64)
    flux = np.add.reduceat(val, starts)
    # Weights: the residual, floored at a small positive value so faint components whose
    # residual sum is near zero still get their geometric centre.
    wt = np.maximum(val, 1e-3)
    sw = np.add.reduceat(wt, starts)
    cx = np.add.reduceat(wt * xs, starts) / sw
    cy = np.add.reduceat(wt * ys, starts) / sw
    peak = np.maximum.reduceat(smoothed[ys, xs], starts).astype(np.float64)
    x0, y0 = np.minimum.reduceat(xs, starts), np.minimum.reduceat(ys, starts)
    bbox = np.column_stack([x0, y0, np.maximum.reduceat(xs, starts) - x0 + 1,
                            np.maximum.reduceat(ys, starts) - y0 + 1]).astype(np.int64)
    keep = np.nonzero((area >= min_area) & (area <= max_area))[0]
    keep = keep[np.argsort(-flux[keep], kind="stable")]
    return Detections(
        xy=np.column_stack([cx[keep], cy[keep]]), area=area[keep].astype(np.int64),
        peak=peak[keep], flux=flux[keep], bbox=bbox[keep], component=lab[starts][keep].astype(np.int64),
        labels=labels if labels_out else np.zeros((0, 0), np.int32), threshold=threshold)


def local_noise(smoothed: np.ndarray, tile: int, smooth_sigma: float, clip: float = 3.0
                ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(level map, sigma map, median level, median sigma) of the detection map ``smoothed``.

    The sources are masked first: pixels above the global robust median + ``clip`` robust stds,
    grown by the reach of a smoothed point source (3 * sqrt(2) * ``smooth_sigma`` px, the
    matched filter's size standing in for the PSF's), so neither a star's core nor its wing
    enters the statistics. The rest gives a clipped median and std per ``tile`` x ``tile``
    tile (:func:`wfviz.stages.noise.tile_statistics`; tiles with too few free pixels take their
    nearest neighbour's), bilinearly interpolated to every pixel."""
    level0, sigma0 = robust_stats(smoothed)
    r = max(1, int(math.ceil(3.0 * math.sqrt(2.0) * max(smooth_sigma, 0.5))))
    src = (smoothed > np.float32(level0 + clip * sigma0)).view(np.uint8)
    free = cv2.dilate(src, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))) == 0
    lv, sg, _, _ = tile_statistics(smoothed, free, tile)
    lv, sg = fill_missing(lv, level0), fill_missing(sg, sigma0)
    shape = smoothed.shape
    return (upsample(lv, shape, tile), upsample(sg, shape, tile),
            float(np.median(lv)), float(np.median(sg)))


def column_offsets(residual: np.ndarray, step: int = 4) -> np.ndarray:
    """Per column: the median of ``residual`` over every ``step``-th row (float32, (w,)).

    A sensor's column fixed pattern (read-out amplifier offsets) is constant along a column and
    static on the sensor; the matched smoothing does not average it away (it is correlated
    along the column), so it inflates the detection map's noise and a bright column segments
    as a string of points that stand still on the sensor. The median over the rows is blind to
    the few rows a star or a target covers."""
    sub = np.ascontiguousarray(residual[::step].T)
    mid = sub.shape[1] // 2
    return np.partition(sub, mid, axis=1)[:, mid].astype(np.float32)


def segment(image: np.ndarray, cfg: StarSegmentationConfig) -> Segmentation:
    """Background, column offsets (:func:`column_offsets`, with ``column_offsets``), matched
    smoothing, threshold in units of the local noise of the smoothed map (:func:`local_noise`;
    one global robust std with ``noise_tile`` 0) and components of one frame."""
    img = image.astype(np.float32, copy=False)
    residual = img - estimate_background(img, cfg.background_block, cfg.background_sigma)
    if cfg.column_offsets and residual.shape[0] >= 64:
        residual -= column_offsets(residual)[None, :]
    smoothed = (cv2.GaussianBlur(residual, (0, 0), cfg.smooth_sigma) if cfg.smooth_sigma > 0
                else residual)
    level_map = sigma_map = None
    if cfg.noise_tile > 0:
        level_map, sigma_map, level, sigma = local_noise(smoothed, cfg.noise_tile, cfg.smooth_sigma)
        binary = (smoothed > cv2.scaleAdd(sigma_map, float(cfg.k_sigma), level_map)).view(np.uint8)
    else:
        level, sigma = robust_stats(smoothed)
        binary = (smoothed > level + cfg.k_sigma * sigma).view(np.uint8)
    thr = level + cfg.k_sigma * sigma
    pts = _components(binary, residual, smoothed, cfg.min_area, cfg.max_area, thr)
    return Segmentation(pts, residual, smoothed, level, sigma, sharpness(pts, residual) > SHARP_FRACTION,
                        level_map, sigma_map)


def sharpness(pts: Detections, residual: np.ndarray) -> np.ndarray:
    """Per point: its brightest residual pixel (3x3 around the centroid) over the residual's
    sum in the 5x5 box around the centroid (the component's own flux would do for bright
    points, but a faint one has few pixels above the threshold)."""
    if not len(pts):
        return np.zeros(0)
    h, w = residual.shape
    xi = np.clip(np.rint(pts.xy[:, 0]).astype(np.int64), 2, w - 3)
    yi = np.clip(np.rint(pts.xy[:, 1]).astype(np.int64), 2, h - 3)
    best = np.full(len(pts), -np.inf)
    total = np.zeros(len(pts))
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            v = residual[yi + dy, xi + dx].astype(np.float64)
            total += v
            if abs(dx) <= 1 and abs(dy) <= 1:
                best = np.maximum(best, v)
    return best / np.maximum(total, np.maximum(best, 1e-6))


def resegment(residual: np.ndarray, sigma: float, x: float, y: float, window: int, k_sigma: float,
              radius: float, references: list[tuple[np.ndarray, np.ndarray]] = (),
              smooth_sigma: float = 1.0, aperture: int = 2) -> Resegmentation:
    """Re-threshold the ``window`` px box of a frame's ``residual`` around (x, y).

    ``references``: other residual frames with the 2x3 affine from this frame's image to
    theirs. When given, the box is searched in ``residual`` *minus their mean warped into this
    frame* (bicubic): the stars, still in the sky, cancel; the target, elsewhere in those
    frames, stays. The (difference) box is smoothed like the detection map and thresholded at
    its own median + ``k_sigma`` * ``sigma``, the detection map's local noise there
    (:func:`local_noise`, estimated with the sources masked), times sqrt(1 + 1/n) for the
    difference with the mean of n references. Not the box's own spread: 15 x 15 correlated
    pixels that hold the target (and perhaps a star's wing) overstate the noise, by 1.2-1.8x
    on the independent sample S5, which put the "lower" threshold above the frame's.

    The target is the local maximum above the threshold nearest (x, y) within ``radius`` px;
    its position is the intensity-weighted centroid of the (difference) residual over the
    above-threshold pixels within ``aperture`` px of the maximum. A maximum rather than a
    component: a target beside a star forms one component with it at any threshold low
    enough to find the target."""
    h, w = residual.shape
    half = window // 2
    xi, yi = int(round(x)), int(round(y))
    x0, y0 = max(0, xi - half), max(0, yi - half)
    x1, y1 = min(w, xi + half + 1), min(h, yi + half + 1)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return Resegmentation(x0, y0, max(0, x1 - x0), max(0, y1 - y0), float("nan"), None)
    pad = int(math.ceil(3 * smooth_sigma))
    px0, py0, px1, py1 = max(0, x0 - pad), max(0, y0 - pad), min(w, x1 + pad), min(h, y1 + pad)
    patch = residual[py0:py1, px0:px1]
    expected = sigma
    if references:
        shift = np.array([[1.0, 0.0, px0], [0.0, 1.0, py0], [0.0, 0.0, 1.0]])
        sky = np.zeros(patch.shape, np.float32)
        for img, m in references:
            sky += cv2.warpAffine(img, (np.vstack([m, [0, 0, 1]]) @ shift)[:2], (px1 - px0, py1 - py0),
                                  flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        patch = patch - sky / len(references)
        expected *= math.sqrt(1.0 + 1.0 / len(references))
    smp = cv2.GaussianBlur(patch, (0, 0), smooth_sigma) if smooth_sigma > 0 else patch
    res = patch[y0 - py0:y1 - py0, x0 - px0:x1 - px0]
    sm = smp[y0 - py0:y1 - py0, x0 - px0:x1 - px0]
    level = float(np.median(sm))
    thr = level + k_sigma * expected
    peaks = (sm > thr) & (sm >= cv2.dilate(sm, np.ones((3, 3), np.uint8)))
    found = None
    ys, xs = np.nonzero(peaks)
    if len(xs):
        d = np.hypot(xs + x0 - x, ys + y0 - y)
        i = int(np.argmin(d))
        if d[i] <= radius:
            py, px = ys[i], xs[i]
            a0, a1 = max(0, px - aperture), min(sm.shape[1], px + aperture + 1)
            b0, b1 = max(0, py - aperture), min(sm.shape[0], py + aperture + 1)
            m = sm[b0:b1, a0:a1] > thr
            wt = np.maximum(res[b0:b1, a0:a1], 1e-3) * m
            gy, gx = np.mgrid[b0:b1, a0:a1]
            s = float(wt.sum())
            found = (float((wt * gx).sum() / s) + x0, float((wt * gy).sum() / s) + y0,
                     float(res[b0:b1, a0:a1][m].sum()), int(m.sum()), float(sm[py, px]))
    return Resegmentation(x0, y0, x1 - x0, y1 - y0, float(thr), found)
