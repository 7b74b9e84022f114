"""Imaging circle of a fisheye lens and the non-imaging mask (GEWC paper, eq. 1)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.config import CircleConfig


#: Confidence ramps of :func:`circle_confidence` (suggested config names in brackets): rim
#: fit residual RMS in px, full at RMS_GOOD, none at RMS_BAD (``circle.rms_good`` /
#: ``circle.rms_bad``); share of rim points that are inliers (``circle.inliers_good`` /
#: ``circle.inliers_bad``); imaging/dark level difference in corner-noise sigmas, log ramp
#: (``circle.contrast_good`` / ``circle.contrast_bad``); share of the 36 ten-degree sectors
#: around the centre that hold inlier rim points (``circle.coverage_good`` /
#: ``circle.coverage_bad``: half the circle determines it well).
RMS_GOOD, RMS_BAD = 0.5, 1.5
INLIERS_GOOD, INLIERS_BAD = 0.95, 0.7
CONTRAST_GOOD, CONTRAST_BAD = 50.0, 10.0
COVERAGE_GOOD, COVERAGE_BAD = 0.5, 0.15
SECTORS = 36


@dataclass(frozen=True)
class ImagingCircle:
    """Distortion centre (x = column, y = row) and pixel radius R_max of the field edge;
    ``confidence`` in [0, 1] (:func:`circle_confidence`; 1 for a configured circle)."""

    cx: float
    cy: float
    radius: float
    confidence: float = 1.0


def _ramp(x: float, bad: float, good: float) -> float:
    """0 at ``bad``, 1 at ``good``, linear between (either order)."""
    return float(np.clip((x - bad) / (good - bad), 0.0, 1.0))


def circle_confidence(rms: float, inliers: float, contrast: float, coverage: float) -> float:
    """Confidence of an estimated circle: the product of four ramps, each 1 when that
    evidence is clearly good and 0 at the estimate's rejection limit:

    - rim fit residual RMS (px): 1 at RMS_GOOD, 0 at RMS_BAD (the rejection limit);
    - inlier share of the rim points: 1 at INLIERS_GOOD, 0 at INLIERS_BAD (the limit);
    - contrast = (imaging level - dark level) / corner noise σ: log ramp, 1 at
      CONTRAST_GOOD, 0 at CONTRAST_BAD (the limit);
    - coverage = share of SECTORS angular sectors around the centre holding inlier rim
      points: 1 at COVERAGE_GOOD, 0 at COVERAGE_BAD.
    """
    c = _ramp(rms, RMS_BAD, RMS_GOOD) * _ramp(inliers, INLIERS_BAD, INLIERS_GOOD)
    c *= _ramp(float(np.log(max(contrast, 1e-9))), float(np.log(CONTRAST_BAD)), float(np.log(CONTRAST_GOOD)))
    return c * _ramp(coverage, COVERAGE_BAD, COVERAGE_GOOD)


def fit_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares (Kasa) circle through points; returns (cx, cy, r)."""
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x * x + y * y
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = sol[0] / 2, sol[1] / 2
    return float(cx), float(cy), float(np.sqrt(sol[2] + cx * cx + cy * cy))


