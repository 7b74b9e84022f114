"""The GEWC tracker on the paper-like 70° scenarios, scored with wfviz.evaluate."""

from __future__ import annotations

from collections import defaultdict

import pytest

from wfviz.run import run
from wfviz.synth.scenarios import make_scenario
from wfviz.trackers import make_tracker


def truth_points(clip):
    shown, hidden = defaultdict(list), defaultdict(list)
    for row in clip.truth():
        (shown if row.visible else hidden)[row.frame].append((row.target_id, row.x, row.y))
    return dict(shown), dict(hidden)


@pytest.mark.parametrize("scenario", ["fov70-maneuver", "fov70-four-targets"])
def test_gewc_mota_and_no_identity_switch_on_70_degree_scenarios(scenario):
    clip = make_scenario(scenario, seed=0)
    scores = run(clip, make_tracker("gewc"), truth=truth_points(clip)).scores
    print(f"{scenario}: MOTA {scores.mota:.3f} IDF1 {scores.idf1:.3f} switches {scores.id_switches} "
          f"FA/frame {scores.fa_per_frame:.3f} CLE RMS {scores.cle_rms:.3f}")
    assert scores.mota >= 0.95
    assert scores.id_switches == 0
