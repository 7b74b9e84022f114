"""Association of detections to tracks (Stone Soup's associator): the detections as the track
manager reads them (:class:`Measurements`), the predictions' :class:`Gates`, the frame's
:class:`Association`, and the global assignment with confirmed tracks first
(:func:`assign_confirmed_first`, :func:`assign_in_gates`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from wfviz.tracking.lsap import linear_sum_assignment
from wfviz.tracking.tracks import Prediction


@dataclass(frozen=True)
class Measurements:
    """This frame's detections as the track manager reads them, one row each: the position and
    the evidence the confirmation rules use (None: the tracker does not measure it).

    ``significance``: σ above the local noise; ``blobness``: :func:`wfviz.stages.detection.blobness`;
    ``novelty``: how new the detection is at its place in the scene (σ); ``clutter``: its
    static-clutter label (:mod:`wfviz.stages.clutter`: 1 static, 0 not, NaN undecided);
    ``density``: false detections per pixel around it (:class:`~wfviz.tracking.confirmation.DetectionDensity`);
    ``linearity``: how much of it is part of a line or an edge (:func:`wfviz.stages.detection.linearity`),
    line-like above ``max_linearity`` (:meth:`line_like`); ``size`` (N, 2): its component's width
    and height (px).
    """

    xy: np.ndarray
    significance: np.ndarray | None = None
    blobness: np.ndarray | None = None
    novelty: np.ndarray | None = None
    clutter: np.ndarray | None = None
    density: np.ndarray | None = None
    linearity: np.ndarray | None = None
    max_linearity: float = 1.0
    size: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.xy))

    def line_like(self) -> np.ndarray:
        """The detections that are part of a line or an edge (``linearity > max_linearity``;
        none where it was not measured): they start no track and their hits count as static
        clutter."""
        if self.linearity is None:
            return np.zeros(len(self), dtype=bool)
        return np.asarray(self.linearity, dtype=np.float64) > self.max_linearity


@dataclass(frozen=True)
class Gates:
    """The rectangular gates of a frame's predictions, one row per track: centres (N, 2), half
    sizes (N, 2), confirmed and meeting flags, inverse innovation covariances (N, 2, 2)."""

    centre: np.ndarray
    half: np.ndarray
    confirmed: np.ndarray
    meeting: np.ndarray
    S_inv: np.ndarray

    @classmethod
    def empty(cls) -> Gates:
        """No gates (no tracks)."""
        return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, dtype=bool), np.zeros(0, dtype=bool),
                   np.zeros((0, 2, 2)))

    @classmethod
    def of(cls, preds: Sequence[Prediction], S_inv: np.ndarray) -> Gates:
        """The gates of ``preds``, with inverse innovation covariances ``S_inv``."""
        return cls(np.array([[p.x, p.y] for p in preds], dtype=np.float64).reshape(-1, 2),
                   np.array([[p.half_w, p.half_h] for p in preds], dtype=np.float64).reshape(-1, 2),
                   np.array([p.confirmed for p in preds], dtype=bool),
                   np.array([p.meeting for p in preds], dtype=bool), S_inv)


def nearest(g: Gates, xy: np.ndarray, reach: float) -> np.ndarray:
    """Per gate, the detection of ``xy`` (N ≥ 1) nearest its centre within the gate and at most
    ``reach`` px away on each axis (-1: none)."""
    diff = xy[None, :, :] - g.centre[:, None, :]
    near = (np.abs(diff) <= np.minimum(g.half, reach)[:, None, :]).all(axis=2)
    dist = np.where(near, np.hypot(diff[..., 0], diff[..., 1]), np.inf)
    return np.where(near.any(axis=1), dist.argmin(axis=1), -1)


def claimed(g: Gates, xy: np.ndarray) -> np.ndarray:
    """Per detection of ``xy``: inside a confirmed gate (such a detection never starts a track)."""
    if not g.confirmed.any():
        return np.zeros(len(xy), dtype=bool)
    c, h = g.centre[g.confirmed], g.half[g.confirmed]
    return (np.abs(xy[None, :, :] - c[:, None, :]) <= h[:, None, :]).all(axis=2).any(axis=0)


def assign_in_gates(g: Gates, xy: np.ndarray) -> dict[int, int]:
    """{gate row: detection} by global assignment of the detections ``xy`` (N ≥ 1) inside the
    gates, at the cost of their squared Mahalanobis distance under the innovation covariance;
    confirmed tracks choose first. Tracks in meeting mode take no measurement, and tentative
    tracks take none inside a confirmed track's gate, even while it is meeting (so they cannot
    steal a meeting pair's detections). No detection is used twice."""
    diff = xy[None, :, :] - g.centre[:, None, :]
    inside = (np.abs(diff) <= g.half[:, None, :]).all(axis=2)
    cost = np.einsum("tdi,tij,tdj->td", diff, g.S_inv, diff)
    return assign_confirmed_first(cost, inside & ~g.meeting[:, None], g.confirmed,
                                  protected=inside[g.confirmed].any(axis=0))


