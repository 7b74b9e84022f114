"""Tracks against ground truth: MOT metrics (py-motmetrics), HOTA (:mod:`wfviz.hota`), centre
error, Pd, false alarms, latency.

Hidden truth (rows with ``visible == 0``) is neither missed nor matchable. Like MOTChallenge's
"don't care" objects, a track point left unmatched by the visible targets that lies within the
gate of a hidden target (one track per hidden target, optimal assignment) is ignored: it is
neither a match nor a false alarm. Only frames in the truth's frame range are evaluated.

Matching rule: a track point may match a truth point within ``gate`` px of its centre. When the
truth has box sizes (``w``, ``h`` columns: a box centred on x, y), a point inside the box, grown
by :data:`BOX_MARGIN` px a side, may match too; the assignment still minimises the distance to
the centres. Hidden targets use the same rule. :attr:`EvalResult.match_rule` says which was used.
"""

from __future__ import annotations

import csv
import math
from collections import Counter, defaultdict
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from wfviz.hota import hota, point_similarity

Point = tuple[int, float, float]
Points = dict[int, list[Point]]
Box = tuple[float, float]  # (w, h) in px, centred on the truth point
Boxes = dict[int, dict[int, Box]]  # {frame: {target_id: (w, h)}}
BOX_MARGIN = 0.5  # px added to each side of a truth box: boxes are drawn on the pixel grid (±0.5 px)
_NAN = float("nan")
_TRUE, _FALSE = {"1", "1.0", "true", "True"}, {"0", "0.0", "false", "False"}
SETTLE = 6  # pd_settled leaves out each target's first SETTLE visible frames (the paper's m = 6 hits)


class TruthError(ValueError):
    """Malformed tracks or truth CSV; the message names file, line and column."""


class Truth(tuple[Points, Points]):
    """Truth as the pair ``(shown, hidden)`` (visible and don't-care points, {frame: [(target_id,
    x, y)]}), so it unpacks and compares like that tuple (boxes aside), plus ``boxes``: {frame:
    {target_id: (w, h)}} of the points that have a box (empty: none)."""

    boxes: Boxes

    def __new__(cls, shown: Points, hidden: Points, boxes: Boxes | None = None) -> Truth:
        self = super().__new__(cls, (shown, hidden))
        self.boxes = boxes or {}
        return self

    def __getnewargs__(self) -> tuple[Points, Points, Boxes]:  # for pickle and copy
        return self[0], self[1], self.boxes

    @property
    def shown(self) -> Points:
        return self[0]

    @property
    def hidden(self) -> Points:
        return self[1]

    @classmethod
    def of(cls, truth: tuple[Points, Points]) -> Truth:
        """``truth`` itself when a Truth, else the pair without boxes."""
        return truth if isinstance(truth, Truth) else cls(truth[0], truth[1])


def describe_rule(gate: float, boxes: bool) -> str:
    """The matching rule in words: ``gate 3 px``, or with ``boxes`` ``gate 3 px or inside the truth box ...``."""
    rule = f"gate {gate:g} px"
    return f"{rule} or inside the truth box (w,h) grown {BOX_MARGIN:g} px a side" if boxes else rule


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


@dataclass(frozen=True)
class TargetEval:
    """One target: visible frames T_i, matched frames k_i, p_d = k_i / T_i, latency in frames."""

    target_id: int
    frames: int
    matched: int
    p_d: float
    latency: float  # first matched frame - first visible frame; NaN if never matched
    main_track: int | None
    id_switches: int
    cle_rms: float
    settled_frames: int = 0   # visible frames after the first SETTLE ones
    settled_matched: int = 0  # of those, matched


