"""Multi-target particle-filter track-before-detect over one region (Wang Hongbo and Wang Zhongwei).

One particle filter PF_n per hypothesis n = 0..N_max targets. Each PF_n is made, every frame,
of three particle sets: *birth* (from PF_n-1 at k-1, plus one new target), *continuation*
(from PF_n at k-1) and *death* (from PF_n+1 at k-1, one target removed). The posterior of the
number of targets is computed analytically from the sets' mean likelihood ratios (Rutten et
al.); the states of the estimated count come from PF_n. At the end of the frame each PF_n is
resampled three times: N_b particles become PF_n+1's birth source, N_c PF_n's continuation
set, N_d PF_n-1's death source. The formulas are in docs/pipeline.md ("The track-before-detect
tracker"). Vectorised over particles; loops only over hypotheses, target pairs and target
permutations (n <= N_max).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from wfviz.trackers.base import StageTimer
from wfviz.trackers.tbd.config import TBDConfig
from wfviz.trackers.tbd.model import likelihood

BIRTH, CONT, DEATH = 0, 1, 2


@dataclass
class Particles:
    """A particle set of n targets: states X (P, n, 4) = (r, v_r, c, v_c) and the Gaussian
    amplitude posterior (m, v) of each target (P, n)."""

    X: np.ndarray
    m: np.ndarray
    v: np.ndarray

    @classmethod
    def empty(cls, count: int, n: int) -> "Particles":
        return cls(np.zeros((count, n, 4)), np.zeros((count, n)), np.ones((count, n)))

    def __len__(self) -> int:
        return self.X.shape[0]

    def take(self, idx: np.ndarray) -> "Particles":
        return Particles(self.X[idx], self.m[idx], self.v[idx])


@dataclass(frozen=True)
class Estimate:
    """PF_n's estimate of its n targets (region coordinates): rows of (r, v_r, c, v_c),
    amplitude (peak SNR) and the posterior std of r and c."""

    state: np.ndarray  # (n, 4)
    amplitude: np.ndarray  # (n,)
    std: np.ndarray  # (n, 2) std of (r, c)


@dataclass(frozen=True)
class BankOutput:
    """One frame of one region: the count posterior, each PF_n's estimate, display particles."""

    log_p: np.ndarray  # (N_max + 1,) log P(N_k = n | Z_k)
    estimates: tuple[Estimate, ...]  # index n = 0..N_max
    particles: np.ndarray  # (K, 3) rows (r, c, n): resampled posterior particles, subsampled
    log_likelihood: np.ndarray  # (N_max + 1, 3) log L_{n,m} for m = n-1, n, n+1 (-inf: no set)

    @property
    def p(self) -> np.ndarray:
        return np.exp(self.log_p)

    @property
    def count(self) -> int:
        return int(np.argmax(self.log_p))


