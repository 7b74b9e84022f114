"""The star-field paper's detection metrics (its eq. 11), counted on the target chains.

p_d(i) = k_i / T_i: T_i the frames target i is visible, k_i the frames in which a point of a
chain that reached Run (Run, Out or lost at the end) was *detected* (by the segmentation or
the local re-segmentation) within ``gate`` px of it; predictions standing in for a missed
detection are excluded, as in the paper. p_f = e / (sum T_i + e), e the detected chain points
that match no visible target (one point per target and frame, optimal assignment; points
on a hidden target are ignored, as in :mod:`wfviz.evaluate`).

Like the paper, this is counted after the sequence, on the stored chains: a chain's first
N = 4 points, found before its promotion to Run, count. ``wfviz eval`` scores the tracks
CSV instead, which is written online: confirmed tracks from their promotion on, predictions
included (the CSV cannot mark them).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass

from wfviz.evaluate import Points, frame_errors
from wfviz.trackers.starfield.chains import PREDICTED, Chain

ChainPointRow = tuple[int, int, float, float, str]  # chain id, frame, u, v, kind


@dataclass(frozen=True)
class PaperScores:
    """Per target: visible frames T_i, detected frames k_i, p_d; overall e and p_f; chain
    points that were predictions (not counted)."""

    frames: dict[int, int]
    detected: dict[int, int]
    p_d: dict[int, float]
    false_detections: int
    p_f: float
    predicted_points: int

    def table(self) -> str:
        """Plain-text summary."""
        lines = [f"paper's metrics on the Run/Out chains (predictions excluded): "
                 f"p_f {self.p_f:.4f} ({self.false_detections} false detections, "
                 f"{self.predicted_points} predicted points not counted)",
                 f"{'target':>6} {'T_i':>5} {'k_i':>5} {'p_d':>6}"]
        for t in sorted(self.frames):
            lines.append(f"{t:>6} {self.frames[t]:>5} {self.detected[t]:>5} {self.p_d[t]:>6.3f}")
        return "\n".join(lines)


def chain_rows(chains: Iterable[Chain]) -> list[ChainPointRow]:
    """Every point of the given chains as (chain id, frame, u, v, kind)."""
    return [(c.chain_id, p.frame, p.u, p.v, p.kind) for c in chains for p in c.points]


def paper_scores(rows: Iterable[ChainPointRow], shown: Points, hidden: Points | None = None,
                 gate: float = 3.0) -> PaperScores:
    """p_d per target and p_f from chain points (module docstring). ``rows`` with the same
    (chain id, frame) more than once: the last one counts (a later frame may re-label it)."""
    hidden = hidden or {}
    latest: dict[tuple[int, int], ChainPointRow] = {}
    for r in rows:
        latest[(r[0], r[1])] = r
    by_frame: dict[int, list[tuple[int, float, float]]] = defaultdict(list)
    n_pred = 0
    for cid, f, u, v, kind in latest.values():
        if kind == PREDICTED:
            n_pred += 1
        else:
            by_frame[f].append((cid, u, v))
    frames: dict[int, int] = defaultdict(int)
    detected: dict[int, int] = defaultdict(int)
    for f, gt in shown.items():
        for tid, _, _ in gt:
            frames[tid] += 1
    e = 0
    for f in sorted(set(shown) | set(by_frame)):
        fe = frame_errors(by_frame.get(f, []), shown.get(f, []), gate, hidden.get(f, []))
        for _, tid, _ in fe.matches:
            detected[tid] += 1
        e += fe.false_alarms
    total = sum(frames.values())
    return PaperScores(dict(frames), {t: detected[t] for t in frames},
                       {t: detected[t] / n for t, n in frames.items()}, e,
                       e / (total + e) if total + e else math.nan, n_pred)
