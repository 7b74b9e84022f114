"""Rerun adapter for the track-before-detect tracker's own stages (see docs/recording.md)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.record.recorder import Recorder
from wfviz.trackers.tbd import TBDResult

# particle colour by hypothesis n (PF_n); index 0 unused (PF_0 has no target)
HYPOTHESIS_COLORS = ((0, 0, 0, 0), (0, 220, 255, 110), (255, 80, 220, 110), (255, 230, 0, 110),
                     (120, 255, 120, 110), (255, 140, 0, 110), (200, 200, 255, 110))
REGION_COLORS = {"tile": (120, 120, 255, 120), "window": (0, 200, 255, 160), "full": (0, 0, 0, 0)}


class TBDRecorder(Recorder):
    """Logs the particles of every PF_n, the posterior of the target count, the normalised
    frame, the regions (tiles or candidate windows), noise sigma and per-track amplitude."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._counts_logged = 0
        self._regions_logged = False

    def image_views(self) -> list[rrb.View]:
        """The particles over the raw and the normalised frames."""
        return [rrb.Spatial2DView(origin="camera", name="Camera + particles",
                                  contents=["$origin/**", "/tbd/particles"]),
                rrb.Spatial2DView(origin="suppressed", name="Normalised frame (z - b) / sigma",
                                  contents=["$origin/**", "/tbd/particles", "/camera/predictions",
                                            "/camera/gates", "/camera/truth", "/camera/regions"])]

    def series_views(self) -> list[rrb.View]:
        """The count posterior first, then the common series."""
        return [rrb.TimeSeriesView(origin="tbd/p_count", name="P(target count)"),
                rrb.TimeSeriesView(origin="timing", name="Stage time (ms)"),
                rrb.TimeSeriesView(origin="eval", name="Errors vs truth")]

    def track_views(self, track_ids: list[int] | None) -> rrb.View | rrb.Container:
        views = [rrb.TimeSeriesView(origin="tbd", name="Count estimate / noise sigma",
                                    contents=["/tbd/count", "/tbd/noise_sigma"])]
        if track_ids:
            views += [rrb.TimeSeriesView(origin="tbd", name="Amplitude (peak SNR)",
                                         contents=[f"/tbd/{i}/amplitude" for i in track_ids]),
                      rrb.TimeSeriesView(origin="tbd", name="Position std (px)",
                                         contents=[f"/tbd/{i}/position_std" for i in track_ids])]
        return rrb.Tabs(*views)

    def log_stages(self, result: TBDResult, images: bool) -> None:  # type: ignore[override]
        rec = self.rec
        if images:
            self.image("suppressed/image", result.normalised.astype(np.float16))
        pts = result.particles
        hyp = pts[:, 2].astype(np.int64)
        colors = np.array(HYPOTHESIS_COLORS, dtype=np.uint8)[np.clip(hyp, 0, len(HYPOTHESIS_COLORS) - 1)]
        points = rr.Points2D(pts[:, :2], colors=colors, radii=0.25)
        if len(pts):  # an empty AnyValues batch only draws a warning
            rec.log("tbd/particles", points, rr.AnyValues(hypothesis=hyp))
        else:
            rec.log("tbd/particles", points)
        p = result.p_count
        n_log = max(len(p), self._counts_logged)
        for n in range(n_log):
            self.scalar(f"tbd/p_count/{n}", float(p[n]) if n < len(p) else 0.0)
        self._counts_logged = n_log
        self.scalar("tbd/count", float(result.count))
        self.scalar("tbd/noise_sigma", float(result.noise_sigma))
        regions = [r for r in result.regions if r.kind != "full"]
        if regions or self._regions_logged:
            rec.log("camera/regions", rr.Boxes2D(
                centers=[[r.x0 + (r.width - 1) / 2, r.y0 + (r.height - 1) / 2] for r in regions] or np.zeros((0, 2)),
                half_sizes=[[r.width / 2, r.height / 2] for r in regions] or np.zeros((0, 2)),
                colors=[REGION_COLORS[r.kind] for r in regions] or None, radii=0.3,
                labels=[f"R{r.region_id} n={r.count}" for r in regions] or None, show_labels=False))
            self._regions_logged = True
        confirmed = result.confirmed_ids
        for tid, amp in result.amplitudes.items():
            if tid in confirmed:
                self.scalar(f"tbd/{tid}/amplitude", float(amp))
                self.scalar(f"tbd/{tid}/position_std", float(result.position_std[tid]))
