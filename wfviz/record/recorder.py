"""Maps the stage results every tracker shares to Rerun entities (see docs/recording.md)."""

from __future__ import annotations

import functools
import warnings
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from wfviz.evaluate import FrameErrors
from wfviz.io.clip import ClipNote, display
from wfviz.explain.types import FrameExplanation
from wfviz.io.frames import Frame
from wfviz.record.evidence import (DRAW_BAD_PIXELS, DRAW_DETECTIONS, DRAW_SEARCH_REGION, DRAW_TRACKS, DRAW_TRUTH,
                                   FALSE_TRACK_COLOR, MISSED_COLOR, Color, ExplanationLog, TestLog, cause_legend,
                                   class_context)
from wfviz.record.colors import track_color
from wfviz.record.images import ArrowBatch, ImageLog, time_columns
from wfviz.record.live import LiveMirror, live_sink
from wfviz.record_options import RecorderOptions
from wfviz.stages.front_end import FrontEndResult
from wfviz.stages.horizon import horizon_confident
from wfviz.stages.registration import CameraState
from wfviz.trackers.base import FrameResult, FrontEndTrackResult
from wfviz.tracking import EventKind
from wfviz.tracking.tracks import Prediction

APPLICATION_ID = "wfviz"
TENTATIVE_COLOR = (150, 150, 150, 90)
DETECTION_COLOR = (255, 200, 0, 255)
TRUTH_COLOR = (255, 255, 255, 200)
TRUTH_HIDDEN_COLOR = (255, 255, 255, 70)
TRUTH_RADIUS = -2.0  # UI points (a fixed size on screen): zoomed in, the prediction and the detection show around it
#: a sensor defect's dot: dull and small, never taken for a miss mark (bright red, 8 px)
BAD_PIXEL_COLOR = (150, 70, 70)
BAD_PIXEL_RADIUS = 2.0
HORIZON_COLOR, HORIZON_IGNORED_COLOR = (0, 255, 120), (120, 120, 120)
NOT_SEARCHED_COLOR = (30, 70, 255, 140)
#: defect pixels replaced in a frame above this share of it: a WARN line (once per onset)
DEFECTS_WARN_SHARE = 0.001
#: the legend (``legend``): rows LEGEND_STEP apart, from y = 0, shown in a view LEGEND_ROWS rows
#: high and 2 x LEGEND_WIDTH wide (scene units: the labels keep their size on screen)
LEGEND_STEP, LEGEND_ROWS, LEGEND_WIDTH = 10.0, 26, 12.0
#: confirmed predictions closer than this (px) share one label ("2+3 meet"), which would overlap
LABEL_MERGE_PX = 8.0
EVENT_LEVELS = {EventKind.BORN: "DEBUG", EventKind.DELETED: "WARN"}  # others INFO; a tentative track's deletion: DEBUG




def class_ids(track_ids: list[int]) -> np.ndarray:
    """Rerun class ids (16-bit) of track ids: the id itself up to 65 535, then wrapping
    (1..65 535), so a long clip's ids stay valid; colours and labels are logged explicitly."""
    return ((np.asarray(track_ids, dtype=np.int64).reshape(-1) - 1) % 65535 + 1).astype(np.uint16)


def track_colors(ids: list[int], confirmed: list[bool] | None = None,
                 color_of: Callable[[int], tuple[int, int, int]] = track_color) -> np.ndarray:
    """(N, 4) uint8 RGBA: each track's colour (``color_of``), ``TENTATIVE_COLOR`` where not
    confirmed. (Arrays, not lists of tuples: rerun converts them 30x faster.)"""
    out = np.empty((len(ids), 4), dtype=np.uint8)
    for k, i in enumerate(ids):
        out[k] = (*color_of(i), 255) if confirmed is None or confirmed[k] else TENTATIVE_COLOR
    return out


MASK_COLOR = (255, 0, 255, 70)
#: legend names of per-frame series (the last part of the path otherwise); per-track and
#: per-target series are named by :func:`series_name`
SERIES_NAMES = {
    "detection/count": "detections", "detection/threshold": "threshold", "detection/noise_sigma": "noise σ (median)",
    "detection/static": "static clutter", "detection/global": "global detection (1/0)",
    "registration/dx": "dx (px)", "registration/dy": "dy (px)", "registration/moving": "moving (1/0)",
    "registration/corners": "corners agreeing", "registration/confidence": "confidence (0-1)",
    "registration/residual": "residual (px)", "registration/fallback": "phase correlation (1/0)",
    "defects/count": "defect pixels replaced",
    "eval/missed": "missed", "eval/false_alarms": "false alarms", "tracks/confirm_level": "confirmation level",
}


def series_name(path: str) -> tuple[str, Color | None] | None:
    """The legend name (and colour) of the series at ``path``: ``track N`` in the track's colour for
    per-track series (``kalman/N/…``, ``fusion/N/…``, ``tbd/N/…``), the stage for ``timing/<stage>``,
    :data:`SERIES_NAMES`; None: Rerun's default (the path below the view's origin)."""
    if path in SERIES_NAMES:
        return SERIES_NAMES[path], None
    parts = path.split("/")
    if parts[0] == "timing" and len(parts) == 2:
        return parts[1], None
    if parts[0] in ("kalman", "fusion", "tbd") and len(parts) == 3 and parts[1].isdigit():
        return f"track {parts[1]}", track_color(int(parts[1]))
    return None
# The .rrd writer keeps a few KB per chunk in memory until the file closes, so a long clip must
# not make many chunks: rows are batched for up to 10 s or 16 MiB (Rerun's default: 0.2 s,
# 2 MiB) and per-track series go through ColumnBuffer. With Rerun's defaults memory grew to
# 1.3 GB over 20 000 frames of long-1024 (docs/performance.md).
BATCHER = rr.ChunkBatcherConfig(flush_tick=10.0, flush_num_bytes=16 * 1024 * 1024)


