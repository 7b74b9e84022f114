"""Confirmation rules of :class:`wfviz.tracking.manager.TrackManager` (``tracking.confirm``): the
GEWC paper's hit count (:class:`HitsRule`) and the sequential tests (:class:`SequentialRule`,
:mod:`wfviz.tracking.confirmation`). A rule scores the new tracks (``start``) and decides each
frame which tracks are confirmed and which deleted (``decide``) from the frame's :class:`Evidence`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from wfviz.tracking import confirmation

if TYPE_CHECKING:
    from wfviz.tracking.manager import TrackManager

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
    level; the birth detection counts as a hit in the first gate.

    A confirmed track is also deleted when it turns into static clutter (a track that left its
    target for a fixed object, or a lamp that moved once): Page's CUSUM (E. S. Page,
    "Continuous inspection schemes", Biometrika 41, 1954) of each hit's clutter evidence since
    confirmation, W ← max(0, W − e), reaches ln((1 − α) / β), the level at which the confirmation
    test itself decides "static clutter" (with the default rates 8 unchanged hits in a row;
    a new hit takes 2.3 off W)."""

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
            mgr.static_cusum[m] = np.maximum(mgr.static_cusum[m] - clutter[m], 0.0)
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
        # a confirmed track that turned static: Page's CUSUM of the clutter evidence since
        # confirmation reaches the static-clutter level of the confirmation test
        static = (conf & ~lost & (mgr.static_cusum >= -th.drop - tie) if tc.delete_when_static
                  else np.zeros(n, dtype=bool))
        mgr.static_cusum[confirm] = 0.0
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
        for i in np.nonzero(static)[0].tolist():
            why[i] = (f"deleted as static clutter: its last hits are not new at their place in the scene "
                      f"(not clutter {mgr.clutter_score[i]:.1f}, CUSUM {mgr.static_cusum[i]:.1f})")
        return confirm, drop | lost | static, why


#: ``tracking.confirm`` -> the confirmation rule it selects
CONFIRMATION_RULES: dict[str, type] = {"hits": HitsRule, "sprt": SequentialRule}
