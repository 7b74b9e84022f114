"""Multi-target particle-filter track-before-detect (Wang Hongbo and Wang Zhongwei): the measurement
model (:mod:`wfviz.tbd.model`) and the bank of per-hypothesis particle filters over one region
(:mod:`wfviz.tbd.filter`). The tracker composing them is :mod:`wfviz.trackers.tbd`."""

from wfviz.tbd.filter import BankOutput, Estimate, Particles, RegionFilter, systematic
from wfviz.tbd.model import likelihood, matched_filter, normalise, psf_factors, psf_patch, robust_sigma

__all__ = ["BankOutput", "Estimate", "Particles", "RegionFilter", "likelihood", "matched_filter",
           "normalise", "psf_factors", "psf_patch", "robust_sigma", "systematic"]