@functools.lru_cache(maxsize=1)
def _bar_chart_template() -> tuple:
    """Descriptors and Arrow types of ``rr.BarChart`` (values as F64 tensor, colour)."""
    ref = list(rr.BarChart(np.zeros(2), color=(0, 0, 0)).as_component_batches())
    struct = ref[0].as_arrow_array().type
    union = struct.field("buffer").type
    names = [union.field(i).name for i in range(union.num_fields)]
    empty = [pa.array([], type=union.field(i).type) for i in range(union.num_fields)]
    return (ref[0].component_descriptor(), ref[1].component_descriptor(), struct, union, names,
            list(union.type_codes), empty, names.index("F64"))


def bar_chart_arrays(values: np.ndarray, colors: np.ndarray) -> tuple[pa.Array, pa.Array]:
    """Arrow arrays of the ``BarChart`` values (one F64 tensor per row of ``values`` (N, B))
    and colours (N, 3), exactly as Rerun's converter builds them row by row."""
    _, _, struct, union, names, codes, empty, f64 = _bar_chart_template()
    v = np.ascontiguousarray(values, dtype=np.float64)
    n, b = v.shape
    children = list(empty)
    children[f64] = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32) * b), pa.array(v.ravel()),
                                             type=union.field(f64).type)
    buffer = pa.UnionArray.from_dense(pa.array(np.full(n, codes[f64], dtype=np.int8)),
                                      pa.array(np.arange(n, dtype=np.int32)), children, names, codes).view(union)
    shape = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32)),
                                     pa.array(np.full(n, b, dtype=np.uint64)), type=struct.field("shape").type)
    tensor = pa.StructArray.from_arrays([shape, pa.nulls(n, type=struct.field("names").type), buffer],
                                        fields=list(struct))
    c = np.asarray(colors, dtype=np.uint32).reshape(-1, 3)
    rgba = pa.array((c[:, 0] << 24) | (c[:, 1] << 16) | (c[:, 2] << 8) | 255, type=pa.uint32())
    return tensor, rgba


def bar_chart_columns(values: np.ndarray, colors: np.ndarray) -> list[rr.ComponentColumn]:
    """``BarChart`` columns for ``send_columns``: one bar chart per row of ``values``, built
    straight in Arrow (Rerun's own tensor converter takes ~0.3 ms a row and cannot batch)."""
    desc, color_desc = _bar_chart_template()[:2]
    tensor, rgba = bar_chart_arrays(values, colors)
    return [rr.ComponentColumn(desc, ArrowBatch(tensor)), rr.ComponentColumn(color_desc, ArrowBatch(rgba))]


def prediction_labels(preds: Sequence[Prediction], xy: np.ndarray) -> list[str]:
    """Labels of the predictions: a confirmed track's id (``N meet`` in meeting mode), "" for a
    tentative track; confirmed tracks closer than :data:`LABEL_MERGE_PX` share the first one's
    label (``2+3 meet``), as their labels would overlap."""
    labels = [(f"{p.track_id}" + (" meet" if p.meeting else "")) if p.confirmed else "" for p in preds]
    conf = [k for k, p in enumerate(preds) if p.confirmed]
    if len(conf) < 2:
        return labels
    pts = xy[conf].astype(np.float64)
    close = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1)) < LABEL_MERGE_PX
    done: set[int] = set()
    for a in range(len(conf)):
        if a in done:
            continue
        group = [b for b in range(a, len(conf)) if close[a, b] and b not in done]
        if len(group) > 1:
            done.update(group)
            members = [preds[conf[b]] for b in group]
            labels[conf[a]] = "+".join(str(p.track_id) for p in members) + (
                " meet" if any(p.meeting for p in members) else "")
            for b in group[1:]:
                labels[conf[b]] = ""
    return labels


def log_geometry(rec: rr.RecordingStream, front: FrontEndResult) -> None:
    """Non-imaging mask and imaging circle (static, when they change), flagged bad pixels and
    the horizon (when re-estimated), from the front end's result ``front``. The circle's and the
    horizon's labels show on hover only (drawn, they sat in the middle of the sky over tracks)."""
    if front.mask_changed:
        rec.log("camera/mask", rr.AnnotationContext([
            rr.ClassDescription(info=rr.AnnotationInfo(id=0, label="imaging", color=(0, 0, 0, 0))),
            rr.ClassDescription(info=rr.AnnotationInfo(id=1, label="non-imaging", color=MASK_COLOR))]),
            static=True)
        rec.log("camera/mask", rr.SegmentationImage(front.mask.astype(np.uint8)), static=True)
        c = front.circle
        a = np.linspace(0, 2 * np.pi, 181)
        rec.log("camera/imaging_circle", rr.LineStrips2D(
            [np.column_stack([c.cx + c.radius * np.cos(a), c.cy + c.radius * np.sin(a)])] if c else [],
            labels=[f"imaging circle R={c.radius:.1f} confidence {c.confidence:.2f}"] if c else None,
            colors=MASK_COLOR[:3], radii=0.5, show_labels=False), static=True)
        rec.log("geometry/circle_confidence", rr.Scalars(float(c.confidence) if c else 0.0))
    if front.bad_pixels_changed:
        bp = front.bad_pixels
        rec.log("camera/bad_pixels", rr.Points2D(bp[:, ::-1].astype(np.float32) if len(bp) else np.zeros((0, 2)),
                                                 class_ids=1, colors=BAD_PIXEL_COLOR, radii=BAD_PIXEL_RADIUS,
                                                 draw_order=DRAW_BAD_PIXELS, show_labels=False))
    if front.horizon_updated:
        h = front.horizon
        line = h.polyline() if h is not None else None
        used = horizon_confident(h)
        label = None if h is None else [f"horizon confidence {h.confidence:.2f} ({'used' if used else 'ignored'})"]
        rec.log("camera/horizon", rr.LineStrips2D(
            [line] if line is not None and len(line) else [], labels=label if line is not None and len(line) else None,
            colors=HORIZON_COLOR if used else HORIZON_IGNORED_COLOR, radii=0.8, show_labels=False))
        rec.log("geometry/horizon_confidence", rr.Scalars(float(h.confidence) if h is not None else 0.0))
        for factor in ("support", "separation", "ground"):    # the confidence's factors
            rec.log(f"geometry/horizon_{factor}", rr.Scalars(float(getattr(h, factor)) if h is not None else 0.0))


