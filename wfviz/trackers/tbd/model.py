"""Measurement model of the track-before-detect filter (Wang Hongbo and Wang Zhongwei).

A frame is normalised to y = (z - b) / sigma, so the noise is N(0, 1) and a target's amplitude
A is its peak SNR. A target at (r, c) (row, column; x = c, y = r; origin at the centre of the
top-left pixel) adds A * h(r, c) to the pixels of a (2k+1) x (2k+1) patch around it, where h
is the pixel-integrated Gaussian PSF of width ``s`` scaled to a continuous peak of 1 and
truncated to the patch (the paper's "truncated 2-D Gaussian"). With n targets and amplitudes
A = (A_1..A_n) the log likelihood ratio against "no target" over the cells they touch is

    log l(y | X, A) = A^T a - 1/2 A^T B A,
    a_j = sum_p h_j(p) y_p,    B_jl = sum_p h_j(p) h_l(p).

The amplitudes are not state components: every particle carries, per target, a Gaussian
posterior N(m_j, v_j) of its amplitude (Rao-Blackwellised) whose prior at birth is
N(mu0, s0^2) truncated to A >= A_min; :func:`likelihood` integrates them out in closed form
(see docs/pipeline.md, "The track-before-detect tracker").

Everything is vectorised over particles and targets: (P, n) arrays, no Python loop over
particles or pixels.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import erf, log_ndtr

_SQRT2 = math.sqrt(2.0)


def psf_factors(pos: np.ndarray, lo: np.ndarray, size: int, sigma: float) -> np.ndarray:
    """Separable factor of the PSF along one axis: for each centre ``pos`` (any shape) and
    first patch index ``lo`` (same shape, int), the (..., size) pixel fractions of a 1-D
    Gaussian times sqrt(2 pi) sigma (so the 2-D product has a continuous peak of 1)."""
    edges = (lo[..., None] + np.arange(size + 1) - 0.5 - pos[..., None]) * (1.0 / (_SQRT2 * sigma))
    e = erf(edges)
    return (e[..., 1:] - e[..., :-1]) * (0.5 * math.sqrt(2.0 * math.pi) * sigma)


def psf_patch(sigma: float, radius: int, dr: float = 0.0, dc: float = 0.0) -> np.ndarray:
    """The (2k+1, 2k+1) PSF patch of a target ``(dr, dc)`` px off the centre pixel."""
    size = 2 * radius + 1
    lo = np.array(-radius)
    hr = psf_factors(np.array(dr), lo, size, sigma)
    hc = psf_factors(np.array(dc), lo, size, sigma)
    return np.outer(hr, hc)


def robust_sigma(res: np.ndarray) -> float:
    """Noise sigma of a residual: 1.4826 MAD, refined by the std of the values within 4 MADs of
    the median (the MAD alone is quantised on integer data: +4 % at sigma = 20 counts). Large
    frames are subsampled 2 x 2."""
    if res.size > 65536:
        res = res[::2, ::2]
    med = float(np.median(res))
    dev = np.abs(res - med)
    mad = float(np.median(dev)) * 1.4826
    if mad <= 0:
        return max(float(res.std()), 1e-6)
    inl = res[dev < 4.0 * mad]
    return max(float(inl.std()), 1e-6)


def normalise(image: np.ndarray, method: str, window: int, spikes: bool = True, noise_window: int = 31
              ) -> tuple[np.ndarray, float, np.ndarray | None]:
    """(y, sigma, texture): the frame minus its background, divided by the noise sigma.

    ``"global"``: background = the frame's median, sigma = the robust std of the residual (a
    flat sky with Gaussian noise, the paper's model). ``"local"``: background = the ``window``
    box mean; the residual over sigma is divided again by its local RMS over ``noise_window``
    (values clipped at +-4 so that a target hardly raises it; floored at 0.5), and ``texture``
    = that local RMS (about 1 on a clear sky, more over clouds and ground, less in dark
    corners); None for ``"global"``. ``spikes``: first, a pixel more than 5 sigma away from
    its 3 x 3 median whose deviation is at least 0.8 of its residual (a hot or dead pixel; a
    point target of sigma >= 0.7 px raises its neighbours, ratio ~0.5) is replaced by that median.
    """
    z = image.astype(np.float32, copy=False)

    def residual(z: np.ndarray) -> np.ndarray:
        if method == "global":
            return z - float(np.median(z))
        return z - cv2.blur(z, (window, window), borderType=cv2.BORDER_REFLECT)

    res = residual(z)
    sigma = robust_sigma(res)
    if spikes:
        med = cv2.medianBlur(z, 3)
        d = z - med
        bad = (np.abs(d) > 5.0 * sigma) & (np.abs(d) >= 0.8 * np.abs(res))
        if bad.any():
            z = z.copy()
            z[bad] = med[bad]
            res = residual(z)
    y = res * np.float32(1.0 / sigma)
    texture = None
    if method != "global":
        y, texture = texture_normalise(y, noise_window)
    return y, sigma, texture


def texture_normalise(y: np.ndarray, noise_window: int) -> tuple[np.ndarray, np.ndarray]:
    """(y / max(texture, 0.5), texture): texture = the local RMS of y over ``noise_window``
    (values clipped at +-4 so that a target hardly raises it); about 1 on a clear sky, more
    over clouds and ground."""
    c = np.clip(y, -4.0, 4.0)
    texture = np.sqrt(cv2.blur(c * c, (noise_window, noise_window), borderType=cv2.BORDER_REFLECT))
    return y / np.maximum(texture, 0.5), texture


def matched_filter(y: np.ndarray, sigma: float, radius: int) -> np.ndarray:
    """t = sum_p h(p) y_p / ||h|| for a target centred on each pixel: N(0, 1) where there is
    only noise, about A ||h|| on a target of amplitude A."""
    h = psf_patch(sigma, radius).astype(np.float32)
    t = cv2.filter2D(y.astype(np.float32, copy=False), -1, h, borderType=cv2.BORDER_CONSTANT)
    return t / float(np.sqrt((h.astype(np.float64) ** 2).sum()))


def patch_sums(y: np.ndarray, r: np.ndarray, c: np.ndarray, sigma: float, radius: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For targets at rows ``r`` and columns ``c`` (shape (P, n)): a = sum h y, the per-axis
    PSF factors hr, hc (P, n, K) (zero on cells outside the frame) and the patch origins
    r0, c0 (P, n). One gather of (P, n, K, K) pixels."""
    size = 2 * radius + 1
    rows, cols = y.shape
    r0 = np.rint(r).astype(np.int64) - radius
    c0 = np.rint(c).astype(np.int64) - radius
    hr = psf_factors(r, r0, size, sigma)
    hc = psf_factors(c, c0, size, sigma)
    k = np.arange(size)
    ri = r0[..., None] + k
    ci = c0[..., None] + k
    hr *= (ri >= 0) & (ri < rows)
    hc *= (ci >= 0) & (ci < cols)
    np.clip(ri, 0, rows - 1, out=ri)
    np.clip(ci, 0, cols - 1, out=ci)
    patch = y[ri[..., :, None], ci[..., None, :]]  # (P, n, K, K)
    a = np.einsum("pnij,pni,pnj->pn", patch, hr, hc, optimize=False)
    b = (hr * hr).sum(-1) * (hc * hc).sum(-1)
    return a, b, hr, hc, r0, c0