@dataclass(frozen=True)
class EvalResult:
    """Whole-sequence metrics; distances in pixels, ``matches`` counts every matched truth point."""

    gate: float
    frames: int
    truth_points: int
    matches: int
    misses: int
    false_positives: int
    ignored: int  # track points on hidden targets (not false alarms)
    id_switches: int
    fragmentations: int
    mota: float
    motp: float
    idf1: float
    cle_mean: float
    cle_rms: float
    pd: float
    fa_per_frame: float
    latency_mean: float
    p_f: float
    per_target: tuple[TargetEval, ...]
    pd_settled: float = _NAN  # Pd without each target's first SETTLE visible frames
    match_rule: str = ""  # describe_rule(); "" becomes the gate's ("gate 3 px")
    hota: float = _NAN   # HOTA (wfviz.hota), similarity max(0, 1 - d / gate) to the truth's centre
    det_a: float = _NAN  # its detection accuracy DetA
    ass_a: float = _NAN  # its association accuracy AssA

    def __post_init__(self) -> None:
        if not self.match_rule:
            object.__setattr__(self, "match_rule", describe_rule(self.gate, False))

    def to_dict(self) -> dict:
        """JSON-ready dict: floats, ints, lists; NaN becomes None."""
        def clean(v: Any) -> Any:
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            if isinstance(v, float) and math.isnan(v):
                return None
            return v
        return clean(asdict(self))


@dataclass(frozen=True)
class FrameErrors:
    """One frame: mean centre error of matches, missed targets, (track, target, px) matches and
    the ids of the false alarms (tracks matching no visible target, those on hidden ones left out)."""

    cle_mean: float
    missed: int
    matches: tuple[tuple[int, int, float], ...]
    false_tracks: tuple[int, ...]

    @property
    def false_alarms(self) -> int:
        return len(self.false_tracks)


def _parse(text: str | None, where: str, col: str, kind: str) -> Any:
    """``text`` as int, float or 0/1 flag, else TruthError naming ``where`` and ``col``."""
    s = (text or "").strip()
    if kind == "flag" and s in _TRUE | _FALSE:
        return s in _TRUE
    try:
        v = float(s)
        if kind != "flag" and math.isfinite(v) and (kind == "float" or v.is_integer()):
            return int(v) if kind == "int" else v
    except ValueError:
        pass
    what = {"int": "an integer", "float": "a number", "flag": "0 or 1"}[kind]
    raise TruthError(f"{where}: column {col!r}: {s!r} is not {what}" if s else f"{where}: column {col!r}: empty")


def _read(path: Path | str, id_column: str, flag: str | None, need_flag: bool = False,
          sizes: bool = False, unless: str | None = None) -> Truth:
    """Rows with ``flag`` 1 (all rows when the column is absent or ``flag`` is None), rows with 0;
    with ``sizes`` and ``w``, ``h`` columns, the boxes of the rows where they are not empty.
    ``need_flag``: a missing ``flag`` column is an error. ``unless``: a column whose rows with
    1 count as rows with ``flag`` 0 (absent: none). A UTF-8 byte-order mark is accepted."""
    name, shown, hidden, seen = Path(path).name, defaultdict(list), defaultdict(list), set()
    boxes: Boxes = defaultdict(dict)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            missing = [c for c in ("frame", id_column, "x", "y") if c not in header]
            if header and missing:
                raise TruthError(f"{name}:1: missing column {missing[0]!r} (header: {','.join(header)})")
            if header and need_flag and flag not in header:
                raise TruthError(f"{name}:1: no {flag!r} column, so tentative tracks cannot be told from "
                                 f"confirmed ones (--all-rows scores every row as confirmed)")
            use_flag = flag is not None and flag in header
            use_unless = unless is not None and unless in header
            use_box = sizes and "w" in header and "h" in header
            for row in reader:
                where = f"{name}:{reader.line_num}"
                f, i, x, y = (_parse(row.get(c), where, c, k) for c, k in
                              (("frame", "int"), (id_column, "int"), ("x", "float"), ("y", "float")))
                if f < 0:
                    raise TruthError(f"{where}: column 'frame': {f} is negative (frames are 0-based)")
                if (f, i) in seen:
                    raise TruthError(f"{where}: column {id_column!r}: {i} repeated in frame {f}")
                seen.add((f, i))
                ok = _parse(row.get(flag), where, flag, "flag") if use_flag else True
                if ok and use_unless and _parse(row.get(unless), where, unless, "flag"):
                    ok = False
                (shown if ok else hidden)[f].append((i, x, y))
                if use_box and ((row.get("w") or "").strip() or (row.get("h") or "").strip()):
                    boxes[f][i] = _box(row, where)
    except UnicodeDecodeError as e:
        raise TruthError(f"{name}: not UTF-8 text ({e.reason})") from None
    except csv.Error as e:  # a field over csv.field_size_limit(), a NUL byte, ...
        raise TruthError(f"{name}:{reader.reader.line_num}: not a valid CSV line ({e})") from None
    return Truth(dict(shown), dict(hidden), dict(boxes))


