"""Sub-pixel target position in a window: GEWC (GEWC paper, eqs. 4-7) or intensity centroid.

Also an improved GEWC (``gewc_weighted_centroid``), a pixel-integrated Gaussian fit and the
Cramér–Rao bound of that spot model (docs/accuracy.md compares them).

Patches are background-free: pixels not belonging to the target are 0. Positions are in
patch coordinates (x = column, y = row, origin at the centre of the patch's top-left pixel).
"""

from __future__ import annotations

from collections.abc import Callable
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


def gewc_centroid(patch: np.ndarray, bins: int = 32, iterations: int = 2,
                  start: tuple[float, float] | None = None) -> CentroidResult | None:
    """Gradient-entropy-weighted centroid (Zhang Shuai et al. 2018, eqs. 4-7) of a
    background-free patch: :func:`gewc_centroids` on one patch.

    The patch's non-zero-gradient pixels are split into 8 direction regions (octants) around
    a centre, first ``start`` (default: the patch centre), then the previous estimate
    (``iterations`` passes). In region r, q_g is the share of pixels at gradient level g
    (eq. 4), M_g their mean position (eq. 5), E_r the entropy of q and W_r = E_r / ΣE (eq. 6);
    the centroid is Σ_r W_r Σ_g q_g M_g (eq. 7).
    """
    starts = None if start is None else np.asarray([start], dtype=np.float64)
    return gewc_centroids(np.asarray(patch)[None], bins, iterations, starts)[0]


def gewc_centroids(patches: np.ndarray, bins: int = 32, iterations: int = 2,
                   starts: np.ndarray | None = None) -> list[CentroidResult | None]:
    """:func:`gewc_centroid` (eqs. 4-7) of a stack of equal-sized patches (N, h, w) at once,
    each started from ``starts`` (N, 2) (x, y), default its patch centre; the one
    implementation of the equations (|∇f| quantised into ``bins`` levels, as eq. 4 needs equal
    gradient values; a patch whose regions each hold one level weighs its occupied regions
    equally)."""
    n, h, w = patches.shape
    if n == 0:
        return []
    gy, gx = np.gradient(patches.astype(np.float64, copy=False), axis=(1, 2))
    grad = np.hypot(gx, gy)
    gmax = grad.reshape(n, -1).max(axis=1)
    alive = gmax > 0
    pn, ys, xs = np.nonzero((grad > (gmax * 1e-9)[:, None, None]) & alive[:, None, None])
    g = grad[pn, ys, xs]
    level = np.minimum((g / gmax[pn] * bins).astype(np.int64), bins - 1)
    size = N_REGIONS * bins
    if starts is None:
        cx, cy = np.full(n, (w - 1) / 2.0), np.full(n, (h - 1) / 2.0)
    else:
        cx, cy = (np.asarray(starts, dtype=np.float64)[:, i].copy() for i in (0, 1))
    ok = alive.copy()
    weights = np.zeros((n, N_REGIONS))
    for _ in range(max(1, iterations)):
        angle = np.arctan2(ys - cy[pn], xs - cx[pn])
        region = ((angle + np.pi) / (2 * np.pi / N_REGIONS)).astype(np.int64) % N_REGIONS
        cell = pn * size + region * bins + level
        k = np.bincount(cell, minlength=n * size).reshape(n, N_REGIONS, bins).astype(np.float64)
        sx = np.bincount(cell, weights=xs, minlength=n * size).reshape(n, N_REGIONS, bins).astype(np.float64)
        sy = np.bincount(cell, weights=ys, minlength=n * size).reshape(n, N_REGIONS, bins).astype(np.float64)
        n_r = k.sum(axis=2, keepdims=True)
        q = np.divide(k, n_r, out=np.zeros_like(k), where=n_r > 0)              # eq. 4
        mx = np.divide(sx, k, out=np.zeros_like(sx), where=k > 0)               # eq. 5
        my = np.divide(sy, k, out=np.zeros_like(sy), where=k > 0)
        region_x, region_y = (q * mx).sum(axis=2), (q * my).sum(axis=2)
        logq = np.log2(q, out=np.zeros_like(q), where=q > 0)
        entropy = -(q * logq).sum(axis=2)                                       # eq. 6
        present = (n_r[:, :, 0] > 0).astype(np.float64)
        tot = entropy.sum(axis=1, keepdims=True)
        npresent = np.maximum(present.sum(axis=1, keepdims=True), 1.0)
        weights = np.where(tot > 0, entropy / np.where(tot > 0, tot, 1.0), present / npresent)
        cx = (weights * region_x).sum(axis=1)                                   # eq. 7
        cy = (weights * region_y).sum(axis=1)
    return [CentroidResult(float(cx[i]), float(cy[i]), weights[i]) if ok[i] else None
            for i in range(n)]


