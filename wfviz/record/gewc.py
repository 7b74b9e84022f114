"""Rerun adapter for the GEWC tracker's own stages (see docs/recording.md)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.record.recorder import Recorder, track_color
from wfviz.trackers.gewc import GEWCResult

MASK_COLOR = (255, 0, 255, 70)


class GEWCRecorder(Recorder):
    """Logs mask, horizon, residual, GEWC measurements and weights, Kalman scalars."""

    def track_views(self, track_ids: list[int] | None) -> rrb.View | rrb.Container:
        if not track_ids:
            return rrb.Tabs(rrb.BarChartView(origin="gewc", name="GEWC region weights"),
                            rrb.TimeSeriesView(origin="kalman", name="Kalman"))
        shown = track_ids[:12]
        return rrb.Tabs(
            rrb.Grid(*[rrb.BarChartView(origin=f"gewc/{i}", name=f"GEWC weights, track {i}")
                       for i in shown], name="GEWC region weights"),
            rrb.TimeSeriesView(origin="kalman", name="Kalman innovation (px)",
                               contents=[f"/kalman/{i}/innovation" for i in track_ids]),
            rrb.TimeSeriesView(origin="kalman", name="Kalman covariance trace",
                               contents=[f"/kalman/{i}/cov_trace" for i in track_ids]),
        )

    def log_stages(self, result: GEWCResult, images: bool) -> None:  # type: ignore[override]
        rec = self.rec
        if result.mask_changed:
            rec.log("camera/mask", rr.AnnotationContext([
                rr.ClassDescription(info=rr.AnnotationInfo(id=0, label="imaging", color=(0, 0, 0, 0))),
                rr.ClassDescription(info=rr.AnnotationInfo(id=1, label="non-imaging", color=MASK_COLOR))]),
                static=True)
            rec.log("camera/mask", rr.SegmentationImage(result.mask.astype(np.uint8)), static=True)
            c = result.circle
            a = np.linspace(0, 2 * np.pi, 181)
            rec.log("camera/imaging_circle", rr.LineStrips2D(
                [np.column_stack([c.cx + c.radius * np.cos(a), c.cy + c.radius * np.sin(a)])] if c else [],
                labels=[f"R={c.radius:.1f}"] if c else None, colors=MASK_COLOR[:3], radii=0.5), static=True)
        if result.bad_pixels_changed:
            hp = result.bad_pixels
            rec.log("camera/bad_pixels", rr.Points2D(hp[:, ::-1].astype(np.float32) if len(hp) else np.zeros((0, 2)),
                                                     colors=(255, 60, 60), radii=2.0))
        if result.horizon_updated:
            line = result.horizon.polyline() if result.horizon is not None else None
            rec.log("camera/horizon", rr.LineStrips2D(
                [line] if line is not None and len(line) else [], colors=(0, 255, 120), radii=0.8))
        if images:
            rec.log("suppressed/image", rr.Image(result.suppressed))
        if result.camera_shift is not None:
            rec.log("registration/dx", rr.Scalars(result.camera_shift[0]))
            rec.log("registration/dy", rr.Scalars(result.camera_shift[1]))
        m = result.measurements
        rec.log("camera/centroids", rr.Points2D(
            [[x.x, x.y] for x in m] if m else np.zeros((0, 2)), class_ids=[x.track_id for x in m],
            colors=[track_color(x.track_id) for x in m], radii=0.5, show_labels=False))
        confirmed = {t.track_id for t in result.tracks if t.confirmed}
        for x in m:
            if x.track_id in confirmed:
                rec.log(f"gewc/{x.track_id}", rr.BarChart(np.asarray(x.weights, dtype=np.float64),
                                                          color=track_color(x.track_id)))
        for tid, nu in result.innovations.items():
            if tid in confirmed:
                rec.log(f"kalman/{tid}/innovation", rr.Scalars(float(np.hypot(*nu))))
        for p in result.predictions:
            if p.confirmed:
                rec.log(f"kalman/{p.track_id}/cov_trace", rr.Scalars(p.cov_trace))
