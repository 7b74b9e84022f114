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
   tracks, hit and miss counting, the confirmation rule (:mod:`wfviz.tracking.rules`: it reads
   the frame's :class:`~wfviz.tracking.decision.Evidence` and returns its
   :class:`~wfviz.tracking.decision.Decisions`), deletions, and births: every detection left
   unused and outside a confirmed gate starts a tentative track (:meth:`TrackManager.initiate`,
   the one place births are decided).

Positions are (x = column, y = row) in pixels. The live tracks are the rows of a
:class:`~wfviz.tracking.table.TrackTable` (struct of arrays); the rule keeps its own statistics
in step with it.
"""

from __future__ import annotations

import numpy as np

from wfviz.config import ClutterConfig, KalmanConfig, TrackingConfig
from wfviz.tracking import confirmation, kalman
from wfviz.tracking.association import Association, Gates, Measurements, assign_in_gates, claimed, nearest
from wfviz.tracking.decision import Decision, Evidence, Verdicts
from wfviz.tracking.rules import CONFIRMATION_RULES, Rule
from wfviz.tracking.table import TrackTable
from wfviz.tracking.tracks import EventKind, Prediction, TrackEvent, TrackState
from wfviz.tracking.subthreshold import NullReads

TEST_MEMORY = 0.9  # weight of the past in the running mean of tentative tracks tested per frame


def gone_reason(manager: TrackManager, i: int, xy: np.ndarray) -> str:
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


class TrackManager:
    """Tracks with CV Kalman filters (Zhang Shuai et al. 2018, eqs. 8-14), meeting mode (eq. 15),
    confirmed and deleted by ``rule`` (:data:`~wfviz.tracking.rules.CONFIRMATION_RULES`, from
    ``tracking.confirm``).

    ``tracks``: the live tracks (:class:`~wfviz.tracking.table.TrackTable`), rows indexed like
    the frame's predictions; ``rule.stats``: the rule's statistics, rows alike."""

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
        self.tracks = TrackTable.blank(0)
        self._preds: list[Prediction] | None = None
        self._gates = Gates.empty()
        self.offset = np.zeros(2)  # accumulated camera shift: scene point s is at s + offset
        self.registration_error = 0.0  # px, standard error of this frame's camera shift (follow_camera)
        self.frame_shape: tuple[int, int] | None = None  # tracks that leave it are deleted
        self.tested_per_frame: float | None = None  # tentative tracks, running mean (TEST_MEMORY)
        self.thresholds: confirmation.Thresholds | None = None  # this frame's (confirm = "sprt")
        self.detection_threshold = detection_threshold
        self.rule: Rule = CONFIRMATION_RULES[tcfg.confirm](tcfg, detection_threshold, clutter_rule)
        #: the last update's decisions (:class:`~wfviz.tracking.decision.Verdicts`; None before one)
        self.verdicts: Verdicts | None = None
        #: per detection of the last update: the id of the track that took it (paired) or started
        #: from it, -1: neither (inside a confirmed gate, or not allowed to start a track)
        self.detection_tracks = np.zeros(0, dtype=np.int64)

    @property
    def clutter_rule(self) -> ClutterConfig | None:
        """The track rule of the static-clutter labels (None: no clutter stage); the rule's."""
        return self.rule.clutter_rule

    @clutter_rule.setter
    def clutter_rule(self, rule: ClutterConfig | None) -> None:
        self.rule.clutter_rule = rule

    def __len__(self) -> int:
        return int(self.tracks.ids.size)

    @property
    def track_ids(self) -> list[int]:
        """Ids of the live tracks, in row order."""
        return self.tracks.ids.tolist()

    @property
    def confirmed_ids(self) -> list[int]:
        """Ids of the confirmed live tracks, in row order."""
        return self.tracks.confirmed_ids

    def velocity(self, i: int) -> np.ndarray:
        """Filtered velocity (vx, vy) of the track in row ``i``."""
        return self.tracks.x[i, 2:].copy()

    def restart(self, track_id: int, state: np.ndarray) -> None:
        """Restart a track's filter at ``state`` (x, y, vx, vy) with P = P₀."""
        t = self.tracks
        rows = np.nonzero(t.ids == track_id)[0]
        if rows.size:
            t.x[rows[0]] = state
            t.P[rows[0]] = self.P0

    def shift(self, dx: float, dy: float) -> None:
        """Move every track (state, birth point and history) by the camera's image motion."""
        d = np.array([dx, dy])
        self.tracks.shift(d)
        self.offset += d

    def follow_camera(self, shift: tuple[float, float], error: float, lost: bool) -> None:
        """This frame's camera motion (:class:`~wfviz.stages.registration.CameraState`): the
        tracks move by its ``shift``; the scene positions measured now carry its standard
        ``error`` (px; NaN: not measured, taken as 0) into the motion test; ``lost`` (the camera
        has moved and this frame's motion is unknown): :meth:`motion_unknown`."""
        self.shift(*shift)
        self.registration_error = float(error) if np.isfinite(error) else 0.0
        if lost:
            self.motion_unknown()

    def motion_unknown(self) -> None:
        """The camera moves and its shift in this frame is unknown: the scene positions measured
        so far are in another frame of reference than those from now on, so no track's motion
        test compares across it (each track's series of scene positions starts again)."""
        self.tracks.motion_ok[:] = False

    # -- predict --------------------------------------------------------------------------
    def _meeting_state(self, i: int) -> np.ndarray:
        """Next state of track ``i`` in meeting mode: linear extrapolation of its own motion."""
        t = self.tracks
        last = t.history[i, -1]
        if self.tcfg.meeting_velocity == "kalman":  # the paper's prose: velocities at k-1..k-3
            k = int(t.velocities_len[i])
            v = np.mean(t.velocities[i, 3 - k:], axis=0) if k else t.x[i, 2:]
            ex, ey = last[0] + v[0], last[1] + v[1]
        else:
            ex, ey = extrapolate(t.history[i])
        return np.array([ex, ey, ex - last[0], ey - last[1]])

    def predict(self, frame: int) -> list[Prediction]:
        """Advance every track to ``frame``; tracks closer than the safety distance meet."""
        self._frame, self._events = frame, []
        self._preds = None
        if not len(self):
            self._gates = Gates.empty()
            return []
        t = self.tracks
        t.x, t.P = kalman.predict(t.x, t.P, self.model)
        for i in np.nonzero(t.meeting & (t.history_len >= 3))[0].tolist():
            t.x[i] = self._meeting_state(i)
        self._update_meeting()
        S = kalman.innovation_covariance(t.P, self.model)
        half = self._gate_half_sizes(S)
        xy = t.x[:, :2].copy()
        trace = np.trace(t.P, axis1=1, axis2=2)
        preds = [Prediction(*row) for row in zip(
            t.ids.tolist(), *xy.T.tolist(), *half.T.tolist(), t.confirmed.tolist(),
            t.meeting.tolist(), trace.tolist())]
        self._preds = preds
        self._gates = Gates(xy, half, t.confirmed.copy(), t.meeting.copy(), np.linalg.inv(S))
        return preds

    def _gate_half_sizes(self, S: np.ndarray) -> np.ndarray:
        """Gate half sizes (N, 2): gate_sigma * sqrt(S_ii), clipped to [gate_min, gate_max]."""
        return np.clip(self.kcfg.gate_sigma * np.sqrt(S[:, [0, 1], [0, 1]]),
                       self.kcfg.gate_min, self.kcfg.gate_max)

    def _update_meeting(self) -> None:
        t = self.tracks
        conf = np.nonzero(t.confirmed)[0]
        close = np.zeros(len(self), dtype=bool)
        if conf.size > 1:
            pos = t.x[conf, :2]
            diff = pos[:, None, :] - pos[None, :, :]
            near = np.hypot(diff[..., 0], diff[..., 1]) < self.tcfg.safety_distance
            if self.tcfg.meeting_overlap:  # gates that overlap may share one merged blob
                half = self._gate_half_sizes(kalman.innovation_covariance(t.P[conf], self.model))
                near &= (np.abs(diff) <= half[:, None, :] + half[None, :, :]).all(axis=2)
            np.fill_diagonal(near, False)
            close[conf] = near.any(axis=1)
        for i in conf[close[conf] | t.meeting[conf]]:
            if close[i] and not t.meeting[i] and t.history_len[i] >= 3 and t.meet_again[i]:
                t.meeting[i], t.meeting_frames[i] = True, 0
                t.x[i] = self._meeting_state(i)
                self._event(EventKind.MEETING_ON, i, "within the safety distance: Kalman updates stop, "
                                             "linear extrapolation (eq. 15)")
            elif t.meeting[i]:
                t.meeting_frames[i] += 1
                expired = t.meeting_frames[i] > self.tcfg.max_meeting_frames
                if not close[i] or expired:
                    t.meeting[i] = False
                    t.meet_again[i] = False  # until its next measurement
                    t.P[i] = self.P0  # re-initialise the filter at the extrapolated state
                    why = "meeting lasted too long" if expired else "separated"
                    self._event(EventKind.MEETING_OFF, i, f"{why}: filter re-initialised")

    def _gates_of(self, preds: list[Prediction]) -> Gates:
        """The gates of ``preds`` (predict's own: cached)."""
        return self._gates if preds is self._preds else Gates.of(preds, self._gates.S_inv)

    # -- associate ------------------------------------------------------------------------
    def gate(self, preds: list[Prediction], xy: np.ndarray) -> Association:
        """The gates of ``preds`` over detections ``xy`` without pairs: each track's nearest
        detection (within 2 ``gate_min``: a meeting track's evidence and static-clutter label)
        and the detections claimed by confirmed gates (for a tracker that pairs by its own cost,
        :meth:`Association.with_pairs`)."""
        near = np.full(len(self), -1, dtype=np.int64)
        if not preds or len(xy) == 0:
            return Association({}, near, np.zeros(len(xy), dtype=bool))
        g = self._gates_of(preds)
        if len(preds) == len(self):
            near = nearest(g, xy, 2.0 * self.kcfg.gate_min)
        return Association({}, near, claimed(g, xy))

    def associate(self, preds: list[Prediction], xy: np.ndarray) -> Association:
        """Global assignment of detections ``xy`` to tracks (:func:`assign_in_gates`: inside the
        gates, by Mahalanobis distance, confirmed tracks first, meeting tracks take none)."""
        gated = self.gate(preds, xy)
        if not preds or len(xy) == 0:
            return gated
        return gated.with_pairs(assign_in_gates(self._gates_of(preds), xy))

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
        g = self._gates_of(preds)
        centres, confirmed, meeting = g.centre, g.confirmed, g.meeting
        lost = np.array([i for i in np.nonzero(confirmed & ~meeting)[0].tolist() if i not in pairs],
                        dtype=np.int64)
        free = np.asarray(eligible, dtype=bool) & ~association.claimed
        free[list(pairs.values())] = False
        cand = np.nonzero(free)[0]
        if lost.size == 0 or cand.size == 0:
            return association
        d = np.hypot(*(xy[None, cand, :] - centres[lost, None, :]).transpose(2, 0, 1))
        out = dict(pairs)
        t = self.tracks
        for flat in np.argsort(d, axis=None).tolist():
            r, k = divmod(flat, cand.size)
            if d[r, k] > radius:
                break
            i, j = int(lost[r]), int(cand[k])
            if i in out or j in out.values():
                continue
            out[i] = j
            self.restart(int(t.ids[i]), np.concatenate([xy[j], t.x[i, 2:]]))
            self._event(EventKind.REACQUIRED, i, f"reacquired at ({xy[j, 0]:.1f}, {xy[j, 1]:.1f}), "
                                         f"{d[r, k]:.1f} px from its prediction (nothing in its gate)")
        return association.with_pairs(out)

    # -- initiate -------------------------------------------------------------------------
    @staticmethod
    def initiate(association: Association, start: np.ndarray | bool | None = None,
                 refused: np.ndarray | None = None) -> np.ndarray:
        """The detections that start tentative tracks this frame (indices). By default (None)
        the unused ones outside every confirmed gate. ``start`` False: none (fusion between its
        global detections); a mask (or True): the unused detections it allows, for a caller with
        its own start rule. ``refused`` (a mask): detections that start none whatever ``start``
        says (line-like ones, :meth:`Measurements.line_like`)."""
        if start is False:
            return np.zeros(0, dtype=np.int64)
        born = ~association.used()
        born &= ~association.claimed if start is None else np.asarray(start, dtype=bool)
        if refused is not None:
            born &= ~np.asarray(refused, dtype=bool)
        return np.nonzero(born)[0]

    # -- update ---------------------------------------------------------------------------
    def update(self, association: Association, detections: Measurements,
               positions: dict[int, tuple[float, float]] | None = None, track_density: np.ndarray | None = None,
               gate_k: np.ndarray | None = None, start: np.ndarray | bool | None = None,
               frame_shape: tuple[int, ...] | None = None,
               track_clutter: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
               track_read: np.ndarray | None = None, read_null: NullReads | None = None) -> list[TrackEvent]:
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
        ``track_clutter``: the clutter map's counts and exposures about each track and this frame's count in its gate
        (:class:`~wfviz.tracking.clutter_map.ClutterMap`; the sequential rule's static prior).
        ``track_read``: the change significance read at each track's prediction and the null of
        such reads ``read_null`` (:mod:`wfviz.tracking.subthreshold`; the sequential rule scores
        a miss's read).

        Per measured track the rules read its detection's significance (a track is confirmed at
        ``confirm_hits`` hits when their mean also reaches ``confirm_significance``; 0 = hits
        only, as in the paper), blobness (:func:`wfviz.stages.detection.blobness`; their mean must
        reach ``confirm_blobness``, 0 = not used), novelty and, with ``clutter_rule``
        (:class:`~wfviz.config.ClutterConfig`), static-clutter label (:mod:`wfviz.stages.clutter`;
        1 static, 0 not, NaN undecided: a track needs ``min_known`` decided labels with a mean
        ≤ ``max_static`` to be confirmed, unless ``wait`` is off, and a confirmed track above
        ``delete_static`` is deleted); a meeting track's label is that of the detection nearest
        its extrapolation. A line-like detection (:meth:`Measurements.line_like`: part of a road,
        a wire, an edge) starts no track, and a tentative track whose hit is line-like is not
        confirmed in that frame (the rule's test "hit not line-like")."""
        d = detections
        pairs = association.pairs
        owner = np.full(len(d), -1, dtype=np.int64)
        if pairs:
            owner[list(pairs.values())] = self.tracks.ids[list(pairs)]
        if frame_shape is not None:
            self.frame_shape = (int(frame_shape[0]), int(frame_shape[1]))
        if positions is None:
            positions = {i: (float(d.xy[j, 0]), float(d.xy[j, 1])) for i, j in pairs.items()}
        rows = np.array(sorted(positions), dtype=np.int64)
        det = np.array([pairs[i] for i in rows.tolist()], dtype=np.int64)
        z = np.array([positions[i] for i in rows.tolist()], dtype=np.float64).reshape(-1, 2)
        novelty = d.novelty if d.novelty is not None else np.full(len(d), np.nan)
        labels = None
        if d.clutter is not None:  # meeting tracks: the detection nearest their extrapolation
            labels = {int(i): float(d.clutter[j]) for i, j in enumerate(association.nearest.tolist())
                      if j >= 0 and self.tracks.meeting[i]}
            labels.update({i: float(d.clutter[pairs[i]]) for i in positions})
        born = self.initiate(association, start, d.line_like())
        births = Measurements(
            np.asarray(d.xy[born], dtype=np.float64).reshape(-1, 2),
            significance=None if d.significance is None else d.significance[born],
            blobness=None if d.blobness is None else d.blobness[born], novelty=novelty[born],
            clutter=None if d.clutter is None else d.clutter[born],
            density=None if d.density is None else d.density[born],
            size=None if d.size is None else d.size[born])
        n = len(self)
        significance = np.full(n, np.nan)  # per track row: its hit's (NaN: none)
        hit_novelty = np.full(n, np.nan)
        if d.significance is not None:
            significance[rows] = d.significance[det]
        hit_novelty[rows] = novelty[det]
        hit_linearity = None
        if d.linearity is not None:
            hit_linearity = np.full(n, np.nan)
            hit_linearity[rows] = np.asarray(d.linearity, dtype=np.float64)[det]
        self._measure(rows, z, None if d.significance is None else d.significance[det],
                      None if d.blobness is None else d.blobness[det])
        if labels:  # measured tracks, and meeting tracks with a detection near them
            lrows = np.array(sorted(labels), dtype=np.int64)
            self._add_clutter(lrows, np.array([labels[i] for i in lrows.tolist()]))
        clutter = None
        if labels is not None:
            clutter = np.full(n, np.nan)
            clutter[list(labels)] = list(labels.values())
        self._decide(rows, z, association.nearest, clutter, track_density, significance, hit_novelty, gate_k,
                     track_clutter, hit_linearity, d.max_linearity,
                     None if d.size is None else np.asarray(d.size, dtype=np.float64)[det], track_read, read_null)
        tested = int((~self.tracks.confirmed).sum()) + len(births)
        b = self.tested_per_frame
        self.tested_per_frame = tested if b is None else TEST_MEMORY * b + (1 - TEST_MEMORY) * tested
        owner[born] = self._next_id + np.arange(len(born))
        self.detection_tracks = owner
        self._birth(births)
        return self._events

    def _measure(self, rows: np.ndarray, z: np.ndarray, significance: np.ndarray | None,
                 blobness: np.ndarray | None) -> None:
        """Kalman updates (eqs. 12-14) of the tracks ``rows`` with measurements ``z``; their hit
        counts and sums of significance and blobness (None: 0)."""
        t = self.tracks
        t.innovation[:] = np.nan
        if not rows.size:
            return
        x, P, nu = kalman.update(t.x[rows], t.P[rows], z, self.model)
        t.x[rows], t.P[rows], t.innovation[rows] = x, P, nu
        t.velocities[rows, :-1] = t.velocities[rows, 1:]
        t.velocities[rows, -1] = x[:, 2:]
        t.velocities_len[rows] = np.minimum(t.velocities_len[rows] + 1, 3)
        t.hits[rows] += 1
        t.misses[rows] = 0
        t.meet_again[rows] = True
        t.score_sum[rows] += (np.zeros(rows.size) if significance is None
                              else np.asarray(significance, dtype=np.float64))
        t.shape_sum[rows] += np.zeros(rows.size) if blobness is None else np.asarray(blobness, dtype=np.float64)

    def _decide(self, rows: np.ndarray, z: np.ndarray, nearest: np.ndarray, clutter: np.ndarray | None,
                density: np.ndarray | None, significance: np.ndarray, novelty: np.ndarray,
                gate_k: np.ndarray | None,
                track_clutter: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                linearity: np.ndarray | None = None, max_linearity: float = 1.0,
                size: np.ndarray | None = None, read: np.ndarray | None = None,
                read_null: NullReads | None = None) -> None:
        """Report, count misses, let the rule decide (the :class:`Evidence` of the measured
        ``rows`` with measurements ``z``, their components' sizes ``size``), end the tracks it
        deletes and those :meth:`_gone`."""
        t = self.tracks
        n = len(self)
        measured = np.zeros(n, dtype=bool)
        measured[rows] = True
        # history: the measurement, or the (coasting / extrapolated) state
        reported = t.x[:, :2].copy()
        reported[rows] = z
        t.path += np.hypot(*(reported - t.history[:, -1]).T)
        t.gapless &= measured
        t.push_history(np.arange(n), reported)
        missed = ~measured & ~t.meeting
        if self.tcfg.meeting_misses:  # a meeting track with nothing in its gate has lost its target
            missed |= t.meeting & (nearest < 0)
            t.misses[t.meeting & (nearest >= 0)] = 0
        t.misses[missed] += 1
        moved = np.hypot(reported[:, 0] - t.origin[:, 0], reported[:, 1] - t.origin[:, 1])
        t.push_motion(rows, self._frame, z - self.offset, self.registration_error, size)
        g = self._gates
        half = g.half if len(g.half) == n else np.full((n, 2), self.kcfg.gate_max)
        ids, was_confirmed = t.ids, t.confirmed.copy()
        out = self.rule.decide(t, Evidence(measured, missed, moved, reported, clutter, density, significance,
                                           novelty, gate_k, half, g.S_inv, nearest, self.tested_per_frame,
                                           clutter_map=track_clutter, linearity=linearity,
                                           max_linearity=max_linearity, read=read, read_null=read_null))
        if out.thresholds is not None:
            self.thresholds = out.thresholds
        confirm, delete, why = out.confirm, out.delete, out.why
        gone = self._gone(measured, reported) & ~delete
        messages: dict[int, str] = {}
        for i in np.nonzero(confirm | delete | gone)[0].tolist():
            if gone[i]:
                messages[i] = self._event(EventKind.DELETED, i, f"deleted: {gone_reason(self, i, reported[i])} "
                                          f"({'confirmed' if t.confirmed[i] else 'tentative'}, "
                                          f"{t.hits[i]} hits)")
            elif confirm[i]:
                t.confirmed[i] = True
                messages[i] = self._event(EventKind.CONFIRMED, i, f"confirmed after {t.hits[i]} hits{why[i]}")
            else:
                messages[i] = self._event(EventKind.DELETED, i, why[i] or (
                    f"deleted after {t.misses[i]} consecutive misses "
                    f"({'confirmed' if t.confirmed[i] else 'tentative'}, {t.hits[i]} hits)"))
        self.verdicts = Verdicts(ids, was_confirmed, out, gone, messages, self.tcfg.confirm,
                                 self.rule.min_hits(self.thresholds))
        ended = delete | gone
        if ended.any():
            keep = ~ended
            t.keep(keep)
            self.rule.keep(keep)

    def _gone(self, measured: np.ndarray, reported: np.ndarray) -> np.ndarray:
        """Coasting tracks (meeting mode included) whose position left the image, or (not in
        meeting mode: its extrapolation does not use the filter's covariance, which is reset when
        the meeting ends) whose position uncertainty (``gate_sigma`` standard deviations)
        outgrew ``kalman.coast_limit``."""
        t = self.tracks
        n = len(self)
        out = np.zeros(n, dtype=bool)
        if self.frame_shape is not None:
            h, w = self.frame_shape
            out = ((reported[:, 0] < -0.5) | (reported[:, 0] > w - 0.5)
                   | (reported[:, 1] < -0.5) | (reported[:, 1] > h - 0.5))
        spread = self.kcfg.gate_sigma * np.sqrt(np.maximum(t.P[:, 0, 0], t.P[:, 1, 1]))
        return ~measured & (out | ((spread > self.kcfg.coast_limit) & ~t.meeting))

    def _add_clutter(self, rows: np.ndarray, labels: np.ndarray) -> None:
        """Fold decided static-clutter labels into the tracks' means: a plain mean while 1/n (n
        labels so far) exceeds ``memory``, then a running one with weight ``memory``."""
        ok = ~np.isnan(labels)
        rows, labels = rows[ok], labels[ok]
        rule = self.clutter_rule
        if rows.size and rule is not None:
            t = self.tracks
            t.clutter_known[rows] += 1
            a = np.maximum(rule.memory, 1.0 / t.clutter_known[rows])
            t.clutter[rows] = (1 - a) * t.clutter[rows] + a * labels

    def _birth(self, births: Measurements) -> None:
        """Start a tentative track at each of ``births`` (its first hit), and the rule's statistics."""
        k = len(births)
        if not k:
            return
        first = self._next_id
        self._next_id += k
        xy = births.xy
        new = TrackTable.blank(k)
        new.ids = np.arange(first, first + k, dtype=np.int64)
        new.x[:, :2] = xy
        new.P[:] = self.P0
        new.hits[:] = 1
        new.score_sum[:] = 0.0 if births.significance is None else np.asarray(births.significance, dtype=np.float64)
        new.shape_sum[:] = 0.0 if births.blobness is None else np.asarray(births.blobness, dtype=np.float64)
        new.origin[:] = xy
        new.birth_image[:] = xy
        new.history[:, -1] = xy
        new.history_len[:] = 1
        new.motion_t[:, -1] = self._frame
        new.motion_xy[:, -1] = xy - self.offset
        new.motion_ok[:, -1] = True
        new.motion_reg[:, -1] = self.registration_error
        if births.size is not None:
            new.motion_wh[:, -1] = births.size
        self.rule.start(births, self._birth_half)
        self.tracks.append(new)
        if births.clutter is not None:
            self._add_clutter(np.arange(len(self) - k, len(self)), np.asarray(births.clutter, dtype=np.float64))
        for (bx, by), tid in zip(xy.tolist(), new.ids.tolist()):
            self._events.append(TrackEvent(self._frame, EventKind.BORN, tid,
                                           f"track {tid} tentative track started at ({bx:.1f}, {by:.1f})"))

    # -- read -----------------------------------------------------------------------------
    def states(self) -> list[TrackState]:
        """Snapshot of every live track; position = last reported (measurement when present)."""
        if not len(self):
            return []
        t = self.tracks
        last = t.history[:, -1]
        return [TrackState(*row) for row in zip(
            t.ids.tolist(), *last.T.tolist(), *t.x[:, 2:].T.tolist(), t.confirmed.tolist(),
            t.meeting.tolist(), t.hits.tolist(), t.misses.tolist())]

    def innovations(self) -> dict[int, np.ndarray]:
        """{track_id: innovation (2,)} for the tracks updated this frame."""
        t = self.tracks
        rows = np.nonzero(~np.isnan(t.innovation[:, 0]))[0]
        return {int(t.ids[i]): t.innovation[i].copy() for i in rows}

    @property
    def decisions(self) -> dict[int, Decision]:
        """{track_id: :class:`Decision`} of the last :meth:`update`, for every track it decided on
        (those it deleted included): verdict, deciding test, each test's value and level, reason."""
        return {} if self.verdicts is None else self.verdicts.all()

    def decision(self, track_id: int) -> Decision | None:
        """The last :meth:`update`'s :class:`Decision` on track ``track_id`` (None: none)."""
        return None if self.verdicts is None else self.verdicts.decision(track_id)

    def _event(self, kind: EventKind, i: int, message: str) -> str:
        """Record an event of the track in row ``i``; returns its message."""
        tid = int(self.tracks.ids[i])
        text = f"track {tid} {message}"
        self._events.append(TrackEvent(self._frame, kind, tid, text))
        return text