#: the entities that are images of the frame (raw, stage and map images, masks)
IMAGE_ENTITIES = ("camera/image", "camera/mask", "camera/search_region", "suppressed/image", "suppressed/noise",
                  "clutter/map", "suppressed/multiframe")


def pixel_centres(rec: Any, paths: tuple[str, ...] = IMAGE_ENTITIES) -> None:
    """Put each image's pixel (i, j) at (i, j) of the view: Rerun draws it over [i, i + 1] x
    [j, j + 1], the overlays use the project's convention (x = column, y = row, origin at the
    centre of the top-left pixel), so every image is moved by half a pixel (static)."""
    for path in paths:
        rec.log(path, rr.Transform3D(translation=[-0.5, -0.5, 0.0]), static=True)


class ColumnBuffer:
    """Per-frame scalars, log lines, bar charts and overlay instances held for a while and sent
    as columns (``send_columns``): one call and one chunk per entity instead of one per value,
    the same data. Every chunk costs the .rrd writer memory until the file closes (about 2 KB
    for scalars, 34 KB for a bar chart), so scalars and lines go every ``frames`` frames, the
    bar charts, held compactly as arrays, every ``bar_frames``, and the overlays (whose
    per-frame building is what columns save) every ``instance_frames``."""

    def __init__(self, rec: rr.RecordingStream, frames: int = 1024, bar_frames: int = 4096,
                 instance_frames: int = 64) -> None:
        self.rec, self.frames, self.bar_frames = rec, frames, bar_frames
        self.instance_frames = instance_frames
        self._instances: dict[tuple[str, type, tuple[str, ...]], _InstanceRows] = {}
        self._instance_pending = 0
        self._scalars: dict[str, tuple[list[int], list[float], list[float]]] = {}
        self._pairs: dict[str, tuple[list[int], list[float], list[float]]] = {}  # two series per entity
        self._texts: dict[str, tuple[list[int], list[float], list[str], list[str]]] = {}
        self._bars: dict[str, _BarRows] = {}
        self._pending = self._bar_pending = 0

    def scalar(self, path: str, frame: int, time: float, value: float) -> None:
        f, t, v = self._scalars.setdefault(path, ([], [], []))
        f.append(frame)
        t.append(time)
        v.append(value)

    def pair(self, path: str, frame: int, time: float, a: float, b: float) -> None:
        """Two series in one entity (a ``Scalars`` row of two values): one chunk where two
        entities would make two (per-track series of many tracks)."""
        f, t, v = self._pairs.setdefault(path, ([], [], []))
        f.append(frame)
        t.append(time)
        v += (a, b)

    def text(self, path: str, frame: int, time: float, text: str, level: str) -> None:
        f, t, x, lv = self._texts.setdefault(path, ([], [], [], []))
        f.append(frame)
        t.append(time)
        x.append(text)
        lv.append(level)

    def bar_chart(self, path: str, frame: int, time: float, values: np.ndarray,
                  color: tuple[int, int, int]) -> None:
        rows = self._bars.get(path)
        if rows is None:
            rows = self._bars[path] = _BarRows(len(values), color)
        rows.add(frame, time, values)

    def instances(self, path: str, frame: int, time: float, archetype: type, n: int,
                  **components: Any) -> None:
        """This frame's ``n`` instances of ``archetype`` (``rr.Points2D``, ``rr.Boxes2D``,
        ``rr.LineStrips2D``, ``rr.AnyValues``) at ``path``: every component one value per
        instance (an array of ``n`` rows or a list of ``n``). Sent with the other frames held as
        columns partitioned by frame, which builds each component once for them all instead of
        an archetype a frame; a frame without instances is an empty row, as an empty batch
        logged then. Components that never change are the caller's to log once, static."""
        key = (path, archetype, tuple(components))
        rows = self._instances.get(key)
        if rows is None:
            rows = self._instances[key] = _InstanceRows(archetype)
        rows.add(frame, time, n, components)

    def end_frame(self) -> None:
        """Count a frame; send what is due."""
        self._pending += 1
        self._bar_pending += 1
        self._instance_pending += 1
        if self._instance_pending >= self.instance_frames:
            self.flush_instances()
        if self._pending >= self.frames:
            self.flush(bars=self._bar_pending >= self.bar_frames)

    def flush_instances(self) -> None:
        """Send the instances held."""
        for (path, _, _), rows in self._instances.items():
            self.rec.send_columns(path, indexes=time_columns(rows.frames, rows.times), columns=rows.columns())
        self._instances.clear()
        self._instance_pending = 0

    def flush(self, bars: bool = True) -> None:
        """Send the scalars and lines held (and the bar charts, with ``bars``), and the instances."""
        self.flush_instances()
        for path, (f, t, v) in self._scalars.items():
            self.rec.send_columns(path, indexes=time_columns(f, t), columns=rr.Scalars.columns(scalars=v))
        for path, (f, t, v) in self._pairs.items():
            self.rec.send_columns(path, indexes=time_columns(f, t),
                                  columns=rr.Scalars.columns(scalars=v).partition(np.full(len(f), 2)))
        for path, (f, t, x, lv) in self._texts.items():
            self.rec.send_columns(path, indexes=time_columns(f, t), columns=rr.TextLog.columns(text=x, level=lv))
        self._scalars.clear()
        self._pairs.clear()
        self._texts.clear()
        self._pending = 0
        if bars:
            for path, rows in self._bars.items():
                n = rows.n
                self.rec.send_columns(path, indexes=time_columns(rows.frames[:n], rows.times[:n]),
                                      columns=bar_chart_columns(rows.values[:n], np.tile(rows.color, (n, 1))))
            self._bars.clear()
            self._bar_pending = 0


