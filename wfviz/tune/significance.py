"""Is a trial's gain over the base more than noise? A paired bootstrap over clips and, within
each clip, blocks of consecutive frames (B. Efron and R. Tibshirani, "An introduction to the
bootstrap", 1993; the moving-blocks idea of H. Künsch, Ann. Statist. 1989, for frames whose
errors come in runs): both runs are scored on the same resampled clips and frames, so what
they share (how hard the clips are) cancels and only their difference varies.

A run on one clip is its frame counts (:data:`wfviz.evaluate.FRAME_COUNTS`, one row per frame
of the truth's range), from which every metric a study reports follows exactly: MOTA, IDF1,
Pd, false tracks a frame and identity switches. A metric over several clips is the mean of the
clips' values, as :func:`wfviz.tune.trial.mean_scores` averages them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

RESAMPLES = 1000  # bootstrap resamples of every gain
BLOCK = 10        # frames a block: a missed target is often missed for many frames in a row
LEVEL = 0.95      # coverage of the reported interval
METRIC_NAMES = ("mota", "idf1", "pd", "fa", "idsw")  # wfviz.tune.trial.METRICS


@dataclass(frozen=True)
class Gain:
    """A trial's ``value`` minus the base's on some clips, and the ``low``–``high`` bootstrap
    interval (coverage :data:`LEVEL`) of that difference; ``samples``: the resampled
    differences (NaN values: resamples where the metric is undefined, left out)."""

    value: float
    low: float
    high: float
    samples: np.ndarray = field(repr=False, compare=False)

    @property
    def noise(self) -> bool:
        """Whether the interval holds 0: the difference is within noise (or undefined)."""
        return not (self.low > 0 or self.high < 0)

    def text(self, fmt: str = "+.3f", note: bool = True) -> str:
        """``+0.012 [+0.004, +0.020]``, with ``note`` and ``, within noise`` when it is;
        ``no change`` when every resample gives 0."""
        if not np.isfinite(self.value):
            return "–"
        if not (np.isfinite(self.low) and np.isfinite(self.high)):
            return f"{self.value:{fmt}} (no interval)"
        if self.value == self.low == self.high == 0:
            return "no change"
        return (f"{self.value:{fmt}} [{self.low:{fmt}}, {self.high:{fmt}}]"
                + (", within noise" if note and self.noise else ""))


def pack(counts: np.ndarray) -> list[list[int]]:
    """Frame counts (frames, k ints) as JSON-ready run-length rows ``[repeat, *row]`` (a run's
    frames mostly repeat one row, so a study's journal stays small)."""
    a = np.asarray(counts, dtype=np.int64)
    if not len(a):
        return []
    starts = np.flatnonzero(np.r_[True, (a[1:] != a[:-1]).any(axis=1)])
    repeats = np.diff(np.r_[starts, len(a)])
    return [[int(n), *map(int, a[s])] for n, s in zip(repeats, starts)]


def unpack(rows: Sequence[Sequence[int]], width: int = 5) -> np.ndarray:
    """The frame counts :func:`pack` packed (``width`` columns when there are no rows)."""
    if not rows:
        return np.zeros((0, width), dtype=np.int64)
    a = np.asarray(rows, dtype=np.int64)
    return np.repeat(a[:, 1:], a[:, 0], axis=0)


def metric(sums: np.ndarray, frames: np.ndarray | float, name: str) -> np.ndarray:
    """Metric ``name`` (:data:`METRIC_NAMES`) of frame counts summed over ``frames`` frames
    (``sums``: (..., 5) in :data:`wfviz.evaluate.FRAME_COUNTS` order, ``frames`` broadcast
    against its leading axes); NaN where it is undefined (no truth point, no frame)."""
    s = np.asarray(sums, dtype=np.float64)
    truth, matches, fp, switches, id_matches = np.moveaxis(s, -1, 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        if name == "mota":
            out = 1.0 - (truth - matches + fp + switches) / truth
        elif name == "pd":
            out = matches / truth
        elif name == "idf1":
            out = 2.0 * id_matches / (truth + matches + fp)
        elif name == "fa":
            out = fp / np.asarray(frames, dtype=np.float64)
        elif name == "idsw":
            out = switches + 0.0
        else:
            raise ValueError(f"unknown metric {name!r} (one of {', '.join(METRIC_NAMES)})")
    return np.where(np.isfinite(out), out, np.nan)


def _blocks(counts: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """The counts summed over consecutive blocks of ``block`` frames, and each block's frames."""
    starts = np.arange(0, len(counts), block)
    return np.add.reduceat(counts, starts, axis=0), np.diff(np.r_[starts, len(counts)])


def paired_gain(trial: Sequence[np.ndarray], base: Sequence[np.ndarray], name: str,
                resamples: int = RESAMPLES, seed: int = 0, block: int = BLOCK, level: float = LEVEL) -> Gain:
    """Metric ``name`` of ``trial`` minus that of ``base``, averaged over clips (one frame count
    array per clip, the two runs' arrays of a clip of equal length), with its paired bootstrap
    interval: each resample draws the clips with replacement and, in each clip, its blocks of
    ``block`` frames with replacement, the same draws for both runs (a clip drawn twice reuses
    its frame draw). Seeded by ``seed``: the same inputs give the same interval."""
    if len(trial) != len(base) or not trial:
        raise ValueError(f"{len(trial)} clips against {len(base)}: a paired gain needs the same clips, at least one")
    rng = np.random.default_rng(seed)
    observed, diffs = [], []
    for a, b in zip(trial, base):
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        if a.shape != b.shape or not len(a):
            raise ValueError(f"frame counts of shapes {a.shape} and {b.shape}: the runs must cover the same frames")
        observed.append(metric(a.sum(0), len(a), name) - metric(b.sum(0), len(b), name))
        ba, lengths = _blocks(a, block)
        bb, _ = _blocks(b, block)
        n = len(lengths)
        w = rng.multinomial(n, np.full(n, 1.0 / n), size=resamples).astype(np.float64)  # (R, blocks)
        frames = w @ lengths
        diffs.append(metric(w @ ba, frames, name) - metric(w @ bb, frames, name))
    d = np.stack(diffs, axis=1)  # (R, clips)
    c = d.shape[1]
    picks = rng.multinomial(c, np.full(c, 1.0 / c), size=resamples)  # (R, clips)
    undefined = ((picks > 0) & np.isnan(d)).any(axis=1)
    samples = np.where(undefined, np.nan, (picks * np.nan_to_num(d)).sum(axis=1) / c)
    return Gain(float(np.mean(observed)), *_interval(samples, level), samples)


def _interval(samples: np.ndarray, level: float) -> tuple[float, float]:
    """The percentile interval of the finite ``samples`` (NaN, NaN when fewer than half are)."""
    ok = samples[np.isfinite(samples)]
    if len(ok) < max(1, len(samples) // 2):
        return float("nan"), float("nan")
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(ok, [tail, 100.0 - tail])
    return float(low), float(high)


def gap_change(tune: Gain, validate: Gain, level: float = LEVEL) -> Gain:
    """How much more the trial's tune score exceeds its validation score than the base's does
    (its tune − validation gap minus the base's): ``tune``'s gain minus ``validate``'s, with the
    interval of their resampled differences (the two drawn independently: disjoint clips, seeds
    apart). Positive: the gain on the tune clips does not carry over, the search fitted them."""
    samples = tune.samples - validate.samples
    return Gain(tune.value - validate.value, *_interval(samples, level), samples)