def _corner_patches(image: np.ndarray) -> np.ndarray:
    h, w = image.shape
    s = max(2, min(h, w) // 24)
    return np.concatenate([image[:s, :s].ravel(), image[:s, -s:].ravel(),
                           image[-s:, :s].ravel(), image[-s:, -s:].ravel()])


def estimate_imaging_circle(image: np.ndarray) -> ImagingCircle | None:
    """Estimate the imaging circle from the dark non-imaging corners of a 180° lens.

    Returns None when the frame has no dark corners (a lens whose image fills the frame):
    the four corner patches must be darker than the frame centre by a clear margin, and the
    bright region's rim must fit a circle. The rim is located at the half level between the
    dark and imaging levels with sub-pixel interpolation along the columns and rows. The
    confidence comes from :func:`circle_confidence` (fit RMS, inlier share, contrast in
    corner-noise sigmas, angular coverage of the inlier rim points).
    """
    img = image.astype(np.float32, copy=False)
    h, w = img.shape
    if min(h, w) < 16:
        return None
    corners = _corner_patches(img)
    dark = float(np.median(corners))
    noise = 1.4826 * float(np.median(np.abs(corners - dark))) + 1e-6
    centre = img[h // 4: 3 * h // 4, w // 4: 3 * w // 4]
    bright = float(np.percentile(centre, 10))
    if bright - dark < max(10 * noise, 1e-3 * max(abs(bright), 1.0)):
        return None
    # every corner patch must itself be dark
    s = max(2, min(h, w) // 24)
    for patch in (img[:s, :s], img[:s, -s:], img[-s:, :s], img[-s:, -s:]):
        if np.median(patch) > dark + 0.25 * (bright - dark):
            return None
    level = dark + 0.5 * (bright - dark)
    smooth = cv2.blur(img, (3, 3))
    inside = (smooth > level).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(inside, connectivity=4)
    if n < 2:
        return None
    main = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    region = labels == main
    xs, ys = _rim_points(img, region, level)
    if xs.size < 20:
        return None
    cx, cy, r = fit_circle(xs, ys)
    resid = np.hypot(xs - cx, ys - cy) - r
    keep = np.abs(resid) < max(2.0, 3 * 1.4826 * np.median(np.abs(resid)))
    if keep.sum() < 20:
        return None
    cx, cy, r = fit_circle(xs[keep], ys[keep])
    resid = np.hypot(xs[keep] - cx, ys[keep] - cy) - r
    rms = float(np.sqrt(np.mean(resid**2)))
    if rms > RMS_BAD or r < 0.2 * min(h, w) or keep.mean() < INLIERS_BAD:
        return None
    ang = np.arctan2(ys[keep] - cy, xs[keep] - cx)
    sectors = np.unique(np.floor((ang + np.pi) / (2 * np.pi) * SECTORS).astype(int) % SECTORS)
    conf = circle_confidence(rms, float(keep.mean()), (bright - dark) / noise, sectors.size / SECTORS)
    return ImagingCircle(cx, cy, r, conf)


def _rim_points(img: np.ndarray, region: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel crossings of ``level`` at the left/right/top/bottom ends of ``region``."""
    h, w = img.shape
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    for axis in (1, 0):  # scan rows (x crossings), then columns (y crossings)
        reg = region if axis == 1 else region.T
        im = img if axis == 1 else img.T
        n_lines, length = reg.shape
        has = reg.any(axis=1)
        first = np.argmax(reg, axis=1)
        last = length - 1 - np.argmax(reg[:, ::-1], axis=1)
        lines = np.nonzero(has)[0]
        for end, step in ((first, -1), (last, 1)):
            e = end[lines]
            o = e + step
            ok = (o >= 0) & (o < length) & (e > 0) & (e < length - 1)
            li, e, o = lines[ok], e[ok], o[ok]
            vin, vout = im[li, e], im[li, o]
            denom = vin - vout
            good = denom > 0
            t = np.clip((vin[good] - level) / denom[good], 0.0, 1.0)
            pos = e[good] + step * t
            along = li[good].astype(np.float64)
            if axis == 1:
                xs.append(pos), ys.append(along)
            else:
                xs.append(along), ys.append(pos)
    return np.concatenate(xs).astype(np.float64), np.concatenate(ys).astype(np.float64)


def non_imaging_mask(shape: tuple[int, int], circle: ImagingCircle | None, margin: float) -> np.ndarray:
    """Eq. 1: True where ||(x - cx, y - cy)|| > R_max - margin (outside the imaging area).

    The paper's Δr is ``-margin``: shrinking the circle removes the rim's strong gradient.
    With no circle (the image fills the frame) the mask is all False.
    """
    if circle is None:
        return np.zeros(shape, dtype=bool)
    yy, xx = np.ogrid[: shape[0], : shape[1]]
    return (xx - circle.cx) ** 2 + (yy - circle.cy) ** 2 > (circle.radius - margin) ** 2


def resolve_circle(image: np.ndarray, cfg: CircleConfig) -> ImagingCircle | None:
    """The imaging circle a config asks for: none, the configured one (confidence 1), or
    estimated from ``image`` with any configured centre or radius taking precedence (the
    estimate's confidence kept)."""
    if not cfg.enabled:
        return None
    if cfg.center is not None and cfg.radius is not None:
        return ImagingCircle(cfg.center[0], cfg.center[1], cfg.radius, 1.0)
    circle = estimate_imaging_circle(image)
    if circle is not None and (cfg.center is not None or cfg.radius is not None):
        circle = ImagingCircle(*(cfg.center or (circle.cx, circle.cy)), cfg.radius or circle.radius,
                               circle.confidence)
    return circle


class ImagingMask:
    """A clip's non-imaging mask (eq. 1): resolved from its first frame (or the config) and
    kept while the frame size stays the same."""

    def __init__(self, cfg: CircleConfig) -> None:
        self.cfg = cfg
        self.circle: ImagingCircle | None = None
        self.mask: np.ndarray | None = None

    def update(self, image: np.ndarray) -> tuple[np.ndarray, bool]:
        """(mask, whether it was computed on this call)."""
        if self.mask is not None and self.mask.shape == image.shape:
            return self.mask, False
        self.circle = resolve_circle(image, self.cfg)
        self.mask = non_imaging_mask(image.shape, self.circle, self.cfg.margin)
        b = self.cfg.border
        if b > 0:
            self.mask[:b], self.mask[-b:], self.mask[:, :b], self.mask[:, -b:] = True, True, True, True
        return self.mask, True