@dataclass(frozen=True)
class Association:
    """Which detection each track takes this frame (:meth:`TrackManager.associate`), for
    :meth:`TrackManager.update`.

    ``pairs``: {track row: detection index}, no detection twice; ``nearest``: per track row, the
    detection nearest its prediction within its gate and 2 ``gate_min`` (-1: none), the evidence
    of a track in meeting mode, which takes no measurement; ``claimed``: per detection, inside a
    confirmed track's gate (such a detection starts no track).
    """

    pairs: dict[int, int]
    nearest: np.ndarray
    claimed: np.ndarray

    def with_pairs(self, pairs: dict[int, int]) -> Association:
        """The same gates with other pairs (a tracker's own associator)."""
        return replace(self, pairs=dict(pairs))

    def used(self) -> np.ndarray:
        """Per detection: taken by a track."""
        out = np.zeros(len(self.claimed), dtype=bool)
        out[list(self.pairs.values())] = True
        return out


_BIG = 1e9  # cost of an inadmissible pair


def assign_confirmed_first(cost: np.ndarray, ok: np.ndarray, confirmed: np.ndarray,
                           protected: np.ndarray | None = None) -> dict[int, int]:
    """{row: column} minimising the total ``cost`` over admissible pairs (``ok``): confirmed
    rows choose first, then tentative rows among the columns left, except ``protected`` ones
    (default: every column admissible to a confirmed row). No column is used twice."""
    out: dict[int, int] = {}
    if cost.size == 0:
        return out
    used = np.zeros(cost.shape[1], dtype=bool)
    if protected is None:
        protected = ok[confirmed].any(axis=0)
    for want in (True, False):
        rows = np.nonzero(confirmed == want)[0]
        if rows.size == 0:
            continue
        allowed = ok[rows] & ~used[None, :]
        if not want:
            allowed &= ~protected[None, :]
        keep = allowed.any(axis=1)  # rows with no admissible column stay out of the solve
        rows, allowed = rows[keep], allowed[keep]
        cols = np.nonzero(allowed.any(axis=0))[0]
        if cols.size == 0:
            continue
        c = np.where(allowed[:, cols], cost[np.ix_(rows, cols)], _BIG)
        ri, ci = linear_sum_assignment(c)
        for r, k in zip(ri, ci):
            if c[r, k] < _BIG:
                out[int(rows[r])] = int(cols[k])
                used[cols[k]] = True
    return out


def gate_boxes(preds: Sequence[Prediction], shape: tuple[int, int]) -> list[tuple[slice, slice]]:
    """(rows, columns) slices of the gates of the confirmed predictions not in meeting mode,
    clipped to the image. The front end searches them even below the horizon: the ground
    exclusion keeps ground clutter from starting tracks, not a confirmed track's target from
    being followed across the skyline."""
    out = []
    h, w = shape
    for p in preds:
        if not p.confirmed or p.meeting:
            continue
        x0, x1 = max(int(np.ceil(p.x - p.half_w)), 0), min(int(np.floor(p.x + p.half_w)) + 1, w)
        y0, y1 = max(int(np.ceil(p.y - p.half_h)), 0), min(int(np.floor(p.y + p.half_h)) + 1, h)
        if x1 > x0 and y1 > y0:
            out.append((slice(y0, y1), slice(x0, x1)))
    return out
