"""Sequential confirmation and deletion of tracks (not in the GEWC paper, which confirms a track
after m = 6 hits; that rule stays selectable as ``tracking.confirm = "hits"``).

**Evidence against noise.** Each frame a track either has a detection in its gate (a hit) or
not (a miss). A target gives a hit with probability ``P_D``; false detections of local density
λ per pixel fall into a gate of area A with probability ``p_fa = 1 - exp(-λ A)``. Wald's
sequential probability ratio test on these outcomes (A. Wald, *Sequential Analysis*, 1947;
for track management S. Blackman and R. Popoli, *Design and Analysis of Modern Tracking
Systems*, 1999, §6.2) adds to a track's score

    L += ln(P_D / p_fa)                  on a hit,
    L += ln((1 - P_D) / (1 - p_fa))      on a miss,

confirms at ``L >= ln((1 - β) / α)`` and drops a tentative track at ``L <= ln(β / (1 - α))``.
α is the chance that a track started by false detections gets confirmed, β the chance that a
target's tentative track is dropped. α follows from the one number a user sets, the rate of
false confirmed tracks per 1000 frames F, and the measured number of tentative tracks tested
per frame b: ``α = F / (1000 b)`` (each test is a chance to confirm a false track). A confirmed
track's score is capped at the confirmation level; it is deleted when it falls ``ln(1 / p_lost)``
below it (with P_D = 0.9 and a clean gate: after 3 consecutive misses, as in the paper).

**Evidence against static clutter.** Stars, lamps, roof corners, hot spots of the ground and
fixed-pattern noise are persistent: they pass any hit count. They stay put in the scene, a
target moves. :func:`motion` tests a track's recent scene positions (camera motion removed)
for a non-zero velocity, robustly (Theil–Sen): under "stationary", T² = |v̂|² / var(v̂) is about
χ² with 2 degrees of freedom, so ``T² >= -2 ln α`` rejects it at the same rate α.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wfviz import normal

EVIDENCE_CAP = 5.0  # most one hit's significance or change may add to or take from a score (nats)


@dataclass(frozen=True)
class Thresholds:
    """Score levels of the sequential test (natural log units)."""

    confirm: float
    drop: float
    delete: float  # below ``confirm``: a confirmed track at this score is deleted
    alpha: float
    motion: float  # T² a stationary track exceeds with probability alpha


def thresholds(false_per_1000: float, tested_per_frame: float, beta: float, p_lost: float) -> Thresholds:
    """Wald's levels for the rate of false confirmed tracks ``false_per_1000`` per 1000 frames
    when ``tested_per_frame`` tentative tracks are tested each frame."""
    alpha = min(false_per_1000 / (1000.0 * max(tested_per_frame, 1.0)), 0.5)
    confirm = math.log((1.0 - beta) / alpha)
    return Thresholds(confirm=confirm, drop=math.log(beta / (1.0 - alpha)),
                      delete=confirm + math.log(p_lost), alpha=alpha, motion=-2.0 * math.log(alpha))


def gate_false_alarm(density: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Probability that false detections of ``density`` (per pixel) put one in each gate
    (half sizes (N, 2) in px, the gate covering (2 w + 1)(2 h + 1) pixels)."""
    area = (2.0 * half[:, 0] + 1.0) * (2.0 * half[:, 1] + 1.0)
    return -np.expm1(-np.asarray(density, dtype=np.float64) * area)


def gate_threshold(half: np.ndarray, p_gate: float, k: float) -> np.ndarray:
    """Detection threshold (in local noise σ) for each gate (half sizes (N, 2) in px) at which
    Gaussian noise crosses it somewhere in the gate with probability ``p_gate`` (each pixel
    counted as independent, which overstates the chance for the smoothed residual: the rate is
    an upper bound), never above the frame's threshold ``k``. A confirmed track looks this deep
    for its target, which fades in and out of the frame's threshold (not in the papers)."""
    area = (2.0 * half[:, 0] + 1.0) * (2.0 * half[:, 1] + 1.0)
    return np.minimum(normal.quantile(1.0 - p_gate / np.maximum(area, 1.0)), k)