def measure_many(residual: np.ndarray, labels: np.ndarray, components: np.ndarray,
                 centres: np.ndarray, sizes: np.ndarray, threshold: float | np.ndarray,
                 method: str = "gewc", bins: int = 32, iterations: int = 2
                 ) -> list[CentroidResult | None]:
    """:func:`measure` for many targets: windows of one size that lie inside the image are
    cut and measured together (faithful GEWC and intensity); the rest go one by one."""
    h, w = residual.shape
    n = len(components)
    out: list[CentroidResult | None] = [None] * n
    sizes = np.asarray(sizes, dtype=np.int64)
    half = sizes // 2
    x0 = np.round(centres[:, 0]).astype(np.int64) - half if n else np.zeros(0, np.int64)
    y0 = np.round(centres[:, 1]).astype(np.int64) - half if n else np.zeros(0, np.int64)
    inside = (x0 >= 0) & (y0 >= 0) & (x0 + sizes <= w) & (y0 + sizes <= h)
    batch = method in ("gewc", "intensity")
    for s in np.unique(sizes[inside]) if batch else []:
        sel = np.nonzero(inside & (sizes == s))[0]
        d = np.arange(s)
        rows = y0[sel, None, None] + d[None, :, None]
        cols = x0[sel, None, None] + d[None, None, :]
        win = residual[rows, cols].astype(np.float64)
        thr = threshold[rows, cols] if isinstance(threshold, np.ndarray) else threshold
        own = labels[rows, cols] == np.asarray(components)[sel, None, None]
        patches = np.where(own, np.maximum(win - thr, 0.0), 0.0)
        if method == "gewc":
            res = gewc_centroids(patches, bins, iterations)
        else:
            tot = patches.sum(axis=(1, 2))
            px = (patches * d[None, None, :]).sum(axis=(1, 2)) / np.where(tot > 0, tot, 1.0)
            py = (patches * d[None, :, None]).sum(axis=(1, 2)) / np.where(tot > 0, tot, 1.0)
            res = [CentroidResult(float(px[j]), float(py[j]), np.full(N_REGIONS, 1.0 / N_REGIONS))
                   if tot[j] > 0 else None for j in range(len(sel))]
        for j, i in enumerate(sel):
            r = res[j]
            if r is not None:
                out[i] = CentroidResult(r.x + x0[i], r.y + y0[i], r.weights)
    for i in np.nonzero(~inside)[0] if batch else range(n):
        out[i] = measure(residual, labels, int(components[i]), (float(centres[i, 0]), float(centres[i, 1])),
                         int(sizes[i]), threshold, method, bins, iterations)
    return out