def logsumexp(a: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """log(sum(exp(a))) along ``axis``; -inf for an empty or all -inf slice (no warnings)."""
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return -np.inf if axis is None else np.full(a.shape[:axis] + a.shape[axis + 1:], -np.inf)
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    out = np.squeeze(out, axis=axis) if axis is not None else float(out.reshape(()))
    return out


def systematic(log_w: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` indices drawn by systematic resampling from normalised log weights."""
    if count == 0 or log_w.size == 0:
        return np.zeros(0, dtype=np.int64)
    w = np.exp(log_w - log_w.max()) if np.isfinite(log_w).any() else np.ones(log_w.size)
    cdf = np.cumsum(w)
    u = (rng.random() + np.arange(count)) * (cdf[-1] / count)
    return np.minimum(np.searchsorted(cdf, u, side="right"), log_w.size - 1)


def _permutations(n: int) -> np.ndarray:
    return np.array(list(itertools.permutations(range(n))), dtype=np.int64)


class RegionFilter:
    """The PF_0..PF_N_max bank over one rectangular region of ``shape`` (rows, columns).

    Coordinates are the region's (row 0, column 0 = its top-left pixel centre). ``step``
    takes the region's normalised pixels y and matched-filter map t (for the birth proposal).
    """

    def __init__(self, config: TBDConfig, shape: tuple[int, int], rng: np.random.Generator,
                 max_speed: float | None = None) -> None:
        self.cfg = config
        ms = config.model.max_speed
        self.max_speed = float(ms if ms is not None else (max_speed if max_speed is not None else 1.0))
        self.shape = shape
        self.rng = rng
        f = config.filter
        self.nmax = N = f.max_targets
        self.sizes = (f.birth_particles, f.continuation_particles, f.death_particles)
        # log Pi(n | m): one birth or one death per frame at most
        pi = np.zeros((N + 1, N + 1))
        for m in range(N + 1):
            up = f.p_birth if m < N else 0.0
            down = f.p_death if m > 0 else 0.0
            pi[m, m] = 1.0 - up - down
            if m < N:
                pi[m + 1, m] = up
            if m > 0:
                pi[m - 1, m] = down
        with np.errstate(divide="ignore"):
            self.log_pi = np.log(pi)  # [n, m]
            self.log_p = np.log(np.eye(N + 1)[0])  # no target before the first frame
        self.log_p_prev = self.log_p.copy()
        nb, nc, nd = self.sizes
        # sources for the next frame, by the hypothesis they feed
        self.src_birth = [None] + [Particles.empty(nb, n - 1) for n in range(1, N + 1)]
        self.src_cont = [Particles.empty(nc, n) for n in range(N + 1)]
        self.src_death = [Particles.empty(nd, n + 1) for n in range(N)] + [None]
        self.prev_est: list[np.ndarray] = [np.zeros((n, 2)) for n in range(N + 1)]  # predicted (r, c)
        self.frames = 0
        self._perms = [_permutations(n) for n in range(N + 1)]

    # -- motion -------------------------------------------------------------------------------
    def _propagate(self, p: Particles) -> Particles:
        """Constant velocity, T = 1: x += v + w/2, v += w, w ~ N(0, q^2) per axis; amplitude
        variance grows by the random walk."""
        mc = self.cfg.model
        X = p.X.copy()
        if X.size:
            w = self.rng.standard_normal((X.shape[0], X.shape[1], 2)) * mc.process_noise
            X[..., 0] += X[..., 1] + 0.5 * w[..., 0]
            X[..., 1] += w[..., 0]
            X[..., 2] += X[..., 3] + 0.5 * w[..., 1]
            X[..., 3] += w[..., 1]
        return Particles(X, p.m.copy(), p.v + mc.amplitude_walk ** 2)

    def _birth_proposal(self, t: np.ndarray, n: int) -> np.ndarray:
        """Per-pixel probabilities q of the new target's pixel (sum 1): (1 - eps) of the mass
        follows exp(max(t, 0)^2 / 2) of the matched-filter map (pixels within 2 px of PF_n-1's
        targets excluded), eps = ``filter.birth_uniform`` is uniform."""
        eps = self.cfg.filter.birth_uniform
        rows, cols = self.shape
        npix = rows * cols
        q = np.full(npix, eps / npix)
        if eps < 1.0:
            s = np.minimum(np.maximum(t, 0.0), 10.0).ravel()
            w = np.exp(0.5 * s * s - 50.0)
            est = self.prev_est[n - 1]
            if len(est):
                rr, cc = np.divmod(np.arange(npix), cols)
                for r, c in est:
                    w[(rr - r) ** 2 + (cc - c) ** 2 < 4.0] = 0.0
            total = w.sum()
            q += (1.0 - eps) * (w / total if total > 0 else 1.0 / npix)
        return q / q.sum()

    def _birth(self, src: Particles, t: np.ndarray, n: int) -> tuple[Particles, np.ndarray]:
        """PF_n-1's resampled particles, moved, plus a new target drawn from the birth proposal;
        returns the set and log(prior / proposal) of each new target."""
        mc = self.cfg.model
        p = self._propagate(src)
        count = len(p)
        rows, cols = self.shape
        q = self._birth_proposal(t, n)
        cdf = np.cumsum(q)
        pix = np.minimum(np.searchsorted(cdf, self.rng.random(count) * cdf[-1], side="right"), q.size - 1)
        r, c = np.divmod(pix, cols)
        u = self.rng.random((count, 4))
        new = np.empty((count, 1, 4))
        new[:, 0, 0] = r + u[:, 0] - 0.5
        new[:, 0, 2] = c + u[:, 1] - 0.5
        new[:, 0, 1] = (2.0 * u[:, 2] - 1.0) * self.max_speed
        new[:, 0, 3] = (2.0 * u[:, 3] - 1.0) * self.max_speed
        X = np.concatenate([p.X, new], axis=1)
        m = np.concatenate([p.m, np.full((count, 1), mc.amplitude_mean)], axis=1)
        v = np.concatenate([p.v, np.full((count, 1), mc.amplitude_std ** 2)], axis=1)
        log_beta = -math.log(q.size) - np.log(q[pix])
        return Particles(X, m, v), log_beta

    def _death(self, src: Particles) -> Particles:
        """PF_n+1's resampled particles with one target, chosen uniformly, removed; moved."""
        count, n1 = src.X.shape[:2]
        gone = self.rng.integers(0, n1, count)
        keep = np.arange(n1 - 1)[None, :].repeat(count, 0)
        keep += keep >= gone[:, None]
        p = Particles(np.take_along_axis(src.X, keep[..., None], 1),
                      np.take_along_axis(src.m, keep, 1), np.take_along_axis(src.v, keep, 1))
        return self._propagate(p)

    # -- one frame -----------------------------------------------------------------------------
    def step(self, y: np.ndarray, t: np.ndarray, timer: StageTimer | None = None) -> BankOutput:
        """Filter one frame of the region (normalised pixels ``y``, matched filter ``t``)."""
        cfg, N = self.cfg, self.nmax
        mc = cfg.model
        rows, cols = self.shape
        timer = timer if timer is not None else StageTimer()
        timer.skip()  # the time since the caller's last lap belongs to no stage of the filter
        lap = timer.lap

        # 1. the three sets of every PF_n (n = 0 has no target: its ratio is 1)
        sets: list[list[tuple[int, Particles, np.ndarray]]] = []
        for n in range(N + 1):
            s: list[tuple[int, Particles, np.ndarray]] = []
            if n >= 1:
                p, lb = self._birth(self.src_birth[n], t, n)
                s.append((BIRTH, p, lb))
            p = self._propagate(self.src_cont[n])
            s.append((CONT, p, np.zeros(len(p))))
            if n < N:
                p = self._death(self.src_death[n])
                s.append((DEATH, p, np.zeros(len(p))))
            sets.append(s)
        lap("predict")

        # 2. likelihood ratios (amplitudes integrated out), merged per PF_n
        merged: list[tuple[Particles, np.ndarray, np.ndarray]] = []  # particles, log(beta*lr), set id
        for n in range(N + 1):
            parts = sets[n]
            P = Particles(np.concatenate([p.X for _, p, _ in parts]),
                          np.concatenate([p.m for _, p, _ in parts]),
                          np.concatenate([p.v for _, p, _ in parts]))
            which = np.concatenate([np.full(len(p), k) for k, p, _ in parts])
            lb = np.concatenate([b for _, _, b in parts])
            if n == 0:
                merged.append((P, lb, which))
                continue
            lr, m, v = likelihood(y, P.X, P.m, P.v, mc.psf_sigma, mc.patch_radius, mc.amplitude_min)
            r, c = P.X[..., 0], P.X[..., 2]
            inside = ((r >= -0.5) & (r < rows - 0.5) & (c >= -0.5) & (c < cols - 0.5)).all(-1)
            lr = np.where(inside, lr, -np.inf)
            merged.append((Particles(P.X, m, v), lb + lr, which))
        lap("likelihood")

        # 3. count posterior: P(n | Z_k) ~ sum_m Pi(n|m) P(m | Z_k-1) L_{n,m}
        log_L = np.full((N + 1, 3), -np.inf)
        log_terms = np.full((N + 1, 3), -np.inf)
        for n in range(N + 1):
            _, lw, which = merged[n]
            for k in (BIRTH, CONT, DEATH):
                sel = which == k
                if not sel.any():
                    continue
                m = n - 1 + k  # source hypothesis at k-1
                log_L[n, k] = logsumexp(lw[sel]) - math.log(sel.sum())
                log_terms[n, k] = self.log_pi[n, m] + self.log_p[m] + log_L[n, k]
        log_post = logsumexp(log_terms, axis=1)
        total = logsumexp(log_post)
        self.log_p_prev = self.log_p
        self.log_p = log_post - total if np.isfinite(total) else np.log(np.eye(N + 1)[0])
        lap("count")

        # 4. particle weights within each PF_n, label alignment, estimates
        weights: list[np.ndarray] = []
        estimates: list[Estimate] = []
        for n in range(N + 1):
            P, lw, which = merged[n]
            counts = np.array([max(int((which == k).sum()), 1) for k in (BIRTH, CONT, DEATH)])
            prior = np.array([self.log_pi[n, n - 1 + k] + self.log_p_prev[n - 1 + k]
                              if 0 <= n - 1 + k <= N else -np.inf for k in (BIRTH, CONT, DEATH)])
            with np.errstate(invalid="ignore"):
                logw = np.where(np.isfinite(prior[which]), prior[which] - np.log(counts[which]) + lw, -np.inf)
            tot = logsumexp(logw) if logw.size else -np.inf
            logw = logw - tot if np.isfinite(tot) else np.full(logw.size, -math.log(max(logw.size, 1)))
            weights.append(logw)
            estimates.append(self._estimate(P, logw, n))
        lap("estimate")

        # 5. resampling in three draws: PF_n+1's birth, PF_n's continuation, PF_n-1's death
        nb, nc, nd = self.sizes
        shown = max(cfg.tracking.particles_shown, 0)
        display = []
        for n in range(N + 1):
            P, _, _ = merged[n]
            logw = weights[n]
            if n < N:
                self.src_birth[n + 1] = P.take(systematic(logw, nb, self.rng))
            idx = systematic(logw, nc, self.rng)
            self.src_cont[n] = P.take(idx)
            if n > 0:
                self.src_death[n - 1] = P.take(systematic(logw, nd, self.rng))
                if shown:
                    sub = idx[:: max(len(idx) // shown, 1)][:shown]
                    pts = P.X[sub][:, :, [0, 2]].reshape(-1, 2)
                    display.append(np.column_stack([pts, np.full(len(pts), n)]))
            est = estimates[n]
            self.prev_est[n] = est.state[:, [0, 2]] + est.state[:, [1, 3]]
        lap("resample")
        self.frames += 1
        return BankOutput(self.log_p.copy(), tuple(estimates),
                          np.concatenate(display) if display else np.zeros((0, 3)), log_L)

    def _estimate(self, P: Particles, logw: np.ndarray, n: int) -> Estimate:
        """Align target labels across particles (the permutation closest to the best particle,
        twice), store the aligned order, return the weighted means and stds."""
        if n == 0 or len(P) == 0:
            return Estimate(np.zeros((n, 4)), np.zeros(n), np.zeros((n, 2)))
        w = np.exp(logw)
        X = P.X
        if n > 1:
            perms = self._perms[n]
            ref = X[int(np.argmax(w)), :, [0, 2]].T  # (n, 2)
            for _ in range(2):
                pos = X[..., [0, 2]]  # (P, n, 2)
                # cost of permutation pi: sum_j |pos[:, pi(j)] - ref[j]|^2
                cost = np.zeros((len(P), len(perms)))
                for j in range(n):
                    cost += ((pos[:, perms[:, j], :] - ref[j]) ** 2).sum(-1)
                best = perms[np.argmin(cost, axis=1)]  # (P, n)
                X = np.take_along_axis(X, best[..., None], 1)
                P.m = np.take_along_axis(P.m, best, 1)
                P.v = np.take_along_axis(P.v, best, 1)
                P.X = X
                ref = np.einsum("p,pjk->jk", w, X[..., [0, 2]])
        mean = np.einsum("p,pjk->jk", w, X)
        var = np.einsum("p,pjk->jk", w, (X - mean) ** 2)
        amp = np.einsum("p,pj->j", w, P.m)
        return Estimate(mean, amp, np.sqrt(np.maximum(var[:, [0, 2]], 0.0)))
