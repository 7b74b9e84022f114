"""The star-field tracker (Gao Jianwei et al. 2012): segmentation (:mod:`.segmentation`), star
registration (:mod:`.registration`), target chains (:mod:`.chains`), the paper's scores
(:mod:`.metrics`) and the tracker composing them (:mod:`.tracker`)."""

from wfviz.trackers.starfield.config import StarfieldConfig
from wfviz.trackers.starfield.tracker import CANDIDATE_STATUS, StarfieldResult, StarfieldTracker

__all__ = ["CANDIDATE_STATUS", "StarfieldConfig", "StarfieldResult", "StarfieldTracker"]
