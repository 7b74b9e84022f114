"""Frame-to-frame star pairing and registration (Gao Jianwei et al. 2012).

The paper pairs the stars of frames k and k+1 through two reference stars S, P present in
both: a point T of frame k and a point I of frame k+1 are the same star when
|d(T, S_k) - d(I, S_k+1)| <= mu and |d(T, P_k) - d(I, P_k+1)| <= mu, I searched in a
``search_box`` square around T. The distances make the test independent of the shift and
rotation between the frames, but everything hangs on S and P: a reference star missed in
frame k+1, or mis-paired with another star, pairs nothing.

Here (:func:`register`):

1. **Reference stars, the paper's way**: S_k, P_k are the brightest stars of frame k at least
   ``reference_separation`` px apart and half a search box from the border; S_k+1, P_k+1 are
   the brightest points of frame k+1 inside the search box around them.
2. **Distance pairing** of every star with those references (eq. 6); a point is used once.
3. **Check**: the pairs must cover ``min_paired_fraction`` of the stars and fit one rigid
   motion (translation + rotation) with an RMS residual <= ``max_rms`` px.
4. **Fallback** when the check fails (a reference star missed or mis-paired): a consensus
   over many pairs, every displacement from the ``vote_stars`` brightest stars to the points
   in their search box votes and the displacement with most support within mu wins (a
   one-point RANSAC evaluated exhaustively); the rigid motion is refined on nearest-neighbour
   pairs, new reference stars are taken from its inliers and the distance pairing runs again.
5. The reported motion (:func:`robust_fit`, every fit above): RANSAC over the pairs
   (two-pair similarity hypotheses, inliers within ``mu`` px; OpenCV), then the least-squares
   rigid fit of its inliers, outliers (> 3 robust stds) dropped. With 40 % of the pairs wrong
   by up to 8 px the fit stays within 0.02 px at the field's corners, where the 3-std
   rejection alone, started from all pairs, is 0.10 px off (``tests/test_starfield_jitter.py``).

Motion: a point p of frame k-1 is at ``c + R(rotation) (p - c) + (dx, dy)`` in frame k, with c
the frame centre; ``matrix`` is that map as a 2x3 affine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from wfviz.trackers.starfield.config import RegistrationConfig

_EMPTY2 = np.zeros((0, 2))


@dataclass(frozen=True)
class Registration:
    """Motion from the previous frame to this one and the star pairs behind it.

    ``pairs`` (K, 2): index into the previous frame's points, index into this frame's;
    ``reference_prev`` / ``reference_cur`` (2, 2): S and P in each frame (empty when none);
    ``method``: "reference" (the paper's pairing with its reference stars passed the check),
    "consensus" (the fallback), "none" (no registration: first frame or too few stars);
    ``note``: why the fallback was used; ``rms``: residual of the rigid fit over the pairs (px).
    """

    dx: float
    dy: float
    rotation: float  # degrees, positive = clockwise on screen (y points down)
    centre: tuple[float, float]
    matrix: np.ndarray
    pairs: np.ndarray
    reference_prev: np.ndarray
    reference_cur: np.ndarray
    method: str
    note: str
    rms: float

    @property
    def ok(self) -> bool:
        """True when the frames were registered."""
        return self.method != "none"


def rigid_matrix(dx: float, dy: float, rotation_deg: float, centre: tuple[float, float]) -> np.ndarray:
    """2x3 affine of p -> c + R(p - c) + (dx, dy)."""
    a = math.radians(rotation_deg)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    c = np.asarray(centre, dtype=np.float64)
    return np.column_stack([R, c - R @ c + np.array([dx, dy])])


def apply(matrix: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Apply a 2x3 affine to (N, 2) points."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return xy @ matrix[:, :2].T + matrix[:, 2]


def rigid_fit(a: np.ndarray, b: np.ndarray, centre: tuple[float, float]) -> tuple[float, float, float]:
    """Least-squares (dx, dy, rotation in degrees) with b ~ c + R(a - c) + (dx, dy)."""
    c = np.asarray(centre, dtype=np.float64)
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    pa, pb = a - ma, b - mb
    ang = math.atan2(float(np.sum(pa[:, 0] * pb[:, 1] - pa[:, 1] * pb[:, 0])),
                     float(np.sum(pa[:, 0] * pb[:, 0] + pa[:, 1] * pb[:, 1])))
    R = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
    t = mb - c - R @ (ma - c)
    return float(t[0]), float(t[1]), math.degrees(ang)


def robust_fit(a: np.ndarray, b: np.ndarray, centre: tuple[float, float], tolerance: float
               ) -> tuple[tuple[float, float, float], np.ndarray, float]:
    """Rigid motion (dx, dy, rotation in degrees) with b ~ c + R(a - c) + (dx, dy) over pairs
    that may hold outliers. RANSAC first (OpenCV's ``estimateAffinePartial2D``: two-pair
    similarity hypotheses, a pair within ``tolerance`` px supports one; deterministic), then
    the least-squares rigid fit of its inliers, residuals beyond 3 robust stds of all pairs (at
    least 0.2 px) dropped and the fit repeated. Returns (motion, inlier mask, RMS residual of
    the inliers)."""
    keep = np.ones(len(a), dtype=bool)
    if len(a) >= 3:
        m, inl = cv2.estimateAffinePartial2D(a.astype(np.float64), b.astype(np.float64), method=cv2.RANSAC,
                                             ransacReprojThreshold=float(tolerance), maxIters=2000,
                                             confidence=0.999, refineIters=0)
        if m is not None and int(inl.sum()) >= 3:
            keep = inl.ravel().astype(bool)
    motion = rigid_fit(a[keep], b[keep], centre)
    for _ in range(2):
        res = np.hypot(*(apply(rigid_matrix(*motion, centre), a) - b).T)
        lim = max(3.0 * 1.4826 * float(np.median(res)), 0.2)
        new = res <= lim
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
        motion = rigid_fit(a[keep], b[keep], centre)
    res = np.hypot(*(apply(rigid_matrix(*motion, centre), a[keep]) - b[keep]).T)
    return motion, keep, float(np.sqrt(np.mean(res ** 2))) if len(res) else math.inf


def _box_neighbours(tree: cKDTree, pts: np.ndarray, src: np.ndarray, half: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j): point j of the tree's set inside the square of half size ``half`` around
    src[i] (flattened index arrays)."""
    lists = tree.query_ball_point(src, half * math.sqrt(2.0), p=2.0)
    counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    if counts.sum() == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i = np.repeat(np.arange(len(src)), counts)
    j = np.fromiter((v for x in lists for v in x), dtype=np.int64, count=int(counts.sum()))
    d = pts[j] - src[i]
    inside = (np.abs(d) <= half).all(axis=1)
    return i[inside], j[inside]


def _one_to_one(i: np.ndarray, j: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Greedy one-to-one selection by increasing cost; returns (K, 2) pairs."""
    order = np.argsort(cost, kind="stable")
    used_i: set[int] = set()
    used_j: set[int] = set()
    out = []
    for o in order:
        a, b = int(i[o]), int(j[o])
        if a in used_i or b in used_j:
            continue
        used_i.add(a)
        used_j.add(b)
        out.append((a, b))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def distance_pairing(prev: np.ndarray, cur: np.ndarray, ref_prev: np.ndarray, ref_cur: np.ndarray,
                     mu: float, half: float, cur_tree: cKDTree | None = None) -> np.ndarray:
    """The paper's eq. 6: T (prev) and I (cur, inside the search box around T) are the same
    star when both distance differences to the reference stars are <= mu. Each point is used
    once, the pair with the smaller larger difference first. Returns (K, 2) index pairs."""
    if len(prev) == 0 or len(cur) == 0:
        return np.zeros((0, 2), np.int64)
    tree = cur_tree if cur_tree is not None else cKDTree(cur)
    i, j = _box_neighbours(tree, cur, prev, half)
    if len(i) == 0:
        return np.zeros((0, 2), np.int64)
    dp = np.hypot(*(prev[:, None, :] - ref_prev[None, :, :]).transpose(2, 0, 1))  # (N, 2)
    dc = np.hypot(*(cur[:, None, :] - ref_cur[None, :, :]).transpose(2, 0, 1))    # (M, 2)
    err = np.abs(dp[i] - dc[j]).max(axis=1)
    ok = err <= mu
    return _one_to_one(i[ok], j[ok], err[ok])


def pick_references(prev: np.ndarray, prev_flux: np.ndarray, shape: tuple[int, int], half: float,
                    separation: float, candidates: np.ndarray | None = None) -> np.ndarray | None:
    """Indices (2,) of S and P: the brightest points (of ``candidates`` if given) half a search
    box inside the frame and at least ``separation`` px apart (the farthest pair otherwise)."""
    h, w = shape
    idx = np.arange(len(prev)) if candidates is None else np.asarray(candidates)
    if len(idx) < 2:
        return None
    p = prev[idx]
    inside = (p[:, 0] >= half) & (p[:, 0] <= w - 1 - half) & (p[:, 1] >= half) & (p[:, 1] <= h - 1 - half)
    idx = idx[inside] if inside.sum() >= 2 else idx
    idx = idx[np.argsort(-prev_flux[idx], kind="stable")][:50]
    s = idx[0]
    d = np.hypot(*(prev[idx] - prev[s]).T)
    far = np.nonzero(d >= separation)[0]
    p_ = idx[far[0]] if len(far) else idx[int(np.argmax(d))]
    if p_ == s:
        return None
    return np.array([s, p_])


def _follow(prev_xy: np.ndarray, cur: np.ndarray, cur_flux: np.ndarray, tree: cKDTree, half: float
            ) -> int | None:
    """The brightest point of ``cur`` in the search box around ``prev_xy`` (None if empty)."""
    i, j = _box_neighbours(tree, cur, prev_xy.reshape(1, 2), half)
    if len(j) == 0:
        return None
    return int(j[np.argmax(cur_flux[j])])


def consensus(prev: np.ndarray, prev_flux: np.ndarray, cur: np.ndarray, mu: float, half: float,
              vote_stars: int, cur_tree: cKDTree) -> tuple[np.ndarray, int] | None:
    """Displacement (2,) with most support: every (bright star, point in its search box) pair
    votes for its displacement; support = distinct stars with a vote within ``mu`` of it."""
    bright = np.argsort(-prev_flux, kind="stable")[:vote_stars]
    i, j = _box_neighbours(cur_tree, cur, prev[bright], half)
    if len(i) == 0:
        return None
    disp = cur[j] - prev[bright][i]
    vt = cKDTree(disp)
    near = vt.query_ball_point(disp, mu)
    support = np.array([len(set(i[n].tolist())) for n in near])
    best = int(np.argmax(support))
    members = np.array(near[best])
    return disp[members].mean(axis=0), int(support[best])


def _none(centre: tuple[float, float], note: str) -> Registration:
    return Registration(0.0, 0.0, 0.0, centre, rigid_matrix(0.0, 0.0, 0.0, centre),
                        np.zeros((0, 2), np.int64), _EMPTY2, _EMPTY2, "none", note, math.nan)


def register(prev: np.ndarray, prev_flux: np.ndarray, cur: np.ndarray, cur_flux: np.ndarray,
             shape: tuple[int, int], cfg: RegistrationConfig,
             references: tuple[np.ndarray, np.ndarray] | None = None) -> Registration:
    """Pair the stars of two frames and estimate the motion between them (module docstring).

    ``references`` forces the reference stars: ((S_k, P_k), (S_k+1, P_k+1)) positions, as the
    paper's background correction would hand them over (tests use it to mis-pair them).
    """
    h, w = shape
    centre = ((w - 1) / 2.0, (h - 1) / 2.0)
    if len(prev) < 3 or len(cur) < 3:
        return _none(centre, "fewer than 3 star points")
    half = cfg.search_box / 2.0
    tree = cKDTree(cur)
    overlap_needed = cfg.min_paired_fraction * min(len(prev), len(cur))

    def attempt(ref_p: np.ndarray, ref_c: np.ndarray) -> tuple[np.ndarray, tuple, float, str]:
        if abs(float(np.hypot(*(ref_p[0] - ref_p[1]))) - float(np.hypot(*(ref_c[0] - ref_c[1])))) > cfg.mu:
            return np.zeros((0, 2), np.int64), (0.0, 0.0, 0.0), math.inf, "reference distance changed"
        pairs = distance_pairing(prev, cur, ref_p, ref_c, cfg.mu, half, tree)
        if len(pairs) < 3:
            return pairs, (0.0, 0.0, 0.0), math.inf, f"{len(pairs)} pairs"
        motion, keep, rms = robust_fit(prev[pairs[:, 0]], cur[pairs[:, 1]], centre, cfg.mu)
        pairs = pairs[keep]
        if len(pairs) < overlap_needed:
            return pairs, motion, rms, f"only {len(pairs)} pairs"
        if rms > cfg.max_rms:
            return pairs, motion, rms, f"fit RMS {rms:.2f} px"
        return pairs, motion, rms, ""

    # 1-3: the paper's reference stars
    if references is not None:
        ref_p, ref_c = (np.asarray(r, dtype=np.float64).reshape(2, 2) for r in references)
        problem = ""
    else:
        ref_p = ref_c = _EMPTY2
        problem = "no reference stars"
        sp = pick_references(prev, prev_flux, shape, half, cfg.reference_separation)
        if sp is not None:
            s1, p1 = (_follow(prev[k], cur, cur_flux, tree, half) for k in sp)
            if s1 is None or p1 is None:
                problem = "reference star not found in the search box"
            elif s1 == p1:
                problem = "both reference stars followed to one point"
            else:
                ref_p, ref_c = prev[sp], cur[[s1, p1]]
                problem = ""
    if not problem:
        pairs, motion, rms, problem = attempt(ref_p, ref_c)
        if not problem:
            return Registration(*motion, centre, rigid_matrix(*motion, centre), pairs, ref_p, ref_c,
                                "reference", "", rms)
    if not cfg.fallback:
        return _none(centre, f"reference stars failed ({problem}), fallback disabled")
    # 4: consensus over many pairs
    vote = consensus(prev, prev_flux, cur, cfg.mu, half, cfg.vote_stars, tree)
    if vote is None or vote[1] < 3:
        return _none(centre, f"reference stars failed ({problem}); no consensus")
    motion = (float(vote[0][0]), float(vote[0][1]), 0.0)
    for radius in (2.0 * cfg.mu, cfg.mu):
        dist, j = tree.query(apply(rigid_matrix(*motion, centre), prev), distance_upper_bound=radius)
        ok = np.isfinite(dist)
        if ok.sum() < 3:
            return _none(centre, f"reference stars failed ({problem}); consensus left < 3 pairs")
        nn = _one_to_one(np.nonzero(ok)[0], j[ok], dist[ok])
        motion, keep, _ = robust_fit(prev[nn[:, 0]], cur[nn[:, 1]], centre, cfg.mu)
        nn = nn[keep]
    sp = pick_references(prev, prev_flux, shape, half, cfg.reference_separation, nn[:, 0])
    if sp is not None:
        rows = [int(np.nonzero(nn[:, 0] == s)[0][0]) for s in sp]
        ref_p, ref_c = prev[sp], cur[nn[rows, 1]]
        pairs, motion2, rms, problem2 = attempt(ref_p, ref_c)
        if not problem2 or len(pairs) >= len(nn):
            return Registration(*motion2, centre, rigid_matrix(*motion2, centre), pairs, ref_p, ref_c,
                                "consensus", problem, rms)
    motion, keep, rms = robust_fit(prev[nn[:, 0]], cur[nn[:, 1]], centre, cfg.mu)
    return Registration(*motion, centre, rigid_matrix(*motion, centre), nn[keep], _EMPTY2, _EMPTY2,
                        "consensus", problem, rms)
