"""benchmarks/opencv_share.py: the time a step spends inside OpenCV calls is counted, and is part of the step."""

import re
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "opencv_share.py"


def test_counts_the_opencv_calls_of_a_step() -> None:
    r = subprocess.run([sys.executable, str(SCRIPT), "synth:fov70-maneuver", "--frames", "6", "--rounds", "1"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    best = [ln for ln in r.stdout.splitlines() if "best round" in ln][0]
    step_mean = float(re.search(r"step median [\d.]+ mean ([\d.]+)", best).group(1))
    inside_mean = float(re.search(r"inside OpenCV median [\d.]+ mean ([\d.]+)", best).group(1))
    assert 0.0 < inside_mean < step_mean
    # the camera motion's flow is GEWC's largest OpenCV call: it must be among those counted
    rows = {m.group(1): float(m.group(3)) for m in re.finditer(r"\| `(\w+)` \| ([\d.]+) \| ([\d.]+) \|", r.stdout)}
    assert "calcOpticalFlowPyrLK" in rows and rows["calcOpticalFlowPyrLK"] > 0
