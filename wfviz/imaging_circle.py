"""Imaging circle of a fisheye lens and the non-imaging mask (GEWC paper, eq. 1)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.config import CircleConfig


@dataclass(frozen=True)
class ImagingCircle:
    """Distortion centre (x = column, y = row) and pixel radius R_max of the field edge."""

    cx: float
    cy: float
    radius: float


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
    dark and imaging levels with sub-pixel interpolation along the columns and rows.
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
    if np.sqrt(np.mean(resid**2)) > 1.5 or r < 0.2 * min(h, w) or keep.mean() < 0.7:
        return None
    return ImagingCircle(cx, cy, r)


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
    """The imaging circle a config asks for: none, the configured one, or estimated from
    ``image`` with any configured centre or radius taking precedence."""
    if not cfg.enabled:
        return None
    if cfg.center is not None and cfg.radius is not None:
        return ImagingCircle(cfg.center[0], cfg.center[1], cfg.radius)
    circle = estimate_imaging_circle(image)
    if circle is not None and (cfg.center is not None or cfg.radius is not None):
        circle = ImagingCircle(*(cfg.center or (circle.cx, circle.cy)), cfg.radius or circle.radius)
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
