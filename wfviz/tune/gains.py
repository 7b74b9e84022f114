"""The report's gains of trials over the base, each with its paired bootstrap interval
(:mod:`wfviz.tune.significance`) from the frame counts a trial keeps (user attribute
``frames``): the scores and gains tables, the verdict on the best trial, the tune − validation
gap against the base's own gap, and the best trials with their validation gains."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from wfviz.tune.significance import BLOCK, LEVEL, METRIC_NAMES, RESAMPLES, Gain, gap_change, paired_gain, unpack
from wfviz.tune.trial import METRICS

SEEDS = {"tune": 0, "validate": 1}  # independent resamples per role, so that gaps can be differenced
ROLE_NAMES = {"tune": "tune", "validate": "validation"}


def num(v: Any, fmt: str = ".3f") -> str:
    """``v`` formatted, "–" for None or a non-finite float."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return format(v, fmt) if isinstance(v, float) else str(v)


def trial_name(t: Any, best: Any) -> str:
    """"3", "0 (base)" or "5 (best)"."""
    return f"{t.number} (base)" if t.user_attrs.get("base") else f"{t.number} (best)" if t is best else str(t.number)


class TrialGains:
    """Gains of trials over ``base`` (None: no base trial) on the clips of each role
    (``labels``: {"tune": [...], "validate": [...]}), computed once each."""

    def __init__(self, base: Any | None, labels: dict[str, list[str]]) -> None:
        self.base = base
        self.labels = labels
        self._cache: dict[tuple[int, str, str], Gain | None] = {}

    def _counts(self, t: Any, role: str) -> list[np.ndarray] | None:
        frames = t.user_attrs.get("frames") or {}
        labels = self.labels.get(role) or []
        if not labels or any(label not in frames for label in labels):
            return None  # a trial run before frame counts were kept
        return [unpack(frames[label]) for label in labels]

    def gain(self, t: Any, role: str, metric: str) -> Gain | None:
        """``t``'s ``metric`` minus the base's on the ``role`` clips, with its interval; None
        without a base or the frame counts of either trial."""
        key = (t.number, role, metric)
        if metric not in METRIC_NAMES:  # HOTA is no sum of per-frame counts: no interval here
            return None
        if key not in self._cache:
            a = self._counts(t, role)
            b = self._counts(self.base, role) if self.base is not None else None
            self._cache[key] = (paired_gain(a, b, metric, seed=SEEDS[role])
                                if a is not None and b is not None else None)
        return self._cache[key]

    def gap(self, t: Any, metric: str) -> Gain | None:
        """``t``'s tune − validation gap minus the base's (:func:`gap_change`)."""
        tune, val = self.gain(t, "tune", metric), self.gain(t, "validate", metric)
        return gap_change(tune, val) if tune is not None and val is not None else None


def _value(t: Any, role: str, metric: str) -> float:
    """``t``'s mean ``metric`` on the ``role`` clips (NaN: not scored, e.g. HOTA in a study
    begun before it was)."""
    return float(t.user_attrs.get(role, {}).get(metric, math.nan))


def _text(g: Gain | None) -> str:
    return g.text() if g is not None else "–"


def method_note() -> str:
    """How every interval of the report is made, in a sentence."""
    return (f"Each gain is the trial's score minus the base's, with its {100 * LEVEL:.0f} % interval from a paired "
            f"bootstrap ({RESAMPLES} resamples: the clips with replacement and, in each clip, blocks of {BLOCK} "
            "consecutive frames with replacement, the same draws for both runs); \"within noise\" when the interval "
            "holds 0. Higher is better except `fa` (false tracks a frame) and `idsw` (identity switches a clip). "
            "\"–\": no base, or a trial run before frame counts were kept.")


def scores_section(shown: list[Any], best: Any | None, gains: TrialGains, metric: str,
                   roles: list[str]) -> list[str]:
    """The "Tune and validation scores" section: every metric of ``shown`` (the base first) on
    each role's clips, with validation the gap (tune − validation) in ``metric`` and its change
    from the base's gap; then the gains over the base with their intervals."""
    has_val = "validate" in roles
    head = "| trial | " + " | ".join(f"{r} {m}" for r in roles for m in METRICS)
    if has_val:
        head += f" | gap (tune − validation) {metric} | gap change from the base"
    md = ["## Tune and validation scores", "", head + " |",
          "|---|" + "---:|" * (len(roles) * len(METRICS) + 2 * has_val)]
    for t in shown:
        row = f"| {trial_name(t, best)} | " + " | ".join(num(_value(t, r, m)) for r in roles for m in METRICS)
        if has_val:
            gap = t.user_attrs["tune"][metric] - t.user_attrs["validate"][metric]
            change = "(reference)" if t is gains.base else _text(gains.gap(t, metric))
            row += f" | {num(gap, '+.3f')} | {change}"
        md.append(row + " |")
    md.append("")
    if has_val:
        md += ["The gap of the base itself says how much harder the validation clips are than the tune clips; "
               "what a trial fitted to the tune clips is the *change* of its gap from the base's (positive: "
               "its tune gain did not carry over).", ""]
    others = [t for t in shown if t is not gains.base]
    if gains.base is None or not others:
        return md
    md += ["### Gains over the base", "", method_note(), "",
           "| trial | clips | " + " | ".join(METRICS) + " |", "|---|---|" + "---:|" * len(METRICS)]
    for t in others:
        for r in roles:
            md.append(f"| {trial_name(t, best)} | {ROLE_NAMES[r]} | "
                      + " | ".join(_text(gains.gain(t, r, m)) for m in METRICS) + " |")
    return md + [""]


