"""Rerun adapter for the GEWC tracker's own stages (see docs/recording.md)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.record.recorder import Recorder, log_geometry, track_color
from wfviz.trackers.gewc import GEWCResult


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
            *self.kalman_views(track_ids),
        )

    def log_stages(self, result: GEWCResult, images: bool) -> None:  # type: ignore[override]
        rec = self.rec
        log_geometry(rec, result)
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
