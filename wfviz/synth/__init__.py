"""Synthetic scenes with exact truth: PSF rendering and the built-in demo clip."""

from wfviz.synth.demo import DemoClip, TruthPoint, demo_clip, horizon_row
from wfviz.synth.psf import add_gaussian_spot, gaussian_spot_image

__all__ = ["DemoClip", "TruthPoint", "add_gaussian_spot", "demo_clip", "gaussian_spot_image",
           "horizon_row"]
