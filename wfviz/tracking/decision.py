"""What a confirmation rule (:mod:`wfviz.tracking.rules`) reads and returns each frame.

The track manager gives the rule the frame's :class:`Evidence` (one row per track); the rule
returns :class:`Decisions`: which tracks it confirms and deletes, and every test it made as a
:class:`Statistic` (values against levels, over all tracks). One track's :class:`Decision` (its
verdict, the test that decided it, each :class:`Check` and a short reason) is read from them on
request (:meth:`wfviz.tracking.manager.TrackManager.decision`), so a recorder or an explanation
sees every test's value without reaching into the manager.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from wfviz.tracking.confirmation import Thresholds
from wfviz.tracking.subthreshold import NullReads

_NOT = {">=": "<", "<=": ">", ">": "<=", "<": ">="}


@dataclass(frozen=True)
class Evidence:
    """One frame's evidence about every track (rows as the track table's), for a confirmation rule.

    ``measured``: updated this frame; ``missed``: not measured and not meeting; ``moved``: px from
    the birth point in the scene; ``reported``: reported position (measurement, or the
    coasting / extrapolated state); ``clutter``: static-clutter label of the measured and meeting
    tracks (NaN: none; None: no clutter stage); ``density``: false detections per pixel at each
    track; ``z``: each hit's significance, ``novelty`` its change significance (NaN: none);
    ``gate_k``: the thresholds the gates were searched at (None: the frame's); ``half``: the gate
    half sizes (N, 2) of this frame's predictions (``kalman.gate_max`` where there were none);
    ``S_inv``: inverse innovation covariances (N, 2, 2) of the predictions; ``nearest``: the
    detection nearest each prediction (:attr:`Association.nearest`, -1: none);
    ``tested_per_frame``: tentative tracks tested per frame, running mean (None: not yet);
    ``clutter_map``: the scene's clutter map at each track (:class:`~wfviz.tracking.clutter_map.ClutterMap`):
    the counts of persistent unexplained detections and the exposures about it
    (:meth:`~wfviz.tracking.clutter_map.ClutterMap.at`) and how many of this frame's lie in its
    gate; None: no map;

    ``linearity``: each hit's linearity (:func:`wfviz.stages.detection.linearity`; NaN: no hit,
    None: not measured), line-like above ``max_linearity``; ``read``: each track's change
    significance read at its prediction (:func:`wfviz.tracking.subthreshold.read_at`; NaN: not
    read, None: no reads), scored on a miss against ``read_null``
    (:func:`wfviz.tracking.subthreshold.read_score`)."""

    measured: np.ndarray
    missed: np.ndarray
    moved: np.ndarray
    reported: np.ndarray
    clutter: np.ndarray | None
    density: np.ndarray | None
    z: np.ndarray
    novelty: np.ndarray
    gate_k: np.ndarray | None
    half: np.ndarray
    S_inv: np.ndarray
    nearest: np.ndarray
    tested_per_frame: float | None
    clutter_map: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    linearity: np.ndarray | None = None
    max_linearity: float = 1.0
    read: np.ndarray | None = None
    read_null: NullReads | None = None

    def line_hits(self) -> np.ndarray:
        """The tracks whose hit this frame is line-like (``linearity > max_linearity``)."""
        if self.linearity is None:
            return np.zeros(len(self.measured), dtype=bool)
        return self.measured & (np.nan_to_num(self.linearity, nan=-np.inf) > self.max_linearity)


class Verdict(StrEnum):
    """A rule's verdict on one track this frame."""

    CONFIRM = "confirm"
    KEEP = "keep"
    DELETE = "delete"