def _overlap(h1: np.ndarray, h2: np.ndarray, d: np.ndarray) -> np.ndarray:
    """sum_i h1[..., i] h2[..., i - d] over valid i (patches ``d`` cells apart)."""
    size = h1.shape[-1]
    idx = np.arange(size) - d[..., None]
    ok = (idx >= 0) & (idx < size)
    shifted = np.take_along_axis(h2, np.clip(idx, 0, size - 1), -1) * ok
    return (h1 * shifted).sum(-1)


def likelihood(y: np.ndarray, X: np.ndarray, m: np.ndarray, v: np.ndarray, sigma: float, radius: int,
               a_min: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Log likelihood ratio of each particle, amplitudes integrated out, and the amplitude
    posteriors.

    ``X`` (P, n, 4) states (r, v_r, c, v_c); ``m``, ``v`` (P, n) the predicted amplitude means
    and variances. Returns (log_lr (P,), m' (P, n), v' (P, n)). Targets whose patches do not
    overlap factorise exactly; particles with overlapping patches are solved jointly with the
    n x n cross terms B_jl. Per target, the truncation A >= ``a_min`` contributes
    log Phi((m' - a_min)/sqrt(v')) - log Phi((m - a_min)/sqrt(v)) (exact for one target; the
    marginal of the joint posterior otherwise).
    """
    P, n = X.shape[:2]
    if n == 0:
        return np.zeros(P), m, v
    a, b, hr, hc, r0, c0 = patch_sums(y, X[..., 0], X[..., 2], sigma, radius)
    lam = b + 1.0 / v
    eta = a + m / v
    m_post = eta / lam
    v_post = 1.0 / lam
    per = -0.5 * np.log1p(v * b) + 0.5 * eta * eta / lam - 0.5 * m * m / v
    log_lr = per.sum(-1)
    if n > 1:
        size = 2 * radius + 1
        joint = np.zeros(P, dtype=bool)
        cross = np.zeros((P, n, n))
        for j in range(n):
            for l in range(j + 1, n):
                dr = r0[:, l] - r0[:, j]
                dc = c0[:, l] - c0[:, j]
                near = (np.abs(dr) < size) & (np.abs(dc) < size)
                if not near.any():
                    continue
                idx = np.flatnonzero(near)
                s = (_overlap(hr[idx, j], hr[idx, l], dr[idx])
                     * _overlap(hc[idx, j], hc[idx, l], dc[idx]))
                cross[idx, j, l] = cross[idx, l, j] = s
                joint[idx] |= s != 0
        if joint.any():
            idx = np.flatnonzero(joint)
            L = cross[idx].copy()
            diag = np.arange(n)
            L[:, diag, diag] = lam[idx]
            Linv = np.linalg.inv(L)
            mu = np.einsum("pij,pj->pi", Linv, eta[idx])
            _, logdet = np.linalg.slogdet(L)
            vi, mi = v[idx], m[idx]
            log_lr[idx] = (-0.5 * (logdet + np.log(vi).sum(-1)) + 0.5 * (eta[idx] * mu).sum(-1)
                           - 0.5 * (mi * mi / vi).sum(-1))
            m_post[idx] = mu
            v_post[idx] = Linv[:, diag, diag]
    log_lr += (log_ndtr((m_post - a_min) / np.sqrt(v_post))
               - log_ndtr((m - a_min) / np.sqrt(v))).sum(-1)
    return log_lr, m_post, v_post
