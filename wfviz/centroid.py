"""Sub-pixel target position in a window: GEWC (GEWC paper, eqs. 4-7) or intensity centroid.

Patches are background-free: pixels not belonging to the target are 0. Positions are in
patch coordinates (x = column, y = row, origin at the centre of the patch's top-left pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_REGIONS = 8


@dataclass(frozen=True)
class CentroidResult:
    """Centroid (x, y) in the patch's coordinates and the 8 region weights W_r (eq. 6)."""

    x: float
    y: float
    weights: np.ndarray


def intensity_centroid(patch: np.ndarray) -> tuple[float, float] | None:
    """Intensity-weighted mean position; None for an all-zero patch."""
    p = patch.astype(np.float64, copy=False)
    total = p.sum()
    if total <= 0:
        return None
    ys, xs = np.indices(p.shape)
    return float((p * xs).sum() / total), float((p * ys).sum() / total)


def gradient_magnitude(patch: np.ndarray) -> np.ndarray:
    """Grey-level gradient magnitude by central differences (one-sided at the border)."""
    gy, gx = np.gradient(patch.astype(np.float64, copy=False))
    return np.hypot(gx, gy)


def _entropy_centroid(grad: np.ndarray, cx: float, cy: float, bins: int) -> CentroidResult | None:
    """One GEWC evaluation with the 8 direction regions centred on (cx, cy)."""
    gmax = grad.max()
    if gmax <= 0:
        return None
    ys, xs = np.nonzero(grad > gmax * 1e-9)
    g = grad[ys, xs]
    # eq. 4 needs equal gradient values: quantise |∇f| into `bins` levels
    level = np.minimum((g / gmax * bins).astype(np.int64), bins - 1)
    angle = np.arctan2(ys - cy, xs - cx)
    region = ((angle + np.pi) / (2 * np.pi / N_REGIONS)).astype(np.int64) % N_REGIONS
    cell = region * bins + level
    size = N_REGIONS * bins
    k = np.bincount(cell, minlength=size).reshape(N_REGIONS, bins).astype(np.float64)
    sx = np.bincount(cell, weights=xs, minlength=size).reshape(N_REGIONS, bins)
    sy = np.bincount(cell, weights=ys, minlength=size).reshape(N_REGIONS, bins)
    n_r = k.sum(axis=1, keepdims=True)
    q = np.divide(k, n_r, out=np.zeros_like(k), where=n_r > 0)              # eq. 4
    mx = np.divide(sx, k, out=np.zeros_like(sx), where=k > 0)               # eq. 5
    my = np.divide(sy, k, out=np.zeros_like(sy), where=k > 0)
    region_x, region_y = (q * mx).sum(axis=1), (q * my).sum(axis=1)         # Σ_g q_g M_g
    logq = np.log2(q, out=np.zeros_like(q), where=q > 0)
    entropy = -(q * logq).sum(axis=1)                                       # eq. 6
    present = n_r[:, 0] > 0
    if entropy.sum() > 0:
        w = entropy / entropy.sum()
    else:  # every region holds a single gradient level: weigh the occupied regions equally
        w = present / present.sum()
    return CentroidResult(float((w * region_x).sum()), float((w * region_y).sum()), w)   # eq. 7


def gewc_centroid(patch: np.ndarray, bins: int = 32, iterations: int = 2,
                  start: tuple[float, float] | None = None) -> CentroidResult | None:
    """Gradient-entropy-weighted centroid (eqs. 4-7) of a background-free patch.

    The patch's non-zero-gradient pixels are split into 8 direction regions (octants) around
    a centre, first ``start`` (default: the patch centre), then the previous estimate
    (``iterations`` passes). In region r, q_g is the share of pixels at gradient level g
    (eq. 4), M_g their mean position (eq. 5), E_r the entropy of q and W_r = E_r / ΣE (eq. 6);
    the centroid is Σ_r W_r Σ_g q_g M_g (eq. 7).
    """
    grad = gradient_magnitude(patch)
    h, w = patch.shape
    cx, cy = start if start is not None else ((w - 1) / 2.0, (h - 1) / 2.0)
    result = None
    for _ in range(max(1, iterations)):
        step = _entropy_centroid(grad, cx, cy, bins)
        if step is None:
            return result
        result = step
        cx, cy = step.x, step.y
    return result


def measure(residual: np.ndarray, labels: np.ndarray, component: int, centre: tuple[float, float],
            size: int, threshold: float, method: str = "gewc", bins: int = 32,
            iterations: int = 2) -> CentroidResult | None:
    """Measure one target in a ``size`` window of ``residual`` centred on ``centre``.

    Only the pixels of connected component ``component`` count, with the detection threshold
    subtracted (so the background and any other target in the window are 0). Returns image
    coordinates; weights are all 1/8 for the intensity centroid.
    """
    h, w = residual.shape
    half = size // 2
    x0 = int(np.clip(round(centre[0]) - half, 0, max(w - 1, 0)))
    y0 = int(np.clip(round(centre[1]) - half, 0, max(h - 1, 0)))
    x1, y1 = min(x0 + size, w), min(y0 + size, h)
    win = residual[y0:y1, x0:x1].astype(np.float64)
    patch = np.where(labels[y0:y1, x0:x1] == component, np.maximum(win - threshold, 0.0), 0.0)
    if method == "intensity":
        c = intensity_centroid(patch)
        if c is None:
            return None
        return CentroidResult(c[0] + x0, c[1] + y0, np.full(N_REGIONS, 1.0 / N_REGIONS))
    r = gewc_centroid(patch, bins=bins, iterations=iterations)
    if r is None:
        return None
    return CentroidResult(r.x + x0, r.y + y0, r.weights)
