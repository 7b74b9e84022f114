"""Sky-ground line with a confidence (GEWC paper: Zhang Shuai et al., Acta Photonica Sinica
47(11), 2018, §1 steps 1-2, eqs. 2-3; the multi-direction maximum gradient of eq. 2 places the
line to a pixel).

The paper's two constraints are the evidence here. (a) A cloud edge has low grey variance on
both sides, the true horizon has a textured ground side: a boundary hypothesis between rows
y - 1 and y of a column is supported when the sky window above it is smooth (as smooth as the
frame's smoothest tenth at that grey level) and the ground below is several times rougher, or
much brighter, and stays so for GROUND_ROWS rows. (b) Scattered clutter does not form a
continuous line: one path y(x) through every imaging column is found by dynamic programming
(smoothness costs, and a fixed cost for a vertical jump at a wall), and the confidence counts
the columns where that path has the evidence. All work is on a working image area-averaged to
about WORK_SIZE px, in units of the frame's own texture, so 8- and 16-bit data are alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from wfviz.config import HorizonConfig
from wfviz.stages.noise import data_quantum

#: Working resolution: the frame is area-averaged by f = ceil(max(h, w) / WORK_SIZE)
#: (suggested config name ``horizon.work_size``).
WORK_SIZE = 320
#: Rows (K) and columns (M) of the sky and ground windows, working pixels
#: (``horizon.window_rows`` / ``horizon.window_cols``).
WINDOW_ROWS = 4
WINDOW_COLS = 3
#: Rows below the line (working pixels) over which the ground must stay rough or bright
#: (``horizon.ground_rows``).
GROUND_ROWS = 12
#: Sky window's texture in units of the texture floor at its grey level: full evidence up to
#: SKY_SMOOTH, none from SKY_ROUGH (``horizon.sky_smooth`` / ``horizon.sky_rough``).
SKY_SMOOTH = 2.0
SKY_ROUGH = 4.0
#: Textured ground: ground/sky texture ratio, log ramp from RATIO_LOW (0) to RATIO_HIGH (1)
#: (``horizon.ratio_low`` / ``horizon.ratio_high``), and the share of pixels rougher than
#: SKY_ROUGH floors over GROUND_ROWS, ramp GROUND_LOW to GROUND_HIGH (``horizon.ground_share``).
RATIO_LOW = 2.0
RATIO_HIGH = 6.0
GROUND_LOW = 0.25
GROUND_HIGH = 0.6
#: Brighter ground: the grey-level step from the sky window to the ground window beyond the
#: sky's own brightening trend, in units of the sky window's texture, log ramp STEP_LOW to
#: STEP_HIGH (``horizon.step_ratio``), and the share of that step the GROUND_ROWS rows below
#: keep on average, ramp STAY_LOW to STAY_HIGH (``horizon.step_stays``).
STEP_LOW = 20.0
STEP_HIGH = 80.0
STAY_LOW = 0.4
STAY_HIGH = 0.7
#: ... and at least TREND_LOW (none) to TREND_HIGH (full) times the sky's own rise over the
#: same distance (``horizon.step_trend``): a steepening sky gradient is not a step.
TREND_LOW = 2.0
TREND_HIGH = 4.0
#: ... and the ground window at least as rough as the sky window: ratio ramp
#: BRIGHT_RATIO_LOW (none) to BRIGHT_RATIO_HIGH (full) (``horizon.bright_texture``).
BRIGHT_RATIO_LOW = 1.0
BRIGHT_RATIO_HIGH = 1.5
#: Share of the evidence that depends on the line sitting on the local grey-level step
#: (``horizon.edge_weight``).
EDGE_WEIGHT = 0.25
#: Path costs per column, in evidence units (evidence is 0..1 per column): a change of one
#: working row, and a jump of any size (a building wall, a tree trunk): a segment between two
#: jumps must gain 2·COST_JUMP, i.e. be at least 4 working columns of full evidence, so masts,
#: stars and noise specks are skipped (``horizon.slope_cost``, ``horizon.jump_cost``).
COST_1 = 0.05
COST_JUMP = 2.0
#: A column supports the line when its path evidence reaches SUPPORT_EVIDENCE
#: (``horizon.support_evidence``).
SUPPORT_EVIDENCE = 0.5
#: Regions above and below the line are distinct (1) when their median textures differ by
#: the factor SEPARATION_RATIO, or when SEPARATION_FULL of the ground lies outside the sky's
#: grey-level and texture range (SEPARATION_NULL: what one region split in two gives)
#: (``horizon.separation_ratio``, ``horizon.separation_share``).
SEPARATION_RATIO = 2.0
SEPARATION_NULL = 0.15
SEPARATION_FULL = 0.6
#: Sky below the line: a line with at most SKY_BELOW_LOW of its column below it (to the imaging
#: area's bottom) sky-like and connected to the sky above the line is a ground line (no doubt; a
#: few such pixels are sky seen through a fence or between trees); from SKY_BELOW_HIGH it is a
#: cloud edge (full doubt: the region below it is sky again further down)
#: (``horizon.sky_below_low`` / ``horizon.sky_below_high``).
SKY_BELOW_LOW = 0.05
SKY_BELOW_HIGH = 0.15
#: Confidence at or above which a horizon is used to split sky from ground
#: (``horizon.confidence_min``).
CONFIDENT = 0.5
#: Tracker: a column agrees with the previous horizon within AGREE_PX px (``horizon.agree_px``).
AGREE_PX = 4.0

_D2 = np.array([1.0, -2.0, 1.0], np.float32)  # second difference
_SKY_END = 1  # the sky window ends this many rows above row y (one mixed row allowed)


@dataclass(frozen=True)
class Horizon:
    """Horizon row for every column (NaN where the column has no horizon); sky is above.

    ``confidence`` = ``support`` · ``separation`` in [0, 1] (see :func:`find_horizon`):
    ``support`` is the share of imaging columns where the line has local evidence and ground
    (not sky) below it, ``separation`` how distinct the regions above and below are;
    ``ground`` is the share of the line's columns with ground below it (not doubted as a cloud
    edge, :func:`sky_below`), a diagnostic already contained in ``support``. A horizon built by
    hand (``Horizon(rows)``) is trusted: all four are 1.
    """

    rows: np.ndarray
    confidence: float = 1.0
    support: float = 1.0
    separation: float = 1.0
    ground: float = 1.0

    def polyline(self, step: int = 4) -> np.ndarray:
        """(N, 2) array of (x, y) points along the horizon, every ``step`` columns."""
        xs = np.nonzero(np.isfinite(self.rows))[0]
        if xs.size == 0:
            return np.zeros((0, 2), dtype=np.float32)
        pick = np.unique(np.concatenate([xs[::step], xs[-1:]]))
        return np.column_stack([pick, self.rows[pick]]).astype(np.float32)


def horizon_confident(h: Horizon | None, threshold: float = CONFIDENT) -> bool:
    """True when ``h`` exists and its confidence reaches ``threshold``."""
    return h is not None and h.confidence >= threshold


def max_gradient(image: np.ndarray, step: int) -> np.ndarray:
    """Eq. 2: Gmax = max(G0, G45, G90, G135) with differences ``step`` pixels apart.

    G0 = |f(i+n,j) - f(i-n,j)|, G45 = |f(i-n,j+n) - f(i+n,j-n)|, G90 = |f(i,j+n) - f(i,j-n)|,
    G135 = |f(i+n,j+n) - f(i-n,j-n)| with i = row, j = column, n = ``step``; borders replicate.
    """
    n = step
    f = cv2.copyMakeBorder(image.astype(np.float32, copy=False), n, n, n, n, cv2.BORDER_REPLICATE)
    h, w = image.shape

    def at(di: int, dj: int) -> np.ndarray:
        return f[n + di: n + di + h, n + dj: n + dj + w]

    g = np.abs(at(n, 0) - at(-n, 0))
    np.maximum(g, np.abs(at(-n, n) - at(n, -n)), out=g)
    np.maximum(g, np.abs(at(0, n) - at(0, -n)), out=g)
    np.maximum(g, np.abs(at(n, n) - at(-n, -n)), out=g)
    return g


def _median_abs(d: np.ndarray) -> float:
    """Median of |d|; integer data by a histogram (exact, and several times faster)."""
    if d.dtype.kind in "iu" and d.size:
        counts = np.bincount(np.abs(d).ravel())
        cdf = np.cumsum(counts)
        n = int(cdf[-1])
        lo, hi = np.searchsorted(cdf, [(n - 1) // 2 + 1, n // 2 + 1])
        return (float(lo) + float(hi)) / 2.0
    return float(np.median(np.abs(d)))


def noise_sigma(image: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Robust temporal-noise estimate: MAD of horizontal neighbour differences / sqrt(2)."""
    f = image.astype(np.int32) if image.dtype.kind in "iu" and image.itemsize <= 2 \
        else image.astype(np.float32, copy=False)
    d = f[:, 1:] - f[:, :-1]
    if valid is not None:
        d = d[valid[:, 1:] & valid[:, :-1]]
    if d.size == 0:
        return 1.0
    return max(1.4826 * _median_abs(d) / np.sqrt(2.0), 1e-6)