class _InstanceRows:
    """One entity's pending instances of one archetype: per frame, the number of instances and
    each component's values."""

    def __init__(self, archetype: type) -> None:
        self.archetype = archetype
        self.frames: list[int] = []
        self.times: list[float] = []
        self.lengths: list[int] = []
        self.values: dict[str, list] = {}

    def add(self, frame: int, time: float, n: int, components: dict[str, Any]) -> None:
        self.frames.append(frame)
        self.times.append(time)
        self.lengths.append(n)
        for name, value in components.items():
            self.values.setdefault(name, []).append(value)

    def columns(self) -> rr.ComponentColumnList:
        """The rows as columns of the archetype, partitioned by frame."""
        merged = {name: np.concatenate(parts) if isinstance(parts[0], np.ndarray) else [x for p in parts for x in p]
                  for name, parts in self.values.items()}
        return self.archetype.columns(**merged).partition(self.lengths)


class _BarRows:
    """One entity's pending bar charts: (frame, time, values) rows in growing arrays."""

    def __init__(self, bins: int, color: tuple[int, int, int]) -> None:
        self.color = np.array(color)
        self.n = 0
        self.frames = np.zeros(64, dtype=np.int64)
        self.times = np.zeros(64)
        self.values = np.zeros((64, bins))

    def add(self, frame: int, time: float, values: np.ndarray) -> None:
        if self.n == len(self.frames):
            grow = len(self.frames)
            self.frames = np.concatenate([self.frames, np.zeros(grow, dtype=np.int64)])
            self.times = np.concatenate([self.times, np.zeros(grow)])
            self.values = np.concatenate([self.values, np.zeros((grow, self.values.shape[1]))])
        self.frames[self.n], self.times[self.n], self.values[self.n] = frame, time, values
        self.n += 1


class RootedStream:
    """A recording stream whose entity paths all lie below ``root`` (``"/"`` is the root
    itself), for a recorder that writes one run of several into one recording."""

    def __init__(self, stream: rr.RecordingStream, root: str) -> None:
        self.stream, self.root = stream, root.strip("/")

    def path(self, entity: str) -> str:
        entity = entity.strip("/")
        return f"{self.root}/{entity}" if entity else self.root

    def log(self, entity: str, *args: object, **kwargs: object) -> None:
        self.stream.log(self.path(entity), *args, **kwargs)  # type: ignore[arg-type]

    def send_columns(self, entity: str, **kwargs: object) -> None:
        self.stream.send_columns(self.path(entity), **kwargs)  # type: ignore[arg-type]

    def set_time(self, timeline: str, **kwargs: object) -> None:
        self.stream.set_time(timeline, **kwargs)  # type: ignore[arg-type]


