"""Track management shared by the trackers, as small parts: the constant-velocity Kalman filter
(:mod:`.kalman`), the track types and lifecycle events (:mod:`.tracks`), association
(:mod:`.association`), the track table (:mod:`.table`), the confirmation rules (:mod:`.rules`)
with their sequential tests (:mod:`.confirmation`), what a rule reads and returns
(:mod:`.decision`: Evidence, Decisions, Decision), and the track manager (:mod:`.manager`) that
runs them per frame."""

from wfviz.tracking.association import (Association, Gates, Measurements, assign_confirmed_first, assign_in_gates,
                                       gate_boxes)
from wfviz.tracking.decision import Check, Decision, Decisions, Evidence, Statistic, Verdict
from wfviz.tracking.manager import TrackManager, extrapolate
from wfviz.tracking.rules import CONFIRMATION_RULES, HitsRule, Rule, SequentialRule
from wfviz.tracking.table import Columns, TrackTable
from wfviz.tracking.tracks import EventKind, Prediction, TrackEvent, TrackState

__all__ = ["CONFIRMATION_RULES", "Association", "Check", "Columns", "Decision", "Decisions", "EventKind",
           "Evidence", "Gates", "HitsRule", "Measurements", "Prediction", "Rule", "SequentialRule", "Statistic",
           "TrackEvent", "TrackManager", "TrackState", "TrackTable", "Verdict", "assign_confirmed_first",
           "assign_in_gates", "extrapolate", "gate_boxes"]
