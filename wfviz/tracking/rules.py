"""Confirmation rules of the track manager (``tracking.confirm``): the GEWC paper's hit count
(:class:`HitsRule`) and the sequential tests (:class:`SequentialRule`,
:mod:`wfviz.tracking.confirmation`).

A rule (:class:`Rule`) owns the columns of its own statistics (:attr:`Rule.stats`, one row per
track, kept in step with the track table by the manager); it starts them for the new tracks
(:meth:`Rule.start`) and decides each frame from the :class:`~wfviz.tracking.decision.Evidence` and
the :class:`~wfviz.tracking.table.TrackTable` which tracks are confirmed and which deleted
(:meth:`Rule.decide`), returning :class:`~wfviz.tracking.decision.Decisions` with every test's
values and levels. A new rule is one subclass here and one entry in :data:`CONFIRMATION_RULES`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wfviz.config import ClutterConfig, TrackingConfig
from wfviz.tracking import confirmation, subthreshold
from wfviz.tracking.association import Measurements
from wfviz.tracking.clutter_map import static_rate
from wfviz.tracking.decision import Decisions, Evidence, Statistic
from wfviz.tracking.table import MOTION_HISTORY, Columns, TrackTable

STEADY_PARTS = 4  # confirmation.motion: parts of the history between which steady progress is asked for (chosen on real half A)
MOTION_MIN_POSITIONS = 3  # confirmation.motion: steady progress needs a position per part (at least 3 parts)
SLIDE_SPEED = 0.3  # px/frame: the slide test judges tracks this fast at least (a hovering target's way has no direction)
STEADY_Z = 4.0  # steady progress: standard errors of the parts' medians that count as progress (chosen on real half A)
MOVER_MAX_STATIC = 0.25  # tracking.confirm_moving: a mover's mean static-clutter label at most this


class Rule:
    """A confirmation rule: its statistics (columns of type :attr:`Stats`, none by default),
    started per new track by :meth:`start` and read and updated by :meth:`decide`.

    ``tcfg``: the tracking section; ``detection_threshold``: the frame's detection threshold (σ);
    ``clutter_rule``: the track rule of the static-clutter labels (None: no clutter stage)."""

    Stats: ClassVar[type[Columns]] = Columns

    def __init__(self, tcfg: TrackingConfig, detection_threshold: float = 4.0,
                 clutter_rule: ClutterConfig | None = None) -> None:
        self.tcfg = tcfg
        self.detection_threshold = detection_threshold
        self.clutter_rule = clutter_rule
        self.stats = self.Stats.blank(0)

    def start(self, births: Measurements, half: np.ndarray) -> None:
        """Append the rows of the new tracks started by ``births`` (their first gate's half sizes
        ``half``, (1, 2)) to :attr:`stats`: blank rows unless a rule scores its births."""
        self.stats.append(self.Stats.blank(len(births)))

    def keep(self, rows: np.ndarray) -> None:
        """Keep the statistics of the tracks the manager keeps (mask ``rows``)."""
        self.stats.keep(rows)

    def decide(self, tracks: TrackTable, e: Evidence) -> Decisions:
        """This frame's decisions on ``tracks`` (already updated with this frame's hits)."""
        raise NotImplementedError

    def min_hits(self, levels: confirmation.Thresholds | None) -> int:
        """The fewest hits in which any track can be confirmed under this rule at ``levels``
        (the sequential test's of this frame; None: not known yet): a tentative track with fewer
        cannot have been confirmed yet (confirmation latency, not a test holding it back)."""
        return 1


def _measured(e: Evidence) -> Statistic:
    """The test every rule makes before confirming: the track was measured this frame."""
    return Statistic("hit this frame", e.measured.astype(np.float64), 1.0, ">=", e.measured)


def _not_line(e: Evidence) -> Statistic | None:
    """The test every rule makes before confirming when detections' linearity is measured: this
    frame's hit is not part of a line or an edge (its linearity at most ``max_linearity``; NaN:
    no hit, not tested). None: not measured."""
    if e.linearity is None:
        return None
    line = e.line_hits()
    return Statistic("hit not line-like: linearity", np.asarray(e.linearity, dtype=np.float64).copy(),
                     e.max_linearity, "<=", ~line)


class HitsRule(Rule):
    """The GEWC paper's rule (Zhang Shuai et al. 2018; ``tracking.confirm = "hits"``): a track is
    confirmed at ``confirm_hits`` hits, and with the optional tests not in the paper (mean
    significance, blobness, displacement, movers, static clutter), deleted after
    ``max_misses`` consecutive misses. Births score nothing."""

    def mover(self, tracks: TrackTable, reported: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """Tracks that count as movers under ``tracking.confirm_moving`` (not in the paper):
        updated in every frame since birth, ``confirm_moving`` px or more from the birth point
        both in the scene (``moved``; camera motion removed) and in the image, along a path at
        most 1 / ``confirm_straightness`` times that long, and (with the static-clutter stage)
        with a mean static label of at most ``MOVER_MAX_STATIC``: the clutter stage agrees."""
        tc = self.tcfg
        if tc.confirm_moving <= 0:
            return np.zeros(len(tracks), dtype=bool)
        in_image = np.hypot(*(reported - tracks.birth_image).T)
        return (tracks.gapless & (moved >= tc.confirm_moving) & (in_image >= tc.confirm_moving)
                & (moved >= tc.confirm_straightness * tracks.path) & (tracks.clutter <= MOVER_MAX_STATIC))

    def min_hits(self, levels: confirmation.Thresholds | None) -> int:
        """``confirm_hits`` (and, when the clutter rule waits for them, its ``min_known``
        decided labels, one per hit at most)."""
        rule = self.clutter_rule
        wait = rule.min_known if rule is not None and rule.wait else 0
        return max(self.tcfg.confirm_hits, wait, 1)

    def decide(self, tracks: TrackTable, e: Evidence) -> Decisions:
        """Confirm and delete; ``why``: the confirmation's reasons, or a deletion's whole message
        ("" for the usual one)."""
        measured, missed, moved, reported, clutter = e.measured, e.missed, e.moved, e.reported, e.clutter
        tc = self.tcfg
        n = len(tracks)
        need = tc.confirm_significance
        mean_score = tracks.score_sum / np.maximum(tracks.hits, 1)
        mean_shape = tracks.shape_sum / np.maximum(tracks.hits, 1)
        mover = self.mover(tracks, reported, moved)
        significant = ((need <= 0) | (mean_score >= need)
                       | (mover & (mean_score >= tc.confirm_moving_significance)))
        confirm = (measured & ~tracks.confirmed & (tracks.hits >= tc.confirm_hits)
                   & significant & (moved >= tc.min_displacement)
                   & ((tc.confirm_blobness <= 0) | (mean_shape >= tc.confirm_blobness)))
        delete = missed & (tracks.misses >= tc.max_misses)
        hits = tracks.hits.astype(np.float64)
        stats = [_measured(e), Statistic("hits", hits, tc.confirm_hits, ">=", hits >= tc.confirm_hits)]
        not_line = _not_line(e)
        if not_line is not None:
            confirm &= not_line.holds
            stats.append(not_line)
        if need > 0:
            level = np.where(mover, min(need, tc.confirm_moving_significance), need)
            stats.append(Statistic("mean significance", mean_score, level, ">=", significant))
        if tc.confirm_blobness > 0:
            stats.append(Statistic("mean blobness", mean_shape, tc.confirm_blobness, ">=",
                                   mean_shape >= tc.confirm_blobness))
        if tc.min_displacement > 0:
            stats.append(Statistic("displacement", moved, tc.min_displacement, ">=",
                                   moved >= tc.min_displacement, unit="px"))
        stats.append(Statistic("misses", tracks.misses.astype(np.float64), tc.max_misses, ">=",
                               delete.copy(), deletes=True))
        static = np.zeros(n, dtype=bool)
        if clutter is not None and self.clutter_rule is not None:
            rule = self.clutter_rule
            judged = tracks.clutter_known >= rule.min_known
            static = judged & (tracks.clutter > rule.max_static)
            labels = tracks.clutter.copy()
            stats.append(Statistic("mean static label", labels, rule.max_static, "<=", ~static))
            if rule.wait:
                stats.append(Statistic("decided static labels", tracks.clutter_known.astype(np.float64),
                                       rule.min_known, ">=", judged))
            confirm &= ~static & (judged | (not rule.wait))
            static &= tracks.confirmed & ~delete & (tracks.clutter > rule.delete_static)
            delete |= static
            stats.append(Statistic("static clutter: mean static label", labels,
                                   np.where(tracks.confirmed, rule.delete_static, np.inf), ">", static.copy(),
                                   deletes=True))
        why = [""] * n
        for i in np.nonzero(confirm | static)[0].tolist():
            if static[i]:
                why[i] = (f"deleted as static clutter (fixed in the scene among many detections: "
                          f"mean static label {tracks.clutter[i]:.2f})")
                confirm[i] = False
                continue
            w = f", mean significance {mean_score[i]:.1f}" if need > 0 else ""
            if need > 0 and mean_score[i] < need:
                w += f" (a mover: {moved[i]:.1f} px in a straight line since birth)"
            w += f", mean blobness {mean_shape[i]:.2f}" if tc.confirm_blobness > 0 else ""
            w += f", moved {moved[i]:.1f} px" if tc.min_displacement > 0 else ""
            why[i] = w
        return Decisions(confirm, delete, why, tuple(stats))


@dataclass(eq=False)
class SequentialStats(Columns):
    """The statistics of :class:`SequentialRule`, one row per track."""

    score: np.ndarray          #: (N,) sequential test against noise (confirmation), nats
    clutter_score: np.ndarray  #: (N,) test against static clutter: sum of ``clutter_hits``
    static_cusum: np.ndarray   #: (N,) since confirmation: Page's CUSUM towards static clutter
    clutter_hits: np.ndarray   #: (N, MOTION_HISTORY) clutter evidence of the last hits, oldest first
    own_static: np.ndarray     #: (N,) persistent unexplained detections in its gates (clutter map)

    @classmethod
    def blank(cls, n: int) -> SequentialStats:
        """``n`` rows of zeros."""
        return cls(score=np.zeros(n), clutter_score=np.zeros(n), static_cusum=np.zeros(n),
                   clutter_hits=np.zeros((n, MOTION_HISTORY)), own_static=np.zeros(n))


def static_prior(count: np.ndarray, exposure: np.ndarray, own: np.ndarray) -> np.ndarray:
    """Probability that a persistent point is static clutter at its place, from the clutter map's
    ``count`` and ``exposure`` about it (:meth:`~wfviz.tracking.clutter_map.ClutterMap.at`):
    ``1 - exp(-r)`` with ``r`` the rate of persistent unexplained detections there per frame
    (:func:`~wfviz.tracking.clutter_map.static_rate`) without the track's ``own`` (those in its
    gates, forgotten alike): the chance that its neighbourhood produced one in a frame."""
    return -np.expm1(-static_rate(np.maximum(count - own, 0.0), exposure))


def least_static_prior(tc: TrackingConfig) -> float:
    """The least :func:`static_prior` the clutter map can give anywhere: no persistent detection
    about a place searched in every frame of its memory (``clutter_memory``; each of the 3 × 3
    cells' exposure then tends to it)."""
    exposure = 9.0 * tc.clutter_memory
    return float(static_prior(np.zeros(1), np.full(1, exposure), np.zeros(1))[0])


def static_levels(th: confirmation.Thresholds, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levels of the two tests against static clutter at a place whose static-clutter prior is
    ``prior`` (:func:`static_prior`): the false-confirmation rate α is what the tests must keep
    a static point to, and the prior already keeps it to ``prior``, so the tests need only
    α / prior more: "not clutter" (Wald's test, nats) ``confirm + ln prior``, the motion T²
    (χ², 2 d.o.f.) ``motion + 2 ln prior``, neither below 0 (0: not needed)."""
    lp = np.log(np.clip(prior, 1e-300, 1.0))
    return np.maximum(th.confirm + lp, 0.0), np.maximum(th.motion + 2.0 * lp, 0.0)


class SequentialRule(Rule):
    """Wald's sequential tests of :mod:`wfviz.tracking.confirmation` (not in the paper;
    ``tracking.confirm = "sprt"``): ``score`` against noise (hits and misses, where the hits lie
    in the gate, how significant they are) and ``clutter_score`` against static clutter (how new
    the hits are at their place in the scene). A track is confirmed when both reach the
    confirmation level, dropped (tentative) or deleted (confirmed) when ``score`` falls to its
    level; the birth detection counts as a hit in the first gate. A tentative track's line-like
    hit (:meth:`~wfviz.tracking.decision.Evidence.line_hits`) counts as an unchanged one in the
    test against static clutter, and holds its confirmation back that frame.

    A confirmed track is also deleted when it turns into static clutter (a track that left its
    target for a fixed object, or a lamp that moved once): Page's CUSUM (E. S. Page,
    "Continuous inspection schemes", Biometrika 41, 1954) of each hit's clutter evidence since
    confirmation, W ← max(0, W − e), reaches ln((1 − α) / β), the level at which the confirmation
    test itself decides "static clutter" (with the default rates 4 unchanged hits in a row;
    a new hit takes 2.6 off W)."""

    Stats = SequentialStats
    stats: SequentialStats

    def start(self, births: Measurements, half: np.ndarray) -> None:
        """Initial scores of the new tracks: a hit in the first gate, with its significance and
        its change evidence."""
        k = len(births)
        tc = self.tcfg
        new = SequentialStats.blank(k)
        lam = np.zeros(k) if births.density is None else np.asarray(births.density, dtype=np.float64)
        p_fa = confirmation.gate_false_alarm(lam, np.repeat(half, k, axis=0))
        new.score[:] = confirmation.score_change(np.ones(k, dtype=bool), tc.p_detect, p_fa)
        if births.significance is not None:
            zb = np.asarray(births.significance, dtype=np.float64)
            below = confirmation.multiframe_only(zb, self.detection_threshold)
            new.score += confirmation.amplitude_score(zb, self.detection_threshold)
            new.score[below] = 0.0  # born of the multi-frame stage: no evidence yet (decide)
            if births.novelty is not None:
                nov = np.asarray(births.novelty, dtype=np.float64)
                new.clutter_hits[:, -1] = np.where(below, 0.0, confirmation.change_evidence(
                    nov, self.detection_threshold, tc.static_change_rate, tc.target_change_rate))
                new.clutter_score[:] = new.clutter_hits[:, -1]
        self.stats.append(new)

    def min_hits(self, levels: confirmation.Thresholds | None) -> int:
        """The "not clutter" test gains at most ln(target_change_rate / static_change_rate) per
        hit (a changed hit), so it needs its level / that many hits; the motion test's steady
        progress is 0 with fewer than 3 positions (:func:`wfviz.tracking.confirmation.motion`);
        the persistence test can be passed by the birth hit alone, but a track is decided on
        from the frame after its birth, where it needs a hit: 2 at least. With the clutter map both
        levels are lowest where its static prior is (:func:`least_static_prior`): the motion
        test is asked for everywhere while that prior exceeds α."""
        tc = self.tcfg
        per_hit = math.log(tc.target_change_rate / tc.static_change_rate)
        need = 2
        prior = least_static_prior(tc) if tc.clutter_map else 1.0
        if levels is not None and per_hit > 0:
            level = max(levels.confirm + math.log(prior), 0.0)
            need = max(need, math.ceil(level / per_hit - 1e-9))
        motion_asked = not tc.clutter_map or levels is None or prior > levels.alpha
        if tc.require_motion and tc.min_motion > 0 and motion_asked:
            need = max(need, MOTION_MIN_POSITIONS)
        return need

    def decide(self, tracks: TrackTable, e: Evidence) -> Decisions:
        """Score the frame's hits and misses, confirm, drop, delete; ``thresholds``: this frame's
        levels."""
        measured, density, z, nov, gate_k = e.measured, e.density, e.z, e.novelty, e.gate_k
        tc, s = self.tcfg, self.stats
        n = len(tracks)
        th = confirmation.thresholds(tc.false_tracks_per_1000, e.tested_per_frame or 1.0,
                                    tc.beta, tc.p_lost)
        halves = e.half
        lam = np.zeros(n) if density is None else np.asarray(density, dtype=np.float64)
        p_fa = confirmation.gate_false_alarm(lam, halves)
        deep = gate_k is not None and len(gate_k) == n
        k_gate = (np.minimum(np.asarray(gate_k, dtype=np.float64), self.detection_threshold) if deep
                  else np.full(n, self.detection_threshold))
        if deep:  # where the gate was searched deeper, noise puts a hit there this often
            p_fa = np.where(k_gate < self.detection_threshold, np.maximum(p_fa, tc.gate_false_alarm), p_fa)
        change = confirmation.score_change(measured, tc.p_detect, p_fa)
        clutter = np.zeros(n)
        m = np.nonzero(measured)[0]
        line = e.line_hits()
        if m.size:
            change[m] += confirmation.position_score(tracks.innovation[m], e.S_inv[m], halves[m])
            change[m] += confirmation.amplitude_score(z[m], k_gate[m])
            clutter[m] = confirmation.change_evidence(nov[m], self.detection_threshold,
                                                     tc.static_change_rate, tc.target_change_rate)
            # a hit only the multi-frame stage found carries no evidence of its own (its score
            # shares its history with the last frames'): it keeps the track on its target
            below = m[confirmation.multiframe_only(z[m], k_gate[m])]
            change[below] = 0.0
            clutter[below] = 0.0
            # a tentative track's line-like hit is evidence for clutter: it counts as unchanged
            clutter[line & ~tracks.confirmed] = math.log((1.0 - tc.target_change_rate)
                                                         / (1.0 - tc.static_change_rate))
        # a meeting track takes no measurement: no evidence while a detection lies near its
        # extrapolation, a miss when none does (it has lost its target)
        change[tracks.meeting & ~measured & (e.nearest >= 0)] = 0.0
        # a miss's read below the threshold: how like a dim target, how like noise it is
        read = np.full(n, np.nan)
        if e.read is not None and e.read_null is not None and len(e.read) == n:
            missed_read = e.missed & tracks.confirmed & np.isfinite(e.read)
            if missed_read.any():
                r = np.nonzero(missed_read)[0]
                read[r] = subthreshold.read_score(e.read[r], k_gate[r], e.read_null)
                change[r] += read[r]
        s.score += change
        if m.size:  # a window of the last MOTION_HISTORY hits: old evidence does not linger
            s.clutter_hits[m, :-1] = s.clutter_hits[m, 1:]
            s.clutter_hits[m, -1] = clutter[m]
            s.clutter_score[m] = s.clutter_hits[m].sum(axis=1)
            s.static_cusum[m] = np.maximum(s.static_cusum[m] - clutter[m], 0.0)
        conf = tracks.confirmed
        s.score[conf] = np.minimum(s.score[conf], th.confirm)
        stats = [_measured(e)]
        if e.read is not None:
            stats.append(Statistic("sub-threshold evidence", read, np.nan, "<=", np.ones(n, dtype=bool),
                                   unit="nats", info=True))
        if tc.clutter_map and e.clutter_map is not None:
            count, exposure, mine = e.clutter_map
            s.own_static = s.own_static * (1.0 - 1.0 / tc.clutter_memory) + mine
            prior = static_prior(count, exposure, s.own_static)
            stats.append(Statistic("clutter map: static prior", prior, np.nan, "<=", np.ones(n, dtype=bool),
                                   info=True))
        else:
            prior = np.ones(n)
        clutter_level, motion_level = static_levels(th, prior)
        not_clutter = (s.clutter_score >= clutter_level) | (clutter_level <= 0)  # level 0: not needed
        confirm = measured & ~conf & (s.score >= th.confirm) & not_clutter & ~line
        score, clutter_score = s.score.copy(), s.clutter_score.copy()
        stats += [Statistic("persistence", score, th.confirm, ">=", score >= th.confirm),
                  Statistic("not clutter", clutter_score, clutter_level, ">=", not_clutter)]
        not_line = _not_line(e)
        if not_line is not None:
            stats.append(not_line)
        if tc.require_motion:
            t2, steady, consecutive, sliding = (np.full(n, np.nan) for _ in range(4))
            # steady progress is asked for wherever motion is
            steady_level = np.where(motion_level > 0, tc.min_motion / 2, 0.0)
            if confirm.any():
                r = np.nonzero(confirm)[0]
                mo = confirmation.motion(tracks.motion_t[r], tracks.motion_xy[r], tracks.motion_ok[r],
                                         tc.position_noise, STEADY_PARTS)
                # min_motion shared by the parts' differences (min_motion / 2 over 3 parts)
                steady_level[r] = np.where(steady_level[r] > 0, tc.min_motion / (mo.parts - 1), 0.0)
                # the camera's registration errors move a fixed point's scene positions alike
                # over frames (no 1/√k): progress must also exceed them
                reg = np.sqrt(2.0) * STEADY_Z * np.where(tracks.motion_ok[r], tracks.motion_reg[r], 0.0).max(axis=1)
                if STEADY_Z > 0:  # significant progress between all parts suffices below that
                    steady_level[r] = np.where(steady_level[r] > 0,
                                               np.minimum(steady_level[r], STEADY_Z * mo.steady_error), 0.0)
                # single positions a part (fewer than 6 recorded): no median stands against a wild
                # centroid, so min_motion's share does not suffice: STEADY_Z standard errors must
                single = mo.per_part < 2
                steady_level[r] = np.where(single & (steady_level[r] > 0), STEADY_Z * mo.steady_error, steady_level[r])
                steady_level[r] = np.where(steady_level[r] > 0, np.maximum(steady_level[r], reg), 0.0)
                # a chain of separate spots: its progress made in the jumps across its misses
                share = mo.consecutive if mo.consecutive is not None else np.full(len(r), np.nan)
                hops = (steady_level[r] > 0) & (share < tc.consecutive_share) & (tc.consecutive_share > 0)
                # the piece of a line whose detected part moves along it
                along = confirmation.slide(tracks.motion_wh[r], tracks.motion_ok[r], mo.velocity)
                along[np.hypot(mo.velocity[:, 0], mo.velocity[:, 1]) < SLIDE_SPEED] = np.nan
                slides = (steady_level[r] > 0) & (along >= tc.max_slide) & (tc.max_slide > 0)
                confirm[r[(mo.t2 < motion_level[r]) | ((mo.steady < steady_level[r]) & (steady_level[r] > 0))
                          | hops | slides]] = False
                t2[r], steady[r], consecutive[r], sliding[r] = mo.t2, mo.steady, share, along
            consecutive_level = np.where((steady_level > 0) & (tc.consecutive_share > 0), tc.consecutive_share, 0.0)
            slide_level = np.where((steady_level > 0) & (tc.max_slide > 0), tc.max_slide, np.inf)
            stats += [Statistic("motion: T²", t2, motion_level, ">=", t2 >= motion_level),
                      Statistic("motion: steady progress", steady, steady_level, ">=",
                                (steady >= steady_level) | (steady_level <= 0), unit="px"),
                      Statistic("motion: consecutive progress", consecutive, consecutive_level, ">=",
                                ~(consecutive < consecutive_level)),
                      Statistic("motion: not sliding along a line", sliding, slide_level, "<",
                                ~(sliding >= slide_level))]
        tie = 1e-9  # a score that reaches a level in exact arithmetic reaches it here too
        drop = ~conf & (s.score <= th.drop + tie)
        lost = conf & (s.score <= th.delete + tie)
        # a confirmed track that turned static: Page's CUSUM of the clutter evidence since
        # confirmation reaches the static-clutter level of the confirmation test
        static = (conf & ~lost & (s.static_cusum >= -th.drop - tie) if self.tcfg.delete_when_static
                  else np.zeros(n, dtype=bool))
        stats.append(Statistic("persistence: deletion level", score, np.where(conf, th.delete, th.drop), "<=",
                               drop | lost, deletes=True))
        if self.tcfg.delete_when_static:
            stats.append(Statistic("static clutter: CUSUM", s.static_cusum.copy(),
                                   np.where(conf, -th.drop, np.inf), ">=", static, deletes=True))
        s.static_cusum[confirm] = 0.0
        why = [""] * n
        for i in np.nonzero(confirm)[0].tolist():
            why[i] = (f": persistence {s.score[i]:.1f} and not clutter {s.clutter_score[i]:.1f} "
                      f">= {th.confirm:.1f}")
        for i in np.nonzero(drop)[0].tolist():
            why[i] = (f"dropped: persistence {s.score[i]:.1f} fell to {th.drop:.1f} (noise, not a target) "
                      f"after {tracks.hits[i]} hits")
        for i in np.nonzero(lost)[0].tolist():
            why[i] = (f"deleted: score {s.score[i]:.1f} fell {th.confirm - s.score[i]:.1f} below "
                      f"confirmation after {tracks.misses[i]} consecutive misses ({tracks.hits[i]} hits)")
            if np.isfinite(read[i]) and e.read is not None:  # what this frame's read said
                why[i] += (f"; this miss {change[i] - read[i]:+.1f} and its read at the prediction "
                           f"(±{subthreshold.WINDOW} px) {e.read[i]:.1f} σ {read[i]:+.1f}")
        for i in np.nonzero(static)[0].tolist():
            why[i] = (f"deleted as static clutter: its last hits are not new at their place in the scene "
                      f"(not clutter {s.clutter_score[i]:.1f}, CUSUM {s.static_cusum[i]:.1f})")
        return Decisions(confirm, drop | lost | static, why, tuple(stats), th)


#: ``tracking.confirm`` -> the confirmation rule it selects (a new rule: one entry here, and its
#: name among the choices of ``TrackingConfig.confirm`` for configuration files)
CONFIRMATION_RULES: dict[str, type[Rule]] = {"hits": HitsRule, "sprt": SequentialRule}