def _box(row: dict[str, str | None], where: str) -> Box:
    """The row's (w, h), both numbers >= 0, else TruthError."""
    w, h = (_parse(row.get(c), where, c, "float") for c in ("w", "h"))
    for c, v in (("w", w), ("h", h)):
        if v < 0:
            raise TruthError(f"{where}: column {c!r}: {v:g} is negative (a box size)")
    return w, h


def read_points(path: Path, id_column: str, confirmed_only: bool = False) -> Points:
    """{frame: [(id, x, y), ...]} from a tracks or truth CSV (``confirmed == 1`` rows if asked)."""
    return _read(path, id_column, "confirmed" if confirmed_only else None)[0]


def _dist(a: Sequence[Point], b: Sequence[Point]) -> np.ndarray:
    """Euclidean distance matrix (len(a), len(b)) between (id, x, y) points."""
    pa = np.array([p[1:] for p in a], float).reshape(-1, 2)
    pb = np.array([p[1:] for p in b], float).reshape(-1, 2)
    return np.hypot(*np.moveaxis(pa[:, None, :] - pb[None, :, :], 2, 0))


def _allowed(a: Sequence[Point], b: Sequence[Point], d: np.ndarray, gate: float,
             sizes: Mapping[int, Box] | None) -> np.ndarray:
    """Which truth ``a`` - point ``b`` pairs may match (:func:`_within`; ``sizes``: {target_id:
    (w, h)})."""
    if not sizes:
        return d <= gate
    half = np.array([sizes.get(p[0], (_NAN, _NAN)) for p in a], float).reshape(-1, 2) / 2
    return _within(np.array([p[1:] for p in a], float).reshape(-1, 2),
                   np.array([p[1:] for p in b], float).reshape(-1, 2), d, gate, half)


def _within(pa: np.ndarray, pb: np.ndarray, d: np.ndarray, gate: float, half: np.ndarray) -> np.ndarray:
    """The matching rule, (len(pa), len(pb)): truth ``pa`` and point ``pb`` (N, 2) at distance
    ``d`` may match when ``d`` <= ``gate`` or ``pb`` lies inside the truth's box of half sizes
    ``half`` (N, 2; NaN: no box) grown by BOX_MARGIN a side."""
    grown = half + BOX_MARGIN
    return (d <= gate) | (np.abs(pb[None, :, :] - pa[:, None, :]) <= grown[:, None, :]).all(axis=2)


def matchable(target: Point, xy: np.ndarray, gate: float, box: Box | None = None) -> np.ndarray:
    """Which points ``xy`` (N, 2) the scoring rule (:func:`_within`) lets match truth point
    ``target`` (id, x, y) with box ``box`` (w, h; None: none)."""
    pb = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    pa = np.array([target[1:]], dtype=np.float64)
    d = np.hypot(pb[:, 0] - pa[0, 0], pb[:, 1] - pa[0, 1])[None, :]
    half = np.array([box if box else (_NAN, _NAN)], dtype=np.float64) / 2
    return _within(pa, pb, d, gate, half)[0]


