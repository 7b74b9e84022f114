"""Tracks against ground truth: per-frame optimal matching, per-target error and identity."""

from __future__ import annotations

import csv
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass(frozen=True)
class TargetScore:
    """One truth target: frames present, frames matched, position errors, identities used."""

    target_id: int
    frames: int
    matched: int
    errors: tuple[float, ...]
    track_ids: tuple[int, ...]
    id_switches: int

    @property
    def main_track(self) -> int | None:
        return Counter(self.track_ids).most_common(1)[0][0] if self.track_ids else None

    @property
    def max_error(self) -> float:
        return max(self.errors) if self.errors else float("nan")

    @property
    def rms_error(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.errors)))) if self.errors else float("nan")


def read_points(path: Path, id_column: str, confirmed_only: bool = False) -> dict[int, list[tuple[int, float, float]]]:
    """{frame: [(id, x, y), ...]} from a tracks or truth CSV (``confirmed == 1`` rows if asked)."""
    out: dict[int, list[tuple[int, float, float]]] = defaultdict(list)
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            if confirmed_only and row.get("confirmed", "1") not in ("1", "1.0", "True", "true"):
                continue
            out[int(row["frame"])].append((int(row[id_column]), float(row["x"]), float(row["y"])))
    return out


def score_targets(tracks: dict[int, list[tuple[int, float, float]]],
                  truth: dict[int, list[tuple[int, float, float]]], gate: float = 3.0) -> list[TargetScore]:
    """Match tracks to truth frame by frame (Hungarian on distance, ``gate`` px at most)."""
    frames: Counter = Counter()
    errors: dict[int, list[float]] = defaultdict(list)
    ids: dict[int, list[int]] = defaultdict(list)
    for f, gt in truth.items():
        for tid, _, _ in gt:
            frames[tid] += 1
        tr = tracks.get(f, [])
        if not tr:
            continue
        g = np.array([[x, y] for _, x, y in gt])
        t = np.array([[x, y] for _, x, y in tr])
        d = np.hypot(*(g[:, None, :] - t[None, :, :]).transpose(2, 0, 1))
        rows, cols = linear_sum_assignment(np.where(d <= gate, d, 1e9))
        for r, c in zip(rows, cols):
            if d[r, c] <= gate:
                errors[gt[r][0]].append(float(d[r, c]))
                ids[gt[r][0]].append(tr[c][0])
    out = []
    for tid in sorted(frames):
        seq = ids[tid]
        switches = sum(1 for a, b in zip(seq, seq[1:]) if a != b)
        out.append(TargetScore(tid, frames[tid], len(errors[tid]), tuple(errors[tid]), tuple(seq), switches))
    return out
