"""The paired bootstrap of a trial's gain over the base (wfviz.tune.significance) and the
frame counts it resamples (wfviz.evaluate.evaluate_by_frame)."""

from __future__ import annotations

import numpy as np
import pytest

from wfviz.evaluate import FRAME_COUNTS, evaluate, evaluate_by_frame
from wfviz.tune.significance import gap_change, metric, pack, paired_gain, unpack


def clip(frames: int, targets: int, seed: int, miss: float = 0.2, fp: float = 0.1) -> np.ndarray:
    """Frame counts of a run that misses each target with probability ``miss`` and has a false
    track with probability ``fp`` a frame (misses in runs of 5 frames, as trackers miss)."""
    rng = np.random.default_rng(seed)
    out = np.zeros((frames, len(FRAME_COUNTS)), dtype=np.int64)
    out[:, 0] = targets
    missed = np.repeat(rng.binomial(targets, miss, size=frames // 5 + 1), 5)[:frames]
    out[:, 1] = targets - missed
    out[:, 2] = rng.random(frames) < fp
    out[:, 4] = out[:, 1]
    return out


def two_clips() -> list[np.ndarray]:
    return [clip(80, 3, 1), clip(50, 4, 2)]  # 80*3 + 50*4 = 440 truth points


def test_identical_runs_are_within_noise():
    base = two_clips()
    for m in ("mota", "idf1", "pd", "fa", "idsw"):
        g = paired_gain(base, [c.copy() for c in base], m)
        assert g.value == 0.0 and g.low == 0.0 and g.high == 0.0 and g.noise, m
        assert g.text() == "no change"


def test_a_known_difference_is_detected():
    base = two_clips()
    better = [c.copy() for c in base]
    for c in better:  # every miss of every other frame found: many more matches, all over both clips
        fix = np.arange(len(c)) % 2 == 0
        c[fix, 1] = c[fix, 0]
        c[:, 4] = c[:, 1]
    g = paired_gain(better, base, "mota")
    assert g.value > 0.05 and g.low > 0 and not g.noise and "within noise" not in g.text()
    worse = paired_gain(base, better, "pd")  # the other way: a real loss
    assert worse.high < 0 and not worse.noise


def test_one_more_matched_point_out_of_437_is_within_noise():
    base = [clip(80, 3, 1), clip(49, 4, 2)]
    base[1][-1, 0] += 1  # 437 truth points in all
    assert sum(int(c[:, 0].sum()) for c in base) == 437
    trial = [c.copy() for c in base]
    frame = int(np.flatnonzero(trial[0][:, 1] < trial[0][:, 0])[0])
    trial[0][frame, 1] += 1  # one more truth point matched, once
    g = paired_gain(trial, base, "mota")
    assert 0 < g.value < 0.005
    assert g.noise and g.low <= 0 <= g.high


def test_the_interval_is_seeded_and_narrows_with_more_frames():
    base, trial = [clip(40, 3, 5)], [clip(40, 3, 6, miss=0.1)]
    a, b = paired_gain(trial, base, "pd", seed=1), paired_gain(trial, base, "pd", seed=1)
    assert (a.low, a.high) == (b.low, b.high)
    long_base, long_trial = [clip(400, 3, 5)], [clip(400, 3, 6, miss=0.1)]
    wide = paired_gain(trial, base, "pd")
    narrow = paired_gain(long_trial, long_base, "pd")
    assert narrow.high - narrow.low < wide.high - wide.low


def test_gap_change_is_the_difference_of_the_gains():
    base_t, base_v = two_clips(), [clip(60, 2, 9)]
    trial_t = [c.copy() for c in base_t]
    for c in trial_t:
        c[:, 1] = c[:, 0]  # perfect on the tune clips
        c[:, 4] = c[:, 1]
    tune = paired_gain(trial_t, base_t, "mota", seed=0)
    val = paired_gain([c.copy() for c in base_v], base_v, "mota", seed=1)
    gap = gap_change(tune, val)
    assert gap.value == pytest.approx(tune.value) and gap.low > 0  # the tune gain did not carry over


def test_pack_round_trips_and_is_small():
    c = clip(300, 3, 4, miss=0.05, fp=0.0)
    rows = pack(c)
    assert (unpack(rows) == c).all() and len(rows) < len(c) / 3
    assert unpack([]).shape == (0, len(FRAME_COUNTS))


def test_mismatched_clips_are_refused():
    with pytest.raises(ValueError, match="same frames"):
        paired_gain([clip(40, 3, 1)], [clip(41, 3, 1)], "mota")
    with pytest.raises(ValueError, match="unknown metric"):
        metric(np.zeros(5), 1, "hota")


def test_frame_counts_give_the_evaluated_scores(tmp_path):
    truth = tmp_path / "truth.csv"
    tracks = tmp_path / "tracks.csv"
    t_rows, k_rows = ["frame,target_id,x,y,visible"], ["frame,track_id,x,y,confirmed"]
    for f in range(30):
        t_rows += [f"{f},1,{10 + f},20,1", f"{f},2,50,{30 + f},1"]
        if f % 7:  # target 1 found, but its track id changes at frame 15
            k_rows.append(f"{f},{1 if f < 15 else 3},{10.5 + f},20,1")
        if f > 4:
            k_rows.append(f"{f},2,50,{31 + f},1")
        if f % 5 == 0:
            k_rows.append(f"{f},9,200,200,1")  # a false track
    truth.write_text("\n".join(t_rows) + "\n")
    tracks.write_text("\n".join(k_rows) + "\n")
    result, counts = evaluate_by_frame(tracks, truth)
    assert result == evaluate(tracks, truth)
    assert counts.shape == (30, len(FRAME_COUNTS))
    s = counts.sum(0)
    assert (s[0], s[1], s[2], s[3]) == (result.truth_points, result.matches, result.false_positives,
                                        result.id_switches)
    assert result.id_switches == 1 and result.false_positives == 6
    for m, want in (("mota", result.mota), ("pd", result.pd), ("fa", result.fa_per_frame),
                    ("idf1", result.idf1), ("idsw", float(result.id_switches))):
        assert float(metric(s, len(counts), m)) == pytest.approx(want), m


def trial(number: int, tune: list[np.ndarray], val: list[np.ndarray], base: bool = False, frames: bool = True):
    """A finished trial as the report reads it: scores per role and packed frame counts per clip."""
    from types import SimpleNamespace

    labels = {f"t{i}": c for i, c in enumerate(tune)} | {f"v{i}": c for i, c in enumerate(val)}
    mean = {r: {m: float(np.mean([metric(c.sum(0), len(c), m) for c in cs])) for m in ("mota", "pd")}
            for r, cs in (("tune", tune), ("validate", val))}
    attrs = {"base": base, **mean} | ({"frames": {k: pack(c) for k, c in labels.items()}} if frames else {})
    return SimpleNamespace(number=number, user_attrs=attrs)


def test_the_verdict_tells_a_real_gain_from_noise():
    from wfviz.tune.gains import TrialGains, verdict

    tune, val = two_clips(), [clip(60, 3, 7)]
    found = [c.copy() for c in tune]
    for c in found:  # every miss found: a real gain on the tune clips
        c[:, 1] = c[:, 0]
    one_more = [c.copy() for c in val]
    one_more[0][int(np.flatnonzero(val[0][:, 1] < val[0][:, 0])[0]), 1] += 1  # one more point on validation
    base = trial(0, tune, val, base=True)
    gains = TrialGains(base, {"tune": ["t0", "t1"], "validate": ["v0"]})
    text = verdict(trial(4, found, one_more), gains, "mota", True)
    assert "beyond noise" in text and "within noise: not confirmed" in text
    assert "the search fitted the tune clips by that much" in text  # its tune gain did not carry over
    noise = verdict(trial(5, [c.copy() for c in tune], one_more), gains, "mota", True)
    assert "**within noise**" in noise and "keep the base" in noise
    old = verdict(trial(6, found, val, frames=False), gains, "mota", True)
    assert "no interval" in old
    assert verdict(base, gains, "mota", True).startswith("The base is the best trial")
