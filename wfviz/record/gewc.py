"""Rerun adapter for the GEWC tracker's own stages (see docs/recording.md)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.record.evidence import DRAW_CLUTTER, DRAW_TRACKS, class_context
from wfviz.record.recorder import Recorder, class_ids, track_color, track_colors
from wfviz.trackers.gewc import GEWCResult


CLUTTER_COLOR = (255, 96, 0, 160)
LINE_COLOR = (0, 200, 255, 200)


class GEWCRecorder(Recorder):
    """Logs mask, horizon, residual, GEWC measurements and weights, Kalman scalars."""

    _clutter_started = False
    _lines_started = False

    def series_views(self) -> list[rrb.View]:
        return super().series_views() + self.motion_views()

    def track_views(self, track_ids: list[int] | None) -> rrb.View | rrb.Container:
        if not track_ids:
            return rrb.Tabs(rrb.BarChartView(origin="gewc", name="GEWC region weights"),
                            rrb.TimeSeriesView(origin="kalman", name="Kalman"))
        shown = track_ids[:12]
        # two columns up to 4 tracks, three beyond: each panel wide enough for its title
        return rrb.Tabs(
            rrb.Grid(*[rrb.BarChartView(origin=f"gewc/{i}", name=f"GEWC weights, track {i}",
                                        plot_legend=rrb.PlotLegend(visible=False))
                       for i in shown], grid_columns=2 if len(shown) <= 4 else 3, name="GEWC region weights"),
            *self.kalman_views(track_ids),
            *self.test_views(track_ids),
        )

    def log_stages(self, result: GEWCResult, images: bool) -> None:  # type: ignore[override]
        rec = self.rec
        self.log_front_end(result, images)
        if images:
            self.image("suppressed/image", result.front.suppressed)
            # a slow map: on exact frames, as the noise map (on image frames with previews only)
            due = self.images.exact if self.images.exact_every else images
            if result.clutter_map is not None and due:  # one value per cell, drawn over the frame's pixels
                h, w = result.front.suppressed.shape[:2]
                cell = result.clutter_map.cell
                prior = result.clutter_map.prior((h, w), result.front.offset).astype(np.float32)
                up = np.repeat(np.repeat(prior, cell, 0), cell, 1)[:h, :w]
                self.image("clutter/map", up, value_map=True)
        if result.clutter is not None:  # static clutter stage (clutter.enabled)
            if not self._clutter_started:
                self._clutter_started = True
                rec.log("camera/clutter", class_context([(1, "static clutter", CLUTTER_COLOR)]), static=True)
                self.add_legend([("static clutter", CLUTTER_COLOR)])
            static = result.clutter == 1
            self.static_once("camera/clutter", lambda: rr.Points2D.from_fields(
                radii=2.5, class_ids=1, colors=CLUTTER_COLOR, draw_order=DRAW_CLUTTER, show_labels=False))
            self.instances("camera/clutter", rr.Points2D, int(static.sum()),
                           positions=result.detections.xy[static].astype(np.float32).reshape(-1, 2))
            self.scalar("detection/static", int(static.sum()))
        self._log_line_like(result)
        m = result.measurements
        ids = [x.track_id for x in m]
        self.static_once("camera/centroids", lambda: rr.Points2D.from_fields(radii=0.5, draw_order=DRAW_TRACKS,
                                                                    show_labels=False))
        self.instances("camera/centroids", rr.Points2D, len(ids),
                       positions=np.array([(x.x, x.y) for x in m], dtype=np.float32).reshape(-1, 2),
                       class_ids=class_ids(ids), colors=track_colors(ids, color_of=self.color_of))
        confirmed = result.confirmed_ids
        for x in m:
            if x.track_id in confirmed:
                self.bar(f"gewc/{x.track_id}", x.weights, track_color(x.track_id))
        self.log_kalman(result, result.innovations)

    def _log_line_like(self, result: GEWCResult) -> None:
        """The line-like detections (part of a road, a wire, an edge: they start no track),
        labelled with their linearity against its level on hover, and their number."""
        d = result.detections
        if d.linearity is None:
            return
        rec = self.rec
        if not self._lines_started:
            self._lines_started = True
            rec.log("camera/line_like", class_context([(1, "line-like", LINE_COLOR)]), static=True)
            self.add_legend([("line-like", LINE_COLOR)])
        line = d.line_like()
        labels = [f"linearity {v:.2f} > {d.max_linearity:.2f}: line-like, starts no track"
                  for v in d.linearity[line].tolist()]
        self.static_once("camera/line_like", lambda: rr.Points2D.from_fields(
            radii=3.0, class_ids=1, colors=LINE_COLOR, draw_order=DRAW_CLUTTER, show_labels=False))
        self.instances("camera/line_like", rr.Points2D, len(labels),
                       positions=d.xy[line].astype(np.float32).reshape(-1, 2), labels=labels)
        self.scalar("detection/line_like", int(line.sum()))