class Recorder:
    """Writes one recording; subclasses (one per tracker) add tracker-specific stages.

    The options' ``image_every`` logs the raw and stage images every N frames (0 = never), exact
    (lossless) on the first image frame of every ``exact_every`` frames and JPEG previews at
    ``jpeg_quality`` between (:mod:`wfviz.record.images`); overlays, scalars and text have a row
    every frame, sent in columns (:class:`ColumnBuffer`).
    """

    def __init__(self, path: Path | None, tracker: str, options: RecorderOptions, *,
                 stream: rr.RecordingStream | None = None, root: str = "", raw_image: bool = True,
                 shared_images: frozenset[str] = frozenset()) -> None:
        """``options``: what the recording is asked for (:class:`RecorderOptions`). ``stream``
        and ``root``: write into another recording, every entity below ``root`` (``wfviz
        compare``'s ``runs/<label>``), which owns the file, the time and the blueprint;
        ``raw_image``: log the raw frame (False: the owner logs it once); ``shared_images``:
        image entities another run of the same front end logs instead. With ``options.live``, the
        run is streamed to a viewer or served as well as written to the file
        (:mod:`wfviz.record.live`)."""
        live = options.live
        # evidence (read by the blueprint, below)
        self._series: set[str] = set()  # series paths seen (named, when they have a name)
        self._legend: dict[str, Color] = {}
        self.tests = TestLog(self)
        self.explanation = ExplanationLog(self, self._explanation_started)
        self._file: rr.RecordingStream | None = None
        if stream is None:
            self._file = rr.RecordingStream(APPLICATION_ID, batcher_config=BATCHER)
            self._file.set_sinks(rr.FileSink(str(path)), default_blueprint=self.blueprint())
            self.rec: rr.RecordingStream | RootedStream | LiveMirror = self._file
            if live is not None:  # its own stream: the file never waits on the network
                mirror = rr.RecordingStream(APPLICATION_ID, recording_id=self._file.get_recording_id())
                try:
                    mirror.set_sinks(live_sink(live), default_blueprint=self.blueprint())
                except BaseException:
                    self._file.disconnect()
                    raise
                self.rec = LiveMirror(self._file, mirror)
        else:
            self.rec = RootedStream(stream, root)
        self.raw_image = raw_image
        self.live = live
        self._live_ended = False
        self.shared_images = shared_images
        self.images = ImageLog(self.rec, options.image_every, options.exact_every, options.jpeg_quality)
        pixel_centres(self.rec, tuple(p for p in IMAGE_ENTITIES if p not in shared_images
                                      and (raw_image or p != "camera/image")))
        self._region_logged: np.ndarray | None = None  # the search region last logged
        self._front_started = False
        self._motion_lost = False
        self._motion_fallback = False
        self._defects_replaced = 0  # flagged at the end of the last frame: replaced in this one
        self._defects_high = False
        self._trails: dict[int, deque] = {}
        self._trail_length = options.trail_length
        self._labelled: set[int] = set()
        self.confirmed_ids: set[int] = set()
        #: a confirmed track's colour in the camera overlays (``wfviz compare`` with truth: the
        #: colour of the truth target it matches, :class:`~wfviz.record.colors.TargetPalette`)
        self.color_of: Callable[[int], tuple[int, int, int]] = track_color
        self.frames_logged = 0
        # overlays as columns every 64 frames (a live view: every frame)
        self.columns = ColumnBuffer(self.rec, instance_frames=1 if live is not None else 64)
        self._static_fields: set[str] = set()  # entities whose constant components were logged
        self._now = (0, 0.0)  # (frame, time) being logged
        self.rec.log("config", rr.TextDocument(
            f"# wfviz {tracker}\n\nSource: `{display(options.source)}`\n\n```toml\n{options.config_text}\n```",
            media_type=rr.MediaType.MARKDOWN), static=True)
        self.rec.log("camera/detections", class_context([(1, "detection", DETECTION_COLOR)]), static=True)
        self.rec.log("camera/truth", class_context([(1, "truth", TRUTH_COLOR), (2, "truth, hidden (don't care)",
                                                                                TRUTH_HIDDEN_COLOR)]), static=True)
        self.add_legend([("detection", DETECTION_COLOR), ("truth", TRUTH_COLOR),
                         ("truth, hidden", TRUTH_HIDDEN_COLOR), ("tentative track", TENTATIVE_COLOR[:3]),
                         ("confirmed track", track_color(1))])

    @property
    def now(self) -> tuple[int, float]:
        """The (frame, time) being logged."""
        return self._now

    # -- layout ---------------------------------------------------------------------------
    def blueprint(self, track_ids: list[int] | None = None) -> rrb.Blueprint:
        """Default layout: raw image with overlays, residual, time series, bars, log.

        ``track_ids`` (known when the recording closes) splits per-track plots by track.
        """
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Horizontal(rrb.Vertical(*self.image_views()), self.legend_view(), column_shares=[4, 1]),
                rrb.Vertical(
                    rrb.Tabs(*self.series_views(), *self.explanation_views(track_ids)),
                    self.track_views(track_ids),
                    rrb.Tabs(rrb.TextLogView(origin="log", name="Track log", rows=rrb.archetypes.TextLogRows(
                                 filter_by_log_level=["INFO", "WARN", "ERROR"])),  # DEBUG: tentative tracks
                             rrb.TextDocumentView(origin="config", name="Config"),
                             rrb.TextDocumentView(origin="eval/summary", name="Scores")),
                    row_shares=[5, 3, 3],  # the stage-time legend (12 series) needs the height
                ),
                column_shares=[3, 2],
            ),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(timeline="frame", state="collapsed"),
        )

    def image_views(self) -> list[rrb.View]:
        """Left column: the raw frame with overlays (sensor defects hidden: tick them in the
        blueprint panel) above the stage image."""
        return [rrb.Spatial2DView(origin="camera", name="Camera + overlays",
                                  overrides={"/camera/bad_pixels": rrb.EntityBehavior(visible=False)}),
                rrb.Spatial2DView(origin="suppressed", name="Background-suppressed",
                                  contents=["$origin/**", "/camera/detections", "/camera/gates",
                                            "/camera/predictions"])]

    @staticmethod
    def legend_view() -> rrb.View:
        """The overlays' colours and what they mean (``legend``), a narrow column beside the images."""
        return rrb.Spatial2DView(origin="legend", name="Legend", background=(20, 20, 20),
                                 visual_bounds=rrb.VisualBounds2D(x_range=[-LEGEND_WIDTH, LEGEND_WIDTH],
                                                                  y_range=[-LEGEND_STEP, LEGEND_STEP * LEGEND_ROWS]))

    def series_views(self) -> list[rrb.View]:
        """Right column, top tabs: per-frame series."""
        return [rrb.TimeSeriesView(origin="timing", name="Stage time (ms)"),
                rrb.TimeSeriesView(origin="detection", name="Detections", contents=["$origin/**", "/defects/**"]),
                rrb.TimeSeriesView(origin="eval", name="Errors vs truth")]

    @staticmethod
    def motion_views() -> list[rrb.View]:
        """The camera's motion and how well it was measured (trackers on the shared front end)."""
        return [rrb.TimeSeriesView(origin="registration", name="Camera motion",
                                   contents=["$origin/**", "- /registration/corners"])]

    def explanation_views(self, track_ids: list[int] | None) -> list[rrb.View | rrb.Container]:
        """Once an explanation was logged (known when the recording closes): each truth target's
        significance, change and threshold (σ), one view per target (at most 12)."""
        targets = sorted(self.explanation.targets)[:12]
        if track_ids is None or not targets:
            return []
        return [rrb.Tabs(*[rrb.TimeSeriesView(origin=f"explain/T{i}", name=f"Truth T{i} (σ)") for i in targets],
                         name="Why missed (σ)")]

    def test_views(self, track_ids: list[int]) -> list[rrb.View | rrb.Container]:
        """One view per confirmation or deletion test: its value and level for each confirmed track
        (``tests/<id>/<test>``), grouped in a tab "Track tests"."""
        tests = sorted(self.tests.views(), key=lambda t: t[0] == "hit this frame")  # the trivial one last
        if not tests or not track_ids:
            return []
        return [rrb.Tabs(*[rrb.TimeSeriesView(origin="tests", name=f"Test: {name}",
                                              contents=[f"/tests/{i}/{slug}" for i in track_ids]) for name, slug in tests],
                         name="Track tests")]

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
        self._now = (frame.index, frame.time)
        images = self.images.begin_frame(self.frames_logged, frame.index, frame.time)
        if images and self.raw_image:
            self.image("camera/image", frame.image)
        self._log_common(result)
        self.log_stages(result, images)
        self.frames_logged += 1
        self.columns.end_frame()

    def image(self, path: str, image: np.ndarray, value_map: bool = False) -> None:
        """An image of the current frame, exact or a preview (:class:`ImageLog`); always exact
        when a ``value_map`` (a map of measured values, not a picture). Not logged when it is one
        of the ``shared_images``."""
        if path not in self.shared_images:
            self.images.log(path, image, value_map=value_map)

    def scalar(self, path: str, value: float) -> None:
        """A ``Scalars`` value at the current frame (sent in columns, see :class:`ColumnBuffer`);
        a new series is named for its legend (:func:`series_name`)."""
        if path not in self._series:
            self._series.add(path)
            named = series_name(path)
            if named is not None:
                self.name_series(path, named[0], named[1])
        self.columns.scalar(path, *self._now, float(value))

    def name_series(self, path: str, name: str | list[str], color: Color | list[Color] | None = None,
                    width: float | list[float] | None = None) -> None:
        """The legend name (and colour, line width) of the series at ``path``, or of each of its
        series given lists (static ``SeriesLines``)."""
        self._series.add(path)
        colors = [c[:3] for c in color] if isinstance(color, list) else color[:3] if color else None
        self.rec.log(path, rr.SeriesLines(names=name, colors=colors, widths=width), static=True)

    def add_legend(self, entries: list[tuple[str, Color]]) -> None:
        """Add (label, colour) rows to the legend (``legend``, static: re-logged whole when rows are added)."""
        new = [(label, color) for label, color in entries if label not in self._legend]
        if not new:
            return
        self._legend.update(new)
        n = len(self._legend)
        self.rec.log("legend", rr.Points2D(
            np.column_stack([np.zeros(n), LEGEND_STEP * np.arange(n)]).astype(np.float32),
            colors=np.array([(*c[:3], 255) for c in self._legend.values()], dtype=np.uint8),
            labels=list(self._legend), radii=0.01, show_labels=True), static=True)

    def log_explanation(self, expl: FrameExplanation) -> None:
        """This frame's explanation (:mod:`wfviz.explain`): each truth target's significance, change
        and threshold (``explain/T<id>/…``), its cause as a marker (``camera/causes``), the misses
        (``camera/misses``) and false tracks (``camera/false_tracks``), as ``wfviz compare`` marks them."""
        self.explanation.log(expl)

    def _explanation_started(self) -> None:
        self.add_legend(cause_legend() + [("missed (mark)", MISSED_COLOR), ("false track (mark)", FALSE_TRACK_COLOR)])

    def bar(self, path: str, values: np.ndarray, color: tuple[int, int, int]) -> None:
        """A ``BarChart`` at the current frame (sent in columns)."""
        self.columns.bar_chart(path, *self._now, values, color)

    def text(self, message: str, level: str = "INFO", path: str = "log") -> None:
        """A ``TextLog`` line at the current frame (sent in columns)."""
        self.columns.text(path, *self._now, display(message), level)

    def log_kalman(self, result: FrameResult, innovations: dict[int, np.ndarray] | None = None) -> None:
        """``kalman/<id>/innovation`` (of the tracks updated this frame, when the tracker reports
        ``innovations``) and ``kalman/<id>/cov_trace`` of the confirmed tracks."""
        confirmed = result.confirmed_ids
        for tid, nu in (innovations or {}).items():
            if tid in confirmed:
                self.scalar(f"kalman/{tid}/innovation", float(np.hypot(*nu)))
        for p in result.predictions:
            if p.confirmed:
                self.scalar(f"kalman/{p.track_id}/cov_trace", p.cov_trace)

    def log_stages(self, result: FrameResult, images: bool) -> None:
        """Tracker-specific stages; overridden by each tracker's adapter."""

    def log_front_end(self, result: FrontEndTrackResult, images: bool) -> None:
        """What the trackers on the shared front end (:mod:`wfviz.stages.front_end`) report in
        common: the scene geometry (:func:`log_geometry`), the sensor defects replaced
        (``defects/count``), the noise map (``suppressed/noise``), the multi-frame significance
        (``suppressed/multiframe``) and the search region (``camera/search_region``) on exact frames, the camera motion (``registration/*``) and the
        sequential test's levels (``tracks/*``)."""
        front = result.front
        if not self._front_started:
            self._front_started = True
            self._front_end_classes()
        log_geometry(self.rec, front)
        self._log_defects(front)
        # on exact frames (on image frames with previews only); half precision: a smooth map
        due = self.images.exact if self.images.exact_every else images
        noise = front.noise
        if noise is not None:
            if due:
                self.image("suppressed/noise", noise.sigma.astype(np.float16), value_map=True)
            self.scalar("detection/noise_sigma", noise.typical_sigma())
        if front.multiframe is not None and due:
            self.image("suppressed/multiframe", front.multiframe.astype(np.float16), value_map=True)
        if due:
            self._log_search_region(front)
        if front.camera is not None:
            self._log_motion(front.camera)
        th = result.thresholds
        if th is not None:
            self.scalar("tracks/confirm_level", th.confirm)

    def _front_end_classes(self) -> None:
        """Class tables (labels on hover) and legend rows of the front end's overlays."""
        rec = self.rec
        rec.log("camera/bad_pixels", class_context([(1, "sensor defect (replaced)", BAD_PIXEL_COLOR)]), static=True)
        rec.log("camera/search_region", class_context([
            (0, "searched", (0, 0, 0, 0)), (1, "not searched (below the horizon, outside the windows)",
                                            NOT_SEARCHED_COLOR)]), static=True)
        self.add_legend([("non-imaging", MASK_COLOR), ("imaging circle", MASK_COLOR), ("horizon, used", HORIZON_COLOR),
                         ("horizon, ignored", HORIZON_IGNORED_COLOR), ("not searched", NOT_SEARCHED_COLOR[:3]),
                         ("defect (hidden)", BAD_PIXEL_COLOR)])

    def _log_defects(self, front: FrontEndResult) -> None:
        """``defects/count``: pixels replaced by their neighbours' median in this frame (those
        flagged up to the last frame); a WARN line when they exceed :data:`DEFECTS_WARN_SHARE` of
        the frame, once each time they rise above it."""
        n = self._defects_replaced
        self._defects_replaced = len(front.bad_pixels)
        self.scalar("defects/count", n)
        limit = DEFECTS_WARN_SHARE * front.image.size
        if n > limit and not self._defects_high:
            self.text(f"{n} pixels replaced as sensor defects ({100 * n / front.image.size:.2f} % of the frame, "
                      f"more than {100 * DEFECTS_WARN_SHARE:g} %)", "WARN")
        self._defects_high = n > limit

    def _log_search_region(self, front: FrontEndResult) -> None:
        """``camera/search_region``: the imaging pixels not searched (class 1), when it changed."""
        region = front.region
        if self._region_logged is not None and np.array_equal(region, self._region_logged):
            return
        self._region_logged = region.copy()
        self.rec.log("camera/search_region", rr.SegmentationImage(
            (front.valid & ~region).view(np.uint8), draw_order=DRAW_SEARCH_REGION))

    def _log_motion(self, camera: CameraState) -> None:
        """``registration/*``: the shift (NaN when it is unknown, never "still"), whether the
        camera moves, the corners that agreed, the confidence, the residual and whether the
        phase-correlation fallback measured it; a WARN line when the motion is lost and when it
        is measured again (filtering WARN shows both ends), and one when the fallback takes over
        from the flow."""
        reliable, fallback = camera.reliable, camera.method == "phase"
        self.scalar("registration/dx", camera.shift[0] if reliable else np.nan)
        self.scalar("registration/dy", camera.shift[1] if reliable else np.nan)
        self.scalar("registration/moving", 1.0 if camera.moving else 0.0)
        self.scalar("registration/corners", camera.corners)
        self.scalar("registration/confidence", camera.confidence)
        self.scalar("registration/residual", camera.residual)
        self.scalar("registration/fallback", 1.0 if fallback else 0.0)
        if not reliable and not self._motion_lost:
            self.text(f"camera motion lost: {camera.corners} corners agreed on the flow and phase correlation found "
                      "no shift the frame's halves agree on; the camera's shift is unknown (tracks are not moved"
                      f"{'; no motion test spans this frame' if camera.moving else ''})", "WARN")
        elif reliable and self._motion_lost:
            how = (f"by phase correlation (response {camera.confidence:.2f})" if fallback else
                   f"{camera.corners} corners agree (confidence {camera.confidence:.2f})")
            self.text(f"camera motion measured again: {how}", "WARN")
        elif fallback and not self._motion_fallback:
            self.text(f"camera motion measured by phase correlation: only {camera.corners} corners agreed on the "
                      f"flow (response {camera.confidence:.2f}, halves {camera.residual:.1f} px apart)", "WARN")
        self._motion_lost = not reliable
        self._motion_fallback = fallback

    def instances(self, path: str, archetype: type, n: int, **components: Any) -> None:
        """This frame's ``n`` instances of ``archetype`` at ``path``, one value per instance in
        every component (sent as columns: :meth:`ColumnBuffer.instances`)."""
        self.columns.instances(path, *self._now, archetype, n, **components)

    def static_once(self, path: str, fields: Callable[[], Any]) -> None:
        """``fields()`` (an archetype's constant components) at ``path``, static, the first time
        (built only then: building one costs about 0.04 ms)."""
        if path not in self._static_fields:
            self._static_fields.add(path)
            self.rec.log(path, fields(), static=True)

    def _log_common(self, result: FrameResult) -> None:
        d = result.detections
        n = len(d)
        self.static_once("camera/detections", lambda: rr.Points2D.from_fields(
            colors=DETECTION_COLOR, class_ids=1, draw_order=DRAW_DETECTIONS, show_labels=False))
        self.instances("camera/detections", rr.Points2D, n, positions=np.asarray(d.xy, dtype=np.float32).reshape(-1, 2),
                       radii=(np.sqrt(d.area / np.pi) + 1.0).astype(np.float32))
        if n:  # hover values; an empty AnyValues batch only draws a warning
            extra = {name: np.asarray(v, dtype=np.float64) for name, v in (
                ("significance", d.significance), ("change", d.change), ("blobness", d.blobness),
                ("linearity", d.linearity), ("multiframe", d.multiframe))
                if v is not None}
            self.instances("camera/detections", rr.AnyValues, n, area=np.asarray(d.area),
                           peak=d.peak.astype(np.float64), flux=d.flux.astype(np.float64), **extra)
        self.scalar("detection/count", n)
        self.scalar("detection/threshold", d.threshold if np.isfinite(d.threshold) else np.nan)
        self._ensure_labels([t.track_id for t in result.tracks if t.confirmed])
        self.confirmed_ids |= result.confirmed_ids
        preds = result.predictions
        ids = [p.track_id for p in preds]
        conf = np.array([p.confirmed for p in preds], dtype=bool)
        colors = track_colors(ids, conf.tolist(), self.color_of)
        geo = np.array([(p.x, p.y, p.half_w, p.half_h) for p in preds], dtype=np.float32).reshape(-1, 4)
        labels = prediction_labels(preds, geo[:, :2])
        cids = class_ids(ids)
        # the labels are drawn under the gates (a point's would cover its target), on hover on the points
        self.static_once("camera/predictions", lambda: rr.Points2D.from_fields(draw_order=DRAW_TRACKS, show_labels=False))
        self.instances("camera/predictions", rr.Points2D, len(preds), positions=geo[:, :2], class_ids=cids,
                       colors=colors, labels=labels, radii=np.where(conf, 1.5, 0.7).astype(np.float32))
        self.static_once("camera/gates", lambda: rr.Boxes2D.from_fields(show_labels=True))
        self.instances("camera/gates", rr.Boxes2D, len(preds), centers=geo[:, :2], half_sizes=geo[:, 2:],
                       class_ids=cids, colors=colors, labels=labels, radii=np.where(conf, 0.5, 0.2).astype(np.float32))
        self._log_trails(result)
        for stage, ms in result.timings.items():
            self.scalar(f"timing/{stage}", ms)
        confirmed = result.confirmed_ids | self._labelled
        for e in result.events:
            level = EVENT_LEVELS.get(e.kind, "INFO")
            if e.kind == EventKind.DELETED and e.track_id not in confirmed:
                level = "DEBUG"
            self.text(e.message, level)
        if result.verdicts is not None:
            self.tests.log(result.verdicts, result.tracks)

    def _log_trails(self, result: FrameResult) -> None:
        live = set()
        for t in result.tracks:
            live.add(t.track_id)
            trail = self._trails.setdefault(t.track_id, deque(maxlen=self._trail_length))
            trail.append((t.x, t.y))
        for tid in list(self._trails):
            if tid not in live:
                del self._trails[tid]
        conf = [t.track_id for t in result.tracks if t.confirmed]
        strips = [np.array(self._trails[i], dtype=np.float32) for i in conf]
        self.static_once("camera/tracks", lambda: rr.LineStrips2D.from_fields(radii=0.6, show_labels=False))
        self.instances("camera/tracks", rr.LineStrips2D, len(conf), strips=strips, class_ids=class_ids(conf),
                       labels=[str(i) for i in conf], colors=track_colors(conf, color_of=self.color_of))

    def _ensure_labels(self, confirmed_ids: list[int]) -> None:
        """Static annotation context: a stable colour and label per confirmed track id."""
        new = set(confirmed_ids) - self._labelled
        if not new:
            return
        self._labelled |= new
        latest = dict(zip(class_ids(sorted(self._labelled)).tolist(), sorted(self._labelled)))
        self.rec.log("/", rr.AnnotationContext([
            rr.ClassDescription(info=rr.AnnotationInfo(id=c, label=f"track {i}", color=track_color(i)))
            for c, i in sorted(latest.items())]), static=True)

    def log_truth(self, shown: list[tuple[int, float, float]], hidden: list[tuple[int, float, float]],
                  errors: FrameErrors) -> None:
        """Truth points (hidden ones dimmed) and this frame's errors under ``eval/``."""
        pts = shown + hidden
        self.rec.log("camera/truth", rr.Points2D(
            [[x, y] for _, x, y in pts] if pts else np.zeros((0, 2)),
            labels=[f"T{i}" for i, _, _ in shown] + [f"T{i} hidden" for i, _, _ in hidden],
            class_ids=np.array([1] * len(shown) + [2] * len(hidden), dtype=np.uint16),
            colors=[TRUTH_COLOR] * len(shown) + [TRUTH_HIDDEN_COLOR] * len(hidden),
            radii=TRUTH_RADIUS, draw_order=DRAW_TRUTH, show_labels=False))
        if "eval/cle" not in self._series:
            self.name_series("eval/cle", "CLE (px)")
        self.rec.log("eval/cle", rr.Scalars(errors.cle_mean))
        self.scalar("eval/missed", errors.missed)
        self.scalar("eval/false_alarms", errors.false_alarms)

    def log_scores(self, table: str) -> None:
        """Final scores against truth as static text."""
        self.rec.log("eval/summary", rr.TextDocument(f"```\n{table}\n```", media_type=rr.MediaType.MARKDOWN),
                     static=True)

    def log_message(self, text: str, level: str = "INFO") -> None:
        """A free text line in ``log`` at the current time."""
        self.text(text, level)

    def close(self) -> None:
        """Send the final default blueprint (per-track and per-target views), flush and close the file (a
        recorder writing into another's ``stream`` only sends what it holds). A live view is
        still open then: :meth:`end_live` closes it (after the file is renamed into place)."""
        self.images.close()
        self.columns.flush()
        if self._file is None:
            return
        ids = sorted(self.confirmed_ids)
        if ids or self.explanation.targets:  # the per-track and per-target views
            self.rec.send_blueprint(self.blueprint(ids), make_active=True, make_default=True)
        self._file.flush()
        self._file.disconnect()

    def end_live(self) -> None:
        """Close the live view (at most ``LIVE_WAIT_SECONDS``), saying in one note if it failed;
        nothing without one, or a second time."""
        if not isinstance(self.rec, LiveMirror) or self._live_ended:
            return
        self._live_ended = True
        problem = self.rec.end()
        if problem:
            warnings.warn(f"live view: {problem}; the file is complete", ClipNote, stacklevel=2)
