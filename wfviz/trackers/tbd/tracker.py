"""Multi-target particle-filter track-before-detect tracker (``--tracker tbd``).

Per frame: normalise the frame (background and noise sigma from the data), choose the regions
(the whole frame, fixed tiles, or windows around candidates of a temporally integrated matched
filter), run each region's bank of particle filters PF_0..PF_N_max (:mod:`wfviz.trackers.tbd.filter`),
then turn the estimated states of the most probable count into tracks with stable ids.
The equations are in docs/pipeline.md ("The track-before-detect tracker").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from wfviz.io.frames import Frame
from wfviz.stages.detection import Detections, no_detections
from wfviz.stages.horizon import HorizonTracker, search_region
from wfviz.stages.imaging_circle import ImagingMask
from wfviz.trackers.base import FrameResult, StageTimer, min_side
from wfviz.trackers.tbd.background import PixelBackground
from wfviz.trackers.tbd.config import TBDConfig
from wfviz.trackers.tbd.filter import BankOutput, Estimate, RegionFilter
from wfviz.trackers.tbd.model import matched_filter, normalise, texture_normalise
from wfviz.tracking import EventKind, Prediction, TrackEvent, TrackState

STAGES = ("normalise", "candidates", "predict", "likelihood", "count", "estimate", "resample", "tracks")
MAX_LOGGED_COUNT = 9  # the total-count posterior is reported for n = 0..9 (the last bin: n >= 9)


@dataclass(frozen=True)
class Region:
    """A rectangle of the frame with its own filter bank: (x0, y0) top-left pixel, size, kind
    (``full``, ``tile`` or ``window``), its id and this frame's count estimate and P(n = 0)."""

    region_id: int
    x0: int
    y0: int
    width: int
    height: int
    kind: str
    count: int
    p0: float


@dataclass(frozen=True, kw_only=True)
class TBDResult(FrameResult):
    """Every stage's output for one frame (the common fields come from FrameResult).

    ``p_count`` is the posterior of the number of targets in the frame (index n; with several
    regions, the convolution of the regions' posteriors, the last bin holding n >= 9);
    ``count`` the estimate (sum over regions of each region's most probable n);
    ``particles`` (K, 3) rows (x, y, n): resampled posterior particles of every PF_n,
    subsampled; ``normalised`` the frame (z - b) / sigma; ``amplitudes`` the estimated peak
    SNR of each reported track."""

    p_count: np.ndarray
    count: int
    count_changed: bool
    particles: np.ndarray
    regions: tuple[Region, ...]
    normalised: np.ndarray
    noise_sigma: float
    amplitudes: dict[int, float]
    position_std: dict[int, float]


class TargetEstimate(NamedTuple):
    """One target of a bank's estimate in frame coordinates: position and velocity (px,
    px/frame), peak SNR, position std (px), whether the bank's count includes it (else it is the
    tentative target of PF_n+1) and the bank's region id."""

    x: float
    y: float
    vx: float
    vy: float
    amplitude: float
    std_x: float
    std_y: float
    confirmed: bool
    region: int


@dataclass
class _Bank:
    region_id: int
    x0: int
    y0: int
    width: int
    height: int
    kind: str
    filter: RegionFilter
    born: int = 0  # frame index of its first frame
    quiet: int = 0  # consecutive frames with P(n = 0) >= close_p0
    last: BankOutput | None = None


@dataclass
class _Track:
    track_id: int
    x: float
    y: float
    vx: float
    vy: float
    last_frame: int
    hits: int = 0
    confirmed: bool = False
    ever_confirmed: bool = False
    history: list = field(default_factory=list)