def _assign(a: Sequence[Point], b: Sequence[Point], gate: float,
            sizes: Mapping[int, Box] | None = None) -> list[tuple[int, int, float]]:
    """Optimal (most pairs, then least total distance) a-b pairing of the pairs allowed by the
    rule (:func:`_allowed`: within ``gate``, or inside a's box from ``sizes``): (i, j, d)."""
    if not a or not b:
        return []
    from scipy.optimize import linear_sum_assignment  # (scoring only: SciPy stays off `track`'s start-up)

    d = _dist(a, b)
    ok = _allowed(a, b, d, gate, sizes)
    rows, cols = linear_sum_assignment(np.where(ok, d, 1e9))
    return [(int(r), int(c), float(d[r, c])) for r, c in zip(rows, cols) if ok[r, c]]


def _drop_hidden(tracks: Sequence[Point], truth: Sequence[Point], hidden: Sequence[Point],
                 gate: float, sizes: Mapping[int, Box] | None = None) -> list[Point]:
    """``tracks`` minus those on hidden targets (not used by the visible truth's assignment)."""
    if not hidden or not tracks:
        return list(tracks)
    used = {j for _, j, _ in _assign(truth, tracks, gate, sizes)}
    free = [j for j in range(len(tracks)) if j not in used]
    on_hidden = {free[j] for _, j, _ in _assign(hidden, [tracks[j] for j in free], gate, sizes)}
    return [t for j, t in enumerate(tracks) if j not in on_hidden]


def frame_errors(track_pts: Sequence[Point], truth_pts: Sequence[Point], gate: float = 3.0,
                 hidden: Sequence[Point] = (), boxes: Mapping[int, Box] | None = None) -> FrameErrors:
    """Errors of one frame: optimal assignment of (id, x, y) tracks to truth within ``gate`` px,
    or inside the truth's box when ``boxes`` ({target_id: (w, h)}, the frame's) has one."""
    tracks = _drop_hidden(track_pts, truth_pts, hidden, gate, boxes)
    pairs = _assign(truth_pts, tracks, gate, boxes)
    matches = tuple((tracks[j][0], truth_pts[i][0], d) for i, j, d in pairs)
    cle = float(np.mean([d for *_, d in matches])) if matches else _NAN
    used = {j for _, j, _ in pairs}
    false = tuple(t[0] for j, t in enumerate(tracks) if j not in used)
    return FrameErrors(cle, len(truth_pts) - len(pairs), matches, false)


def score_targets(tracks: Points, truth: Points, gate: float = 3.0) -> list[TargetScore]:
    """Match tracks to truth frame by frame (Hungarian on distance, ``gate`` px at most)."""
    frames: Counter = Counter()
    errors: dict[int, list[float]] = defaultdict(list)
    ids: dict[int, list[int]] = defaultdict(list)
    for f, gt in truth.items():
        frames.update(tid for tid, _, _ in gt)
        tr = tracks.get(f, [])
        for i, j, d in _assign(gt, tr, gate):
            errors[gt[i][0]].append(d)
            ids[gt[i][0]].append(tr[j][0])
    out = []
    for tid in sorted(frames):
        seq = ids[tid]
        switches = sum(1 for a, b in zip(seq, seq[1:]) if a != b)
        out.append(TargetScore(tid, frames[tid], len(errors[tid]), tuple(errors[tid]), tuple(seq), switches))
    return out


def _evaluate(tracks: Points, truth: Points, hidden: Points, gate: float, boxes: Boxes) -> EvalResult:
    """Feed every frame of the truth's range to a motmetrics accumulator and summarise."""
    return _summarise(*_accumulate(tracks, truth, hidden, gate, boxes), truth, gate)


