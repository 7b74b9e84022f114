"""Multi-target particle-filter track-before-detect (Wang Hongbo and Wang Zhongwei): the measurement
model (:mod:`.model`), the per-pixel background (:mod:`.background`), the bank of per-hypothesis
particle filters over one region (:mod:`.filter`) and the tracker composing them (:mod:`.tracker`)."""

from wfviz.trackers.tbd.config import TBDConfig
from wfviz.trackers.tbd.filter import BankOutput, Estimate, Particles, RegionFilter, systematic
from wfviz.trackers.tbd.model import likelihood, matched_filter, normalise, psf_factors, psf_patch, robust_sigma
from wfviz.trackers.tbd.tracker import STAGES, TBDResult, TBDTracker

__all__ = ["STAGES", "BankOutput", "Estimate", "Particles", "RegionFilter", "TBDConfig", "TBDResult", "TBDTracker",
           "likelihood", "matched_filter", "normalise", "psf_factors", "psf_patch", "robust_sigma", "systematic"]