def measure(residual: np.ndarray, labels: np.ndarray, component: int, centre: tuple[float, float],
            size: int, threshold: float | np.ndarray, method: str = "gewc", bins: int = 32,
            iterations: int = 2) -> CentroidResult | None:
    """Measure one target in a ``size`` window of ``residual`` centred on ``centre``.

    Only the pixels of connected component ``component`` count, with the detection threshold
    subtracted (so the background and any other target in the window are 0). Returns image
    coordinates; weights are all 1/8 for the intensity centroid.

    ``method``: a key of :data:`CENTROID_METHODS`: "gewc" (faithful, eqs. 4-7), "intensity",
    "gewc-weighted" (:func:`gewc_weighted_centroid`) or "gaussian" (:func:`gaussian_fit`); the
    last two also read the unthresholded window, without the pixels of other components.
    """
    h, w = residual.shape
    half = size // 2
    x0 = int(np.clip(round(centre[0]) - half, 0, max(w - 1, 0)))
    y0 = int(np.clip(round(centre[1]) - half, 0, max(h - 1, 0)))
    x1, y1 = min(x0 + size, w), min(y0 + size, h)
    win = residual[y0:y1, x0:x1].astype(np.float64)
    thr = threshold[y0:y1, x0:x1] if isinstance(threshold, np.ndarray) else threshold
    patch = np.where(labels[y0:y1, x0:x1] == component, np.maximum(win - thr, 0.0), 0.0)
    if method not in CENTROID_METHODS:
        raise ValueError(f"unknown centroid method {method!r} (available: {', '.join(CENTROID_METHODS)})")

    def others_out() -> np.ndarray:  # the window without the pixels of other components
        lab = labels[y0:y1, x0:x1]
        return (lab == component) | (lab == 0)

    r = CENTROID_METHODS[method](win, patch, others_out, bins, iterations)
    return None if r is None else CentroidResult(r.x + x0, r.y + y0, r.weights)


_EQUAL = np.full(N_REGIONS, 1.0 / N_REGIONS)


def _by_intensity(win: np.ndarray, patch: np.ndarray, others_out: Callable[[], np.ndarray], bins: int,
                  iterations: int) -> CentroidResult | None:
    c = intensity_centroid(patch)
    return None if c is None else CentroidResult(c[0], c[1], _EQUAL.copy())


def _by_gewc(win: np.ndarray, patch: np.ndarray, others_out: Callable[[], np.ndarray], bins: int,
             iterations: int) -> CentroidResult | None:
    return gewc_centroid(patch, bins=bins, iterations=iterations)


def _by_gewc_weighted(win: np.ndarray, patch: np.ndarray, others_out: Callable[[], np.ndarray], bins: int,
                      iterations: int) -> CentroidResult | None:
    return gewc_weighted_centroid(win, patch, others_out(), bins=bins)


def _by_gaussian(win: np.ndarray, patch: np.ndarray, others_out: Callable[[], np.ndarray], bins: int,
                 iterations: int) -> CentroidResult | None:
    start = intensity_centroid(patch)  # fit the unthresholded window; other components left out
    fit = None if start is None else gaussian_fit(win, others_out(), start)
    return None if fit is None else CentroidResult(fit.x, fit.y, _EQUAL.copy())


# method -> f(window, thresholded component patch, mask without other components (a call),
# bins, iterations) -> CentroidResult in window coordinates, or None
CentroidMethod = Callable[[np.ndarray, np.ndarray, Callable[[], np.ndarray], int, int], CentroidResult | None]
CENTROID_METHODS: dict[str, CentroidMethod] = {
    "gewc": _by_gewc, "intensity": _by_intensity, "gewc-weighted": _by_gewc_weighted,
    "gaussian": _by_gaussian}


# --- Gaussian fit and Cramér–Rao bound (pixel-integrated Gaussian spot + constant background) ---

_SQRT2 = float(np.sqrt(2.0))
_SQRT_PI = float(np.sqrt(np.pi))
_SQRT_2PI = float(np.sqrt(2.0 * np.pi))
GAUSSIAN_PARAMS = ("peak", "x", "y", "sigma", "background")


@dataclass(frozen=True)
class GaussianFit:
    """Least-squares pixel-integrated Gaussian: peak (continuous profile), centre, σ, background."""

    peak: float
    x: float
    y: float
    sigma: float
    background: float
    rms_residual: float


