"""Multi-target track management: gating, global assignment, confirmation, deletion, meeting.

The parts, called in this order each frame (in the spirit of Stone Soup's predictor,
associator, updater, initiator and deleter):

1. :meth:`TrackManager.predict` (predictor): Kalman prediction, gates, meeting mode (GEWC
   eq. 15);
2. :meth:`TrackManager.associate` (associator): global assignment of this frame's
   :class:`Measurements` to tracks inside their gates, returned as an :class:`Association`; a
   tracker with its own associator (fusion's fused cost) takes :meth:`TrackManager.gate` and
   adds its pairs; :meth:`TrackManager.reacquire` may extend it;
3. :meth:`TrackManager.update` (updater, initiator, deleter): Kalman updates of the associated
   tracks, hit and miss counting, the confirmation rule (:class:`HitsRule`, the paper's, or
   :class:`SequentialRule`, :mod:`wfviz.tracking.confirmation`), deletions, and births: every
   detection left unused and outside a confirmed gate starts a tentative track
   (:meth:`TrackManager.initiate`, the one place births are decided).

Positions are (x = column, y = row) in pixels. The live tracks are held as arrays, one row per
track (struct of arrays): a frame costs a few numpy calls whatever the number of tracks, which
matters with tens of tentative tracks started by noise every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np
from scipy.optimize import linear_sum_assignment

from wfviz.config import ClutterConfig, KalmanConfig, TrackingConfig
from wfviz.tracking import confirmation, kalman


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


class EventKind(StrEnum):
    """What can happen to a track; the value is the string recordings and logs show."""

    BORN = "born"                # a tentative track started (a New chain: star field)
    CONFIRMED = "confirmed"      # passed its confirmation test
    DELETED = "deleted"          # ended (dropped, lost, left the image)
    MEETING_ON = "meeting_on"    # GEWC eq. 15: two tracks within the safety distance
    MEETING_OFF = "meeting_off"  # the meeting ended, filter re-initialised
    REACQUIRED = "reacquired"    # a lost track took over a new detection near its path
    WINDOW_LOST = "window_lost"  # fusion: no candidate in its search window, global detection reruns
    RECOVERED = "recovered"      # fusion: found again by that global detection
    COUNT = "count"              # tbd: the most probable number of targets changed (track_id -1)
    REJOINED = "rejoined"        # star field: a new three-frame chain continues a Run chain
    EXITED = "exited"            # star field: the chain's prediction left the field
    REDETECTED = "redetected"    # star field: found by local re-segmentation
    PROMOTED = "promoted"        # star field: New -> Run
    ABSORBED = "absorbed"        # star field: took over the points of a dropped New chain


@dataclass(frozen=True)
class TrackEvent:
    """Something that happened to a track (``kind``: :class:`EventKind`) in ``frame``;
    ``track_id`` -1 for an event of the whole frame."""

    frame: int
    kind: EventKind
    track_id: int
    message: str


@dataclass(frozen=True)
class Measurements:
    """This frame's detections as the track manager reads them, one row each: the position and
    the evidence the confirmation rules use (None: the tracker does not measure it).

    ``significance``: σ above the local noise; ``blobness``: :func:`wfviz.stages.detection.blobness`;
    ``novelty``: how new the detection is at its place in the scene (σ); ``clutter``: its
    static-clutter label (:mod:`wfviz.stages.clutter`: 1 static, 0 not, NaN undecided);
    ``density``: false detections per pixel around it (:class:`~wfviz.tracking.confirmation.DetectionDensity`).
    """

    xy: np.ndarray
    significance: np.ndarray | None = None
    blobness: np.ndarray | None = None
    novelty: np.ndarray | None = None
    clutter: np.ndarray | None = None
    density: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.xy))


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


def gone_reason(manager: "TrackManager", i: int, xy: np.ndarray) -> str:
    """Why :meth:`TrackManager._gone` ended track row ``i`` (reported position ``xy``)."""
    if manager.frame_shape is not None:
        h, w = manager.frame_shape
        if not (-0.5 <= xy[0] <= w - 0.5 and -0.5 <= xy[1] <= h - 0.5):
            return f"its prediction ({xy[0]:.1f}, {xy[1]:.1f}) left the image"
    return f"its position uncertainty outgrew kalman.coast_limit ({manager.kcfg.coast_limit:g} px)"


def extrapolate(history: list[tuple[float, float]] | np.ndarray) -> tuple[float, float]:
    """Eq. 15 (Zhang Shuai et al. 2018) as we read it: s(k) = s(k-1) + (s(k-1) - s(k-3)) / 2."""
    s1, s3 = np.asarray(history[-1]), np.asarray(history[-3])
    s = s1 + (s1 - s3) / 2.0
    return float(s[0]), float(s[1])


HISTORY = 3  # reported positions kept per track: eq. 15 reads s(k-1) and s(k-3)
MOTION_HISTORY = 32  # measured scene positions kept per track for the motion test (confirmation)
TEST_MEMORY = 0.9  # weight of the past in the running mean of tentative tracks tested per frame
MOVER_MAX_STATIC = 0.25  # tracking.confirm_moving: a mover's mean static-clutter label at most this


def _blank(n: int) -> dict[str, np.ndarray]:
    """The per-track arrays of ``n`` empty rows (TrackManager's struct of arrays)."""
    return dict(
        ids=np.zeros(n, dtype=np.int64),
        x=np.zeros((n, 4)),
        P=np.zeros((n, 4, 4)),
        hits=np.zeros(n, dtype=np.int64),
        misses=np.zeros(n, dtype=np.int64),
        confirmed=np.zeros(n, dtype=bool),
        meeting=np.zeros(n, dtype=bool),
        meeting_frames=np.zeros(n, dtype=np.int64),
        meet_again=np.ones(n, dtype=bool),      # False after a meeting until the next hit
        score_sum=np.zeros(n),                  # sum of the significance of the hits
        shape_sum=np.zeros(n),                  # sum of the blobness of the hits
        origin=np.zeros((n, 2)),                # birth position, moved with the camera
        birth_image=np.zeros((n, 2)),           # birth position in the image (not moved)
        path=np.zeros(n),                       # length of the reported path (scene), since birth
        gapless=np.ones(n, dtype=bool),         # updated in every frame since birth
        history=np.zeros((n, HISTORY, 2)),      # last reported (x, y), oldest first
        history_len=np.zeros(n, dtype=np.int64),
        velocities=np.zeros((n, 3, 2)),         # filtered (vx, vy) of the last updates
        velocities_len=np.zeros(n, dtype=np.int64),
        innovation=np.full((n, 2), np.nan),     # NaN: not updated this frame
        clutter=np.zeros(n),                    # mean of the hits' static-clutter labels (_add_clutter)
        clutter_known=np.zeros(n, dtype=np.int64),  # hits with a decided label
        score=np.zeros(n),                      # sequential test against noise (confirmation), nats
        clutter_score=np.zeros(n),              # test against static clutter: sum of clutter_hits
        clutter_hits=np.zeros((n, MOTION_HISTORY)),  # its evidence from the last hits, oldest first
        motion_t=np.zeros((n, MOTION_HISTORY)),  # frames of the measured scene positions
        motion_xy=np.zeros((n, MOTION_HISTORY, 2)),  # measured positions, camera motion removed
        motion_ok=np.zeros((n, MOTION_HISTORY), dtype=bool),
        _S_inv=np.zeros((n, 2, 2)),             # inverse innovation covariances (predict)
    )


_FIELDS = tuple(_blank(0))


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


@dataclass(frozen=True)
class Evidence:
    """One frame's evidence about every track (rows as the manager's), for a confirmation rule:
    measured this frame, missed (not measured and not meeting), moved (px from the birth point,
    in the scene), reported position, static-clutter labels of the measured and meeting tracks
    (None: no clutter stage), false detections per pixel at each track, each hit's significance
    ``z`` and novelty (NaN: none), the thresholds the gates were searched at (None: the frame's)."""

    measured: np.ndarray
    missed: np.ndarray
    moved: np.ndarray
    reported: np.ndarray
    clutter: dict[int, float] | None
    density: np.ndarray | None
    z: np.ndarray
    novelty: np.ndarray
    gate_k: np.ndarray | None


class HitsRule:
    """The GEWC paper's rule (Zhang Shuai et al. 2018; ``tracking.confirm = "hits"``): a track is
    confirmed at ``confirm_hits`` hits, and with the optional tests not in the paper (mean
    significance, blobness, displacement, movers, static clutter), deleted after
    ``max_misses`` consecutive misses. Births score nothing."""

    def start(self, mgr: TrackManager, new: dict[str, np.ndarray], birth_scores: np.ndarray | None,
              birth_density: np.ndarray | None, birth_novelty: np.ndarray | None) -> None:
        """Initial evidence of the new tracks' rows ``new`` of ``mgr`` (none for this rule)."""

    def decide(self, mgr: TrackManager, e: Evidence) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """(confirm, delete, message per row: the confirmation's reasons, or a deletion's whole
        message, "" for the usual one)."""
        measured, missed, moved, reported, clutter = e.measured, e.missed, e.moved, e.reported, e.clutter
        tc = mgr.tcfg
        n = len(mgr)
        need = tc.confirm_significance
        mean_score = mgr.score_sum / np.maximum(mgr.hits, 1)
        mean_shape = mgr.shape_sum / np.maximum(mgr.hits, 1)
        mover = mgr._mover(reported, moved)
        significant = ((need <= 0) | (mean_score >= need)
                       | (mover & (mean_score >= tc.confirm_moving_significance)))
        confirm = (measured & ~mgr.confirmed & (mgr.hits >= tc.confirm_hits)
                   & significant & (moved >= tc.min_displacement)
                   & ((tc.confirm_blobness <= 0) | (mean_shape >= tc.confirm_blobness)))
        delete = missed & (mgr.misses >= tc.max_misses)
        static = np.zeros(n, dtype=bool)
        if clutter is not None and mgr.clutter_rule is not None:
            rule = mgr.clutter_rule
            judged = mgr.clutter_known >= rule.min_known
            static = judged & (mgr.clutter > rule.max_static)
            confirm &= ~static & (judged | (not rule.wait))
            static &= mgr.confirmed & ~delete & (mgr.clutter > rule.delete_static)
            delete |= static
        why = [""] * n
        for i in np.nonzero(confirm | static)[0].tolist():
            if static[i]:
                why[i] = (f"deleted as static clutter (fixed in the scene among many detections: "
                          f"mean static label {mgr.clutter[i]:.2f})")
                confirm[i] = False
                continue
            w = f", mean significance {mean_score[i]:.1f}" if need > 0 else ""
            if need > 0 and mean_score[i] < need:
                w += f" (a mover: {moved[i]:.1f} px in a straight line since birth)"
            w += f", mean blobness {mean_shape[i]:.2f}" if tc.confirm_blobness > 0 else ""
            w += f", moved {moved[i]:.1f} px" if tc.min_displacement > 0 else ""
            why[i] = w
        return confirm, delete, why


class SequentialRule:
    """Wald's sequential tests of :mod:`wfviz.tracking.confirmation` (not in the paper;
    ``tracking.confirm = "sprt"``): ``score`` against noise (hits and misses, where the hits lie
    in the gate, how significant they are) and ``clutter_score`` against static clutter (how new
    the hits are at their place in the scene). A track is confirmed when both reach the
    confirmation level, dropped (tentative) or deleted (confirmed) when ``score`` falls to its
    level; the birth detection counts as a hit in the first gate."""

    def start(self, mgr: TrackManager, new: dict[str, np.ndarray], birth_scores: np.ndarray | None,
              birth_density: np.ndarray | None, birth_novelty: np.ndarray | None) -> None:
        """Initial scores of the new tracks' rows ``new`` of ``mgr``."""
        k = len(new["ids"])
        half = mgr._birth_half
        lam = np.zeros(k) if birth_density is None else np.asarray(birth_density, dtype=np.float64)
        p_fa = confirmation.gate_false_alarm(lam, np.repeat(half, k, axis=0))
        new["score"][:] = confirmation.score_change(np.ones(k, dtype=bool), mgr.tcfg.p_detect, p_fa)
        if birth_scores is not None:
            zb = np.asarray(birth_scores, dtype=np.float64)
            new["score"] += confirmation.amplitude_score(zb, mgr.detection_threshold)
            if birth_novelty is not None:
                new["clutter_hits"][:, -1] = confirmation.change_evidence(
                    np.asarray(birth_novelty, dtype=np.float64), mgr.detection_threshold,
                    mgr.tcfg.static_change_rate, mgr.tcfg.target_change_rate)
                new["clutter_score"][:] = new["clutter_hits"][:, -1]

    def decide(self, mgr: TrackManager, e: Evidence) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """(confirm, delete, message per row); sets ``mgr.thresholds`` to this frame's levels."""
        measured, density, z, nov, gate_k = e.measured, e.density, e.z, e.novelty, e.gate_k
        tc = mgr.tcfg
        n = len(mgr)
        th = confirmation.thresholds(tc.false_tracks_per_1000, mgr.tested_per_frame or 1.0,
                                    tc.beta, tc.p_lost)
        mgr.thresholds = th
        halves = mgr._pred_arrays[1] if len(mgr._pred_arrays) and len(mgr._pred_arrays[1]) == n \
            else np.full((n, 2), mgr.kcfg.gate_max)
        lam = np.zeros(n) if density is None else np.asarray(density, dtype=np.float64)
        p_fa = confirmation.gate_false_alarm(lam, halves)
        deep = gate_k is not None and len(gate_k) == n
        k_gate = (np.minimum(np.asarray(gate_k, dtype=np.float64), mgr.detection_threshold) if deep
                  else np.full(n, mgr.detection_threshold))
        if deep:  # where the gate was searched deeper, noise puts a hit there this often
            p_fa = np.where(k_gate < mgr.detection_threshold, np.maximum(p_fa, tc.gate_false_alarm), p_fa)
        change = confirmation.score_change(measured, tc.p_detect, p_fa)
        clutter = np.zeros(n)
        m = np.nonzero(measured)[0]
        if m.size:
            change[m] += confirmation.position_score(mgr.innovation[m], mgr._S_inv[m], halves[m])
            change[m] += confirmation.amplitude_score(z[m], k_gate[m])
            clutter[m] = confirmation.change_evidence(nov[m], mgr.detection_threshold,
                                                     tc.static_change_rate, tc.target_change_rate)
        # a meeting track takes no measurement: no evidence while a detection lies near its
        # extrapolation, a miss when none does (it has lost its target)
        change[mgr.meeting & ~measured & (mgr._nearest_now >= 0)] = 0.0
        mgr.score += change
        if m.size:  # a window of the last MOTION_HISTORY hits: old evidence does not linger
            mgr.clutter_hits[m, :-1] = mgr.clutter_hits[m, 1:]
            mgr.clutter_hits[m, -1] = clutter[m]
            mgr.clutter_score[m] = mgr.clutter_hits[m].sum(axis=1)
        conf = mgr.confirmed
        mgr.score[conf] = np.minimum(mgr.score[conf], th.confirm)
        confirm = measured & ~conf & (mgr.score >= th.confirm) & (mgr.clutter_score >= th.confirm)
        if tc.require_motion and confirm.any():
            r = np.nonzero(confirm)[0]
            mo = confirmation.motion(mgr.motion_t[r], mgr.motion_xy[r], mgr.motion_ok[r],
                                    tc.position_noise)
            confirm[r[(mo.t2 < th.motion) | (mo.steady < tc.min_motion / 2)]] = False
        tie = 1e-9  # a score that reaches a level in exact arithmetic reaches it here too
        drop = ~conf & (mgr.score <= th.drop + tie)
        lost = conf & (mgr.score <= th.delete + tie)
        why = [""] * n
        for i in np.nonzero(confirm)[0].tolist():
            why[i] = (f": persistence {mgr.score[i]:.1f} and not clutter {mgr.clutter_score[i]:.1f} "
                      f">= {th.confirm:.1f}")
        for i in np.nonzero(drop)[0].tolist():
            why[i] = (f"dropped: persistence {mgr.score[i]:.1f} fell to {th.drop:.1f} (noise, not a target) "
                      f"after {mgr.hits[i]} hits")
        for i in np.nonzero(lost)[0].tolist():
            why[i] = (f"deleted: score {mgr.score[i]:.1f} fell {th.confirm - mgr.score[i]:.1f} below "
                      f"confirmation after {mgr.misses[i]} consecutive misses ({mgr.hits[i]} hits)")
        return confirm, drop | lost, why


#: ``tracking.confirm`` -> the confirmation rule it selects
CONFIRMATION_RULES: dict[str, type] = {"hits": HitsRule, "sprt": SequentialRule}


class TrackManager:
    """Tracks with CV Kalman filters (Zhang Shuai et al. 2018, eqs. 8-14), meeting mode (eq. 15),
    confirmed and deleted by ``rule`` (:data:`CONFIRMATION_RULES`, from ``tracking.confirm``).

    Per-track state lives in arrays indexed like the predictions of the frame: ``ids``,
    ``x`` (N, 4), ``P`` (N, 4, 4), hit/miss counters, flags, the last :data:`HISTORY`
    reported positions and the last three filtered velocities.
    """

    def __init__(self, kcfg: KalmanConfig, tcfg: TrackingConfig, detection_threshold: float = 4.0) -> None:
        self.kcfg, self.tcfg = kcfg, tcfg
        self.model = kalman.CVModel.make(kcfg.q, kcfg.r)
        self.P0 = kalman.initial_covariance(kcfg.r, kcfg.initial_velocity_std)
        S0 = kalman.innovation_covariance(kalman.predict(np.zeros((1, 4)), self.P0[None], self.model)[1],
                                          self.model)
        self._birth_half = self._gate_half_sizes(S0)  # a new track's first gate
        self._next_id = 1
        self._frame = 0
        self._events: list[TrackEvent] = []
        self.__dict__.update(_blank(0))
        self._preds: list[Prediction] | None = None
        self._pred_arrays: tuple[np.ndarray, ...] = ()
        self._nearest_now = np.zeros(0, dtype=np.int64)  # the update's Association.nearest
        self.clutter_rule: ClutterConfig | None = None  # track rule of the static-clutter labels
        self.offset = np.zeros(2)  # accumulated camera shift: scene point s is at s + offset
        self.frame_shape: tuple[int, int] | None = None  # tracks that leave it are deleted
        self.tested_per_frame: float | None = None  # tentative tracks, running mean (TEST_MEMORY)
        self.thresholds: confirmation.Thresholds | None = None  # this frame's (confirm = "sprt")
        self.detection_threshold = detection_threshold
        self.rule: HitsRule | SequentialRule = CONFIRMATION_RULES[tcfg.confirm]()

    def __len__(self) -> int:
        return int(self.ids.size)

    @property
    def track_ids(self) -> list[int]:
        """Ids of the live tracks, in row order."""
        return self.ids.tolist()

    def velocity(self, i: int) -> np.ndarray:
        """Filtered velocity (vx, vy) of the track in row ``i``."""
        return self.x[i, 2:].copy()

    def restart(self, track_id: int, state: np.ndarray) -> None:
        """Restart a track's filter at ``state`` (x, y, vx, vy) with P = P₀."""
        rows = np.nonzero(self.ids == track_id)[0]
        if rows.size:
            self.x[rows[0]] = state
            self.P[rows[0]] = self.P0

    def shift(self, dx: float, dy: float) -> None:
        """Move every track (state, birth point and history) by the camera's image motion."""
        d = np.array([dx, dy])
        self.x[:, :2] += d
        self.origin += d
        self.history += d
        self.offset += d

    def _push_history(self, rows: np.ndarray, xy: np.ndarray) -> None:
        self.history[rows, :-1] = self.history[rows, 1:]
        self.history[rows, -1] = xy
        self.history_len[rows] = np.minimum(self.history_len[rows] + 1, HISTORY)

    # -- predict --------------------------------------------------------------------------
    def _meeting_state(self, i: int) -> np.ndarray:
        """Next state of track ``i`` in meeting mode: linear extrapolation of its own motion."""
        last = self.history[i, -1]
        if self.tcfg.meeting_velocity == "kalman":  # the paper's prose: velocities at k-1..k-3
            k = int(self.velocities_len[i])
            v = np.mean(self.velocities[i, 3 - k:], axis=0) if k else self.x[i, 2:]
            ex, ey = last[0] + v[0], last[1] + v[1]
        else:
            ex, ey = extrapolate(self.history[i])
        return np.array([ex, ey, ex - last[0], ey - last[1]])

    def predict(self, frame: int) -> list[Prediction]:
        """Advance every track to ``frame``; tracks closer than the safety distance meet."""
        self._frame, self._events = frame, []
        self._preds = None
        if not len(self):
            return []
        self.x, self.P = kalman.predict(self.x, self.P, self.model)
        for i in np.nonzero(self.meeting & (self.history_len >= 3))[0]:
            self.x[i] = self._meeting_state(i)
        self._update_meeting()
        S = kalman.innovation_covariance(self.P, self.model)
        half = self._gate_half_sizes(S)
        self._S_inv = np.linalg.inv(S)
        xy = self.x[:, :2].copy()
        trace = np.trace(self.P, axis1=1, axis2=2)
        preds = [Prediction(*row) for row in zip(
            self.ids.tolist(), *xy.T.tolist(), *half.T.tolist(), self.confirmed.tolist(),
            self.meeting.tolist(), trace.tolist())]
        self._preds = preds
        self._pred_arrays = (xy, half, self.confirmed.copy(), self.meeting.copy())
        return preds

    def _gate_half_sizes(self, S: np.ndarray) -> np.ndarray:
        """Gate half sizes (N, 2): gate_sigma * sqrt(S_ii), clipped to [gate_min, gate_max]."""
        return np.clip(self.kcfg.gate_sigma * np.sqrt(S[:, [0, 1], [0, 1]]),
                       self.kcfg.gate_min, self.kcfg.gate_max)

    def _update_meeting(self) -> None:
        conf = np.nonzero(self.confirmed)[0]
        close = np.zeros(len(self), dtype=bool)
        if conf.size > 1:
            pos = self.x[conf, :2]
            diff = pos[:, None, :] - pos[None, :, :]
            near = np.hypot(diff[..., 0], diff[..., 1]) < self.tcfg.safety_distance
            if self.tcfg.meeting_overlap:  # gates that overlap may share one merged blob
                half = self._gate_half_sizes(kalman.innovation_covariance(self.P[conf], self.model))
                near &= (np.abs(diff) <= half[:, None, :] + half[None, :, :]).all(axis=2)
            np.fill_diagonal(near, False)
            close[conf] = near.any(axis=1)
        for i in conf[close[conf] | self.meeting[conf]]:
            if close[i] and not self.meeting[i] and self.history_len[i] >= 3 and self.meet_again[i]:
                self.meeting[i], self.meeting_frames[i] = True, 0
                self.x[i] = self._meeting_state(i)
                self._event(EventKind.MEETING_ON, i, "within the safety distance: Kalman updates stop, "
                                             "linear extrapolation (eq. 15)")
            elif self.meeting[i]:
                self.meeting_frames[i] += 1
                expired = self.meeting_frames[i] > self.tcfg.max_meeting_frames
                if not close[i] or expired:
                    self.meeting[i] = False
                    self.meet_again[i] = False  # until its next measurement
                    self.P[i] = self.P0  # re-initialise the filter at the extrapolated state
                    why = "meeting lasted too long" if expired else "separated"
                    self._event(EventKind.MEETING_OFF, i, f"{why}: filter re-initialised")

    def _arrays(self, preds: list[Prediction]) -> tuple[np.ndarray, ...]:
        """(centres, half sizes, confirmed, meeting) of ``preds`` (cached for predict's own)."""
        if preds is self._preds:
            return self._pred_arrays
        return (np.array([[p.x, p.y] for p in preds], dtype=np.float64).reshape(-1, 2),
                np.array([[p.half_w, p.half_h] for p in preds], dtype=np.float64).reshape(-1, 2),
                np.array([p.confirmed for p in preds], dtype=bool),
                np.array([p.meeting for p in preds], dtype=bool))

    # -- associate ------------------------------------------------------------------------
    def gate(self, preds: list[Prediction], xy: np.ndarray) -> Association:
        """The gates of ``preds`` over detections ``xy`` without pairs: each track's nearest
        detection and the detections claimed by confirmed gates (for a tracker that pairs by
        its own cost, :meth:`Association.with_pairs`)."""
        return Association({}, self._nearest(preds, xy), self._claimed(preds, xy))

    def associate(self, preds: list[Prediction], xy: np.ndarray) -> Association:
        """Global assignment of detections ``xy`` to tracks; confirmed tracks choose first.

        A detection is a candidate for a track when it lies inside the track's gate; the
        cost is the Mahalanobis distance under the innovation covariance. Tracks in meeting
        mode take no measurement, and tentative tracks take none inside a confirmed track's
        gate (so they cannot steal a meeting pair's detections). No detection is used twice.
        """
        gated = self.gate(preds, xy)
        if not preds or len(xy) == 0:
            return gated
        centres, halves, confirmed, meeting = self._arrays(preds)
        diff = xy[None, :, :] - centres[:, None, :]
        inside = (np.abs(diff) <= halves[:, None, :]).all(axis=2)
        cost = np.einsum("tdi,tij,tdj->td", diff, self._S_inv, diff)  # squared Mahalanobis
        # a confirmed track's gate is off limits to tentative ones, even while it is meeting
        return gated.with_pairs(assign_confirmed_first(cost, inside & ~meeting[:, None], confirmed,
                                                       protected=inside[confirmed].any(axis=0)))

    def _nearest(self, preds: list[Prediction], xy: np.ndarray) -> np.ndarray:
        """Per track, the detection nearest its prediction within its gate and at most 2
        ``gate_min`` away (-1: none); a meeting track's evidence (does its target still show
        near its extrapolation?) and its static-clutter label come from it."""
        out = np.full(len(self), -1, dtype=np.int64)
        if not preds or len(xy) == 0 or len(preds) != len(self):
            return out
        centres, halves, _, _ = self._arrays(preds)
        diff = xy[None, :, :] - centres[:, None, :]
        near = (np.abs(diff) <= np.minimum(halves, 2.0 * self.kcfg.gate_min)[:, None, :]).all(axis=2)
        dist = np.where(near, np.hypot(diff[..., 0], diff[..., 1]), np.inf)
        return np.where(near.any(axis=1), dist.argmin(axis=1), -1)

    def reacquire(self, preds: list[Prediction], xy: np.ndarray, association: Association,
                  eligible: np.ndarray, radius: float) -> Association:
        """``association`` plus re-acquisitions (not in the paper): a confirmed, non-meeting track
        with no detection in its gate takes the nearest ``eligible`` detection within ``radius``
        px of its prediction that is unused and outside every confirmed gate (nearest pairs
        first), and its filter restarts there (velocity kept, P = P₀): a jerk of the camera,
        or of a target the camera follows, threw it out of its gate."""
        pairs = association.pairs
        if not preds or len(xy) == 0:
            return association
        centres, _, confirmed, meeting = self._arrays(preds)
        lost = np.array([i for i in np.nonzero(confirmed & ~meeting)[0].tolist() if i not in pairs],
                        dtype=np.int64)
        free = np.asarray(eligible, dtype=bool) & ~association.claimed
        free[list(pairs.values())] = False
        cand = np.nonzero(free)[0]
        if lost.size == 0 or cand.size == 0:
            return association
        d = np.hypot(*(xy[None, cand, :] - centres[lost, None, :]).transpose(2, 0, 1))
        out = dict(pairs)
        for flat in np.argsort(d, axis=None).tolist():
            r, k = divmod(flat, cand.size)
            if d[r, k] > radius:
                break
            i, j = int(lost[r]), int(cand[k])
            if i in out or j in out.values():
                continue
            out[i] = j
            self.restart(int(self.ids[i]), np.concatenate([xy[j], self.x[i, 2:]]))
            self._event(EventKind.REACQUIRED, i, f"reacquired at ({xy[j, 0]:.1f}, {xy[j, 1]:.1f}), "
                                         f"{d[r, k]:.1f} px from its prediction (nothing in its gate)")
        return association.with_pairs(out)

    def _claimed(self, preds: list[Prediction], xy: np.ndarray) -> np.ndarray:
        """Detections inside a confirmed track's gate: they never start new tracks."""
        if len(xy) == 0 or not preds:
            return np.zeros(len(xy), dtype=bool)
        centres, halves, confirmed, _ = self._arrays(preds)
        if not confirmed.any():
            return np.zeros(len(xy), dtype=bool)
        c, h = centres[confirmed], halves[confirmed]
        return (np.abs(xy[None, :, :] - c[:, None, :]) <= h[:, None, :]).all(axis=2).any(axis=0)

    # -- initiate -------------------------------------------------------------------------
    @staticmethod
    def initiate(association: Association, start: np.ndarray | bool | None = None) -> np.ndarray:
        """The detections that start tentative tracks this frame (indices). By default (None)
        the unused ones outside every confirmed gate. ``start`` False: none (fusion between its
        global detections); a mask (or True): the unused detections it allows, for a caller with
        its own start rule."""
        if start is False:
            return np.zeros(0, dtype=np.int64)
        born = ~association.used()
        born &= ~association.claimed if start is None else np.asarray(start, dtype=bool)
        return np.nonzero(born)[0]

    # -- update ---------------------------------------------------------------------------
    def update(self, association: Association, detections: Measurements,
               positions: dict[int, tuple[float, float]] | None = None, track_density: np.ndarray | None = None,
               gate_k: np.ndarray | None = None, start: np.ndarray | bool | None = None) -> list[TrackEvent]:
        """Apply this frame's ``association`` of ``detections``; count misses, confirm, delete,
        start new tracks (:meth:`initiate`; ``start`` as there). Returns the frame's events
        (including the meeting events of :meth:`predict` and those of :meth:`reacquire`).

        ``positions``: {track row: measured (x, y)} for the associated tracks that were measured
        (GEWC: the centroid in the window; a pair left out takes no update but still uses its
        detection); default the detections' positions. ``track_density``: false detections per
        pixel at each track (the sequential rule). ``gate_k``: the threshold (σ) each track's
        gate was searched at (:func:`wfviz.tracking.confirmation.gate_threshold`); where it is
        below the frame's, a hit's false-alarm probability is at least
        ``tracking.gate_false_alarm`` and its significance is scored from there.

        Per measured track the rules read its detection's significance, blobness, novelty and
        (with ``clutter_rule``) static-clutter label; a meeting track's label is that of the
        detection nearest its extrapolation."""
        d = detections
        pairs = association.pairs
        if positions is None:
            positions = {i: (float(d.xy[j, 0]), float(d.xy[j, 1])) for i, j in pairs.items()}
        taken = {i: pairs[i] for i in positions}

        def per_track(values: np.ndarray | None) -> dict[int, float] | None:
            return None if values is None else {i: float(values[j]) for i, j in taken.items()}

        novelty = d.novelty if d.novelty is not None else np.full(len(d), np.nan)
        clutter = None
        if d.clutter is not None:  # meeting tracks: the detection nearest their extrapolation
            clutter = {int(i): float(d.clutter[j]) for i, j in enumerate(association.nearest.tolist())
                       if j >= 0 and self.meeting[i]}
            clutter.update(per_track(d.clutter) or {})
        born = self.initiate(association, start)
        self._nearest_now = association.nearest
        return self._apply(
            positions, d.xy[born], scores=per_track(d.significance),
            birth_scores=None if d.significance is None else d.significance[born],
            clutter=clutter, birth_clutter=None if d.clutter is None else d.clutter[born],
            shapes=per_track(d.blobness), birth_shapes=None if d.blobness is None else d.blobness[born],
            density=track_density, birth_density=None if d.density is None else d.density[born],
            novelty=per_track(novelty), birth_novelty=novelty[born], gate_k=gate_k)

    def _apply(self, measurements: dict[int, tuple[float, float]], births: np.ndarray,
               scores: dict[int, float] | None = None, birth_scores: np.ndarray | None = None,
               clutter: dict[int, float] | None = None, birth_clutter: np.ndarray | None = None,
               shapes: dict[int, float] | None = None, birth_shapes: np.ndarray | None = None,
               density: np.ndarray | None = None, birth_density: np.ndarray | None = None,
               novelty: dict[int, float] | None = None, birth_novelty: np.ndarray | None = None,
               gate_k: np.ndarray | None = None,
               ) -> list[TrackEvent]:
        """:meth:`update` on parallel values: measurements {track row: (x, y)} and the births'
        positions, with each one's evidence.

        ``scores`` / ``birth_scores``: the significance of each measurement / birth; a track is
        confirmed at ``confirm_hits`` hits when its mean significance also reaches
        ``confirm_significance`` (0 = hits only, as in the paper). ``shapes`` / ``birth_shapes``:
        the blobness of each (:func:`wfviz.stages.detection.blobness`); a track is confirmed only when its
        hits' mean reaches ``confirm_blobness`` (0 = not used). ``clutter`` /
        ``birth_clutter``: static-clutter labels (:mod:`wfviz.stages.clutter`; 1 static, 0 not, NaN
        undecided) under ``clutter_rule`` (:class:`~wfviz.config.ClutterConfig`): a track needs
        ``min_known`` decided labels with a mean ≤ ``max_static`` to be confirmed (unless
        ``wait`` is off: then undecided tracks may be confirmed too), and a confirmed track
        above ``delete_static`` is deleted. ``gate_k``: the threshold (σ) each track's gate was
        searched at (see :meth:`update`).
        """
        scores, shapes = scores or {}, shapes or {}
        tc = self.tcfg
        n = len(self)
        self.innovation[:] = np.nan
        idx = np.array(sorted(measurements), dtype=np.int64)
        z = np.array([measurements[i] for i in idx.tolist()], dtype=np.float64).reshape(-1, 2)
        measured = np.zeros(n, dtype=bool)
        measured[idx] = True
        if idx.size:
            x, P, nu = kalman.update(self.x[idx], self.P[idx], z, self.model)
            self.x[idx], self.P[idx], self.innovation[idx] = x, P, nu
            self.velocities[idx, :-1] = self.velocities[idx, 1:]
            self.velocities[idx, -1] = x[:, 2:]
            self.velocities_len[idx] = np.minimum(self.velocities_len[idx] + 1, 3)
            self.hits[idx] += 1
            self.misses[idx] = 0
            self.meet_again[idx] = True
            self.score_sum[idx] += np.array([scores.get(i, 0.0) for i in idx.tolist()])
            self.shape_sum[idx] += np.array([shapes.get(i, 0.0) for i in idx.tolist()])
        if clutter:  # measured tracks, and meeting tracks with a detection near them
            rows = np.array(sorted(clutter), dtype=np.int64)
            self._add_clutter(rows, np.array([clutter[i] for i in rows.tolist()]))
        # history: the measurement, or the (coasting / extrapolated) state
        reported = self.x[:, :2].copy()
        reported[idx] = z
        self.path += np.hypot(*(reported - self.history[:, -1]).T)
        self.gapless &= measured
        self._push_history(np.arange(n), reported)
        missed = ~measured & ~self.meeting
        if tc.meeting_misses:  # a meeting track with nothing in its gate has lost its target
            missed |= self.meeting & (self._nearest_now < 0)
            self.misses[self.meeting & (self._nearest_now >= 0)] = 0
        self.misses[missed] += 1
        moved = np.hypot(reported[:, 0] - self.origin[:, 0], reported[:, 1] - self.origin[:, 1])
        self._push_motion(idx, z)
        z, nov = np.full(n, np.nan), np.full(n, np.nan)
        z[idx] = [scores.get(i, np.nan) for i in idx.tolist()]
        nov[idx] = [(novelty or {}).get(i, np.nan) for i in idx.tolist()]
        confirm, delete, why = self.rule.decide(self, Evidence(measured, missed, moved, reported, clutter,
                                                               density, z, nov, gate_k))
        gone = self._gone(measured, reported) & ~delete
        for i in np.nonzero(confirm | delete | gone)[0].tolist():
            if gone[i]:
                self._event(EventKind.DELETED, i, f"deleted: {gone_reason(self, i, reported[i])} "
                                          f"({'confirmed' if self.confirmed[i] else 'tentative'}, "
                                          f"{self.hits[i]} hits)")
            elif confirm[i]:
                self.confirmed[i] = True
                self._event(EventKind.CONFIRMED, i, f"confirmed after {self.hits[i]} hits{why[i]}")
            else:
                self._event(EventKind.DELETED, i, why[i] or (
                    f"deleted after {self.misses[i]} consecutive misses "
                    f"({'confirmed' if self.confirmed[i] else 'tentative'}, {self.hits[i]} hits)"))
        delete |= gone
        if delete.any():
            keep = ~delete
            for name in _FIELDS:
                setattr(self, name, getattr(self, name)[keep])
        births = np.asarray(births, dtype=np.float64).reshape(-1, 2)
        tested = int((~self.confirmed).sum()) + len(births)
        b = self.tested_per_frame
        self.tested_per_frame = tested if b is None else TEST_MEMORY * b + (1 - TEST_MEMORY) * tested
        self._birth(births, birth_scores, birth_clutter, birth_shapes, birth_density, birth_novelty)
        return self._events

    def _gone(self, measured: np.ndarray, reported: np.ndarray) -> np.ndarray:
        """Coasting tracks (meeting mode included) whose position left the image, or (not in
        meeting mode: its extrapolation does not use the filter's covariance, which is reset when
        the meeting ends) whose position uncertainty (``gate_sigma`` standard deviations)
        outgrew ``kalman.coast_limit``."""
        n = len(self)
        out = np.zeros(n, dtype=bool)
        if self.frame_shape is not None:
            h, w = self.frame_shape
            out = ((reported[:, 0] < -0.5) | (reported[:, 0] > w - 0.5)
                   | (reported[:, 1] < -0.5) | (reported[:, 1] > h - 0.5))
        spread = self.kcfg.gate_sigma * np.sqrt(np.maximum(self.P[:, 0, 0], self.P[:, 1, 1]))
        return ~measured & (out | ((spread > self.kcfg.coast_limit) & ~self.meeting))

    def _push_motion(self, rows: np.ndarray, z: np.ndarray) -> None:
        """Record the measured scene positions (image position minus the camera offset)."""
        if not rows.size:
            return
        for name in ("motion_t", "motion_xy", "motion_ok"):
            a = getattr(self, name)
            a[rows, :-1] = a[rows, 1:]
        self.motion_t[rows, -1] = self._frame
        self.motion_xy[rows, -1] = z - self.offset
        self.motion_ok[rows, -1] = True

    def _mover(self, reported: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """Tracks that count as movers under ``tracking.confirm_moving`` (not in the paper):
        updated in every frame since birth, ``confirm_moving`` px or more from the birth point
        both in the scene (``moved``; camera motion removed) and in the image, along a path at
        most 1 / ``confirm_straightness`` times that long, and (with the static-clutter stage)
        with a mean static label of at most ``MOVER_MAX_STATIC``: the clutter stage agrees."""
        tc = self.tcfg
        if tc.confirm_moving <= 0:
            return np.zeros(len(self), dtype=bool)
        in_image = np.hypot(*(reported - self.birth_image).T)
        return (self.gapless & (moved >= tc.confirm_moving) & (in_image >= tc.confirm_moving)
                & (moved >= tc.confirm_straightness * self.path) & (self.clutter <= MOVER_MAX_STATIC))

    def _add_clutter(self, rows: np.ndarray, labels: np.ndarray) -> None:
        """Fold decided static-clutter labels into the tracks' means: a plain mean while 1/n (n
        labels so far) exceeds ``memory``, then a running one with weight ``memory``."""
        ok = ~np.isnan(labels)
        rows, labels = rows[ok], labels[ok]
        if rows.size and self.clutter_rule is not None:
            self.clutter_known[rows] += 1
            a = np.maximum(self.clutter_rule.memory, 1.0 / self.clutter_known[rows])
            self.clutter[rows] = (1 - a) * self.clutter[rows] + a * labels

    def _birth(self, births: np.ndarray, birth_scores: np.ndarray | None,
               birth_clutter: np.ndarray | None = None, birth_shapes: np.ndarray | None = None,
               birth_density: np.ndarray | None = None, birth_novelty: np.ndarray | None = None) -> None:
        k = len(births)
        if not k:
            return
        first = self._next_id
        self._next_id += k
        new = _blank(k)
        new["ids"] = np.arange(first, first + k, dtype=np.int64)
        new["x"][:, :2] = births
        new["P"][:] = self.P0
        new["hits"][:] = 1
        new["score_sum"][:] = 0.0 if birth_scores is None else np.asarray(birth_scores, dtype=np.float64)
        new["shape_sum"][:] = 0.0 if birth_shapes is None else np.asarray(birth_shapes, dtype=np.float64)
        new["origin"][:] = births
        new["birth_image"][:] = births
        new["history"][:, -1] = births
        new["history_len"][:] = 1
        new["motion_t"][:, -1] = self._frame
        new["motion_xy"][:, -1] = births - self.offset
        new["motion_ok"][:, -1] = True
        self.rule.start(self, new, birth_scores, birth_density, birth_novelty)
        for name in _FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), new[name]]))
        if birth_clutter is not None:
            self._add_clutter(np.arange(len(self) - k, len(self)), np.asarray(birth_clutter, dtype=np.float64))
        for (bx, by), tid in zip(births.tolist(), new["ids"].tolist()):
            self._events.append(TrackEvent(self._frame, EventKind.BORN, tid,
                                           f"track {tid} tentative track started at ({bx:.1f}, {by:.1f})"))

    def states(self) -> list[TrackState]:
        """Snapshot of every live track; position = last reported (measurement when present)."""
        if not len(self):
            return []
        last = self.history[:, -1]
        return [TrackState(*row) for row in zip(
            self.ids.tolist(), *last.T.tolist(), *self.x[:, 2:].T.tolist(), self.confirmed.tolist(),
            self.meeting.tolist(), self.hits.tolist(), self.misses.tolist())]

    def innovations(self) -> dict[int, np.ndarray]:
        """{track_id: innovation (2,)} for the tracks updated this frame."""
        rows = np.nonzero(~np.isnan(self.innovation[:, 0]))[0]
        return {int(self.ids[i]): self.innovation[i].copy() for i in rows}

    def _event(self, kind: EventKind, i: int, message: str) -> None:
        tid = int(self.ids[i])
        self._events.append(TrackEvent(self._frame, kind, tid, f"track {tid} {message}"))
