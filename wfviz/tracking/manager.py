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

import numpy as np

from wfviz.config import ClutterConfig, KalmanConfig, TrackingConfig
from wfviz.tracking import confirmation, kalman
from wfviz.tracking.association import Association, Measurements, assign_confirmed_first
from wfviz.tracking.rules import CONFIRMATION_RULES, Evidence, HitsRule, SequentialRule
from wfviz.tracking.tracks import EventKind, Prediction, TrackEvent, TrackState


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
        static_cusum=np.zeros(n),               # since confirmation: Page's CUSUM towards static clutter
        clutter_hits=np.zeros((n, MOTION_HISTORY)),  # its evidence from the last hits, oldest first
        motion_t=np.zeros((n, MOTION_HISTORY)),  # frames of the measured scene positions
        motion_xy=np.zeros((n, MOTION_HISTORY, 2)),  # measured positions, camera motion removed
        motion_ok=np.zeros((n, MOTION_HISTORY), dtype=bool),
        _S_inv=np.zeros((n, 2, 2)),             # inverse innovation covariances (predict)
    )


_FIELDS = tuple(_blank(0))


class TrackManager:
    """Tracks with CV Kalman filters (Zhang Shuai et al. 2018, eqs. 8-14), meeting mode (eq. 15),
    confirmed and deleted by ``rule`` (:data:`CONFIRMATION_RULES`, from ``tracking.confirm``).

    Per-track state lives in arrays indexed like the predictions of the frame: ``ids``,
    ``x`` (N, 4), ``P`` (N, 4, 4), hit/miss counters, flags, the last :data:`HISTORY`
    reported positions and the last three filtered velocities.
    """

    def __init__(self, kcfg: KalmanConfig, tcfg: TrackingConfig, detection_threshold: float = 4.0,
                 clutter_rule: ClutterConfig | None = None) -> None:
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
        self.clutter_rule = clutter_rule  # track rule of the static-clutter labels (None: no clutter stage)
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
               gate_k: np.ndarray | None = None, start: np.ndarray | bool | None = None,
               frame_shape: tuple[int, ...] | None = None) -> list[TrackEvent]:
        """Apply this frame's ``association`` of ``detections``; count misses, confirm, delete,
        start new tracks (:meth:`initiate`; ``start`` as there). Returns the frame's events
        (including the meeting events of :meth:`predict` and those of :meth:`reacquire`).

        ``positions``: {track row: measured (x, y)} for the associated tracks that were measured
        (GEWC: the centroid in the window; a pair left out takes no update but still uses its
        detection); default the detections' positions. ``track_density``: false detections per
        pixel at each track (the sequential rule). ``gate_k``: the threshold (σ) each track's
        gate was searched at (:func:`wfviz.tracking.confirmation.gate_threshold`); where it is
        below the frame's, a hit's false-alarm probability is at least
        ``tracking.gate_false_alarm`` and its significance is scored from there. ``frame_shape``:
        the image's (rows, columns); a coasting track whose position leaves it is deleted.

        Per measured track the rules read its detection's significance, blobness, novelty and
        (with ``clutter_rule``) static-clutter label; a meeting track's label is that of the
        detection nearest its extrapolation."""
        d = detections
        pairs = association.pairs
        if frame_shape is not None:
            self.frame_shape = (int(frame_shape[0]), int(frame_shape[1]))
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
