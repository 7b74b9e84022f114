"""Synthetic scenes with exact truth: PSF rendering, the built-in demo clip, scenarios."""

from wfviz.synth.camera import FisheyeCamera
from wfviz.synth.clip import GeneratedClip, TruthRow, truth_points
from wfviz.synth.demo import DemoClip, demo_clip, horizon_row
from wfviz.synth.psf import add_gaussian_spot, gaussian_spot_image
from wfviz.synth.scenarios import ScenarioClip, ScenarioInfo, list_scenarios, make_scenario, write_scenario

__all__ = ["DemoClip", "FisheyeCamera", "GeneratedClip", "ScenarioClip", "ScenarioInfo", "TruthRow",
           "add_gaussian_spot", "demo_clip", "gaussian_spot_image", "horizon_row",
           "list_scenarios", "make_scenario", "truth_points", "write_scenario"]
