"""Multi-target track management: gating, global assignment, confirmation, deletion, meeting.

Composable steps, called in order each frame: :meth:`TrackManager.predict` (Kalman
prediction, gates, meeting mode), :meth:`TrackManager.associate` (global assignment of
detections to tracks inside their gates), :meth:`TrackManager.update` (Kalman updates,
hit/miss counting, births and deletions). Positions are (x = column, y = row) in pixels.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from wfviz import kalman
from wfviz.config import KalmanConfig, TrackingConfig


@dataclass(frozen=True)
class TrackState:
    """A live track after the frame's update; (x, y) is the reported position."""

    track_id: int
    x: float
    y: float
    vx: float
    vy: float
    confirmed: bool
    meeting: bool
    hits: int
    misses: int


@dataclass(frozen=True)
class Prediction:
    """A track's prediction for this frame and its rectangular gate (half sizes in px)."""

    track_id: int
    x: float
    y: float
    half_w: float
    half_h: float
    confirmed: bool
    meeting: bool
    cov_trace: float


@dataclass(frozen=True)
class TrackEvent:
    """Something that happened to a track: born, confirmed, deleted, meeting_on, meeting_off."""

    frame: int
    kind: str
    track_id: int
    message: str


@dataclass
class _Track:
    track_id: int
    x: np.ndarray
    P: np.ndarray
    hits: int = 1
    misses: int = 0
    confirmed: bool = False
    meeting: bool = False
    meeting_frames: int = 0
    score_sum: float = 0.0  # sum of the significance of the hits
    origin: np.ndarray | None = None  # birth position, moved with the camera (scene-fixed)
    history: deque = field(default_factory=lambda: deque(maxlen=64))  # reported (x, y)
    velocities: list = field(default_factory=list)  # filtered (vx, vy) before meeting, last 3
    innovation: np.ndarray | None = None


def extrapolate(history: list[tuple[float, float]] | deque) -> tuple[float, float]:
    """Eq. 15 as read in METHODS.md: s(k) = s(k-1) + (s(k-1) - s(k-3)) / 2."""
    s1, s3 = np.asarray(history[-1]), np.asarray(history[-3])
    s = s1 + (s1 - s3) / 2.0
    return float(s[0]), float(s[1])


def _meeting_state(t: "_Track", how: str) -> np.ndarray:
    """Next state of a track in meeting mode: linear extrapolation of its own motion."""
    last = t.history[-1]
    if how == "kalman":  # the paper's prose: the target's velocities at k-1, k-2, k-3
        v = np.mean(t.velocities[-3:], axis=0) if t.velocities else t.x[2:]
        ex, ey = last[0] + v[0], last[1] + v[1]
    else:
        ex, ey = extrapolate(t.history)
    return np.array([ex, ey, ex - last[0], ey - last[1]])