def grey_step(image: np.ndarray) -> float:
    """Step between an integer image's grey levels (gcd of the gaps between the values present,
    from every other row and column); 0 for float data or more than 16 bits."""
    if image.dtype.kind not in "iu" or image.itemsize > 2:
        return 0.0
    return data_quantum(image[::2, ::2])


def _downsample(image: np.ndarray, valid: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """Area mean of ``factor`` × ``factor`` blocks (float32); a block is valid when all its
    pixels are."""
    if factor == 1:
        return image.astype(np.float32, copy=False), valid.astype(bool, copy=False)
    h, w = (image.shape[0] // factor) * factor, (image.shape[1] // factor) * factor
    size = (w // factor, h // factor)
    src = image[:h, :w]
    if src.dtype not in (np.uint8, np.uint16, np.float32):
        src = src.astype(np.float32)
    small = cv2.resize(src, size, interpolation=cv2.INTER_AREA)
    ok = cv2.resize(valid[:h, :w].astype(np.uint8) * 255, size, interpolation=cv2.INTER_AREA) == 255
    return small.astype(np.float32, copy=False), ok


def _erode(mask: np.ndarray, kw: int, kh: int) -> np.ndarray:
    return cv2.erode(mask.astype(np.uint8), np.ones((kh, kw), np.uint8),
                     borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def _rows_box(a: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Mean of ``a`` over rows [y, y + rows) and columns x ± cols // 2 (zero outside), float32."""
    return cv2.boxFilter(a, cv2.CV_32F, (cols, rows), anchor=(cols // 2, 0), normalize=True,
                         borderType=cv2.BORDER_CONSTANT)


def _shift(a: np.ndarray, dy: int, fill: float = 0.0) -> np.ndarray:
    """out[y] = a[y + dy]; ``fill`` where that row does not exist."""
    out = np.full_like(a, fill)
    h = a.shape[0]
    if dy >= 0:
        out[: h - dy] = a[dy:]
    else:
        out[-dy:] = a[: h + dy]
    return out


def _ramp(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """0 at ``lo``, 1 at ``hi``, linear between (float32; NaN stays NaN)."""
    r = x * np.float32(1.0 / (hi - lo))
    r -= np.float32(lo / (hi - lo))
    return np.clip(r, 0.0, 1.0, out=r)


def _log_ramp(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """ramp(log x; log lo, log hi), float32 (x <= 0 -> 0)."""
    r = cv2.log(np.maximum(x, np.float32(1e-20)))
    return _ramp(r, float(np.log(lo)), float(np.log(hi)))


def texture_floor(tex: np.ndarray, level: np.ndarray, base: float, bins: int = 8
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Texture floor as a function of grey level: (level centres, floors), non-decreasing.

    The windows are split into ``bins`` equally populated grey-level classes; a class's floor
    is the 10th percentile of its windows' texture (its smoothest tenth), at least ``base``;
    the floors are made non-decreasing with level (shot noise and gain non-uniformity grow
    with the signal), so a bright sky near the horizon is judged against its own noise.
    """
    if tex.size < bins * 8:
        v = float(np.partition(tex, tex.size // 10)[tex.size // 10]) if tex.size else base
        return np.array([0.0], np.float32), np.array([max(v, base)], np.float32)
    order = np.argsort(level, kind="stable")
    t, lv = tex[order], level[order]
    parts = np.array_split(np.arange(t.size), bins)
    centres = np.array([lv[p[p.size // 2]] for p in parts], np.float32)
    floors = np.array([max(float(np.partition(t[p], p.size // 10)[p.size // 10]), base)
                       for p in parts], np.float32)
    return centres, np.maximum.accumulate(floors)


@dataclass(frozen=True)
class BoundaryEvidence:
    """Per working pixel (y, x): ``evidence`` in [0, 1] that the sky-ground boundary lies
    between working rows y - 1 (sky) and y (ground), NaN where the windows leave the imaging
    area; ``texture`` the K × M window texture starting at row y and ``level`` the median-
    filtered frame (both for the region statistics); ``floor`` the lowest texture floor."""

    evidence: np.ndarray
    texture: np.ndarray
    level: np.ndarray
    floor: float


def boundary_evidence(small: np.ndarray, valid: np.ndarray, quantum: float = 0.0) -> BoundaryEvidence:
    """Evidence of a sky-ground boundary at each working pixel (constraint (a) of eq. 3).

    g = 3×3 median of the working frame (stars, hot pixels and targets are not texture).
    Texture T = min(mean |g(x-1) - 2g + g(x+1)|, mean |g(y-1) - 2g + g(y+1)|) over a K × M
    window (K = WINDOW_ROWS, M = WINDOW_COLS): texture in both directions, so column stripes
    (fixed-pattern noise), vertical sky gradients and a straight horizontal edge are not
    texture, while ground is. τ(level) is the texture floor of :func:`texture_floor` (at least
    half a grey step ``quantum``). For a boundary between rows y - 1 and y, with the sky window
    S = rows [y-K-1, y-2] (one mixed row allowed) and the ground window G = rows [y, y+K):

    - sky = 1 - ramp(T_S / τ(level_S); SKY_SMOOTH, SKY_ROUGH);
    - textured = ramp(log(T_G / max(T_S, τ)); log RATIO_LOW, log RATIO_HIGH) ·
      ramp(share of the pixels of rows [y, y+L) rougher than SKY_ROUGH · τ_min; GROUND_LOW,
      GROUND_HIGH), L = GROUND_ROWS, τ_min the lowest floor;
    - bright = ramp(log(step / max(T_S, τ)); log STEP_LOW, log STEP_HIGH) ·
      ramp(kept; STAY_LOW, STAY_HIGH) · ramp(step / max(trend, T_S, τ); TREND_LOW, TREND_HIGH)
      · ramp(T_G / max(T_S, τ); BRIGHT_RATIO_LOW, BRIGHT_RATIO_HIGH), where rise = mean(G) -
      mean(S), trend = the sky's own rise over that distance (from the window above S,
      positive part), step = rise - trend, kept = (mean(rows [y, y+L)) - mean(S)) / rise;
    - edge = E / max(E over ± (K + 1) rows), E = |mean(rows y, y+1) - mean(rows y-2, y-1)|;
    - evidence = sky · max(textured, bright) · (1 - EDGE_WEIGHT + EDGE_WEIGHT · edge).

    A cloud edge is smooth on both sides and its cloud does not stay rough or bright below;
    terrain under terrain fails the sky term; a smooth, steepening sky gradient has no step
    beyond its trend; a bright sky band under darker clouds is smoother than they are.
    """
    k, m, L = WINDOW_ROWS, WINDOW_COLS, GROUND_ROWS
    f = small.astype(np.float32, copy=False)
    h, w = f.shape
    g = cv2.medianBlur(f, 3)
    ok = _erode(valid, 3, 3)
    okf = ok.astype(np.float32)
    th = np.abs(cv2.filter2D(g, -1, _D2.reshape(1, 3), borderType=cv2.BORDER_REPLICATE))
    tv = np.abs(cv2.filter2D(g, -1, _D2.reshape(3, 1), borderType=cv2.BORDER_REPLICATE))
    th *= okf
    tv *= okf
    full = _rows_box(okf, k, m) > 0.999
    tex = np.minimum(_rows_box(th, k, m), _rows_box(tv, k, m))
    gok = g * okf
    lvl = _rows_box(gok, k, m)
    sub = (slice(None, None, 4), slice(None, None, 4))
    sel = full[sub]
    okv = g[sub][ok[sub]]
    base = max(0.5 * quantum, 1e-4 * float(abs(np.median(okv))) if okv.size else 0.0, 1e-6)
    centres, floors = texture_floor(tex[sub][sel], lvl[sub][sel], base)
    floor_min = float(floors[0])
    ks = k + _SKY_END
    ls, t_sky = _shift(lvl, -ks), _shift(tex, -ks)
    t_gnd = tex
    if centres.size > 1 and centres[-1] > centres[0]:
        lut = np.interp(np.linspace(centres[0], centres[-1], 256), centres, floors).astype(np.float32)
        idx = (ls - centres[0]) * np.float32(255.0 / (centres[-1] - centres[0]))
        sky_floor = lut[np.clip(idx, 0, 255).astype(np.intp)]
    else:
        sky_floor = np.full_like(ls, floors[0])
    ok_all = _shift(full, -ks, False) & full & valid
    # rows [y, y+L): share of rough pixels and mean level, over the valid pixels there
    tpix = np.minimum(cv2.blur(th, (m, 1)), cv2.blur(tv, (m, 1)))
    rough = ((tpix > SKY_ROUGH * floor_min) & ok).astype(np.float32)
    n_long = _rows_box(okf, L, m)
    ok_all &= n_long * np.float32(L * m) >= k * m - 0.5
    inv_n = 1.0 / np.maximum(n_long, np.float32(1e-6))
    share = _rows_box(rough, L, m) * inv_n
    lvl_long = _rows_box(gok, L, m) * inv_n
    sky_t = np.maximum(t_sky, sky_floor)
    inv_sky = 1.0 / sky_t
    ratio = t_gnd * inv_sky
    sky = 1.0 - _ramp(t_sky / sky_floor, SKY_SMOOTH, SKY_ROUGH)
    textured = _log_ramp(ratio, RATIO_LOW, RATIO_HIGH)
    textured *= _ramp(share, GROUND_LOW, GROUND_HIGH)
    trend = np.maximum(ls - _shift(lvl, -ks - k, np.inf), 0.0)   # no window above: no trend
    trend *= np.float32(ks / k)
    rise = lvl - ls
    step = rise - trend
    kept = (lvl_long - ls) / np.maximum(rise, np.float32(1e-12))
    bright = _log_ramp(step * inv_sky, STEP_LOW, STEP_HIGH)
    bright *= _ramp(kept, STAY_LOW, STAY_HIGH)
    bright *= _ramp(step / np.maximum(trend, sky_t), TREND_LOW, TREND_HIGH)
    bright *= _ramp(ratio, BRIGHT_RATIO_LOW, BRIGHT_RATIO_HIGH)
    rowm = cv2.blur(f, (m, 1))
    two = rowm + _shift(rowm, 1)
    grad = np.abs(two - _shift(two, -2))
    grad[:2] = 0.0
    grad[-1:] = 0.0
    peak = cv2.dilate(grad, np.ones((2 * k + 3, 1), np.uint8))
    edge = grad / np.maximum(peak, np.float32(1e-12))
    ev = np.maximum(textured, bright)
    ev *= sky
    ev *= np.float32(1.0 - EDGE_WEIGHT) + np.float32(EDGE_WEIGHT) * edge
    ev[~ok_all] = np.nan
    return BoundaryEvidence(ev, tex, g, floor_min)


def best_path(evidence: np.ndarray) -> np.ndarray:
    """Row per column maximising Σ evidence - Σ transition costs (dynamic programming).

    Moving 0 or 1 row between neighbouring columns costs 0 or COST_1; any larger move (a
    wall, or a line steeper than 45°) costs COST_JUMP. NaN evidence (outside the imaging
    area) is forbidden; a column without any allowed row is skipped (its neighbours are
    joined) and gets -1. One vectorised step per column (a loop over columns only).
    """
    h, w = evidence.shape
    allowed = np.isfinite(evidence)
    cols = np.nonzero(allowed.any(axis=0))[0]
    path = np.full(w, -1, dtype=np.int64)
    if cols.size == 0:
        return path
    et = np.ascontiguousarray(np.where(allowed, evidence, np.float32(-1e6)).T[cols], dtype=np.float32)
    n = cols.size
    scores = np.full((n, h + 2), -np.inf, dtype=np.float32)   # a -inf guard row either side
    m1 = np.empty(h, np.float32)
    scores[0, 1: h + 1] = et[0]
    c1, cj = np.float32(COST_1), np.float32(COST_JUMP)
    vmax, top = np.maximum, np.maximum.reduce
    for i in range(1, n):
        p = scores[i - 1]
        vmax(p[0:h], p[2: h + 2], out=m1)
        m1 -= c1
        vmax(m1, p[1: h + 1], out=m1)
        vmax(m1, top(p) - cj, out=m1)
        np.add(m1, et[i], out=scores[i, 1: h + 1])
    # backtrack: the predecessor is y, y ± 1 or (a jump) the previous column's best row
    y = int(scores[-1].argmax()) - 1
    out = np.empty(n, dtype=np.int64)
    out[-1] = y
    for i in range(n - 1, 0, -1):
        p = scores[i - 1]
        cand, val = y, p[y + 1]
        for d in (-1, 1):
            v = p[y + 1 + d] - c1
            if v > val:
                cand, val = y + d, v
        j = int(p.argmax())
        if p[j] - cj > val:
            cand = j - 1
        y = cand
        out[i - 1] = y
    path[cols] = out
    return path


def _refine(image: np.ndarray, valid: np.ndarray, coarse: np.ndarray, factor: int,
            cfg: HorizonConfig) -> np.ndarray:
    """Sub-pixel row per column near ``coarse`` (full-resolution boundary rows, NaN = none).

    Gmax (eq. 2, step n = ``cfg.step``, on a ``cfg.smooth`` box-filtered frame) is evaluated
    on a band of rows centred on the coarse boundary (± ``factor`` + n + ``cfg.smooth`` // 2);
    the line is the response-weighted mean row of the topmost run of rows whose Gmax reaches
    half the band's maximum (a step between rows b - 1 and b gives a run centred on b - 0.5).
    Columns without any response keep the coarse row.
    """
    h, w = image.shape
    cols = np.nonzero(np.isfinite(coarse))[0]
    out = np.full(w, np.nan)
    if cols.size == 0:
        return out
    n = cfg.step
    sm = max(1, cfg.smooth)
    half = factor + n + sm // 2
    off = np.arange(-half, half + 1)
    base = np.floor(coarse[cols]).astype(np.int64) + 1          # row b for a boundary at b - 0.5
    lo = max(0, int(base.min()) - half - n - sm)
    hi = min(h, int(base.max()) + half + n + sm + 1)
    crop = image[lo:hi]
    if crop.dtype not in (np.uint8, np.uint16, np.float32):
        crop = crop.astype(np.float32)
    f = cv2.blur(crop, (sm, sm)) if sm > 1 else crop
    f = f.astype(np.float32, copy=False)
    hh = f.shape[0]
    rr = np.clip(base[None, :] + off[:, None] - lo, n, hh - 1 - n)  # rows n away from the crop's edges
    cc = np.broadcast_to(cols[None, :], rr.shape)
    g = max_gradient(f, n)[rr, cc]
    g *= valid[rr + lo, cc]
    strong = g >= 0.5 * g.max(axis=0)[None, :]
    idx = np.arange(off.size)[:, None]
    first = np.argmax(strong, axis=0)[None, :]
    after = (idx > first) & ~strong
    stop = np.where(after.any(axis=0), np.argmax(after, axis=0), off.size)[None, :]
    wgt = np.where((idx >= first) & (idx < stop), g, 0.0)
    tot = wgt.sum(axis=0)
    res = coarse[cols].copy()
    good = tot > 0
    res[good] = ((wgt * (rr + lo)).sum(axis=0) / np.maximum(tot, 1e-12))[good]
    out[cols] = res
    return out


def _separation(ev: BoundaryEvidence, path: np.ndarray) -> float:
    """How distinct the regions above (sky) and below (ground) the path are, in [0, 1].

    The larger of two measures, on every other working pixel:
    - texture: ramp(log(median ground texture / median sky texture); 0, log SEPARATION_RATIO);
    - range: ramp(U; SEPARATION_NULL, SEPARATION_FULL), U = share of the ground pixels unlike
      any sky: grey level outside the sky's 5th-95th percentiles or texture above the sky's
      95th percentile (two regions drawn from one distribution give U ≈ 0.15).
    """
    k = WINDOW_ROWS
    tex, lvl = ev.texture[::2, ::2], ev.level[::2, ::2]
    ok = np.isfinite(ev.evidence[::2, ::2])
    p = path[::2][None, : tex.shape[1]]
    yy = np.arange(0, ev.texture.shape[0], 2)[:, None]
    has = p >= 0
    above = ok & has & (yy < p - k - _SKY_END)
    below = ok & has & (yy >= p)
    if above.sum() < 16 or below.sum() < 16:
        return 0.0
    ta, la = tex[above], lvl[above]
    tb, lb = tex[below], lvl[below]
    ratio = float(np.median(tb) / max(float(np.median(ta)), ev.floor))
    by_texture = np.clip(np.log(max(ratio, 1e-6)) / np.log(SEPARATION_RATIO), 0.0, 1.0)
    lo, hi = np.percentile(la, [5, 95])
    rough = max(float(np.percentile(ta, 95)), ev.floor)
    unlike = float(np.mean((lb < lo) | (lb > hi) | (tb > rough)))
    by_range = np.clip((unlike - SEPARATION_NULL) / (SEPARATION_FULL - SEPARATION_NULL), 0.0, 1.0)
    return float(max(by_texture, by_range))


def sky_below(ev: BoundaryEvidence, valid: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Per working pixel (y, x): the share of the imaging pixels of rows [y, bottom) of column
    x that are sky, i.e. sky-like and connected to the sky above ``path``.

    Sky-like: grey level within the 5th-95th percentiles of the pixels above the path (rows
    above its sky window) and texture at most their 95th percentile (the regions of
    :func:`_separation`). Sky: a 4-connected sky-like region that reaches above the path. The
    region below a cloud edge is sky again further down and joins the sky beside the cloud
    (where the path is on the ground), so a line on a cloud edge (or on the sun) has a large
    share of sky below it; ground is warmer or rougher than the sky, and the sky-like patches
    in it (a field, a road) do not connect to the sky. All zeros when the path has too little
    sky above it.
    """
    k = WINDOW_ROWS
    h = ev.level.shape[0]
    yy = np.arange(h)[:, None]
    p = path[None, :]
    above = valid & (p >= 0) & (yy < p - k - _SKY_END)
    if above.sum() < 16:
        return np.zeros(ev.level.shape, np.float32)
    sub = (slice(None, None, 2), slice(None, None, 2))      # statistics on every other pixel
    la, ta = ev.level[sub][above[sub]], ev.texture[sub][above[sub]]
    if la.size < 4:  # the sky above lies on the rows or columns the subsampling skips
        la, ta = ev.level[above], ev.texture[above]
    lo, hi = np.percentile(la, [5, 95])
    rough = max(float(np.percentile(ta, 95)), ev.floor)
    like = valid & (ev.level >= lo) & (ev.level <= hi) & (ev.texture <= rough)
    n, labels = cv2.connectedComponents(like.astype(np.uint8), connectivity=4)
    seeded = np.zeros(n, bool)
    seeded[labels[above & like]] = True
    seeded[0] = False
    n_sky = _count_below(seeded[labels])
    return n_sky / np.maximum(_count_below(valid), np.float32(1.0))


def _count_below(mask: np.ndarray) -> np.ndarray:
    """Per pixel (y, x): the number of true pixels of ``mask`` in rows [y, bottom) of column x
    (float32; a column difference of the flipped mask's integral image)."""
    integral = cv2.integral(np.ascontiguousarray(mask[::-1]).astype(np.uint8))
    return np.diff(integral[1:], axis=1)[::-1].astype(np.float32)


def find_horizon(image: np.ndarray, valid: np.ndarray, cfg: HorizonConfig) -> Horizon | None:
    """Detect the sky-ground line in ``image`` inside ``valid`` (the imaging area).

    1. Working image: area mean of f × f blocks, f = ceil(max(h, w) / WORK_SIZE).
    2. Evidence per working pixel (:func:`boundary_evidence`, constraint (a) of eq. 3).
    3. One path y(x) across the imaging columns maximising the evidence less the transition
       costs (:func:`best_path`; constraint (b): clutter does not form a continuous line).
    4. Cloud doubt: the sky below each pixel (:func:`sky_below`, from the sky above that
       path), doubt = ramp(sky below; SKY_BELOW_LOW, SKY_BELOW_HIGH); the evidence is scaled
       by 1 - doubt (a cloud edge, the sun: sky again further down) and, when the path had
       any doubt, the path is found again, so it takes the ground line under a cloud band.
    5. Rows at full resolution: the Gmax (eq. 2) centroid near the path (:func:`_refine`).

    Confidence = support · separation, three factors in all:
    - support = share of the path's columns (working columns with at least one allowed row)
      whose evidence · (1 - doubt) reaches SUPPORT_EVIDENCE: the line has local evidence
      there (constraint (a)) and ground below it (``ground`` = share of the path's columns
      with doubt below 0.5, recorded on its own; a line on a cloud edge loses those columns);
    - separation (:func:`_separation`) = how distinct the regions above and below the path are
    (terrain-only views have locally sky-like smooth patches, but no line splits them into
    two different regions). Rows are given for every column of the imaging area, confident
    or not (columns too near the area's side for the windows take the nearest path row).
    None when the imaging area has no place for the windows.
    """
    h, w = image.shape
    factor = max(1, int(np.ceil(max(h, w) / WORK_SIZE)))
    small, ok = _downsample(image, valid, factor)
    if min(small.shape) < 2 * WINDOW_ROWS + GROUND_ROWS or not ok.any():
        return None
    ev = boundary_evidence(small, ok, grey_step(image) / factor**2)
    path = best_path(ev.evidence)
    cols = np.nonzero(path >= 0)[0]
    if cols.size == 0:
        return None
    doubt = _ramp(sky_below(ev, ok, path), SKY_BELOW_LOW, SKY_BELOW_HIGH)
    evidence = ev.evidence * (np.float32(1.0) - doubt)
    if np.any(doubt[path[cols], cols] > 0):
        path = best_path(evidence)
    e_path = evidence[path[cols], cols]
    support = float(np.mean(e_path >= SUPPORT_EVIDENCE))
    ground = float(np.mean(doubt[path[cols], cols] < 0.5))
    separation = _separation(ev, path) if support > 0 else 0.0
    # full resolution: working column c covers columns [c·f, c·f + f); the boundary between
    # working rows y - 1 and y lies at full-resolution row f·y - 0.5
    # (working columns without a path, at the imaging area's sides, take the nearest one's row)
    idx = np.arange(path.size)
    right = np.clip(np.searchsorted(cols, idx), 0, cols.size - 1)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(cols[left] - idx) <= np.abs(cols[right] - idx), cols[left], cols[right])
    filled = path[nearest]
    pw = filled[np.minimum(np.arange(w) // factor, path.size - 1)]
    coarse = np.where(valid.any(axis=0), factor * pw - 0.5, np.nan)
    rows = _refine(image, valid, coarse, factor, cfg)
    return Horizon(rows, confidence=support * separation, support=support, separation=separation,
                   ground=ground)


def search_region(valid: np.ndarray, horizon: Horizon | None, margin: float) -> np.ndarray:
    """Deep-sky search region: inside ``valid`` and more than ``margin`` px above the horizon.

    The limit is the lowest horizon row within ``margin`` columns either side, so narrow
    dips of the skyline (a missed column on a rooftop) do not open the ground to detection.
    A horizon that is not confident (:func:`horizon_confident`) is ignored.
    """
    if not horizon_confident(horizon):
        return valid
    yy = np.arange(valid.shape[0])[:, None]
    return valid & (yy < search_limit(horizon, margin)[None, :])


def search_limit(horizon: Horizon, margin: float) -> np.ndarray:
    """Per column, the row the deep-sky search region stops at (:func:`search_region`: rows
    above it are searched; inf where the column has no horizon): the lowest horizon row within
    ``margin`` columns either side, minus ``margin``."""
    rows = np.where(np.isfinite(horizon.rows), horizon.rows, np.inf)
    k = int(np.ceil(margin))
    if k > 0:
        padded = np.pad(rows, k, mode="edge")
        rows = np.min(np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1), axis=1)
    return rows - margin


def search_zones(valid: np.ndarray, horizon: Horizon | None, margin: float, exclude_ground: str,
                 fisheye: bool) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Where to detect, and the zones that get their own threshold (None: one threshold).

    ``exclude_ground``: "always" searches only the deep sky above the horizon (the paper);
    "never" also the ground; "auto" excludes the ground only in a fisheye sky view
    (``fisheye``: an imaging circle was found), since a narrow view may show targets over the
    ground. When the ground is searched it is its own zone, so its clutter does not raise the
    sky's threshold. A horizon that is not confident counts as none.
    """
    if not horizon_confident(horizon):
        horizon = None
    sky = search_region(valid, horizon, margin)
    exclude = exclude_ground == "always" or (exclude_ground == "auto" and fisheye)
    if exclude or horizon is None:
        return sky, None
    return valid, [sky, valid & ~sky]


def blend(old: Horizon | None, new: Horizon | None, smoothing: float,
          agree_px: float = AGREE_PX, threshold: float = CONFIDENT) -> Horizon | None:
    """Combine the previous horizon with a new estimate.

    Agreement a = share of the columns where both have a row that differ by at most
    ``agree_px``; s = ``smoothing``.

    - A new estimate that is confident, or follows one that was not: rows from the new
      estimate, blended with the previous ones (weight s) in the agreeing columns; confidence
      new + a·s·(old - new), i.e. smoothed in time as far as the lines agree, the new
      estimate's own where they do not (a panning camera, a changed scene).
    - A failed estimate (not confident) after a confident one: the previous rows are kept,
      confidence s·old + (1 - s)·new, so one failure keeps the horizon and repeated failures
      let it fade below ``threshold``.
    - No new estimate (None): the previous horizon unchanged.
    """
    if new is None:
        return old
    if old is None:
        return new
    if new.confidence < threshold <= old.confidence:
        conf = smoothing * old.confidence + (1.0 - smoothing) * new.confidence
        return Horizon(old.rows, conf, new.support, new.separation, new.ground)
    both = np.isfinite(old.rows) & np.isfinite(new.rows)
    close = both & (np.abs(np.where(both, old.rows - new.rows, 0.0)) <= agree_px)
    agree = float(close.sum() / both.sum()) if both.any() else 0.0
    conf = new.confidence + agree * smoothing * (old.confidence - new.confidence)
    rows = new.rows.copy()
    rows[close] = smoothing * old.rows[close] + (1.0 - smoothing) * new.rows[close]
    return Horizon(rows, conf, new.support, new.separation, new.ground)


class HorizonTracker:
    """Re-estimates the horizon every ``cfg.every`` frames and smooths it over time
    (:func:`blend` with weight ``cfg.smoothing`` on the previous horizon): the confidence is
    the new estimate's, smoothed with the previous value as far as the two lines agree; a
    failed estimate (None, or not confident after a confident one) keeps the previous rows,
    and repeated failures let its confidence fade."""

    def __init__(self, cfg: HorizonConfig) -> None:
        self.cfg = cfg
        self.horizon: Horizon | None = None
        self._count = 0

    def update(self, image: np.ndarray, valid: np.ndarray) -> tuple[Horizon | None, bool]:
        """Return (current horizon, whether it was re-estimated on this call)."""
        due = self._count % self.cfg.every == 0
        self._count += 1
        if not self.cfg.enabled or not due:
            return self.horizon, False
        new = find_horizon(image, valid, self.cfg)
        self.horizon = blend(self.horizon, new, self.cfg.smoothing)
        return self.horizon, True
