"""``wfviz compare``'s recording: every run under ``runs/<label>/`` (the paths of a single
recording below that root, by the run's own adapter), the raw frame once at ``camera/image``,
and the comparison under ``compare/`` (metrics with a series per run, disagreement marks and
log, the parameters in which the runs differ, the closing table). With truth, each run's tracks
are coloured by the truth target they match (:class:`~wfviz.record.colors.TargetPalette`), so a
target has one colour in every run. See docs/recording.md."""

from __future__ import annotations

import signal
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from wfviz.compare.differences import KINDS, FrameComparison
from wfviz.compare.parameters import differences_markdown, parameter_differences
from wfviz.compare.runs import RunSpec
from wfviz.compare.summary import CompareSummary, format_summary, summarize
from wfviz.evaluate import format_table
from wfviz.io.frames import Frame
from wfviz.io.outputs import replace_into, temp_path
from wfviz.record import recorder_class
from wfviz.record.colors import TargetPalette
from wfviz.record.evidence import DRAW_MARKS, DRAW_MISSES, FALSE_TRACK_COLOR, MARK_RADIUS, MISS_RADIUS, MISSED_COLOR
from wfviz.record.images import ImageLog
from wfviz.record.recorder import APPLICATION_ID, BATCHER, ColumnBuffer, pixel_centres
from wfviz.record_options import RecorderOptions
from wfviz.sinks import BaseSink, FrameTruth, RunEnd, Step

#: images a run sharing another run's front end leaves to it (the same arrays)
SHARED_IMAGES = frozenset({"suppressed/image", "suppressed/noise"})
RUN_COLORS = ((31, 160, 255), (255, 127, 14), (44, 200, 80), (230, 60, 60), (170, 110, 230), (140, 86, 75),
              (240, 120, 200), (190, 190, 40), (23, 210, 210), (150, 150, 150))
MARK_COLORS = {"missed": MISSED_COLOR, "false_track": FALSE_TRACK_COLOR, "switch": (255, 0, 255),
               "unmatched": FALSE_TRACK_COLOR}  # a single recording's explanation marks look the same
#: each mark's radius and draw order: misses larger and over the others (and the defects' dots)
MARK_STYLE = {kind: (MISS_RADIUS, DRAW_MISSES) if kind == "missed" else (MARK_RADIUS, DRAW_MARKS) for kind in KINDS}
METRICS = (("pd", "Pd per frame"), ("false_tracks", "False tracks"), ("cle", "CLE (px)"),
           ("tracks", "Confirmed tracks"), ("ms", "ms per frame"))


def run_color(i: int) -> tuple[int, int, int]:
    return RUN_COLORS[i % len(RUN_COLORS)]


def compare_blueprint(labels: list[str], image_of: list[str], truth: bool) -> rrb.Blueprint:
    """The runs' camera views side by side (raw frame, the run's overlays but its sensor
    defects, which a tick in the blueprint panel shows, the marks), their residuals in a second
    tab, the metrics with one series per run, the disagreement log, the closing table and the
    parameters in which the runs differ. ``image_of[i]``: the run whose residual run ``i`` shows."""
    cams = [rrb.Spatial2DView(origin="/", name=label, contents=[
        "/camera/image", f"/runs/{label}/camera/**", "/compare/marks/**"],
        overrides={f"/runs/{label}/camera/bad_pixels": rrb.EntityBehavior(visible=False)}) for label in labels]
    residuals = [rrb.Spatial2DView(origin="/", name=f"{label}: background-suppressed", contents=[
        f"/runs/{src}/suppressed/**", f"/runs/{label}/camera/detections", f"/runs/{label}/camera/predictions",
        "/compare/marks/**"]) for label, src in zip(labels, image_of)]
    shown = [m for m in METRICS if truth or m[0] in ("tracks", "ms")]
    plots = [rrb.TimeSeriesView(origin=f"compare/metrics/{m}", name=n) for m, n in shown]
    half = (len(plots) + 1) // 2
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Tabs(rrb.Horizontal(*cams, name="Camera + overlays"),
                     rrb.Horizontal(*residuals, name="Background-suppressed")),
            rrb.Horizontal(
                rrb.Tabs(*plots[:half]), rrb.Tabs(*plots[half:]),
                rrb.Tabs(rrb.TextLogView(origin="compare/log", name="Disagreements"),
                         rrb.TextDocumentView(origin="compare/summary", name="Scores"),
                         rrb.TextDocumentView(origin="compare/parameters", name="Parameters"),
                         *[rrb.TextLogView(origin=f"runs/{label}/log", name=f"{label} log") for label in labels]),
            ),
            row_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="frame", state="collapsed"),
    )


