"""Feature-fusion Kalman tracker (METHODS.md §2, Zheng Jia et al.): global multi-target
detection, per-target features (centre of the bounding rectangle, area, grey sum) fused into one
matching cost, constant-velocity Kalman search windows, and global re-detection whenever a
confirmed track's window holds no candidate.

Per frame (:meth:`FusionTracker.step`):

1. ``defects``: flagged hot/dead pixels replaced (``defects.BadPixels``).
2. ``mask`` / ``horizon``: imaging circle (first frame) and sky-ground line (global frames only).
3. Kalman prediction of every track (``TrackManager.predict``): the gate is the search window.
4. ``windows``: background suppression and thresholding *inside the windows only* (the
   threshold is the one of the last global detection), connected components, features.
5. ``suppress`` + ``detect``: global detection on the whole frame on the first frame, while no
   track is confirmed, every ``fusion.detect_every`` frames, and whenever a confirmed track's
   window holds no candidate (the window search is then replaced by the global candidates).
6. ``associate``: optimal assignment minimising the fused cost (confirmed tracks first, no
   candidate used twice); a confirmed track whose window is empty may *recover* the best
   candidate of the global detection within ``fusion.recover_radius``.
7. ``kalman``: updates, hits and misses, births from unused global detections.

Features and the fused cost (docs/pipeline.md, "The feature-fusion tracker"): the centre c is
the centre of the component's bounding rectangle (axis-aligned by default), the area a its
pixel count, the grey sum g the sum of its background-suppressed residual. With the track's
predicted centre, window half sizes (w, h) and last matched area and grey sum,

    cost = α·‖(Δx / w, Δy / h)‖ + β·|a_t − a| / max(a_t, a) + γ·|g_t − g| / max(g_t, g)

(``fusion.cost = "sum"``), or ``|Φ_t − Φ(j)|`` of the scalar fused feature
Φ = α·ĉ + β·a / a₀ + γ·g / g₀ (``"scalar"``; ĉ the position normalised by the frame, a₀ and g₀
the means of the track's matched areas and grey sums). Φ is logged per track in both modes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.ndimage import find_objects

from wfviz.background import suppress_background
from wfviz.config import FusionConfig
from wfviz.defects import BadPixels
from wfviz.detection import Detections, detect, score_detections
from wfviz.frames import Frame
from wfviz.horizon import Horizon, HorizonTracker, search_zones
from wfviz.imaging_circle import ImagingCircle, ImagingMask
from wfviz.trackers.base import FrameResult, StageTimer
from wfviz.tracking import Prediction, TrackEvent, TrackManager, assign_confirmed_first

_BIG = 1e9
DENSE_CROPS = 64  # more search crops than this: one full-frame crop is faster


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


@dataclass(frozen=True)
class Match:
    """A track continued by a candidate: fused cost, scalar Φ, recovered by global detection."""

    track_id: int
    detection: int
    x: float
    y: float
    cost: float
    phi: float
    recovered: bool


@dataclass(frozen=True)
class FusionResult(FrameResult):
    """Every stage's output for one frame (the common fields come from FrameResult).

    ``detections`` are the frame's candidates: all components of the global detection on
    global frames, the components found inside the search windows otherwise (their ``xy`` is
    ``features.centre``). ``suppressed`` is the full residual on global frames and the residual
    inside the searched windows (0 elsewhere) on the other frames.
    """

    features: Features
    matches: tuple[Match, ...]
    assigned: np.ndarray  # (N,) track id of each candidate, -1 when unused
    global_detection: bool
    global_reason: str  # "" when only the windows were searched
    searched: tuple[tuple[int, int, int, int], ...]  # (x0, y0, x1, y1) crops searched
    lost: tuple[Prediction, ...]  # confirmed tracks whose window held no candidate
    recover_radius: float
    suppressed: np.ndarray
    circle: ImagingCircle | None
    mask: np.ndarray
    mask_changed: bool
    horizon: Horizon | None
    horizon_updated: bool
    innovations: dict[int, np.ndarray]
    bad_pixels: np.ndarray
    bad_pixels_changed: bool


@dataclass
class _Ref:
    """A track's reference features: last matched area and grey sum (the fused cost), their
    means over the track's matches (the scales a₀, g₀ of the scalar Φ), and whether its last
    frame was a match inside its own window (only then may it recover)."""

    area: float
    grey: float
    area0: float
    grey0: float
    n: int = 1
    phi: float = float("nan")
    in_window: bool = True

    def add(self, area: float, grey: float, phi: float, in_window: bool) -> None:
        self.n += 1
        self.area0 += (area - self.area0) / self.n
        self.grey0 += (grey - self.grey0) / self.n
        self.area, self.grey, self.phi, self.in_window = area, grey, phi, in_window


@dataclass
class _Segments:
    """Components found in one crop, in frame coordinates."""

    centre: list = field(default_factory=list)
    area: list = field(default_factory=list)
    peak: list = field(default_factory=list)
    flux: list = field(default_factory=list)
    raw: list = field(default_factory=list)
    bbox: list = field(default_factory=list)
    rects: list = field(default_factory=list)


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


def component_features(labels: np.ndarray, n: int, residual: np.ndarray, raw: np.ndarray | None,
                       threshold: float, centre: str) -> dict[str, np.ndarray]:
    """Features of components 1..n-1 of ``labels`` (index k = label k + 1): ``bbox`` (x, y, w,
    h), ``area``, ``centroid`` of (residual - threshold), ``peak``, ``flux`` (residual sum),
    ``raw`` (raw grey sum, when ``raw`` is given), ``centre`` and ``rects`` (corners (4, 2)).

    ``centre``: "bbox" the centre of the axis-aligned bounding rectangle, "centroid" the
    intensity centroid (rects stay axis-aligned); for "min_area_rect" this function returns the
    axis-aligned values and the caller refines the components it keeps with :func:`min_area_rects`.
    """
    idx = np.flatnonzero(labels)
    lab = labels.ravel()[idx]
    w = labels.shape[1]
    xs, ys = (idx % w).astype(np.float64), (idx // w).astype(np.float64)
    res = residual.ravel()[idx].astype(np.float64)
    area = np.bincount(lab, minlength=n)[1:]
    ok = area > 0
    box = np.zeros((n - 1, 4), dtype=np.int64)  # y0, y1, x0, x1 (half-open)
    for k, sl in enumerate(find_objects(labels, max_label=n - 1)):
        if sl is not None:
            box[k] = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
    x0, y0 = box[:, 2], box[:, 0]
    bw, bh = np.where(ok, box[:, 3] - x0, 0), np.where(ok, box[:, 1] - y0, 0)
    ex = np.maximum(res - threshold, 0.0)
    s = np.bincount(lab, weights=ex, minlength=n)[1:]
    safe = np.where(s > 0, s, 1.0)
    cen = np.column_stack([np.bincount(lab, weights=ex * xs, minlength=n)[1:] / safe,
                           np.bincount(lab, weights=ex * ys, minlength=n)[1:] / safe])
    peak = np.zeros(n)
    np.maximum.at(peak, lab, res)
    bbox = np.column_stack([x0, y0, bw, bh]).astype(np.int64)
    out = dict(area=area, bbox=bbox, centroid=cen, peak=peak[1:], rects=box_corners(bbox),
               flux=np.bincount(lab, weights=res, minlength=n)[1:],
               centre=cen if centre == "centroid"
               else np.column_stack([x0 + (bw - 1) / 2.0, y0 + (bh - 1) / 2.0]).astype(np.float64))
    if raw is not None:
        out["raw"] = np.bincount(lab, weights=raw.ravel()[idx].astype(np.float64), minlength=n)[1:]
    return out


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


class FusionTracker:
    """Streams frames through the feature-fusion pipeline; ``step`` returns a :class:`FusionResult`."""

    name = "fusion"

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        c = self.config
        self.manager = TrackManager(c.kalman, c.tracking)
        self.horizon = HorizonTracker(c.horizon)
        self.bad = BadPixels(c.defects)
        self.imaging = ImagingMask(c.circle)
        self.horizon_line: Horizon | None = None
        self._region: np.ndarray | None = None
        self._zones: list[np.ndarray] | None = None  # sky and ground, each its own threshold
        self._threshold = float("inf")
        self._refs: dict[int, _Ref] = {}
        self._steps = 0
        self._inf_map: np.ndarray | None = None
        self._inf_dirty: list[tuple[int, int, int, int]] = []

    # -- helpers --------------------------------------------------------------------------
    @property
    def circle(self) -> ImagingCircle | None:
        """The clip's imaging circle (None: the image fills the frame, or not seen yet)."""
        return self.imaging.circle

    def _crops(self, preds: list[Prediction], shape: tuple[int, int]
               ) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
        """Search crops: each window grown by ``fusion.pad``; overlapping ones are searched as
        one crop (their union box). When the crops would cover more than a quarter of the
        frame or number more than ``DENSE_CROPS``, one full-frame crop is cheaper.

        Returns [((x0, y0, x1, y1) half-open, prediction indices), ...]."""
        h, w = shape
        if not preds:
            return []
        pad = self.config.fusion.pad
        c = np.array([[p.x, p.y] for p in preds])
        hs = np.array([[p.half_w, p.half_h] for p in preds])
        lo = np.floor(c - hs).astype(np.int64) - pad
        hi = np.ceil(c + hs).astype(np.int64) + pad + 1
        lo = np.maximum(lo, 0)
        hi = np.minimum(hi, [w, h])
        ok = (hi > lo).all(axis=1)
        idx = np.nonzero(ok)[0]
        if idx.size == 0:
            return []
        lo, hi = lo[idx], hi[idx]
        area = np.prod(hi - lo, axis=1).sum()
        if idx.size > DENSE_CROPS or area > 0.25 * h * w:
            return [((0, 0, w, h), idx)]
        overlap = ((lo[:, None, :] < hi[None, :, :]) & (lo[None, :, :] < hi[:, None, :])).all(axis=2)
        comp = np.arange(idx.size)
        while True:  # each crop takes the smallest index of its overlap cluster
            new = np.where(overlap, comp[None, :], idx.size).min(axis=1)
            if np.array_equal(new, comp):
                break
            comp = new
        out = []
        for k in np.unique(comp):
            m = np.nonzero(comp == k)[0]
            x0, y0 = lo[m].min(axis=0)
            x1, y1 = hi[m].max(axis=0)
            out.append(((int(x0), int(y0), int(x1), int(y1)), idx[m]))
        return out

    def _search_windows(self, img: np.ndarray, preds: list[Prediction], search: list[int]
                        ) -> tuple[Detections, Features, np.ndarray, np.ndarray, list]:
        """Suppression, thresholding and components inside the search windows only."""
        c = self.config
        h, w = img.shape
        size = c.suppression.size
        reach = 2 * (size // 2)  # the opening looks this far: crops are grown so it is exact
        suppressed = np.zeros(img.shape, dtype=img.dtype if img.dtype in (np.uint8, np.uint16, np.float32)
                              else np.float32)
        if self._inf_map is None or self._inf_map.shape != img.shape:
            self._inf_map = np.full(img.shape, np.inf, dtype=np.float32)
        for x0, y0, x1, y1 in self._inf_dirty:  # restore last frame's windows
            self._inf_map[y0:y1, x0:x1] = np.inf
        residual_map = self._inf_map  # defects test only the windows (inf: never a spike)
        self._inf_dirty = []
        labels_full = np.zeros(img.shape, dtype=np.int32)
        seg = _Segments()
        searched = []
        T = self._threshold
        region = self._region
        gap = c.detection.merge_gap
        kernel = np.ones((2 * gap + 1, 2 * gap + 1), np.uint8) if gap > 0 else None
        want_raw = c.features.grey == "raw"
        sub = [preds[i] for i in search]
        next_label = 1
        for (x0, y0, x1, y1), members in self._crops(sub, img.shape):
            X0, Y0 = max(x0 - reach, 0), max(y0 - reach, 0)
            X1, Y1 = min(x1 + reach, w), min(y1 + reach, h)
            res = suppress_background(img[Y0:Y1, X0:X1], size, c.suppression.method)
            res = res[y0 - Y0:y1 - Y0, x0 - X0:x1 - X0]
            suppressed[y0:y1, x0:x1] = res
            residual_map[y0:y1, x0:x1] = res
            searched.append((x0, y0, x1, y1))
            self._inf_dirty.append((x0, y0, x1, y1))
            binary = ((res.astype(np.float32, copy=False) > T) & region[y0:y1, x0:x1]).astype(np.uint8)
            if not binary.any():
                continue
            if kernel is not None:
                grown = cv2.dilate(binary, kernel)
                n, labels = cv2.connectedComponents(grown, connectivity=8, ltype=cv2.CV_32S)
                labels[binary == 0] = 0
            else:
                n, labels = cv2.connectedComponents(binary, connectivity=8, ltype=cv2.CV_32S)
            if n <= 1:
                continue
            f = component_features(labels, n, res, img[y0:y1, x0:x1] if want_raw else None, T,
                                   c.features.centre)
            off = np.array([x0, y0], dtype=np.float64)
            cen = f["centre"] + off  # the bbox centre in "min_area_rect" mode: refined below
            # keep components of allowed size whose centre lies in one of the crop's windows
            pc = np.array([[sub[m].x, sub[m].y] for m in members])
            ph = np.array([[sub[m].half_w, sub[m].half_h] for m in members])
            inside = (np.abs(cen[None, :, :] - pc[:, None, :]) <= ph[:, None, :]).all(axis=2).any(axis=0)
            keep = np.nonzero(inside & (f["area"] >= c.detection.min_area)
                              & (f["area"] <= c.detection.max_area))[0]
            if keep.size == 0:
                continue
            rects = f["rects"][keep]
            if c.features.centre == "min_area_rect":
                rc, rects = min_area_rects(labels, keep + 1)
                cen[keep] = rc + off
            remap = np.zeros(n, dtype=np.int32)
            remap[keep + 1] = np.arange(next_label, next_label + keep.size, dtype=np.int32)
            next_label += keep.size
            mapped = remap[labels]
            hit = mapped > 0
            labels_full[y0:y1, x0:x1][hit] = mapped[hit]
            seg.centre.append(cen[keep])
            seg.area.append(f["area"][keep])
            seg.peak.append(f["peak"][keep])
            seg.flux.append(f["flux"][keep])
            if want_raw:
                seg.raw.append(f["raw"][keep])
            b = f["bbox"][keep].copy()
            b[:, 0] += x0
            b[:, 1] += y0
            seg.bbox.append(b)
            seg.rects.append(rects + off)
        cat = (lambda v, shape: np.concatenate(v) if v else np.zeros(shape))
        centre = cat(seg.centre, (0, 2))
        area = cat(seg.area, (0,)).astype(np.int64)
        flux = cat(seg.flux, (0,))
        dets = Detections(xy=centre, area=area, peak=cat(seg.peak, (0,)), flux=flux,
                          bbox=cat(seg.bbox, (0, 4)).astype(np.int64),
                          component=np.arange(1, len(area) + 1), labels=labels_full, threshold=T)
        grey = cat(seg.raw, (0,)) if want_raw else flux.astype(np.float64)
        feats = Features(centre, area, grey, cat(seg.rects, (0, 4, 2)))
        return dets, feats, suppressed, residual_map, searched

    def _global(self, img: np.ndarray, valid: np.ndarray, mask_changed: bool
                ) -> tuple[Detections, Features, np.ndarray, bool, dict[str, float]]:
        """Horizon (when due), full-frame suppression and detection, features."""
        c = self.config
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        horizon, updated = self.horizon.update(img, valid)
        if updated or mask_changed or self._region is None:
            self._region, self._zones = search_zones(valid, horizon, c.horizon.margin,
                                                     c.horizon.exclude_ground, self.circle is not None)
        self.horizon_line = horizon
        t1 = time.perf_counter()
        times["horizon"] = (t1 - t0) * 1e3
        suppressed = suppress_background(img, c.suppression.size, c.suppression.method)
        t2 = time.perf_counter()
        times["suppress"] = (t2 - t1) * 1e3
        dets = detect(suppressed, self._region, c.detection, self._zones)
        if np.isfinite(dets.threshold):
            self._threshold = dets.threshold
        if not len(dets):
            feats = Features(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 4, 2)))
        else:
            # detect() already measured each component: bbox, area, residual sum, centroid
            b = dets.bbox.astype(np.float64)
            rects = box_corners(b)
            if c.features.centre == "min_area_rect":
                centre, rects = min_area_rects(dets.labels, dets.component)
            elif c.features.centre == "centroid":
                centre = dets.xy.astype(np.float64)
            else:
                centre = np.column_stack([b[:, 0] + (b[:, 2] - 1) / 2.0, b[:, 1] + (b[:, 3] - 1) / 2.0])
            if c.features.grey == "raw":
                idx = np.flatnonzero(dets.labels)
                sums = np.bincount(dets.labels.ravel()[idx], weights=img.ravel()[idx].astype(np.float64),
                                   minlength=int(dets.component.max()) + 1)
                grey = sums[dets.component]
            else:
                grey = dets.flux.astype(np.float64)
            feats = Features(centre, dets.area, grey, rects)
            dets = replace(dets, xy=feats.centre)
        times["detect"] = (time.perf_counter() - t2) * 1e3
        return dets, feats, suppressed, updated, times

    # -- per frame ------------------------------------------------------------------------
    def step(self, frame: Frame) -> FusionResult:
        """Run every stage on one frame."""
        fc = self.config.fusion
        timer = StageTimer(("defects", "mask", "horizon", "windows", "suppress", "detect",
                            "associate", "kalman"))
        lap, timings = timer.lap, timer.timings
        raw, img = frame.image, self.bad.clean(frame.image)
        lap("defects")
        mask, mask_changed = self.imaging.update(img)
        if mask_changed:
            self._region = None
        valid = ~mask
        lap("mask")
        preds = self.manager.predict(frame.index)
        pred_xy = np.array([[p.x, p.y] for p in preds], dtype=np.float64).reshape(-1, 2)
        half = np.array([[p.half_w, p.half_h] for p in preds], dtype=np.float64).reshape(-1, 2)
        confirmed = np.array([p.confirmed for p in preds], dtype=bool)
        active = np.array([not p.meeting for p in preds], dtype=bool)  # meeting tracks take nothing
        lap("associate")

        reason = ""
        if self._steps == 0 or self._region is None:
            reason = "first frame"
        elif not confirmed.any():
            reason = "no confirmed track"
        elif fc.detect_every > 0 and self._steps % fc.detect_every == 0:
            reason = f"periodic, every {fc.detect_every} frames"
        self._steps += 1

        searched: list = []
        horizon_updated = False
        residual_map = None
        pairs: dict[int, int] = {}
        lost: list[int] = []
        if not reason:
            search = [i for i in range(len(preds)) if active[i]]
            dets, feats, suppressed, residual_map, searched = self._search_windows(img, preds, search)
            lap("windows")
            pairs, cost = self._associate(preds, pred_xy, half, confirmed, active, feats, frame.image.shape)
            lost = [i for i in range(len(preds)) if confirmed[i] and active[i] and i not in pairs]
            lap("associate")
            if lost:
                ids = ", ".join(str(preds[i].track_id) for i in lost)
                reason = f"track{'s' if len(lost) > 1 else ''} {ids}: no candidate in the search window"
        is_global = bool(reason)
        events_pre: list[TrackEvent] = []
        if is_global:
            for i in lost:
                events_pre.append(TrackEvent(frame.index, "redetect", preds[i].track_id,
                                             f"track {preds[i].track_id}: no candidate in its search "
                                             f"window, global detection reruns"))
            dets, feats, suppressed, horizon_updated, times = self._global(img, valid, mask_changed)
            for k, v in times.items():
                timings[k] += v
            timer.skip()  # _global timed its own stages
            pairs, cost = self._associate(preds, pred_xy, half, confirmed, active, feats, frame.image.shape)
            lost = [i for i in range(len(preds)) if confirmed[i] and active[i] and i not in pairs]
            recovered, recover_cost = self._recover(preds, pred_xy, lost, pairs, feats, confirmed,
                                                    half, frame.image.shape)
            lap("associate")
        else:
            recovered, recover_cost = {}, {}
        matches, meas = self._matches(preds, pairs, recovered, recover_cost, cost, feats,
                                      frame.image.shape)
        births = np.zeros((0, 2))
        born_idx = np.zeros(0, dtype=np.int64)
        if is_global and len(dets):
            used = np.zeros(len(dets), dtype=bool)
            used[list(pairs.values()) + list(recovered.values())] = True
            claimed = self.manager.claimed(preds, feats.centre)
            born_idx = np.nonzero(~used & ~claimed)[0]
            births = feats.centre[born_idx]
        velocities = {i: self.manager.velocity(i) for i in recovered}
        tc = self.config.tracking  # for the confirmation tests (and the hover values)
        dets = score_detections(dets, img, self._region, self.config.detection,
                                self.config.detection.significance or tc.confirm_significance > 0,
                                tc.confirm_blobness > 0)
        sig, blob = dets.significance, dets.blobness
        taken = {**pairs, **recovered}
        events = events_pre + self.manager.update(
            meas, births,
            scores=None if sig is None else {i: float(sig[j]) for i, j in taken.items()},
            birth_scores=None if sig is None else sig[born_idx],
            shapes=None if blob is None else {i: float(blob[j]) for i, j in taken.items()},
            birth_shapes=None if blob is None else blob[born_idx])
        self._restart(preds, recovered, velocities, feats)
        events += [TrackEvent(frame.index, "recovered", preds[i].track_id,
                              f"track {preds[i].track_id} recovered by global detection at "
                              f"({feats.centre[j, 0]:.1f}, {feats.centre[j, 1]:.1f}), "
                              f"{math.hypot(*(feats.centre[j] - pred_xy[i])):.1f} px from its prediction")
                   for i, j in recovered.items()]
        self._update_refs(events, born_idx, feats, matches)
        lap("kalman")
        # hot-pixel evidence: the full residual on global frames, the windows only otherwise
        if residual_map is None or is_global:
            bad_changed = self.bad.update(raw, suppressed, dets.threshold)
        else:
            bad_changed = self.bad.update(raw, residual_map, self._threshold)
        lap("defects")
        assigned = np.full(len(dets), -1, dtype=np.int64)
        for m in matches:
            assigned[m.detection] = m.track_id
        timings = timer.done()
        return FusionResult(
            index=frame.index, time=frame.time, tracks=tuple(self.manager.states()),
            predictions=tuple(preds), detections=dets, events=tuple(events), timings=timings,
            features=feats, matches=tuple(matches), assigned=assigned, global_detection=is_global,
            global_reason=reason, searched=tuple(searched),
            lost=tuple(preds[i] for i in lost if i not in recovered), recover_radius=fc.recover_radius,
            suppressed=suppressed, circle=self.circle, mask=mask, mask_changed=mask_changed,
            horizon=self.horizon_line, horizon_updated=horizon_updated,
            innovations=self.manager.innovations(), bad_pixels=self.bad.flagged,
            bad_pixels_changed=bad_changed,
        )

    # -- association ----------------------------------------------------------------------
    def _ref_arrays(self, preds: list[Prediction]) -> tuple[np.ndarray, ...]:
        refs = [self._refs.get(p.track_id) for p in preds]
        get = (lambda attr: np.array([getattr(r, attr) if r else np.nan for r in refs], dtype=np.float64))
        return get("area"), get("grey"), get("area0"), get("grey0")

    def _cost(self, preds: list[Prediction], pred_xy: np.ndarray, half: np.ndarray, feats: Features,
              shape: tuple[int, int]) -> np.ndarray:
        """(T, N) fused matching cost of the configured kind."""
        fc = self.config.fusion
        area, grey, area0, grey0 = self._ref_arrays(preds)
        if fc.cost == "scalar":
            phi_t = scalar_phi(pred_xy, area, grey, area0, grey0, shape, fc.alpha, fc.beta, fc.gamma)
            phi_c = scalar_phi(feats.centre[None, :, :], feats.area[None, :].astype(np.float64),
                               feats.grey[None, :], area0[:, None], grey0[:, None], shape,
                               fc.alpha, fc.beta, fc.gamma)
            cost = np.abs(phi_t[:, None] - phi_c)
        else:
            cost = fused_cost(pred_xy, half, area, grey, feats.centre, feats.area, feats.grey,
                              fc.alpha, fc.beta, fc.gamma)
        return np.where(np.isfinite(cost), cost, _BIG)

    def _associate(self, preds: list[Prediction], pred_xy: np.ndarray, half: np.ndarray,
                   confirmed: np.ndarray, active: np.ndarray, feats: Features,
                   shape: tuple[int, int]) -> tuple[dict[int, int], np.ndarray]:
        """{prediction index: candidate index} by minimal fused cost inside the windows."""
        if not preds or not len(feats):
            return {}, np.zeros((len(preds), len(feats)))
        cost = self._cost(preds, pred_xy, half, feats, shape)
        diff = np.abs(feats.centre[None, :, :] - pred_xy[:, None, :])
        ok = (diff <= half[:, None, :]).all(axis=2) & active[:, None] & (cost <= self.config.fusion.max_cost)
        return assign_confirmed_first(cost, ok, confirmed), cost

    def _recover(self, preds: list[Prediction], pred_xy: np.ndarray, lost: list[int],
                 pairs: dict[int, int], feats: Features, confirmed: np.ndarray, half: np.ndarray,
                 shape: tuple[int, int]) -> tuple[dict[int, int], dict[int, float]]:
        """Lost confirmed tracks take the best unused global candidate within the recovery
        radius (centre term normalised by the radius), outside other confirmed windows."""
        # a target that *left* its window: the track was measured inside it on the last frame
        # (repeated recoveries would keep a track on clutter alive indefinitely)
        lost = [i for i in lost if (ref := self._refs.get(preds[i].track_id)) is not None and ref.in_window]
        if not lost or not len(feats):
            return {}, {}
        fc = self.config.fusion
        r = fc.recover_radius
        sub = [preds[i] for i in lost]
        cost = self._cost(sub, pred_xy[lost], np.full((len(lost), 2), r), feats, shape)
        dist = np.hypot(*(feats.centre[None, :, :] - pred_xy[lost][:, None, :]).transpose(2, 0, 1))
        used = np.zeros(len(feats), dtype=bool)
        used[list(pairs.values())] = True
        others = [i for i in range(len(preds)) if confirmed[i] and i not in lost]
        if others:
            d = np.abs(feats.centre[None, :, :] - pred_xy[others][:, None, :])
            used |= (d <= half[others][:, None, :]).all(axis=2).any(axis=0)
        ok = (dist <= r) & ~used[None, :] & (cost <= fc.recover_max_cost)
        got = assign_confirmed_first(cost, ok, np.ones(len(lost), dtype=bool))
        return {lost[k]: j for k, j in got.items()}, {lost[k]: float(cost[k, j]) for k, j in got.items()}

    def _matches(self, preds: list[Prediction], pairs: dict[int, int], recovered: dict[int, int],
                 recover_cost: dict[int, float], cost: np.ndarray, feats: Features,
                 shape: tuple[int, int]
                 ) -> tuple[list[Match], dict[int, tuple[float, float]]]:
        fc = self.config.fusion
        out, meas = [], {}
        for i, j in list(pairs.items()) + list(recovered.items()):
            p = preds[i]
            ref = self._refs.get(p.track_id)
            a0, g0 = (ref.area0, ref.grey0) if ref else (float(feats.area[j]), float(feats.grey[j]))
            phi = float(scalar_phi(feats.centre[j], float(feats.area[j]), float(feats.grey[j]), a0, g0,
                                   shape, fc.alpha, fc.beta, fc.gamma))
            cst = float(cost[i, j]) if i in pairs else recover_cost[i]  # recovery: centre term / radius
            x, y = float(feats.centre[j, 0]), float(feats.centre[j, 1])
            out.append(Match(p.track_id, j, x, y, cst, phi, i in recovered))
            meas[i] = (x, y)
        return out, meas

    # -- bookkeeping ----------------------------------------------------------------------
    def _restart(self, preds: list[Prediction], recovered: dict[int, int], velocities: dict,
                 feats: Features) -> None:
        """A recovered track restarts its filter at the new position (velocity kept, P = P₀):
        the old state would pull its next window back towards where the target was lost."""
        if not recovered:
            return
        for i, j in recovered.items():
            self.manager.restart(preds[i].track_id, np.array(
                [feats.centre[j, 0], feats.centre[j, 1], *velocities[i]], dtype=np.float64))

    def _update_refs(self, events: list[TrackEvent], born_idx: np.ndarray, feats: Features,
                     matches: list[Match]) -> None:
        matched = {m.track_id for m in matches}
        for tid, ref in self._refs.items():
            if tid not in matched:
                ref.in_window = False
        for m in matches:
            ref = self._refs.get(m.track_id)
            a, g = float(feats.area[m.detection]), float(feats.grey[m.detection])
            if ref is None:
                self._refs[m.track_id] = _Ref(a, g, a, g, 1, m.phi, not m.recovered)
            else:
                ref.add(a, g, m.phi, not m.recovered)
        born = [e.track_id for e in events if e.kind == "born"]
        for tid, j in zip(born, born_idx):
            a, g = float(feats.area[j]), float(feats.grey[j])
            self._refs[tid] = _Ref(a, g, a, g)
        live = set(self.manager.track_ids)
        for tid in list(self._refs):
            if tid not in live:
                del self._refs[tid]