def _pixel_profile(n: int, centre: float, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fraction F_i of a unit 1-D Gaussian in pixels 0..n-1 and dF_i/dcentre, dF_i/dsigma."""
    from scipy.special import erf  # (the Gaussian fit only: SciPy is imported on first use)

    u = (np.arange(n + 1, dtype=np.float64) - 0.5 - centre) / (_SQRT2 * sigma)
    e = np.exp(-u * u)
    f = 0.5 * np.diff(erf(u))
    d_centre = -np.diff(e) / (_SQRT_2PI * sigma)
    d_sigma = -np.diff(u * e) / (_SQRT_PI * sigma)
    return f, d_centre, d_sigma


def gaussian_model(shape: tuple[int, int], params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-integrated Gaussian μ = peak·2πσ²·F_y⊗F_x + background and its Jacobian.

    ``params`` = (peak, x, y, σ, background), as :data:`GAUSSIAN_PARAMS`; the same pixel model as
    :func:`wfviz.synth.psf.add_gaussian_spot`. Returns μ (h, w) and ∂μ/∂params (h·w, 5).
    """
    peak, x, y, s, b = (float(v) for v in params)
    h, w = shape
    fx, dfx, dfx_s = _pixel_profile(w, x, s)
    fy, dfy, dfy_s = _pixel_profile(h, y, s)
    k = 2.0 * np.pi * s * s
    g = np.outer(fy, fx)
    mu = peak * k * g + b
    jac = np.empty((h * w, 5))
    jac[:, 0] = (k * g).ravel()
    jac[:, 1] = (peak * k * np.outer(fy, dfx)).ravel()
    jac[:, 2] = (peak * k * np.outer(dfy, fx)).ravel()
    jac[:, 3] = (peak * (2.0 / s) * k * g + peak * k * (np.outer(dfy_s, fx) + np.outer(fy, dfx_s))).ravel()
    jac[:, 4] = 1.0
    return mu, jac


def gaussian_fit(window: np.ndarray, mask: np.ndarray | None = None,
                 start: tuple[float, float] | None = None) -> GaussianFit | None:
    """Least-squares fit of :func:`gaussian_model` (5 parameters) to the pixels of ``mask``.

    Starts at ``start`` (default: the window's brightest pixel), background = median of the
    masked pixels, peak = brightest value above it, σ from the flux (flux = peak·2πσ²). Solved by
    ``scipy.optimize.least_squares`` (trust-region, analytic Jacobian), the centre bounded to the
    window and σ to [0.2, window/2], at most 100 evaluations (a one-pixel spot leaves the
    position inside its pixel nearly unobservable; the last iterate is then returned). None
    for fewer than 6 pixels, flat data or a failed solve.
    """
    data = window.astype(np.float64, copy=False)
    h, w = data.shape
    sel = np.ones(data.shape, bool) if mask is None else mask.astype(bool)
    if sel.sum() < 6:
        return None
    vals = data[sel]
    b0 = float(np.median(vals))
    a0 = float(vals.max() - b0)
    if a0 <= 0:
        return None
    if start is None:
        iy, ix = np.unravel_index(np.argmax(np.where(sel, data, -np.inf)), data.shape)
        start = (float(ix), float(iy))
    flux = float(np.clip(vals - b0, 0, None).sum())
    s_max = max(h, w) / 2.0
    s0 = float(np.clip(np.sqrt(flux / (2 * np.pi * a0)), 0.4, s_max * 0.9))
    lo = np.array([0.0, -0.5, -0.5, 0.2, -np.inf])
    hi = np.array([np.inf, w - 0.5, h - 0.5, s_max, np.inf])
    x0 = np.clip(np.array([a0, start[0], start[1], s0, b0]), lo + 1e-6, hi - 1e-6)
    idx = np.flatnonzero(sel.ravel())

    from scipy.optimize import least_squares  # (imported on first use: not the default centroid)

    def fun(p: np.ndarray) -> np.ndarray:
        return gaussian_model((h, w), p)[0].ravel()[idx] - data.ravel()[idx]

    def jac(p: np.ndarray) -> np.ndarray:
        return gaussian_model((h, w), p)[1][idx]

    try:
        res = least_squares(fun, x0, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac",
                            xtol=1e-8, ftol=1e-8, max_nfev=100)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if res.status < 0 or not np.all(np.isfinite(res.x)):   # budget exhausted: keep last iterate
        return None
    p = res.x
    return GaussianFit(float(p[0]), float(p[1]), float(p[2]), float(p[3]), float(p[4]),
                       float(np.sqrt(np.mean(res.fun ** 2))))


def position_crb(peak: float, sigma: float, noise: float, dx: float = 0.0, dy: float = 0.0,
                 nuisance: tuple[str, ...] = ("peak", "sigma", "background"),
                 half: int | None = None) -> tuple[float, float]:
    """Cramér–Rao bound (std of x, std of y) for the centre of a pixel-integrated Gaussian spot.

    Spot of continuous peak ``peak`` and width ``sigma`` at sub-pixel offset (dx, dy) from a
    pixel centre, white Gaussian noise of std ``noise``: Fisher information I = JᵀJ / noise² of
    :func:`gaussian_model` over a (2·half+1)² grid (default half = ⌈6σ⌉ + 2, i.e. all the
    information), estimated jointly with the ``nuisance`` parameters (any of "peak", "sigma",
    "background"); the bound is √diag(I⁻¹) for x and y. Well-sampled limit (σ ≫ 1 px, unit pixel
    area): √(2/π)·noise/peak ≈ 0.798·noise/peak per axis, for any σ.
    """
    half = int(np.ceil(6 * sigma)) + 2 if half is None else half
    n = 2 * half + 1
    _, jac = gaussian_model((n, n), np.array([peak, half + dx, half + dy, sigma, 0.0]))
    cols = [1, 2] + [GAUSSIAN_PARAMS.index(name) for name in nuisance]
    j = jac[:, cols]
    cov = np.linalg.inv(j.T @ j) * noise ** 2
    return float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))