class CompareRecorder(BaseSink):
    """Writes one comparison recording (see the module docstring): a sink of the drive loop,
    reading each frame's :class:`FrameComparison` (the :class:`~wfviz.compare.session.DisagreementSink`'s)
    and every run's :class:`FrameTruth` (its :class:`~wfviz.sinks.ScoreSink`'s, with truth) from
    what the sinks publish. ``options``: the source shown and the images (as a single
    recording's); ``truth``: truth is given (the metrics against it are shown, the tracks are
    coloured by the target they match)."""

    def __init__(self, path: Path, runs: list[RunSpec], groups: list[int], options: RecorderOptions, *,
                 truth: bool = False) -> None:
        self.path, self.temp = path, temp_path(path)
        self.specs, self.groups = list(runs), list(groups)
        self.labels = [r.label for r in runs]
        self.rec = rr.RecordingStream(APPLICATION_ID, batcher_config=BATCHER)
        image_of = [self.labels[g] for g in groups]
        try:
            self.rec.set_sinks(rr.FileSink(str(self.temp)),  # not save(): a name that is not UTF-8 works
                               default_blueprint=compare_blueprint(self.labels, image_of, truth))
        except BaseException:
            self.temp.unlink(missing_ok=True)
            raise
        self.images = ImageLog(self.rec, options.image_every, options.exact_every, options.jpeg_quality)
        pixel_centres(self.rec, ("camera/image",))
        self.frames_logged = 0
        self.columns = ColumnBuffer(self.rec)
        self.runs: list[Any] = []
        self.palettes = [TargetPalette() for _ in runs] if truth else []
        for i, (r, g) in enumerate(zip(runs, groups)):
            cls = recorder_class(r.tracker)
            own = replace(options, source=f"{options.source} ({r.source})", config_text=r.config_text,
                          trail_length=r.config.tracking.trail_length, live=None)
            sub = cls(None, r.tracker, own, stream=self.rec, root=f"runs/{r.label}", raw_image=False,
                      shared_images=SHARED_IMAGES if g != i else frozenset())
            if truth:
                sub.color_of = self.palettes[i].color
            self.runs.append(sub)
        self.metrics = tuple(m for m, _ in METRICS if truth or m in ("tracks", "ms"))
        for m in self.metrics:
            for i, label in enumerate(self.labels):
                self.rec.log(f"compare/metrics/{m}/{label}", rr.SeriesLines(colors=run_color(i), names=label,
                                                                           widths=1.5), static=True)
        self.rec.log("compare/runs", rr.TextDocument("\n".join(
            f"- **{r.label}**: {r.tracker}, {r.source}" + (f" (front end shared with {self.labels[g]})" if g != i else "")
            for i, (r, g) in enumerate(zip(runs, groups))), media_type=rr.MediaType.MARKDOWN), static=True)
        self.rec.log("compare/parameters", rr.TextDocument(differences_markdown(parameter_differences(runs)),
                                                           media_type=rr.MediaType.MARKDOWN), static=True)
        self._closed = False

    def step(self, step: Step) -> None:
        cmp = step.facts.get(FrameComparison)
        assert cmp is not None, "no DisagreementSink in the comparison"
        self.log(step.frame, step.results, cmp, step.run_ms,
                 [step.facts.get(FrameTruth, i) for i in range(len(self.runs))])

    def finish(self, end: RunEnd) -> None:
        self.close(summarize(self.specs, self.groups, end))

    def log(self, frame: Frame, results: tuple[Any, ...], cmp: FrameComparison, ms: tuple[float, ...],
            truths: list[FrameTruth | None]) -> None:
        """One frame: the raw image (see :class:`ImageLog`), every run's stages (with truth: its
        tracks coloured by the targets they match, its truth and errors), the marks, the
        disagreements that began or ended, the metrics."""
        rec = self.rec
        rec.set_time("frame", sequence=frame.index)
        rec.set_time("time", duration=frame.time)
        if self.images.begin_frame(self.frames_logged, frame.index, frame.time):
            self.images.log("camera/image", frame.image)
        for i, (sub, result, truth) in enumerate(zip(self.runs, results, truths)):
            if truth is not None and self.palettes:
                self.palettes[i].update((track, target) for track, target, _ in truth.errors.matches)
            sub.log(frame, result)
            if truth is not None:
                sub.log_truth(truth.shown, truth.hidden, truth.errors)
        for kind in KINDS:
            ms_ = [m for m in cmp.marks if m.kind == kind]
            rec.log(f"compare/marks/{kind}", rr.Points2D(
                np.array([(m.x, m.y) for m in ms_], dtype=np.float32).reshape(-1, 2),
                labels=[m.text for m in ms_], colors=MARK_COLORS[kind], radii=MARK_STYLE[kind][0],
                draw_order=MARK_STYLE[kind][1], show_labels=False))
        f, t = frame.index, frame.time
        for m in cmp.began:
            self.columns.text("compare/log", f, t, m.text, "WARN")
        for m in cmp.ended:
            self.columns.text("compare/log", f, t, f"agree again: {m.text}", "INFO")
        self.columns.scalar("compare/disagreements", f, t, float(len(cmp.marks)))
        for i, (label, rf) in enumerate(zip(self.labels, cmp.runs)):
            values = {"pd": rf.pd, "false_tracks": rf.false_tracks, "cle": rf.cle, "tracks": rf.tracks, "ms": ms[i]}
            for name in self.metrics:
                self.columns.scalar(f"compare/metrics/{name}/{label}", f, t, float(values[name]))
        self.frames_logged += 1
        self.columns.end_frame()

    def close(self, summary: CompareSummary) -> None:
        """The closing table (``compare/summary``), every run's scores, a warning when a signal
        stopped the run; the file is completed and renamed into place."""
        self.rec.log("compare/summary", rr.TextDocument(f"```\n{format_summary(summary)}\n```",
                                                        media_type=rr.MediaType.MARKDOWN), static=True)
        for sub, outcome in zip(self.runs, summary.runs):
            if outcome.scores is not None:
                sub.log_scores(format_table(outcome.scores))
            if summary.signal is not None:
                sub.log_message(f"interrupted by {signal.Signals(summary.signal).name} after {summary.frames} frames",
                                level="WARN")
            sub.close()
        self._close()
        replace_into(self.temp, self.path)

    def abort(self) -> None:
        """Remove the partial file."""
        try:
            self._close()
        except Exception:  # noqa: BLE001 - the file is removed anyway
            pass
        self.temp.unlink(missing_ok=True)

    def _close(self) -> None:
        if not self._closed:
            self._closed = True
            for log in (self.images, *(sub.images for sub in self.runs)):
                log.close()  # every image sent (idempotent: the runs' close() did it after finish)
            self.columns.flush()
            self.rec.flush()
            self.rec.disconnect()

