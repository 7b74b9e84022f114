"""Rerun adapter for the feature-fusion tracker's own stages (see docs/recording.md)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.record.evidence import DRAW_TRACKS
from wfviz.record.recorder import DETECTION_COLOR, Recorder, class_ids, track_colors
from wfviz.trackers.fusion import FusionResult
from wfviz.tracking import EventKind

LOST_COLOR = (255, 80, 80, 200)


class FusionRecorder(Recorder):
    """Logs candidates' features, rectangles, measurements, Φ and matching cost per track,
    global re-detections, residual, mask, horizon and Kalman scalars."""

    def series_views(self) -> list[rrb.View]:
        return super().series_views() + self.motion_views()

    def track_views(self, track_ids: list[int] | None) -> rrb.View | rrb.Container:
        if not track_ids:
            return rrb.Tabs(rrb.TimeSeriesView(origin="fusion", name="Fused feature Φ / cost"),
                            rrb.TimeSeriesView(origin="kalman", name="Kalman"))
        return rrb.Tabs(
            rrb.TimeSeriesView(origin="fusion", name="Fused feature Φ",
                               contents=[f"/fusion/{i}/phi" for i in track_ids]),
            rrb.TimeSeriesView(origin="fusion", name="Matching cost",
                               contents=[f"/fusion/{i}/cost" for i in track_ids]),
            *self.kalman_views(track_ids),
            *self.test_views(track_ids),
        )

    def log_stages(self, result: FusionResult, images: bool) -> None:  # type: ignore[override]
        rec = self.rec
        self.log_front_end(result, images)
        if images:
            self.image("suppressed/image", result.front.suppressed)
        f, n = result.features, len(result.features)
        phi = np.full(n, np.nan)
        cost = np.full(n, np.nan)
        for m in result.matches:
            phi[m.detection], cost[m.detection] = m.phi, m.cost
        # features on hover, next to the base's area / peak / flux
        if n:  # an empty AnyValues batch only draws a warning
            rec.log("camera/detections", rr.AnyValues(
                grey=f.grey.astype(np.float64), phi=phi, cost=cost, track=result.assigned.astype(np.int64),
                rect_width=np.linalg.norm(f.rects[:, 1] - f.rects[:, 0], axis=1),
                rect_height=np.linalg.norm(f.rects[:, 3] - f.rects[:, 0], axis=1)))
        colors = [self.color_of(int(t)) if t >= 0 else DETECTION_COLOR[:3] for t in result.assigned]
        rec.log("camera/rects", rr.LineStrips2D(
            [np.vstack([r, r[:1]]) for r in f.rects], colors=colors, radii=0.3))
        m = result.matches
        ids = [x.track_id for x in m]
        rec.log("camera/measurements", rr.Points2D(
            np.array([(x.x, x.y) for x in m], dtype=np.float32).reshape(-1, 2),
            class_ids=class_ids(ids), colors=track_colors(ids, color_of=self.color_of), radii=0.5,
            draw_order=DRAW_TRACKS, show_labels=False))
        a = np.linspace(0, 2 * np.pi, 73)
        r = result.recover_radius
        lost = result.lost if result.global_detection else ()
        rec.log("camera/recovery", rr.LineStrips2D(
            [np.column_stack([p.x + r * np.cos(a), p.y + r * np.sin(a)]) for p in lost],
            class_ids=class_ids([p.track_id for p in lost]), colors=LOST_COLOR, radii=0.4))
        self.scalar("detection/global", 1.0 if result.global_detection else 0.0)
        if result.global_detection and not any(e.kind == EventKind.WINDOW_LOST for e in result.events):
            self.text(f"global detection ({result.global_reason}): "
                      f"{len(result.detections)} candidates", level="DEBUG")
        confirmed = result.confirmed_ids
        for x in m:
            if x.track_id in confirmed:
                self.scalar(f"fusion/{x.track_id}/phi", x.phi)
                self.scalar(f"fusion/{x.track_id}/cost", x.cost)
        self.log_kalman(result, result.innovations)