def score_change(hit: np.ndarray, p_detect: float, p_fa: np.ndarray) -> np.ndarray:
    """The score each track adds this frame: a hit or a miss (see the module docstring)."""
    p = np.clip(p_fa, 1e-12, 1.0 - 1e-9)
    return np.where(hit, np.log(p_detect / p), np.log((1.0 - p_detect) / (1.0 - p)))


def position_score(innovation: np.ndarray, S_inv: np.ndarray, half: np.ndarray) -> np.ndarray:
    """ln of the likelihood ratio of where a hit lies in its gate: the Gaussian innovation density
    N(ν; 0, S) of a target against the uniform density 1 / A of a false detection anywhere in the
    gate (A: the gate's area). Near the prediction it adds, at the gate's edge it takes away."""
    area = (2.0 * half[:, 0] + 1.0) * (2.0 * half[:, 1] + 1.0)
    d2 = np.einsum("ni,nij,nj->n", innovation, S_inv, innovation)
    det = np.maximum(np.linalg.det(S_inv), 1e-300)
    return np.log(area) + 0.5 * np.log(det) - np.log(2.0 * np.pi) - 0.5 * d2


def amplitude_score(z: np.ndarray, k: float | np.ndarray, z_max: float = 1000.0,
                    cap: float = EVIDENCE_CAP) -> np.ndarray:
    """ln of the likelihood ratio of a hit's significance z (local noise σ, :mod:`wfviz.stages.noise`):
    a target's significance is taken uniform in ln z between the detection threshold ``k`` (per
    hit where a gate was searched deeper, :func:`gate_threshold`) and ``z_max``; noise that
    crossed the threshold is Gaussian beyond it, density φ(z) / Q(k). A hit just above a lowered
    threshold is thus evidence for noise, a bright one for a target. Bounded to ±``cap`` per
    hit (real noise tails are heavier than the model's). NaN: 0."""
    z = np.asarray(z, dtype=np.float64)
    k = np.broadcast_to(np.asarray(k, dtype=np.float64), z.shape)
    ok = np.isfinite(z) & (z > 0)
    zz = np.where(ok, np.maximum(z, k), k)
    log_f1 = -np.log(zz) - np.log(np.log(np.maximum(z_max / k, 1.0 + 1e-9)))
    log_f0 = -0.5 * zz * zz - 0.5 * math.log(2 * math.pi) - normal.log_cdf(-k)
    return np.where(ok, np.clip(log_f1 - log_f0, -cap, cap), 0.0)


def multiframe_only(z: np.ndarray, k: float | np.ndarray) -> np.ndarray:
    """Hits whose own significance ``z`` is below their threshold ``k`` (σ): found by the
    multi-frame stage only (:func:`wfviz.stages.detection.detect`; NaN: not known, False)."""
    z = np.asarray(z, dtype=np.float64)
    return np.isfinite(z) & (z < np.asarray(k, dtype=np.float64) - 1e-9)


def change_evidence(z_change: np.ndarray, threshold: float, q_static: float, q_target: float) -> np.ndarray:
    """ln of the likelihood ratio that a hit's change significance gives against static clutter,
    in Wald's form for a yes/no observation: the hit has *changed* when its change significance
    exceeds ``threshold`` (it is new at its place in the scene). Static clutter changes in a
    fraction ``q_static`` of its hits (noise, a video codec's refresh), a target in ``q_target``
    (a target that has moved off its earlier image always; a hovering one rarely). NaN: 0."""
    zc = np.asarray(z_change, dtype=np.float64)
    yes = math.log(q_target / q_static)
    no = math.log((1.0 - q_target) / (1.0 - q_static))
    return np.where(np.isfinite(zc), np.where(zc > threshold, yes, no), 0.0)