@dataclass(frozen=True)
class Check:
    """One test of one track: ``value`` compared with ``level`` by ``op`` as the rule compares
    them; ``holds``: the comparison's outcome. A confirmation test must hold for the track to be
    confirmed; a deletion test (``deletes``) deletes it when it holds. NaN value: not tested."""

    name: str
    value: float
    level: float
    op: str
    holds: bool
    deletes: bool = False
    unit: str = ""
    info: bool = False  #: a value the tests read (e.g. a prior), not a test: it always holds

    def __str__(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if np.isnan(self.value):
            return f"{self.name}: not tested"
        if self.info:
            return f"{self.name} {self.value:.3g}{unit}"
        op = self.op if self.holds else _NOT[self.op]
        return f"{self.name} {self.value:.3g}{unit} {op} {self.level:.3g}"


@dataclass(frozen=True)
class Statistic:
    """One test over every track (rows as the table's): the statistic ``value``, its ``level``
    (one for all or per track), ``op`` and whether the test ``holds`` per track (the rule's own
    outcome, tolerances included); see :class:`Check`."""

    name: str
    value: np.ndarray
    level: float | np.ndarray
    op: str
    holds: np.ndarray
    deletes: bool = False
    unit: str = ""
    info: bool = False  #: see :attr:`Check.info`

    def check(self, row: int) -> Check:
        """This test of the track in ``row``."""
        levels = np.asarray(self.level)
        level = levels if levels.ndim == 0 else levels[row]
        return Check(self.name, float(self.value[row]), float(level), self.op, bool(self.holds[row]),
                     self.deletes, self.unit, self.info)


@dataclass(frozen=True)
class Decision:
    """A rule's decision on one track this frame: the ``verdict``; the ``rule``
    (``tracking.confirm``); the ``test`` that decided it (a deletion: the test that deleted it; a
    tentative track kept: the first confirmation test that holds it back; "" when every
    confirmation test held or a confirmed track is kept); every ``checks``; a short ``reason``."""

    verdict: Verdict
    rule: str
    test: str
    checks: tuple[Check, ...]
    reason: str


@dataclass(frozen=True)
class Decisions:
    """A rule's decisions this frame, one row per track: ``confirm`` and ``delete`` masks,
    ``why`` per row (a confirmation's reasons appended to its event message, a deletion's whole
    message, "" for the usual one), each test as a :class:`Statistic`, and the frame's levels of
    the sequential test (``thresholds``; None for a rule without them)."""

    confirm: np.ndarray
    delete: np.ndarray
    why: list[str]
    statistics: tuple[Statistic, ...] = ()
    thresholds: Thresholds | None = None

    def decision(self, rule: str, row: int, confirmed: bool, message: str = "", gone: bool = False) -> Decision:
        """The :class:`Decision` on the track in ``row``, confirmed before this frame's decision
        or not; ``message``: its event's message (a confirmation or deletion); ``gone``: deleted
        by the manager (it left the image, or its position uncertainty outgrew the coast limit)."""
        checks = tuple(s.check(row) for s in self.statistics)
        if gone:
            return Decision(Verdict.DELETE, rule, "gone", checks, message)
        if self.delete[row]:
            test = next((c.name for c in checks if c.deletes and c.holds), "")
            return Decision(Verdict.DELETE, rule, test, checks, message)
        if self.confirm[row]:
            return Decision(Verdict.CONFIRM, rule, "", checks, message)
        if confirmed:
            kept = "; ".join(str(c) for c in checks if c.deletes)
            return Decision(Verdict.KEEP, rule, "", checks, f"confirmed{': ' + kept if kept else ''}")
        held = next((c for c in checks if not c.deletes and not c.holds and not np.isnan(c.value)), None)
        if held is None:
            return Decision(Verdict.KEEP, rule, "", checks, "tentative")
        return Decision(Verdict.KEEP, rule, held.name, checks, str(held))


@dataclass(frozen=True)
class Verdicts:
    """A track manager's decisions of one frame, as the recorder and the explanation read them:
    the decided tracks' ``ids`` (rows as the rule's) and whether each was ``confirmed`` before
    the frame, the rule's :class:`Decisions`, the tracks the manager ended itself (``gone``),
    the event messages by row, the ``rule`` (``tracking.confirm``) and ``min_hits``: the fewest
    hits in which any track can be confirmed under the rule at this frame's levels (a tentative
    track with fewer cannot have been confirmed yet). :meth:`decision` builds one track's
    :class:`Decision` on request (nothing is built for tracks nobody asks about)."""

    ids: np.ndarray
    confirmed: np.ndarray
    decisions: Decisions
    gone: np.ndarray
    messages: dict[int, str]
    rule: str
    min_hits: int

    def decision(self, track_id: int) -> Decision | None:
        """The :class:`Decision` on track ``track_id`` (None: not decided this frame)."""
        rows = np.nonzero(self.ids == track_id)[0]
        return self._at(int(rows[0])) if len(rows) else None

    def all(self) -> dict[int, Decision]:
        """{track_id: :class:`Decision`} of every decided track (deleted ones included)."""
        return {tid: self._at(r) for r, tid in enumerate(self.ids.tolist())}

    def _at(self, row: int) -> Decision:
        return self.decisions.decision(self.rule, row, bool(self.confirmed[row]), self.messages.get(row, ""),
                                       bool(self.gone[row]))