def _accumulate(tracks: Points, truth: Points, hidden: Points, gate: float,
                boxes: Boxes) -> tuple[Any, range, int, bool, list]:
    """A motmetrics accumulator fed every frame of the truth's range that has points, the
    range, the track points ignored on hidden truth, whether a truth box was used and each
    frame's (truth ids, track ids, similarity) for HOTA."""
    import motmetrics as mm  # pandas-heavy: import only when evaluating

    acc = mm.MOTAccumulator(auto_id=False)
    span = [f for f, v in (*truth.items(), *hidden.items()) if v]
    frames = range(min(span), max(span) + 1) if span else range(0)
    ignored = 0
    scored = []  # (truth ids, track ids, similarity) a frame, for HOTA
    # only frames with points: the others add no event, so the cost follows the rows, not the span
    busy = sorted({f for f in (*truth, *hidden, *tracks) if f in frames})
    for f in busy:
        gt, tr, sizes = truth.get(f, []), tracks.get(f, []), boxes.get(f)
        kept = _drop_hidden(tr, gt, hidden.get(f, []), gate, sizes)
        ignored += len(tr) - len(kept)
        # Own Euclidean matrix (not norm2squared_matrix, which returns squared distances): NaN = no pair.
        d = _dist(gt, kept)
        ok = _allowed(gt, kept, d, gate, sizes)
        acc.update([p[0] for p in gt], [p[0] for p in kept], np.where(ok, d, np.nan), frameid=f)
        scored.append(([p[0] for p in gt], [p[0] for p in kept], point_similarity(d, gate)))
    return acc, frames, ignored, any(boxes.get(f) for f in busy), scored


def _summarise(acc: Any, frames: range, ignored: int, boxed: bool, scored: list, truth: Points,
               gate: float) -> EvalResult:
    """The :class:`EvalResult` of an accumulator :func:`_accumulate` fed (``scored``: its
    per-frame ids and similarities, for HOTA)."""
    import motmetrics as mm

    s = mm.metrics.create().compute(acc, name="all", metrics=[
        "num_detections", "num_misses", "num_false_positives", "num_switches",
        "num_fragmentations", "mota", "motp", "idf1", "num_objects"]).iloc[0]
    ev = acc.mot_events
    hit = ev[ev.Type.isin(["MATCH", "SWITCH"])]  # SWITCH rows are matches too
    hit_frames = hit.index.get_level_values("FrameId")
    visible: dict[int, list[int]] = defaultdict(list)
    for f in sorted(truth):
        for tid, _, _ in truth[f]:
            visible[tid].append(f)
    per = []
    for tid in sorted(visible):
        mine = (hit.OId == tid).to_numpy()
        d, fr = hit.D.to_numpy(float)[mine], hit_frames[mine]
        k, t = int(mine.sum()), len(visible[tid])
        main = Counter(int(h) for h in hit.HId[mine]).most_common(1)
        late = visible[tid][SETTLE:]
        per.append(TargetEval(tid, t, k, k / t, float(min(fr) - visible[tid][0]) if k else _NAN,
                              main[0][0] if main else None,
                              int(((ev.Type == "SWITCH") & (ev.OId == tid)).sum()),
                              float(np.sqrt(np.mean(d ** 2))) if k else _NAN,
                              len(late), int(np.isin(np.asarray(fr), late).sum()) if late else 0))
    settled_n = sum(p.settled_frames for p in per)
    settled_m = sum(p.settled_matched for p in per)
    dist = hit.D.to_numpy(float)
    n_truth, fp = int(s.num_objects), int(s.num_false_positives)
    lat = [p.latency for p in per if not math.isnan(p.latency)]
    ho = hota(scored)
    return EvalResult(
        gate=float(gate), frames=len(frames), truth_points=n_truth, matches=int(s.num_detections),
        misses=int(s.num_misses), false_positives=fp, ignored=ignored, id_switches=int(s.num_switches),
        fragmentations=int(s.num_fragmentations), mota=float(s.mota), motp=float(s.motp),
        idf1=float(s.idf1), cle_mean=float(dist.mean()) if dist.size else _NAN,
        cle_rms=float(np.sqrt(np.mean(dist ** 2))) if dist.size else _NAN,
        pd=float(s.num_detections) / n_truth if n_truth else _NAN,
        fa_per_frame=fp / len(frames) if frames else _NAN,
        latency_mean=float(np.mean(lat)) if lat else _NAN,
        p_f=fp / (n_truth + fp) if n_truth + fp else _NAN, per_target=tuple(per),
        pd_settled=settled_m / settled_n if settled_n else _NAN,
        match_rule=describe_rule(gate, boxed),
        hota=ho.hota, det_a=ho.det_a, ass_a=ho.ass_a)


