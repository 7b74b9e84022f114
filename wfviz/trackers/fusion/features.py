"""Feature-fusion features and costs (Zheng Jia, Li Jiangyong and Chen Gang): per-candidate centre
(bounding rectangle, minimum-area rectangle or centroid), area and grey sum, the fused matching
cost (sum mode) and the scalar fused feature Φ (scalar mode)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Features:
    """Per-candidate features, aligned with the frame's ``Detections``.

    ``centre`` (N, 2) the position used for matching and as the Kalman measurement (centre of
    the bounding rectangle, or the intensity centroid with ``features.centre = "centroid"``);
    ``area`` pixel count; ``grey`` grey sum (residual or raw); ``rects`` (N, 4, 2) corners of
    each candidate's bounding rectangle (pixel edges, for drawing).
    """

    centre: np.ndarray
    area: np.ndarray
    grey: np.ndarray
    rects: np.ndarray

    def __len__(self) -> int:
        return int(self.centre.shape[0])



def min_area_rect(xs: np.ndarray, ys: np.ndarray) -> tuple[tuple[float, float], np.ndarray]:
    """Centre and corners (4, 2) of the minimum-area rectangle enclosing the pixel squares
    (centres ``xs``, ``ys``), by ``cv2.minAreaRect`` on the squares' corners."""
    off = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    pts = (np.column_stack([xs, ys])[:, None, :] + off[None]).reshape(-1, 2).astype(np.float32)
    box = cv2.minAreaRect(pts)
    return (float(box[0][0]), float(box[0][1])), cv2.boxPoints(box).astype(np.float64)


def box_corners(bbox: np.ndarray) -> np.ndarray:
    """Corners (N, 4, 2) of axis-aligned boxes (x, y, w, h) covering whole pixels: the
    rectangle's edges lie on the pixel edges (x - 0.5 ... x + w - 0.5)."""
    b = np.asarray(bbox, dtype=np.float64).reshape(-1, 4)
    a, t = b[:, 0] - 0.5, b[:, 1] - 0.5
    r, d = a + b[:, 2], t + b[:, 3]
    return np.stack([np.column_stack([a, t]), np.column_stack([r, t]), np.column_stack([r, d]),
                     np.column_stack([a, d])], axis=1)


def min_area_rects(labels: np.ndarray, components: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres (k, 2) and corners (k, 4, 2) of the minimum-area rectangles of the listed
    component labels (``cv2.minAreaRect`` on the corners of their pixels)."""
    k = len(components)
    centres, corners = np.zeros((k, 2)), np.zeros((k, 4, 2))
    if k == 0:
        return centres, corners
    idx = np.flatnonzero(np.isin(labels, components))
    lab = labels.ravel()[idx]
    order = np.argsort(lab, kind="stable")
    idx, lab = idx[order], lab[order]
    w = labels.shape[1]
    for i, comp in enumerate(components):
        lo, hi = np.searchsorted(lab, comp), np.searchsorted(lab, comp, side="right")
        sel = idx[lo:hi]
        if sel.size:
            centres[i], corners[i] = min_area_rect((sel % w).astype(np.float64),
                                                   (sel // w).astype(np.float64))
    return centres, corners


def fused_cost(pred: np.ndarray, half: np.ndarray, ref_area: np.ndarray, ref_grey: np.ndarray,
               centre: np.ndarray, area: np.ndarray, grey: np.ndarray, alpha: float, beta: float,
               gamma: float) -> np.ndarray:
    """(T, N) cost α·‖Δ/half‖ + β·|Δa|/max(a) + γ·|Δg|/max(g) between tracks (predicted centre,
    window half sizes, reference area and grey sum) and candidates."""
    d = (centre[None, :, :] - pred[:, None, :]) / half[:, None, :]
    c = np.hypot(d[..., 0], d[..., 1])
    a_t, a_c = ref_area[:, None], area[None, :].astype(np.float64)
    g_t, g_c = ref_grey[:, None], grey[None, :].astype(np.float64)
    da = np.abs(a_t - a_c) / np.maximum(np.maximum(a_t, a_c), 1e-12)
    dg = np.abs(g_t - g_c) / np.maximum(np.maximum(np.abs(g_t), np.abs(g_c)), 1e-12)
    return alpha * c + beta * da + gamma * dg


def scalar_phi(centre: np.ndarray, area: np.ndarray, grey: np.ndarray, area0: np.ndarray,
               grey0: np.ndarray, shape: tuple[int, int], alpha: float, beta: float,
               gamma: float) -> np.ndarray:
    """Scalar fused feature Φ = α·ĉ + β·a / a₀ + γ·g / g₀, ĉ = ‖(x / (W-1), y / (H-1))‖ / √2
    (a₀, g₀: the track's mean area and grey sum, so a steady target has Φ ≈ α·ĉ + β + γ).

    Broadcasts: ``centre`` (..., 2) with ``area``/``grey`` (...) and the references a₀, g₀."""
    h, w = shape
    c = np.hypot(centre[..., 0] / max(w - 1, 1), centre[..., 1] / max(h - 1, 1)) / math.sqrt(2.0)
    return (alpha * c + beta * area / np.maximum(area0, 1e-12)
            + gamma * grey / np.where(np.abs(grey0) > 1e-12, grey0, 1e-12))