@dataclass(frozen=True)
class Motion:
    """A track's motion over its recorded scene positions: Theil–Sen ``velocity`` (px per frame,
    the median of the slopes between every pair of positions, per axis); ``t2`` = |v|² Σ(t - t̄)²
    / σ², with σ the robust scatter of the positions about that line (1.4826 × median absolute
    residual, at least ``sigma_floor``): about χ² with 2 degrees of freedom for a track that does
    not move; ``steady``: the least progress made in the direction of travel from the median
    position of each of ``parts`` consecutive parts of the positions (oldest first) to that of
    the next (px): a target keeps moving, a centroid that jumps once to a neighbouring spot makes
    its progress between two neighbouring parts only, or splits it over the two differences
    next to the part the jump falls in; with 4 parts a third difference stays free of it.
    ``consecutive``: :func:`consecutive_progress` (NaN: not measured)."""

    velocity: np.ndarray
    steady: np.ndarray
    t2: np.ndarray
    steady_error: np.ndarray  #: standard error of ``steady`` under the position scatter σ (px)
    parts: np.ndarray  #: parts ``steady`` was measured over: ``parts`` where 2 positions per part are recorded, else 3
    per_part: np.ndarray  #: positions in each of the oldest and newest parts (1: no median, single positions)
    consecutive: np.ndarray | None = None