def read_truth(path: Path | str) -> Truth:
    """Truth CSV as (visible points, hidden points), each {frame: [(target_id, x, y)]}, with the
    boxes (``w``, ``h`` columns; a row with both empty has none) as ``.boxes``."""
    return _read(path, "target_id", "visible", sizes=True)


def evaluate_points(tracks: Points, truth: Points, gate: float = 3.0,
                    hidden: Points | None = None, boxes: Boxes | None = None) -> EvalResult:
    """Score {frame: [(track_id, x, y)]} tracks against {frame: [(target_id, x, y)]} truth
    (``boxes``: {frame: {target_id: (w, h)}}, matched within the gate or inside the box)."""
    return _evaluate(tracks, truth, hidden or {}, gate, boxes or {})


def _load(tracks: Path | str, truth: Path | str, gate: float, all_rows: bool, use_boxes: bool,
          online: bool) -> tuple[Points, Points, Points, float, Boxes]:
    """:func:`_accumulate`'s arguments from a tracks CSV and a truth CSV (see :func:`evaluate`)."""
    t = read_truth(truth)
    if not t.shown and not t.hidden:
        raise TruthError(f"{Path(truth).name}: no truth rows (only a header, or empty)")
    track_pts = (_read(tracks, "track_id", None) if all_rows
                 else _read(tracks, "track_id", "confirmed", need_flag=True,
                            unless="backfilled" if online else None))[0]
    return track_pts, t.shown, t.hidden, gate, t.boxes if use_boxes else {}


def evaluate(tracks: Path | str, truth: Path | str, gate: float = 3.0, all_rows: bool = False,
             use_boxes: bool = True, online: bool = False) -> EvalResult:
    """Score a tracks CSV (``confirmed == 1`` rows; every row with ``all_rows``, and a file
    without a ``confirmed`` column only then) against a truth CSV (``visible == 1`` rows),
    with its boxes unless not ``use_boxes``. ``online``: rows with ``backfilled == 1`` (a
    track's tentative rows rewritten as confirmed, ``--backfill``) count as tentative, the
    scores a live run had. A truth file without any row is an error."""
    return _evaluate(*_load(tracks, truth, gate, all_rows, use_boxes, online))


#: the columns of :func:`evaluate_by_frame`'s counts, one row per frame of the truth's range:
#: visible truth points, matched ones, false positives, identity switches and identity matches
#: (matches of the truth-track pairs IDF1's global assignment keeps, its IDTP)
FRAME_COUNTS = ("truth", "matches", "false_positives", "id_switches", "id_matches")


def evaluate_by_frame(tracks: Path | str, truth: Path | str, gate: float = 3.0) -> tuple[EvalResult, np.ndarray]:
    """:func:`evaluate` (confirmed rows, boxes used) and the counts behind it frame by frame:
    an int array (frames of the truth's range, :data:`FRAME_COUNTS`) whose column sums give the
    result's counts (misses = truth − matches; MOTA, Pd, false tracks a frame and IDF1 follow)."""
    track_pts, shown, hidden, gate, boxes = _load(tracks, truth, gate, False, True, False)
    acc, frames, ignored, boxed, scored = _accumulate(track_pts, shown, hidden, gate, boxes)
    return _summarise(acc, frames, ignored, boxed, scored, shown, gate), _frame_counts(acc, frames)