def verdict(best: Any, gains: TrialGains, metric: str, has_val: bool) -> str:
    """Whether the best trial's gain over the base is real on the tune clips, holds on the
    validation clips, and how much of it the search fitted (the change of the gap)."""
    base = gains.base
    if base is None or best is base:
        return "The base is the best trial on the tune clips: no trial beat it." if base is not None else ""
    t = gains.gain(best, "tune", metric)
    v = gains.gain(best, "validate", metric) if has_val else None
    if t is None:
        gain_t = _value(best, "tune", metric) - _value(base, "tune", metric)
        why = ("HOTA is not a sum of per-frame counts, which the resampling redraws" if metric not in METRIC_NAMES
               else "its trials were run before frame counts were kept")
        return f"The best trial gains {gain_t:+.3f} {metric} over the base on the tune clips (no interval: {why})."
    if t.noise:
        text = (f"The best trial's {metric} gain over the base on the tune clips, {t.text(note=False)}, is **within noise**: "
                "the search found nothing better than the base on these clips beyond chance; keep the base.")
    else:
        text = f"The best trial gains {t.text(note=False)} {metric} over the base on the tune clips, beyond noise."
    if v is None:
        return text
    if v.low > 0:
        text += f" On the validation clips it gains {v.text(note=False)}: the gain holds."
    elif v.high < 0:
        text += (f" On the validation clips it loses {v.text(note=False)}: the gain does **not** hold (the search fitted "
                 "the tune clips).")
    else:
        text += (f" On the validation clips its gain, {v.text(note=False)}, is within noise: not confirmed (more or longer "
                 "validation clips would tell).")
    g = gains.gap(best, metric)
    if g is not None:
        gap = best.user_attrs["tune"][metric] - best.user_attrs["validate"][metric]
        gap0 = base.user_attrs["tune"][metric] - base.user_attrs["validate"][metric]
        what = ("no sign that the search fitted the tune clips" if g.noise else
                "the search fitted the tune clips by that much" if g.low > 0 else
                "the trial does better on the validation clips than its tune gain promised")
        text += (f" Its tune − validation gap is {gap:+.3f} against the base's {gap0:+.3f}: a change of "
                 f"{g.text(note=False)}: {what}.")
    return text


def best_section(best: list[Any], shown: int, gains: TrialGains, metrics: tuple[str, ...],
                 names: list[str], has_val: bool) -> list[str]:
    """The best ``shown`` trials: each objective metric on the tune clips and (with validation
    clips) the validation clips, each with its gain over the base, then the parameters; and
    which of them beat the base on the validation clips beyond noise."""
    top = best[:shown]
    roles = ["tune"] + (["validate"] if has_val else [])
    cols = [(r, m) for m in metrics for r in roles]
    md = [f"## Best {len(top)} trials", "",
          "Ranked on the tune clips; the gains are over the base, with their intervals (see above).", "",
          "| trial | " + " | ".join(f"{ROLE_NAMES[r]} {m} | gain ({ROLE_NAMES[r]})" for r, m in cols)
          + " | " + " | ".join(names) + " | s |",
          "|---|" + "---:|" * (2 * len(cols)) + "---|" * len(names) + "---:|"]
    for t in top:
        cells = []
        for r, m in cols:
            g = None if t is gains.base else gains.gain(t, r, m)
            cells += [num(_value(t, r, m)), "(base)" if t is gains.base else _text(g)]
        md.append(f"| {trial_name(t, best[0])} | " + " | ".join(cells) + " | "
                  + " | ".join(num(t.params.get(n), ".4g") for n in names)
                  + f" | {num(t.user_attrs.get('seconds'), '.1f')} |")
    md.append("")
    if has_val and gains.base is not None:
        m = metrics[0]
        real = [t for t in top if t is not gains.base and (g := gains.gain(t, "validate", m)) is not None and g.low > 0]
        md += [(f"Beat the base on the validation clips in {m} beyond noise: trial(s) "
                + ", ".join(str(t.number) for t in real) + "." if real else
                f"No trial of this table beats the base on the validation clips in {m} beyond noise."), ""]
    return md