# --- improved GEWC: moment-weighted, soft octant pairs, adaptive Gaussian window ---

def _octant(xs: np.ndarray, ys: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """Direction region 0..7 of each position around (cx, cy), as in the faithful GEWC."""
    angle = np.arctan2(ys - cy, xs - cx)
    return ((angle + np.pi) / (2 * np.pi / N_REGIONS)).astype(np.int64) % N_REGIONS


def _pair_entropy(patch: np.ndarray, cx: float, cy: float, bins: int) -> np.ndarray:
    """Entropy E_p (bits, eqs. 4 and 6) of the gradient levels of each opposite-octant pair p.

    Pair p = octants p and p + 4 around (cx, cy), pooled; the levels are the faithful GEWC's
    (|∇f| of the background-free patch quantised into ``bins`` levels, non-zero gradient only).
    """
    grad = gradient_magnitude(patch)
    gmax = grad.max()
    if gmax <= 0:
        return np.zeros(N_REGIONS // 2)
    ys, xs = np.nonzero(grad > gmax * 1e-9)
    level = np.minimum((grad[ys, xs] / gmax * bins).astype(np.int64), bins - 1)
    pair = _octant(xs, ys, cx, cy) % (N_REGIONS // 2)
    k = np.bincount(pair * bins + level, minlength=N_REGIONS // 2 * bins)
    k = k.reshape(N_REGIONS // 2, bins).astype(np.float64)
    n = k.sum(axis=1, keepdims=True)
    q = np.divide(k, n, out=np.zeros_like(k), where=n > 0)                  # eq. 4
    logq = np.log2(q, out=np.zeros_like(q), where=q > 0)
    return -(q * logq).sum(axis=1)                                          # eq. 6


def _soft_pair_weight(w4: np.ndarray, xs: np.ndarray, ys: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """Angular weight of each position: pair weights ``w4`` placed at the pair axes
    (π/8 + p·π/4, period π) and interpolated linearly in angle (soft octant borders)."""
    a = np.mod(np.arctan2(ys - cy, xs - cx) + np.pi, np.pi)
    t = (a - np.pi / 8) / (np.pi / 4)
    i0 = np.floor(t).astype(np.int64)
    f = t - i0
    return w4[i0 % 4] * (1.0 - f) + w4[(i0 + 1) % 4] * f


def gewc_weighted_centroid(window: np.ndarray, patch: np.ndarray, mask: np.ndarray | None = None,
                           bins: int = 32, max_iterations: int = 20, min_width: float = 0.8,
                           tol: float = 1e-4) -> CentroidResult | None:
    """Improved GEWC: gradient-entropy-weighted direction regions on intensity moments.

    ``patch`` is the background-free component patch of :func:`gewc_centroid`; ``window`` the
    same pixels' unthresholded values (any constant background) and ``mask`` the pixels that
    may be used (default all; leave out other targets). Steps:

    1. start at the intensity centroid of ``patch``; the 8 octants are centred there;
    2. eqs. 4 and 6 per opposite-octant pair (the two octants' gradient levels pooled):
       entropy E_p, weight ω_p ∝ 1 + E_p (one extra bit, so a one-level pair is not dropped);
       each pixel's weight interpolates ω linearly in angle between the pair axes;
    3. background b = median of the masked pixels outside the patch's gradient support;
    4. eq. 7 with intensity moments instead of plain mean positions: the Gaussian-windowed
       first moment  d = Σ a·g·(f−b)·(p−c) / Σ a·g·(f−b),  g = exp(−|p−c|²/2s²),
       c ← c + (1 + σ̂²/s²)·d, re-centring the octant angles on c; the window width s follows
       the spot (s² = σ̂², the width from the windowed second moment, at least ``min_width``),
       until the step is below ``tol`` px.

    Returns the centre and the 8 octant weights (ω of pair p on octants p and p+4, sum 1);
    None for an empty patch or a non-positive windowed flux.
    """
    p = patch.astype(np.float64, copy=False)
    start = intensity_centroid(p)
    if start is None:
        return None
    cx, cy = start
    use = np.ones(p.shape, bool) if mask is None else mask.astype(bool)
    support = gradient_magnitude(p) > 0
    far = use & ~support & (p <= 0)
    b = float(np.median(window[far])) if far.sum() > 5 else 0.0
    ys, xs = np.nonzero(use)
    x, y = xs.astype(np.float64), ys.astype(np.float64)
    f = window[ys, xs].astype(np.float64) - b
    w4 = 1.0 + _pair_entropy(p, cx, cy, bins)
    w4 = w4 / w4.mean()
    s2 = 1.0
    for _ in range(max_iterations):
        dx_, dy_ = x - cx, y - cy
        r2 = dx_ * dx_ + dy_ * dy_
        g = _soft_pair_weight(w4, x, y, cx, cy) * np.exp(-r2 / (2.0 * s2)) * f
        den = g.sum()
        if den <= 0:
            return None
        m = float(np.clip((g * r2).sum() / den / 2.0, 0.05, 0.95 * s2))   # windowed 2nd moment
        sig2 = m * s2 / (s2 - m)                                           # spot width σ̂²
        gain = 1.0 + min(sig2, 9.0) / s2
        step_x = float(np.clip(gain * (g * dx_).sum() / den, -1.0, 1.0))
        step_y = float(np.clip(gain * (g * dy_).sum() / den, -1.0, 1.0))
        cx, cy = cx + step_x, cy + step_y
        s2 = float(np.clip(sig2, min_width ** 2, 9.0))
        if abs(step_x) < tol and abs(step_y) < tol:
            break
    weights = np.concatenate([w4, w4]) / (2.0 * w4.sum())
    return CentroidResult(float(cx), float(cy), weights)