def _frame_counts(acc: Any, frames: range) -> np.ndarray:
    """The :data:`FRAME_COUNTS` of every frame in ``frames`` from a fed accumulator."""
    import motmetrics as mm

    out = np.zeros((len(frames), len(FRAME_COUNTS)), dtype=np.int64)
    ev = acc.mot_events
    if not len(frames) or ev.empty:
        return out
    row = ev.index.get_level_values("FrameId").to_numpy(int) - frames.start
    kind = ev.Type.astype(str).to_numpy()
    for col, types in ((0, ("MATCH", "SWITCH", "MISS")), (1, ("MATCH", "SWITCH")), (2, ("FP",)), (3, ("SWITCH",))):
        np.add.at(out[:, col], row[np.isin(kind, types)], 1)
    dfm = mm.metrics.events_to_df_map(acc.events)
    ids = mm.metrics.id_global_assignment(dfm)
    ocs, hcs, _ = mm.metrics.extract_counts_from_df_map(dfm)
    oids, hids = sorted(ocs), sorted(hcs)
    kept = {(oids[r], hids[c]) for r, c in zip(ids["rids"], ids["cids"]) if r < len(oids) and c < len(hids)}
    raw = dfm.raw.dropna(subset=["D"])
    if kept and not raw.empty:
        pairs = zip(raw.OId.to_numpy(), raw.HId.to_numpy())
        hit = np.fromiter(((o, h) in kept for o, h in pairs), dtype=bool, count=len(raw))
        np.add.at(out[:, 4], raw.index.get_level_values("FrameId").to_numpy(int)[hit] - frames.start, 1)
    return out


def format_table(result: EvalResult) -> str:
    """Plain-text report: overall metrics, then one row per target."""
    def num(v: float | int | None, fmt: str = ".3f") -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)

    r = result
    lines = [
        f"frames {r.frames}   truth points {r.truth_points}   {r.match_rule}",
        f"MOTA {num(r.mota)}   MOTP {num(r.motp)} px   IDF1 {num(r.idf1)}"
        f"   HOTA {num(r.hota)} (DetA {num(r.det_a)}, AssA {num(r.ass_a)})",
        f"matches {r.matches}   misses {r.misses}   false positives {r.false_positives}"
        f"   ignored (hidden) {r.ignored}   ID switches {r.id_switches}   fragmentations {r.fragmentations}",
        f"CLE mean {num(r.cle_mean)} px   RMS {num(r.cle_rms)} px",
        f"Pd {num(r.pd)} ({num(r.pd_settled)} after each target's first {SETTLE} frames)"
        f"   false alarms/frame {num(r.fa_per_frame)}   p_f {num(r.p_f, '.4f')}"
        f"   mean latency {num(r.latency_mean, '.1f')} frames",
        "",
        f"{'target':>6} {'frames':>6} {'matched':>7} {'p_d':>6} {'latency':>7} {'track':>5} {'id-sw':>5} {'CLE rms':>7}",
    ]
    for t in r.per_target:
        lines.append(f"{t.target_id:>6} {t.frames:>6} {t.matched:>7} {num(t.p_d):>6} {num(t.latency, '.0f'):>7} "
                     f"{num(t.main_track, 'd'):>5} {t.id_switches:>5} {num(t.cle_rms):>7}")
    return "\n".join(lines)



def format_backfilled(result: EvalResult, online: bool = False) -> str:
    """One line: the scores of the same run the other way, with every confirmed track reported
    from its first frame (``--backfill``; ``online``: without, as a live run reported them)."""
    def num(v: float | None, fmt: str = ".3f") -> str:
        return "-" if v is None or math.isnan(v) else format(v, fmt)

    r = result
    how = ("online (backfilled rows as tentative)" if online
           else "with --backfill (confirmed tracks from their first frame)")
    return (f"{how}: Pd {num(r.pd)} ({num(r.pd_settled)} after each target's first {SETTLE} frames)"
            f"   MOTA {num(r.mota)}   false alarms/frame {num(r.fa_per_frame)}"
            f"   mean latency {num(r.latency_mean, '.1f')} frames")


def has_backfilled_rows(tracks: Path | str) -> bool:
    """Whether a tracks CSV has a ``backfilled`` column with a 1 in it (``--backfill``)."""
    with open(tracks, newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        if "backfilled" not in (reader.fieldnames or []):
            return False
        return any((row.get("backfilled") or "").strip() == "1" for row in reader)