class TrackManager:
    """Tracks with CV Kalman filters, confirmed after m hits, deleted after n misses."""

    def __init__(self, kcfg: KalmanConfig, tcfg: TrackingConfig) -> None:
        self.kcfg, self.tcfg = kcfg, tcfg
        self.model = kalman.CVModel.make(kcfg.q, kcfg.r)
        self.P0 = kalman.initial_covariance(kcfg.r, kcfg.initial_velocity_std)
        self.tracks: list[_Track] = []
        self._next_id = 1
        self._frame = 0
        self._events: list[TrackEvent] = []

    def shift(self, dx: float, dy: float) -> None:
        """Move every track (state and history) by the camera's image motion (dx, dy)."""
        for t in self.tracks:
            t.x[0] += dx
            t.x[1] += dy
            t.origin = t.origin + (dx, dy)
            t.history = deque(((x + dx, y + dy) for x, y in t.history), maxlen=t.history.maxlen)

    # -- predict --------------------------------------------------------------------------
    def predict(self, frame: int) -> list[Prediction]:
        """Advance every track to ``frame``; tracks closer than the safety distance meet."""
        self._frame, self._events = frame, []
        if not self.tracks:
            return []
        x = np.stack([t.x for t in self.tracks])
        P = np.stack([t.P for t in self.tracks])
        x, P = kalman.predict(x, P, self.model)
        for t, xi, Pi in zip(self.tracks, x, P):
            t.x, t.P = xi, Pi
            if t.meeting and len(t.history) >= 3:
                t.x = _meeting_state(t, self.tcfg.meeting_velocity)
        self._update_meeting()
        S = kalman.innovation_covariance(np.stack([t.P for t in self.tracks]), self.model)
        half = np.clip(self.kcfg.gate_sigma * np.sqrt(S[:, [0, 1], [0, 1]]),
                       self.kcfg.gate_min, self.kcfg.gate_max)
        return [Prediction(t.track_id, float(t.x[0]), float(t.x[1]), float(h[0]), float(h[1]),
                           t.confirmed, t.meeting, float(np.trace(t.P)))
                for t, h in zip(self.tracks, half)]

    def _update_meeting(self) -> None:
        conf = [t for t in self.tracks if t.confirmed]
        close: set[int] = set()
        if len(conf) > 1:
            pos = np.array([t.x[:2] for t in conf])
            d = np.hypot(*(pos[:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
            np.fill_diagonal(d, np.inf)
            close = {conf[i].track_id for i in np.nonzero((d < self.tcfg.safety_distance).any(axis=1))[0]}
        for t in conf:
            if t.track_id in close and not t.meeting and len(t.history) >= 3:
                t.meeting, t.meeting_frames = True, 0
                t.x = _meeting_state(t, self.tcfg.meeting_velocity)
                self._event("meeting_on", t, "within the safety distance: Kalman updates stop, "
                                             "linear extrapolation (eq. 15)")
            elif t.meeting:
                t.meeting_frames += 1
                expired = t.meeting_frames > self.tcfg.max_meeting_frames
                if t.track_id not in close or expired:
                    t.meeting = False
                    t.P = self.P0.copy()  # re-initialise the filter at the extrapolated state
                    why = "meeting lasted too long" if expired else "separated"
                    self._event("meeting_off", t, f"{why}: filter re-initialised")

    # -- associate ------------------------------------------------------------------------
    def associate(self, preds: list[Prediction], xy: np.ndarray) -> dict[int, int]:
        """Global assignment {track index: detection index}; confirmed tracks choose first.

        A detection is a candidate for a track when it lies inside the track's gate; the
        cost is the Mahalanobis distance under the innovation covariance. Tracks in meeting
        mode take no measurement, and tentative tracks take none inside a confirmed track's
        gate (so they cannot steal a meeting pair's detections). No detection is used twice.
        """
        if not preds or len(xy) == 0:
            return {}
        S_inv = np.linalg.inv(kalman.innovation_covariance(np.stack([t.P for t in self.tracks]), self.model))
        centres = np.array([[p.x, p.y] for p in preds])
        halves = np.array([[p.half_w, p.half_h] for p in preds])
        diff = xy[None, :, :] - centres[:, None, :]
        inside = (np.abs(diff) <= halves[:, None, :]).all(axis=2)
        cost = np.einsum("tdi,tij,tdj->td", diff, S_inv, diff)
        result: dict[int, int] = {}
        used = np.zeros(len(xy), dtype=bool)
        confirmed_gates = inside[[i for i, p in enumerate(preds) if p.confirmed]].any(axis=0)
        for want_confirmed in (True, False):
            rows = [i for i, p in enumerate(preds) if p.confirmed == want_confirmed and not p.meeting]
            if not rows:
                continue
            ok = inside[rows] & ~used[None, :]
            if not want_confirmed:  # a confirmed track's gate is off limits to tentative ones
                ok &= ~confirmed_gates[None, :]
            big = 1e9
            c = np.where(ok, cost[rows], big)
            keep_cols = np.nonzero(ok.any(axis=0))[0]
            if keep_cols.size == 0:
                continue
            ri, ci = linear_sum_assignment(c[:, keep_cols])
            for r_, c_ in zip(ri, ci):
                if c[r_, keep_cols[c_]] < big:
                    result[rows[r_]] = int(keep_cols[c_])
                    used[keep_cols[c_]] = True
        return result

    def claimed(self, preds: list[Prediction], xy: np.ndarray) -> np.ndarray:
        """Detections inside a confirmed track's gate: they never start new tracks."""
        if len(xy) == 0 or not preds:
            return np.zeros(len(xy), dtype=bool)
        conf = [p for p in preds if p.confirmed]
        if not conf:
            return np.zeros(len(xy), dtype=bool)
        c = np.array([[p.x, p.y] for p in conf])
        h = np.array([[p.half_w, p.half_h] for p in conf])
        return (np.abs(xy[None, :, :] - c[:, None, :]) <= h[:, None, :]).all(axis=2).any(axis=0)

    # -- update ---------------------------------------------------------------------------
    def update(self, measurements: dict[int, tuple[float, float]], births: np.ndarray,
               scores: dict[int, float] | None = None, birth_scores: np.ndarray | None = None
               ) -> list[TrackEvent]:
        """Apply measurements {track index: (x, y)}, count misses, delete, start new tracks.

        ``scores`` / ``birth_scores``: the significance of each measurement / birth; a track is
        confirmed at ``confirm_hits`` hits when its mean significance also reaches
        ``confirm_significance`` (0 = hits only, as in the paper). Returns the frame's events
        (including meeting events from :meth:`predict`).
        """
        scores = scores or {}
        idx = sorted(measurements)
        for t in self.tracks:
            t.innovation = None
        if idx:
            x = np.stack([self.tracks[i].x for i in idx])
            P = np.stack([self.tracks[i].P for i in idx])
            z = np.array([measurements[i] for i in idx], dtype=np.float64)
            x, P, nu = kalman.update(x, P, z, self.model)
            for i, xi, Pi, ni in zip(idx, x, P, nu):
                t = self.tracks[i]
                t.x, t.P, t.innovation = xi, Pi, ni
                t.velocities = (t.velocities + [xi[2:].copy()])[-3:]
        survivors: list[_Track] = []
        for i, t in enumerate(self.tracks):
            if i in measurements:
                t.hits += 1
                t.misses = 0
                t.score_sum += scores.get(i, 0.0)
                t.history.append(measurements[i])
                need = self.tcfg.confirm_significance
                moved = float(np.hypot(*(np.asarray(measurements[i]) - t.origin)))
                if (not t.confirmed and t.hits >= self.tcfg.confirm_hits
                        and (need <= 0 or t.score_sum / t.hits >= need)
                        and moved >= self.tcfg.min_displacement):
                    t.confirmed = True
                    why = f", mean significance {t.score_sum / t.hits:.1f}" if need > 0 else ""
                    why += f", moved {moved:.1f} px" if self.tcfg.min_displacement > 0 else ""
                    self._event("confirmed", t, f"confirmed after {t.hits} hits{why}")
            elif t.meeting:
                t.history.append((float(t.x[0]), float(t.x[1])))
            else:
                t.misses += 1
                t.history.append((float(t.x[0]), float(t.x[1])))
                if t.misses >= self.tcfg.max_misses:
                    self._event("deleted", t, f"deleted after {t.misses} consecutive misses "
                                              f"({'confirmed' if t.confirmed else 'tentative'}, {t.hits} hits)")
                    continue
            survivors.append(t)
        self.tracks = survivors
        births = np.asarray(births, dtype=np.float64).reshape(-1, 2)
        bscore = np.zeros(len(births)) if birth_scores is None else np.asarray(birth_scores, dtype=np.float64)
        for (bx, by), sc in zip(births, bscore):
            t = _Track(self._next_id, np.array([bx, by, 0.0, 0.0]), self.P0.copy(), score_sum=float(sc),
                       origin=np.array([bx, by]))
            t.history.append((float(bx), float(by)))
            self._next_id += 1
            self.tracks.append(t)
            self._event("born", t, f"tentative track started at ({bx:.1f}, {by:.1f})")
        return self._events

    def states(self) -> list[TrackState]:
        """Snapshot of every live track; position = last reported (measurement when present)."""
        out = []
        for t in self.tracks:
            x, y = t.history[-1]
            out.append(TrackState(t.track_id, float(x), float(y), float(t.x[2]), float(t.x[3]),
                                  t.confirmed, t.meeting, t.hits, t.misses))
        return out

    def innovations(self) -> dict[int, np.ndarray]:
        """{track_id: innovation (2,)} for the tracks updated this frame."""
        return {t.track_id: t.innovation for t in self.tracks if t.innovation is not None}

    def _event(self, kind: str, t: _Track, message: str) -> None:
        self._events.append(TrackEvent(self._frame, kind, t.track_id, f"track {t.track_id} {message}"))
