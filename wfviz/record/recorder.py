"""Maps the stage results every tracker shares to Rerun entities (see docs/recording.md)."""

from __future__ import annotations

import colorsys
from collections import deque
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.evaluate import FrameErrors
from wfviz.frames import Frame
from wfviz.trackers.base import FrameResult

APPLICATION_ID = "wfviz"
TENTATIVE_COLOR = (150, 150, 150, 90)
DETECTION_COLOR = (255, 200, 0, 255)
TRUTH_COLOR = (255, 255, 255, 200)
TRUTH_HIDDEN_COLOR = (255, 255, 255, 70)
EVENT_LEVELS = {"born": "DEBUG", "confirmed": "INFO", "deleted": "WARN",
                "meeting_on": "INFO", "meeting_off": "INFO"}  # deleting a tentative track: DEBUG


def track_color(track_id: int) -> tuple[int, int, int]:
    """A stable, well-separated colour for a track id (golden-ratio hue steps)."""
    h = (track_id * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.85, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


MASK_COLOR = (255, 0, 255, 70)


def log_geometry(rec: rr.RecordingStream, result: object) -> None:
    """Non-imaging mask and imaging circle (static, when they change), flagged bad pixels and
    the horizon (when re-estimated), for trackers whose results carry them."""
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
        bp = result.bad_pixels
        rec.log("camera/bad_pixels", rr.Points2D(bp[:, ::-1].astype(np.float32) if len(bp) else np.zeros((0, 2)),
                                                 colors=(255, 60, 60), radii=2.0))
    if result.horizon_updated:
        line = result.horizon.polyline() if result.horizon is not None else None
        rec.log("camera/horizon", rr.LineStrips2D(
            [line] if line is not None and len(line) else [], colors=(0, 255, 120), radii=0.8))


class Recorder:
    """Writes one recording; subclasses (one per tracker) add tracker-specific stages.

    ``image_every`` logs the raw and stage images every N frames (0 = never); overlays,
    scalars and text are logged every frame.
    """

    def __init__(self, path: Path, *, source: str, tracker: str, config_text: str,
                 image_every: int = 1, trail_length: int = 60) -> None:
        self.rec = rr.RecordingStream(APPLICATION_ID)
        self.rec.save(path, default_blueprint=self.blueprint())
        self.image_every = image_every
        self._trails: dict[int, deque] = {}
        self._trail_length = trail_length
        self._labelled: set[int] = set()
        self.confirmed_ids: set[int] = set()
        self.frames_logged = 0
        self.rec.log("config", rr.TextDocument(
            f"# wfviz {tracker}\n\nSource: `{source}`\n\n```toml\n{config_text}\n```",
            media_type=rr.MediaType.MARKDOWN), static=True)

    # -- layout ---------------------------------------------------------------------------
    def blueprint(self, track_ids: list[int] | None = None) -> rrb.Blueprint:
        """Default layout: raw image with overlays, residual, time series, bars, log.

        ``track_ids`` (known when the recording closes) splits per-track plots by track.
        """
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Vertical(*self.image_views()),
                rrb.Vertical(
                    rrb.Tabs(*self.series_views()),
                    self.track_views(track_ids),
                    rrb.Tabs(rrb.TextLogView(origin="log", name="Track log", rows=rrb.archetypes.TextLogRows(
                                 filter_by_log_level=["INFO", "WARN", "ERROR"])),  # DEBUG: tentative tracks
                             rrb.TextDocumentView(origin="config", name="Config"),
                             rrb.TextDocumentView(origin="eval/summary", name="Scores")),
                ),
                column_shares=[3, 2],
            ),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(timeline="frame", state="collapsed"),
        )

    def image_views(self) -> list[rrb.View]:
        """Left column: the raw frame with overlays above the stage image."""
        return [rrb.Spatial2DView(origin="camera", name="Camera + overlays"),
                rrb.Spatial2DView(origin="suppressed", name="Background-suppressed",
                                  contents=["$origin/**", "/camera/detections", "/camera/gates",
                                            "/camera/predictions"])]

    def series_views(self) -> list[rrb.View]:
        """Right column, top tabs: per-frame series."""
        return [rrb.TimeSeriesView(origin="timing", name="Stage time (ms)"),
                rrb.TimeSeriesView(origin="detection", name="Detections"),
                rrb.TimeSeriesView(origin="eval", name="Errors vs truth")]

    def track_views(self, track_ids: list[int] | None) -> rrb.View | rrb.Container:
        """Per-track views (right column, middle); overridden by tracker adapters."""
        return rrb.TimeSeriesView(origin="kalman", name="Kalman")

    @staticmethod
    def kalman_views(track_ids: list[int]) -> list[rrb.View]:
        """Innovation and covariance-trace plots of the given tracks."""
        return [rrb.TimeSeriesView(origin="kalman", name="Kalman innovation (px)",
                                   contents=[f"/kalman/{i}/innovation" for i in track_ids]),
                rrb.TimeSeriesView(origin="kalman", name="Kalman covariance trace",
                                   contents=[f"/kalman/{i}/cov_trace" for i in track_ids])]

    # -- per frame ------------------------------------------------------------------------
    def log(self, frame: Frame, result: FrameResult) -> None:
        """Log one frame's results on the ``frame`` and ``time`` timelines."""
        rec = self.rec
        rec.set_time("frame", sequence=frame.index)
        rec.set_time("time", duration=frame.time)
        images = self.image_every > 0 and self.frames_logged % self.image_every == 0
        if images:
            rec.log("camera/image", rr.Image(frame.image))
        self._log_common(result)
        self.log_stages(result, images)
        self.frames_logged += 1

    def log_stages(self, result: FrameResult, images: bool) -> None:
        """Tracker-specific stages; overridden by each tracker's adapter."""

    def _log_common(self, result: FrameResult) -> None:
        rec = self.rec
        d = result.detections
        points = rr.Points2D(d.xy, radii=np.sqrt(d.area / np.pi) + 1.0, colors=DETECTION_COLOR)
        if len(d):  # hover values; an empty AnyValues batch only draws a warning
            rec.log("camera/detections", points, rr.AnyValues(
                area=d.area, peak=d.peak.astype(np.float64), flux=d.flux.astype(np.float64)))
        else:
            rec.log("camera/detections", points)
        rec.log("detection/count", rr.Scalars(float(len(d))))
        rec.log("detection/threshold", rr.Scalars(float(d.threshold) if np.isfinite(d.threshold) else np.nan))
        self._ensure_labels([t.track_id for t in result.tracks if t.confirmed])
        self.confirmed_ids.update(t.track_id for t in result.tracks if t.confirmed)
        preds = result.predictions
        ids = [p.track_id for p in preds]
        colors = [track_color(p.track_id) if p.confirmed else TENTATIVE_COLOR for p in preds]
        labels = [(f"{p.track_id}" + (" meet" if p.meeting else "")) if p.confirmed else ""
                  for p in preds]
        rec.log("camera/predictions", rr.Points2D(
            [[p.x, p.y] for p in preds] if preds else np.zeros((0, 2)), class_ids=ids,
            colors=colors, labels=labels, radii=[1.5 if p.confirmed else 0.7 for p in preds],
            show_labels=True))
        rec.log("camera/gates", rr.Boxes2D(
            centers=[[p.x, p.y] for p in preds] if preds else np.zeros((0, 2)),
            half_sizes=[[p.half_w, p.half_h] for p in preds] if preds else np.zeros((0, 2)),
            class_ids=ids, colors=colors, radii=[0.5 if p.confirmed else 0.2 for p in preds],
            show_labels=False))
        self._log_trails(result)
        for stage, ms in result.timings.items():
            rec.log(f"timing/{stage}", rr.Scalars(ms))
        confirmed = {t.track_id for t in result.tracks if t.confirmed} | self._labelled
        for e in result.events:
            level = EVENT_LEVELS.get(e.kind, "INFO")
            if e.kind == "deleted" and e.track_id not in confirmed:
                level = "DEBUG"
            rec.log("log", rr.TextLog(e.message, level=level))

    def _log_trails(self, result: FrameResult) -> None:
        live = set()
        for t in result.tracks:
            live.add(t.track_id)
            trail = self._trails.setdefault(t.track_id, deque(maxlen=self._trail_length))
            trail.append((t.x, t.y))
        for tid in list(self._trails):
            if tid not in live:
                del self._trails[tid]
        conf = [t for t in result.tracks if t.confirmed]
        strips = [np.array(self._trails[t.track_id], dtype=np.float32) for t in conf]
        self.rec.log("camera/tracks", rr.LineStrips2D(
            strips, class_ids=[t.track_id for t in conf], labels=[str(t.track_id) for t in conf],
            colors=[track_color(t.track_id) for t in conf], radii=0.6, show_labels=False))

    def _ensure_labels(self, confirmed_ids: list[int]) -> None:
        """Static annotation context: a stable colour and label per confirmed track id."""
        new = set(confirmed_ids) - self._labelled
        if not new:
            return
        self._labelled |= new
        self.rec.log("/", rr.AnnotationContext([
            rr.ClassDescription(info=rr.AnnotationInfo(id=i, label=f"track {i}", color=track_color(i)))
            for i in sorted(self._labelled)]), static=True)

    def log_truth(self, shown: list[tuple[int, float, float]], hidden: list[tuple[int, float, float]],
                  errors: FrameErrors) -> None:
        """Truth points (hidden ones dimmed) and this frame's errors under ``eval/``."""
        pts = shown + hidden
        self.rec.log("camera/truth", rr.Points2D(
            [[x, y] for _, x, y in pts] if pts else np.zeros((0, 2)),
            labels=[f"T{i}" for i, _, _ in shown] + [f"T{i} hidden" for i, _, _ in hidden],
            colors=[TRUTH_COLOR] * len(shown) + [TRUTH_HIDDEN_COLOR] * len(hidden),
            radii=3.0, show_labels=False))
        self.rec.log("eval/cle", rr.Scalars(errors.cle_mean))
        self.rec.log("eval/missed", rr.Scalars(float(errors.missed)))
        self.rec.log("eval/false_alarms", rr.Scalars(float(errors.false_alarms)))

    def log_scores(self, table: str) -> None:
        """Final scores against truth as static text."""
        self.rec.log("eval/summary", rr.TextDocument(f"```\n{table}\n```", media_type=rr.MediaType.MARKDOWN),
                     static=True)

    def log_message(self, text: str, level: str = "INFO") -> None:
        """A free text line in ``log`` at the current time."""
        self.rec.log("log", rr.TextLog(text, level=level))

    def close(self) -> None:
        """Send the final default blueprint (per-track views), flush and close the file."""
        ids = sorted(self.confirmed_ids)
        if ids:
            self.rec.send_blueprint(self.blueprint(ids), make_active=True, make_default=True)
        self.rec.flush()
        self.rec.disconnect()
