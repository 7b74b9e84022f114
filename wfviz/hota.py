"""HOTA, Higher Order Tracking Accuracy (J. Luiten et al., "HOTA: A Higher Order Metric for
Evaluating Multi-Object Tracking", IJCV 2021), for point targets.

The algorithm is the paper's reference implementation (TrackEval, ``trackeval/metrics/hota.py``)
step for step: each frame's truth-track pairs are chosen by one Hungarian assignment that
maximises the similarity weighted by the pair's global alignment score (the identities'
similarity-weighted Jaccard overlap over the whole sequence); then, at each localisation
threshold α = 0.05, 0.10, ..., 0.95, a pair is a true positive when its similarity is >= α,
DetA = TP / (TP + FN + FP), AssA = the mean over true positives of their identities' Jaccard
overlap TPA / (TPA + FNA + FPA), and HOTA_α = sqrt(DetA_α AssA_α). The results are the means
over α. The similarity of a truth point and a track point ``d`` px apart is
``max(0, 1 - d / gate)`` (:func:`point_similarity`). Counts are kept sparse (per matched
identity pair), so memory follows the matches, not truth ids x track ids.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: the localisation thresholds α (TrackEval's ``np.arange(0.05, 0.99, 0.05)``: 19 values)
ALPHAS = np.arange(0.05, 0.99, 0.05)
_EPS = np.finfo(float).eps

#: one frame: truth ids, track ids, similarity (len(truth ids), len(track ids)), values in [0, 1]
Frame = tuple[Sequence[int], Sequence[int], np.ndarray]


@dataclass(frozen=True)
class Hota:
    """HOTA and its detection (DetA) and association (AssA) parts, each the mean over
    :data:`ALPHAS`; NaN when there was neither a truth nor a track point."""

    hota: float
    det_a: float
    ass_a: float


def point_similarity(d: np.ndarray, gate: float) -> np.ndarray:
    """Similarity of points ``d`` px apart: ``max(0, 1 - d / gate)`` (1 at 0 px, 0 from ``gate`` on)."""
    return np.maximum(0.0, 1.0 - np.asarray(d, dtype=np.float64) / gate)


def hota(frames: Sequence[Frame]) -> Hota:
    """HOTA, DetA and AssA of a sequence given as its frames (:data:`Frame`: truth ids, track
    ids and their similarity matrix; ids unique within a frame, frames without points may be
    left out)."""
    from scipy.optimize import linear_sum_assignment  # (scoring only: SciPy stays off `track`'s start-up)

    sims = [np.asarray(s, dtype=np.float64).reshape(len(g), len(t)) for g, t, s in frames]
    g_inv, n_truth = _dense([g for g, _, _ in frames])
    t_inv, n_track = _dense([t for _, t, _ in frames])
    if not n_truth and not n_track:
        return Hota(float("nan"), float("nan"), float("nan"))
    g_count = np.bincount(np.concatenate(g_inv), minlength=1).astype(np.float64)
    t_count = np.bincount(np.concatenate(t_inv), minlength=1).astype(np.float64)
    width = max(1, len(t_count))
    keys, align = _alignment(g_inv, t_inv, sims, g_count, t_count, width)
    # each frame's pairs: Hungarian on the similarity weighted by the global alignment
    pair_key, pair_sim = [], []
    for g, t, s in zip(g_inv, t_inv, sims):
        rows, cols = np.nonzero(s > 0)
        if not rows.size:
            continue  # no pair could reach any α
        k = g[rows] * width + t[cols]
        at = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
        score = np.zeros_like(s)
        score[rows, cols] = np.where(keys[at] == k, align[at], 0.0) * s[rows, cols]
        r, c = linear_sum_assignment(-score)
        pair_key.append(g[r] * width + t[c])
        pair_sim.append(s[r, c])
    pk = np.concatenate(pair_key) if pair_key else np.zeros(0, np.int64)
    ps = np.concatenate(pair_sim) if pair_sim else np.zeros(0)
    hit = ps[None, :] >= ALPHAS[:, None] - _EPS  # (alphas, pairs)
    tp = hit.sum(axis=1).astype(np.float64)
    det_a = tp / np.maximum(1.0, n_truth + n_track - tp)  # TP / (TP + FN + FP)
    ass_a = np.array([_ass_a(pk[h], g_count, t_count, width) for h in hit]) / np.maximum(1.0, tp)
    return Hota(float(np.mean(np.sqrt(det_a * ass_a))), float(np.mean(det_a)), float(np.mean(ass_a)))


def _dense(ids: Sequence[Sequence[int]]) -> tuple[list[np.ndarray], int]:
    """Each frame's ids as indices 0..n-1 over the whole sequence, and the number of points."""
    flat = np.concatenate([np.asarray(i, dtype=np.int64).reshape(-1) for i in ids]) if ids else np.zeros(0, np.int64)
    inv = np.unique(flat, return_inverse=True)[1].reshape(-1)
    return np.split(inv, np.cumsum([len(i) for i in ids])[:-1]), len(flat)


def _alignment(g_inv: list[np.ndarray], t_inv: list[np.ndarray], sims: list[np.ndarray], g_count: np.ndarray,
               t_count: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The global alignment score of every identity pair that is ever similar: (sorted keys
    ``truth * width + track``, scores). Per frame, a pair's similarity is normalised by the
    sums of its row and column (less itself); summed over frames into a Jaccard overlap."""
    keys, vals = [], []
    for g, t, s in zip(g_inv, t_inv, sims):
        denom = s.sum(axis=0)[None, :] + s.sum(axis=1)[:, None] - s
        iou = np.zeros_like(s)
        ok = denom > _EPS
        iou[ok] = s[ok] / denom[ok]
        rows, cols = np.nonzero(iou)
        keys.append(g[rows] * width + t[cols])
        vals.append(iou[rows, cols])
    flat = np.concatenate(keys) if keys else np.zeros(0, np.int64)
    uniq, inv = np.unique(flat, return_inverse=True)
    potential = np.bincount(inv.reshape(-1), weights=np.concatenate(vals) if vals else None, minlength=len(uniq))
    gi, ti = np.divmod(uniq, width)
    return uniq, potential / (g_count[gi] + t_count[ti] - potential)


def _ass_a(keys: np.ndarray, g_count: np.ndarray, t_count: np.ndarray, width: int) -> float:
    """Sum over true positives of their identity pair's TPA / (TPA + FNA + FPA) (``keys``: one
    per true positive)."""
    uniq, tpa = np.unique(keys, return_counts=True)
    gi, ti = np.divmod(uniq, width)
    return float(np.sum(tpa * tpa / np.maximum(1.0, g_count[gi] + t_count[ti] - tpa)))
