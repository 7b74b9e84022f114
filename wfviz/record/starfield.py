"""Rerun adapter for the star-field tracker's own stages (see docs/recording.md)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.evaluate import FrameErrors
from wfviz.record.recorder import Recorder, class_ids, track_colors
from wfviz.trackers.starfield import CANDIDATE_STATUS, StarfieldResult
from wfviz.trackers.starfield.metrics import paper_scores

STAR_COLOR = (120, 190, 255, 160)
UNPAIRED_COLOR = (200, 200, 200, 160)
REFERENCE_COLOR = (0, 255, 120)
PAIR_COLOR = (120, 190, 255, 120)
NEW_COLOR = (255, 220, 0, 150)
OUT_COLOR = (255, 80, 80, 150)
DEFECT_COLOR = (255, 60, 60)
STATUS_COLORS = ((255, 150, 0, 255), (140, 140, 140, 200), (255, 60, 60, 255), (90, 90, 90, 200),
                 (200, 200, 200, 120))  # by CANDIDATE_STATUS
FOUND_COLOR, NOT_FOUND_COLOR = (0, 255, 120), (255, 80, 80)


class StarfieldRecorder(Recorder):
    """Logs star points, reference stars, star pairs, candidates, chains by list,
    re-segmentation windows, registration scalars and the paper's p_d / p_f."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._frame = 0
        self._defects_logged = -1
        self._chain_points: list[tuple[int, int, float, float, str]] = []
        self._shown: dict[int, list] = {}
        self._hidden: dict[int, list] = {}

    def track_views(self, track_ids: list[int] | None) -> rrb.View | rrb.Container:
        views = [rrb.TimeSeriesView(origin="registration", name="Registration (dx, dy px; rotation deg)",
                                    contents=["/registration/dx", "/registration/dy", "/registration/rotation"]),
                 rrb.TimeSeriesView(origin="registration", name="Star pairs / fit RMS",
                                    contents=["/registration/pairs", "/registration/rms"]),
                 rrb.TimeSeriesView(origin="chains", name="Chains (New / Run / Out)")]
        if track_ids:
            views.append(rrb.TimeSeriesView(origin="kalman", name="Kalman covariance trace",
                                            contents=[f"/kalman/{i}/cov_trace" for i in track_ids]))
        else:
            views.append(rrb.TimeSeriesView(origin="kalman", name="Kalman"))
        return rrb.Tabs(*views)

    def log_stages(self, result: StarfieldResult, images: bool) -> None:  # type: ignore[override]
        rec = self.rec
        self._frame = result.index
        if images:
            self.image("suppressed/image", result.residual.astype(np.float16))
        s = result.stars
        stars = rr.Points2D(s.xy, radii=np.sqrt(s.area / np.pi) + 0.5,
                            colors=[STAR_COLOR if p else UNPAIRED_COLOR for p in result.paired])
        if len(s.xy):  # an empty AnyValues batch only draws a warning
            rec.log("camera/stars", stars,
                    rr.AnyValues(flux=s.flux.astype(np.float64), area=s.area, paired=result.paired))
        else:
            rec.log("camera/stars", stars)
        reg = result.registration
        ref = reg.reference_cur
        rec.log("camera/reference_stars", rr.Points2D(
            ref if len(ref) else np.zeros((0, 2)), labels=["S", "P"][:len(ref)], colors=REFERENCE_COLOR,
            radii=6.0, show_labels=True))
        rec.log("camera/star_pairs", rr.LineStrips2D(result.pair_segments, colors=PAIR_COLOR, radii=0.3))
        un = result.unpaired
        rec.log("camera/candidates", rr.Points2D(
            s.xy[un] if len(un) else np.zeros((0, 2)), radii=2.5,
            colors=[STATUS_COLORS[c] for c in result.unpaired_status],
            labels=[CANDIDATE_STATUS[c] for c in result.unpaired_status], show_labels=False))
        if len(result.defects) != self._defects_logged:
            self._defects_logged = len(result.defects)
            rec.log("camera/defects", rr.Points2D(result.defects if len(result.defects) else np.zeros((0, 2)),
                                                  colors=DEFECT_COLOR, radii=2.0))
        self._log_chains(result)
        wins = [r for r in result.redetections if r.found.window is not None and r.frame == result.index]
        rec.log("camera/resegment", rr.Boxes2D(
            mins=[r.found.window[:2] for r in wins] if wins else np.zeros((0, 2)),
            sizes=[r.found.window[2:] for r in wins] if wins else np.zeros((0, 2)),
            colors=[FOUND_COLOR if r.found.uv is not None else NOT_FOUND_COLOR for r in wins],
            labels=[f"{r.chain_id} {'found' if r.found.uv is not None else 'predicted'} "
                    f"(thr {r.found.threshold:.1f})" for r in wins], radii=0.3, show_labels=False))
        if reg.ok:
            self.scalar("registration/dx", reg.dx)
            self.scalar("registration/dy", reg.dy)
            self.scalar("registration/rotation", reg.rotation)
            self.scalar("registration/rms", reg.rms)
        self.scalar("registration/pairs", float(len(reg.pairs)))
        if reg.note and reg.note != "first frame":
            level = "WARN" if reg.method == "none" else "INFO"
            what = "no registration" if reg.method == "none" else "consensus fallback"
            self.text(f"registration: {what} ({reg.note})", level=level)
        self.log_kalman(result)
        self._chain_points.extend(result.chain_points)

    def _log_chains(self, result: StarfieldResult) -> None:
        rec = self.rec
        by = {"new": [], "run": [], "out": []}
        for c in result.chains:
            by[c.status].append(c)
        for name in by:
            self.scalar(f"chains/{name}", float(len(by[name])))
        rec.log("camera/chains/new", rr.LineStrips2D(
            [c.xy for c in by["new"]], colors=NEW_COLOR, radii=0.3,
            labels=[f"New {c.chain_id}" for c in by["new"]], show_labels=False))
        run = by["run"]
        rec.log("camera/chains/run", rr.LineStrips2D(
            [c.xy for c in run], class_ids=class_ids([c.chain_id for c in run]),
            colors=track_colors([c.chain_id for c in run]), radii=0.5,
            labels=[f"Run {c.chain_id}" for c in run], show_labels=False))
        pts = [(c.chain_id, xy) for c in run for xy, k in zip(c.xy, c.kinds) if k == "predicted"]
        rec.log("camera/chains/predicted", rr.Points2D(
            [xy for _, xy in pts] if pts else np.zeros((0, 2)), class_ids=class_ids([i for i, _ in pts]),
            colors=(255, 255, 255, 120), radii=0.8))
        rec.log("camera/chains/out", rr.LineStrips2D(
            [c.xy for c in by["out"]], colors=OUT_COLOR, radii=0.4,
            labels=[f"Out {c.chain_id}" for c in by["out"]], show_labels=False))

    def log_truth(self, shown: list[tuple[int, float, float]], hidden: list[tuple[int, float, float]],
                  errors: FrameErrors) -> None:
        super().log_truth(shown, hidden, errors)
        self._shown[self._frame], self._hidden[self._frame] = shown, hidden

    def log_scores(self, table: str) -> None:
        """The ``wfviz eval`` table plus the paper's p_d / p_f counted on the chains."""
        if self._shown:
            ps = paper_scores(self._chain_points, self._shown, self._hidden)
            table = f"{table}\n\n{ps.table()}"
        super().log_scores(table)