class TBDTracker:
    """Streams frames through the track-before-detect filters; ``step`` returns a :class:`TBDResult`."""

    name = "tbd"

    def __init__(self, config: TBDConfig | None = None) -> None:
        self.config = config or TBDConfig()
        self.rng = np.random.Generator(np.random.PCG64(self.config.filter.seed))
        self.banks: list[_Bank] = []
        self._mode: str | None = None
        self._shape: tuple[int, int] | None = None
        self._ema: np.ndarray | None = None
        self._cooldown: list[tuple[int, int, int, int, int]] = []  # closed windows: x0, y0, w, h, until
        self._next_region = 1
        self._tracks: dict[int, _Track] = {}
        self._next_id = 1
        self._count = 0
        self.horizon = HorizonTracker(self.config.horizon)
        self.imaging = ImagingMask(self.config.circle)
        self._valid: np.ndarray | None = None
        self._search: np.ndarray | None = None
        m = self.config.model
        self._bg = PixelBackground(m.background_memory, m.background_clip, m.noise_tile, m.noise_memory,
                                   m.hot_pixel_k, coherence=m.background_coherence)
        self._hold: np.ndarray | None = None  # pixels under the last frame's targets

    # -- regions ------------------------------------------------------------------------------
    def _setup(self, shape: tuple[int, int]) -> None:
        rc = self.config.regions
        rows, cols = shape
        mode = rc.mode
        if mode == "auto":
            mode = "full" if rows * cols <= rc.full_max_pixels else "candidates"
        self._mode, self._shape = mode, shape
        self.banks = []
        if mode == "full":
            self._add_bank(0, 0, cols, rows, "full")
        elif mode == "tiles":
            for y0 in _starts(rows, rc.tile, rc.tile_overlap):
                for x0 in _starts(cols, rc.tile, rc.tile_overlap):
                    self._add_bank(x0, y0, min(rc.tile, cols), min(rc.tile, rows), "tile")

    def _add_bank(self, x0: int, y0: int, w: int, h: int, kind: str, born: int = 0) -> _Bank:
        bank = _Bank(self._next_region, x0, y0, w, h, kind, RegionFilter(self.config, (h, w), self.rng,
                                                                       self._max_speed()), born)
        self._next_region += 1
        self.banks.append(bank)
        return bank

    def _search_region(self, img: np.ndarray) -> np.ndarray | None:
        """Sky search region (``regions.search``; "auto": over tiles and windows only): inside
        the imaging circle and above the horizon, as for the GEWC tracker; None = everywhere."""
        c = self.config
        mode = c.regions.search
        if mode == "all" or (mode == "auto" and self._mode == "full"):
            return None
        mask, changed = self.imaging.update(img)
        if changed:
            self._valid = ~mask
        horizon, updated = self.horizon.update(img, self._valid)
        if changed or updated or self._search is None:
            self._search = search_region(self._valid, horizon, c.horizon.margin)
        return self._search

    def _max_speed(self) -> float:
        """``model.max_speed``, or when "auto" 1 px/frame on small frames (the paper's sub-pixel
        targets) and 3 px/frame over tiles and windows (wide-field targets are faster)."""
        ms = self.config.model.max_speed
        if ms is not None:
            return float(ms)
        return 1.0 if self._mode == "full" else 3.0

    def _background(self) -> str:
        m = self.config.model.background
        return "temporal" if m == "auto" else m

    def _normalise(self, img: np.ndarray) -> tuple[np.ndarray, float, np.ndarray | None]:
        """(y, sigma, texture) by ``model.background``: "temporal" (per-pixel running
        background, per-tile noise from frame differences, hot pixels excluded:
        :mod:`wfviz.trackers.tbd.background`; over tiles and windows y is then divided by its local RMS as
        for "local"), or the single-frame "global" / "local" estimates of :func:`normalise`."""
        mc = self.config.model
        method = self._background()
        if method != "temporal":
            return normalise(img, method, mc.background_window, mc.remove_spikes, mc.noise_window)
        nf = self._bg.step(img, self._hold)
        y = nf.y
        texture = None
        if self._mode != "full":
            y, texture = texture_normalise(y, mc.noise_window)
        return y, nf.sigma, texture

    def _hold_mask(self, shape: tuple[int, int], estimates: list[TargetEstimate]) -> np.ndarray | None:
        """Pixels within the PSF patch radius + 1 of this frame's estimated targets (their
        background is not updated next frame, so a slow target is not learnt as background)."""
        if not estimates:
            return None
        rows, cols = shape
        rad = self.config.model.patch_radius + 1
        mask = np.zeros(shape, bool)
        for e in estimates:
            c, r = int(round(e.x)), int(round(e.y))
            mask[max(r - rad, 0):max(min(r + rad + 1, rows), 0), max(c - rad, 0):max(min(c + rad + 1, cols), 0)] = True
        return mask

    def _candidates(self, t: np.ndarray, texture: np.ndarray | None, index: int
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Windows mode: temporally integrated matched filter u (an EMA of t scaled to unit
        noise std), its local maxima above ``regions.candidate_k`` where the local texture is
        at most ``regions.clutter_max`` (clouds and ground excluded); opens windows on new ones
        and closes windows whose P(n = 0) stayed high. Returns candidate (x, y) and scores."""
        rc = self.config.regions
        a = rc.candidate_memory
        self._ema = a * t if self._ema is None else (1.0 - a) * self._ema + a * t
        u = self._ema / math.sqrt(a / (2.0 - a))
        peaks = (u >= cv2.dilate(u, np.ones((3, 3), np.uint8))) & (u > rc.candidate_k)
        if texture is not None:
            peaks &= texture <= rc.clutter_max
        ys, xs = np.nonzero(peaks)
        score = u[ys, xs]
        order = np.argsort(-score, kind="stable")
        xs, ys, score = xs[order], ys[order], score[order]
        # close quiet windows (their targets left or were noise)
        keep = []
        for b in self.banks:
            if b.quiet >= rc.close_after:
                self._cooldown.append((b.x0, b.y0, b.width, b.height, index + rc.close_after))
            else:
                keep.append(b)
        self.banks = keep
        self._cooldown = [c for c in self._cooldown if c[4] > index]
        rows, cols = t.shape
        w, h = min(rc.window, cols), min(rc.window, rows)
        margin = self.config.model.patch_radius + 2
        # support of a window: its best candidate this frame (0 if none)
        support = {b.region_id: 0.0 for b in self.banks}
        for b in self.banks:
            inside = (xs >= b.x0) & (xs < b.x0 + b.width) & (ys >= b.y0) & (ys < b.y0 + b.height)
            if inside.any():
                support[b.region_id] = float(score[inside].max())
        for x, y, sc in zip(xs, ys, score):
            if any(b.x0 + margin <= x < b.x0 + b.width - margin and b.y0 + margin <= y < b.y0 + b.height - margin
                   for b in self.banks):
                continue
            if any(c[0] <= x < c[0] + c[2] and c[1] <= y < c[1] + c[3] for c in self._cooldown):
                continue
            if len(self.banks) >= rc.max_windows:
                # full: replace the least supported window that has run for close_after frames,
                # if this candidate is at least 1.5 times stronger
                old = [b for b in self.banks if index - b.born >= rc.close_after]
                if not old:
                    break
                weakest = min(old, key=lambda b: support[b.region_id])
                if sc < 1.5 * support[weakest.region_id]:
                    break
                self.banks.remove(weakest)
                self._cooldown.append((weakest.x0, weakest.y0, weakest.width, weakest.height,
                                       index + rc.close_after))
            x0 = int(min(max(x - w // 2, 0), cols - w))
            y0 = int(min(max(y - h // 2, 0), rows - h))
            bank = self._add_bank(x0, y0, w, h, "window", index)
            support[bank.region_id] = float(sc)
        return np.column_stack([xs, ys]).astype(np.float64), score

    # -- one frame ----------------------------------------------------------------------------
    def min_frame_side(self) -> int:
        """Smallest frame side the horizon's windows fit in."""
        return min_side(horizon=self.config.horizon)

    def step(self, frame: Frame) -> TBDResult:
        """Run every stage on one frame."""
        c = self.config
        img = frame.image
        if img.ndim == 3:
            img = img.mean(axis=2)
        timer = StageTimer(STAGES)
        if self._shape != img.shape:
            self._setup(img.shape)
        y, sigma, texture = self._normalise(img)
        t = matched_filter(y, c.model.psf_sigma, c.model.patch_radius)
        sky = self._search_region(img)
        if sky is not None:  # no evidence outside the search region
            y[~sky] = 0.0
            t[~sky] = 0.0
        timer.lap("normalise")
        dets = no_detections(img.shape)
        if self._mode == "candidates":
            xy, score = self._candidates(t, texture, frame.index)
            n = len(xy)
            dets = Detections(xy, np.ones(n, dtype=np.int64), score, t[xy[:, 1].astype(int), xy[:, 0].astype(int)]
                              if n else np.zeros(0), np.column_stack([xy - 1, np.full((n, 2), 3)]).astype(np.int64),
                              np.arange(1, n + 1), dets.labels, float(c.regions.candidate_k))
        timer.lap("candidates")

        estimates: list[TargetEstimate] = []
        particles = []
        p_total = np.ones(1)
        count = 0
        for b in self.banks:
            ys, xs = slice(b.y0, b.y0 + b.height), slice(b.x0, b.x0 + b.width)
            out = b.filter.step(np.ascontiguousarray(y[ys, xs]), t[ys, xs], timer)
            b.last = out
            p = out.p
            b.quiet = b.quiet + 1 if p[0] >= c.regions.close_p0 else 0
            p_total = _convolve(p_total, p)
            n = out.count
            count += n
            estimates += self._reported(b, out, n)
            if len(out.particles):
                pts = out.particles.copy()
                pts[:, [0, 1]] = pts[:, [1, 0]]
                pts[:, 0] += b.x0
                pts[:, 1] += b.y0
                particles.append(pts)
        timer.skip()  # the bank loop's own bookkeeping belongs to no stage
        self._hold = self._hold_mask(img.shape, estimates)
        tracks, preds, events, amps, stds = self._associate(frame.index, estimates, c)
        changed = count != self._count
        if changed:
            pc = float(p_total[min(count, len(p_total) - 1)])
            events.append(TrackEvent(frame.index, EventKind.COUNT, -1,
                                     f"target count estimate {self._count} -> {count} (P = {pc:.2f})"))
        self._count = count
        timer.lap("tracks")
        timings = timer.done()
        regions = tuple(Region(b.region_id, b.x0, b.y0, b.width, b.height, b.kind,
                               b.last.count if b.last else 0, float(b.last.p[0]) if b.last else 1.0)
                        for b in self.banks)
        return TBDResult(
            index=frame.index, time=frame.time, tracks=tuple(tracks), predictions=tuple(preds),
            detections=dets, events=tuple(events), timings=timings, p_count=p_total, count=count,
            count_changed=changed, particles=np.concatenate(particles) if particles else np.zeros((0, 3)),
            regions=regions, normalised=y, noise_sigma=sigma, amplitudes=amps, position_std=stds)

    def _reported(self, b: _Bank, out: BankOutput, n: int) -> list[TargetEstimate]:
        """The targets of PF_n (confirmed) and, when P(n + 1) >= tentative_p, the target of
        PF_n+1 farthest from PF_n's (tentative), if it is localised (position std within
        ``tracking.id_gate``)."""

        def conv(e: Estimate, j: int, confirmed: bool) -> TargetEstimate:
            s = e.state[j]
            return TargetEstimate(x=s[2] + b.x0, y=s[0] + b.y0, vx=s[3], vy=s[1], amplitude=float(e.amplitude[j]),
                            std_x=e.std[j, 1], std_y=e.std[j, 0], confirmed=confirmed, region=b.region_id)

        est = out.estimates[n]
        rows = [conv(est, j, True) for j in range(n)]
        p = out.p
        tp = self.config.tracking.tentative_p
        if n + 1 < len(p) and p[n + 1] >= tp and tp > 0:
            nxt = out.estimates[n + 1]
            j = 0
            if n > 0:
                d = np.linalg.norm(nxt.state[:, None, [0, 2]] - est.state[None, :, [0, 2]], axis=-1)
                j = int(np.argmax(d.min(axis=1)))
            if float(np.hypot(*nxt.std[j])) <= self.config.tracking.id_gate:
                rows.append(conv(nxt, j, False))
        return rows

    # -- track ids ----------------------------------------------------------------------------
    def _associate(self, index: int, estimates: list[TargetEstimate], c: TBDConfig
                   ) -> tuple[list[TrackState], list[Prediction], list[TrackEvent], dict, dict]:
        """Stable ids: estimates are assigned (Hungarian, distance <= ``tracking.id_gate``) to
        the tracks' predicted positions (last estimate + velocity x frames since). Estimates
        closer than ``merge_distance`` (the same target seen by overlapping regions, a tentative
        target on a confirmed one, or two hypothesised targets on one extended spot) are merged,
        keeping confirmed ones first, then the older region's.

        Not :class:`wfviz.tracking.TrackManager`: in the paper (Wang Hongbo and Wang Zhongwei) a
        target's birth, existence and death are the particle filters' (the bank's most probable
        count and each hypothesis' estimate); there are no detections to gate, update or start
        tracks from. This only labels the filters' estimates over time."""
        tc = c.tracking
        est = sorted(estimates, key=lambda e: (not e.confirmed, e.region))  # confirmed first, then region
        kept: list[TargetEstimate] = []
        for e in est:
            if all(math.hypot(e.x - k.x, e.y - k.y) >= tc.merge_distance for k in kept):
                kept.append(e)
        live = [tr for tr in self._tracks.values() if index - tr.last_frame <= tc.id_memory + 1]
        events: list[TrackEvent] = []
        pairs: dict[int, _Track] = {}
        if kept and live:
            cost = np.full((len(kept), len(live)), 1e6)
            for i, e in enumerate(kept):
                for j, tr in enumerate(live):
                    dt = index - tr.last_frame
                    d = math.hypot(e.x - (tr.x + tr.vx * dt), e.y - (tr.y + tr.vy * dt))
                    if d <= tc.id_gate:
                        cost[i, j] = d
            ri, ci = linear_sum_assignment(cost)
            for i, j in zip(ri, ci):
                if cost[i, j] < 1e6:
                    pairs[i] = live[j]
        tracks, preds, amps, stds = [], [], {}, {}
        for i, e in enumerate(kept):
            x, y_, vx, vy, amp, sx, sy, confirmed = e.x, e.y, e.vx, e.vy, e.amplitude, e.std_x, e.std_y, e.confirmed
            tr = pairs.get(i)
            if tr is None:
                tr = _Track(self._next_id, x, y_, vx, vy, index)
                self._tracks[tr.track_id] = tr
                self._next_id += 1
                events.append(TrackEvent(index, EventKind.BORN, tr.track_id,
                                         f"track {tr.track_id} tentative target at ({x:.1f}, {y_:.1f})"
                                         if not confirmed else
                                         f"track {tr.track_id} started at ({x:.1f}, {y_:.1f})"))
            tr.x, tr.y, tr.vx, tr.vy, tr.last_frame = x, y_, vx, vy, index
            tr.hits += 1
            tr.confirmed = bool(confirmed)
            if confirmed and not tr.ever_confirmed:
                tr.ever_confirmed = True
                events.append(TrackEvent(index, EventKind.CONFIRMED, tr.track_id,
                                         f"track {tr.track_id} confirmed: the count estimate includes it "
                                         f"(amplitude {amp:.1f} sigma)"))
            tracks.append(TrackState(tr.track_id, x, y_, vx, vy, tr.confirmed, False, tr.hits, 0))
            preds.append(Prediction(tr.track_id, x, y_, max(2.0 * sx, 0.5), max(2.0 * sy, 0.5),
                                    tr.confirmed, False, float(sx * sx + sy * sy)))
            amps[tr.track_id] = amp
            stds[tr.track_id] = float(math.hypot(sx, sy))
        for tid in list(self._tracks):
            tr = self._tracks[tid]
            if index - tr.last_frame > tc.id_memory:
                del self._tracks[tid]
                events.append(TrackEvent(index, EventKind.DELETED, tid,
                                         f"track {tid} deleted: not in the estimate for "
                                         f"{index - tr.last_frame} frames"))
        return tracks, preds, events, amps, stds


def _starts(size: int, tile: int, overlap: int) -> list[int]:
    """Tile origins covering ``size`` with ``tile``-long tiles overlapping by ``overlap``."""
    if size <= tile:
        return [0]
    step = tile - overlap
    starts = list(range(0, size - tile + 1, step))
    if starts[-1] + tile < size:
        starts.append(size - tile)
    return starts


def _convolve(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Posterior of the sum of two independent counts, the tail folded into bin MAX_LOGGED_COUNT."""
    r = np.convolve(p, q)
    if len(r) > MAX_LOGGED_COUNT + 1:
        r = np.concatenate([r[:MAX_LOGGED_COUNT], [r[MAX_LOGGED_COUNT:].sum()]])
    return r