def motion(t: np.ndarray, xy: np.ndarray, ok: np.ndarray, sigma_floor: float, parts: int = 3) -> Motion:
    """:class:`Motion` of each track from positions ``xy`` (N, K, 2) at frames ``t`` (N, K)
    where ``ok`` (N, K), its steady progress over ``parts`` parts (fewer, at least 3, while
    there are fewer than 2 positions per part; from 3 positions on, one a part). Pairs, not a least-squares line: a centroid that jumps once to a
    neighbouring spot and stays there, or hops back and forth, moves neither the median slope
    nor the median residual much (up to about 29 % of the pairs may be wild). Zero with fewer
    than 3 positions."""
    n, k = t.shape
    i, j = np.triu_indices(k, 1)
    both = ok[:, i] & ok[:, j]
    dt = t[:, j] - t[:, i]
    good = both & (dt > 0)
    slope = (xy[:, j, :] - xy[:, i, :]) / np.where(good, dt, 1.0)[..., None]
    slope = np.where(good[..., None], slope, np.nan)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            v = np.nanmedian(slope, axis=1)
            v = np.where(np.isfinite(v), v, 0.0)
            tt = np.where(ok, t, np.nan)
            t0 = np.nanmedian(tt, axis=1)
            x0 = np.nanmedian(np.where(ok[..., None], xy - v[:, None, :] * (t - t0[:, None])[..., None],
                                       np.nan), axis=1)
            resid = np.where(ok[..., None], xy - x0[:, None, :] - v[:, None, :] * (t - t0[:, None])[..., None],
                             np.nan)
            sigma = 1.4826 * np.nanmedian(np.hypot(resid[..., 0], resid[..., 1]), axis=1) / np.sqrt(2.0)
            span = np.nanmax(tt, axis=1) - np.nanmin(tt, axis=1)
            tm = np.nanmean(tt, axis=1)
            sxx = np.nansum((tt - tm[:, None]) ** 2, axis=1)
    npos = ok.sum(axis=1)
    sigma = np.maximum(np.nan_to_num(sigma, nan=sigma_floor), sigma_floor)
    speed = np.hypot(v[:, 0], v[:, 1])
    enough = npos >= 3
    t2 = np.where(enough, speed ** 2 * np.nan_to_num(sxx) / sigma ** 2, 0.0)
    del span
    # a part's median of k positions scatters by 1.2533 σ / √k (kept for k <= 2 too, where it is
    # their mean: real centroids' tails are heavier than Gaussian); a progress is a difference of two
    n_parts = np.clip(npos // 2, 3, max(parts, 3))
    part = np.maximum(npos // n_parts, 1)
    error = np.sqrt(2.0) * 1.2533 * sigma / np.sqrt(part)
    single = enough & (part < 2)
    if single.any():  # single positions a part: a median of the residuals of 3 to 5 says little
        rows = np.nonzero(single)[0]
        error[rows] = np.maximum(error[rows], np.sqrt(2.0) * 1.2533 * _path_scatter(t[rows], xy[rows], ok[rows]))
    v = np.where(enough[:, None], v, 0.0)
    return Motion(v, _steady(t, xy, ok, n_parts), t2, error, n_parts, part, consecutive_progress(t, xy, ok, v))


def _path_scatter(t: np.ndarray, xy: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Each track's position scatter σ (px) from how far each position lies off the chord of its
    two neighbours in time: for a target at constant velocity that is noise alone, of variance
    σ² (1 + a² + b²) per axis (a, b: the neighbours' shares of the time between them), whatever
    the velocity (the variate-difference method); 0 with fewer than 3 positions."""
    out = np.zeros(len(t))
    for i in range(len(t)):
        order = np.argsort(t[i][ok[i]])
        tt, p = t[i][ok[i]][order], xy[i][ok[i]][order]
        if len(p) < 3:
            continue
        span = tt[2:] - tt[:-2]
        b = (tt[1:-1] - tt[:-2]) / span
        a = 1.0 - b
        off = p[1:-1] - (a[:, None] * p[:-2] + b[:, None] * p[2:])
        out[i] = float(np.sqrt(np.mean((off ** 2).sum(axis=1) / (2.0 * (1.0 + a * a + b * b)))))
    return out


def consecutive_progress(t: np.ndarray, xy: np.ndarray, ok: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Per track, the progress its positions ``xy`` (N, K, 2) at frames ``t`` (N, K) where ``ok``
    (oldest first) make between positions of consecutive frames, in the direction of
    ``velocity`` (N, 2), as a share of the progress that velocity predicts over those frames (1:
    a target that moves alike whether it is detected or not). A track that takes separate static
    spots, re-acquiring the next one across missed frames in its grown gate, makes its progress
    in the jumps: its share is near 0. NaN (not measured) without a missed frame between two
    positions (the share is then the whole progress, which the other motion tests judge),
    without positions of consecutive frames, or without velocity."""
    n, k = t.shape
    last = np.maximum.accumulate(np.where(ok, np.arange(k), -1), axis=1)
    prev = np.empty_like(last)
    prev[:, 0] = -1
    prev[:, 1:] = last[:, :-1]                # the position before each one (-1: none)
    pair = ok & (prev >= 0)
    rows = np.arange(n)[:, None]
    p = np.maximum(prev, 0)
    dt = t - t[rows, p]
    step = pair & (dt > 0) & (dt < 1.5)       # positions of consecutive frames
    gap = pair & (dt >= 1.5)                  # a missed frame between them
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    d = xy - xy[rows, p]
    along = (d[..., 0] * velocity[:, :1] + d[..., 1] * velocity[:, 1:]) / np.where(speed > 0, speed, 1.0)[:, None]
    made = np.where(step, along, 0.0).sum(axis=1)
    predicted = speed * step.sum(axis=1)
    measured = gap.any(axis=1) & (predicted > 0)
    return np.where(measured, made / np.where(measured, predicted, 1.0), np.nan)


def slide(size: np.ndarray, ok: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Per track, how many times longer its hits' components (``size`` (N, K, 2): width, height;
    NaN unknown; where ``ok``) are along the direction of ``velocity`` (N, 2) than across it, the
    median of each over its hits (across at least 1 px): about 1 for a compact target, 2 and
    more for the piece of a road or an edge whose detected part moves along it. NaN: no size
    known, or no velocity."""
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    u = np.abs(velocity) / np.where(speed > 0, speed, 1.0)[:, None]
    wh = np.where(ok[..., None], size, np.nan)
    along = wh[..., 0] * u[:, :1] + wh[..., 1] * u[:, 1:]
    across = wh[..., 0] * u[:, 1:] + wh[..., 1] * u[:, :1]
    count = np.isfinite(along).sum(axis=1)
    ratio = _median(along, count) / np.maximum(_median(across, count), 1.0)
    return np.where((count > 0) & (speed > 0), ratio, np.nan)


def _median(a: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Per row, the median of the ``count`` finite values of ``a`` (N, K) (NaN elsewhere; any
    value where ``count`` is 0)."""
    s = np.sort(a, axis=1)  # NaN last
    rows = np.arange(len(a))
    lo, hi = np.maximum((count - 1) // 2, 0), np.maximum(count // 2, 0)
    return 0.5 * (s[rows, np.minimum(lo, a.shape[1] - 1)] + s[rows, np.minimum(hi, a.shape[1] - 1)])


def _steady(t: np.ndarray, xy: np.ndarray, ok: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """:attr:`Motion.steady` of each track over its ``parts`` (0 with fewer than one position
    per part): the oldest and newest parts hold ``n // parts`` positions each, the middle ones
    share the rest."""
    out = np.zeros(len(t))
    for i in range(len(t)):
        p = xy[i][ok[i]][np.argsort(t[i][ok[i]])]
        n_parts = int(parts[i])
        k = len(p) // n_parts
        if k < 1:
            continue
        inner = np.array_split(p[k:len(p) - k], n_parts - 2)
        m = np.array([np.median(q, axis=0) for q in (p[:k], *inner, p[len(p) - k:])])
        d = m[-1] - m[0]
        norm = float(np.hypot(*d))
        if norm > 0:
            out[i] = float(np.min(np.diff(m, axis=0) @ (d / norm)))
    return out


class DetectionDensity:
    """Local density of false detections per pixel, on a grid of ``tile`` px tiles: this
    frame's detections not taken by a confirmed track, summed over the 3 × 3 tiles around
    each tile, blended over time (weight ``memory`` on the past) and divided by those tiles'
    valid pixels. ``prior`` detections per frame are added to every neighbourhood, so that
    a clean patch of sky is not taken for one where a false detection is impossible."""

    def __init__(self, tile: int = 32, memory: float = 0.8, prior: float = 0.1) -> None:
        self.tile, self.memory, self.prior = tile, memory, prior
        self.grid: np.ndarray | None = None
        self._area: tuple[np.ndarray, np.ndarray] | None = None  # (valid mask, its 3 x 3 tile areas)

    def update(self, xy: np.ndarray, valid: np.ndarray) -> None:
        """Add this frame's false-detection candidates ``xy`` (N, 2) over the ``valid`` pixels."""
        h, w = valid.shape
        t = self.tile
        ny, nx = -(-h // t), -(-w // t)
        counts = np.zeros((ny, nx))
        if len(xy):
            r = np.clip((xy[:, 1] // t).astype(np.int64), 0, ny - 1)
            c = np.clip((xy[:, 0] // t).astype(np.int64), 0, nx - 1)
            np.add.at(counts, (r, c), 1.0)
        if self._area is None or self._area[0] is not valid:
            pad = np.zeros((ny * t, nx * t))
            pad[:h, :w] = valid
            self._area = (valid, box3(pad.reshape(ny, t, nx, t).sum(axis=(1, 3))))
        density = (box3(counts) + self.prior) / np.maximum(self._area[1], 1.0)
        if self.grid is None or self.grid.shape != density.shape:
            self.grid = density
        else:
            self.grid = self.memory * self.grid + (1.0 - self.memory) * density

    def at(self, xy: np.ndarray) -> np.ndarray:
        """Density at the points ``xy`` (N, 2) (their tile's value)."""
        if self.grid is None or not len(xy):
            return np.zeros(len(xy))
        ny, nx = self.grid.shape
        r = np.clip((np.asarray(xy)[:, 1] // self.tile).astype(np.int64), 0, ny - 1)
        c = np.clip((np.asarray(xy)[:, 0] // self.tile).astype(np.int64), 0, nx - 1)
        return self.grid[r, c]


def box3(a: np.ndarray) -> np.ndarray:
    """Sum over each cell's 3 × 3 neighbourhood (zero outside the grid)."""
    import cv2

    return cv2.boxFilter(np.asarray(a, dtype=np.float64), -1, (3, 3), normalize=False,
                         borderType=cv2.BORDER_CONSTANT)
