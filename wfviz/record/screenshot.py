"""Render an .rrd recording in the real Rerun viewer, headless, and save a PNG screenshot.

The viewer (`rerun --headless`) renders offscreen through wgpu on Vulkan. Without a GPU this
needs Mesa's software rasteriser lavapipe (Debian: ``apt-get install mesa-vulkan-drivers``,
which pulls in ``libvulkan1``). The viewer is started on a free loopback port in its own
process group, driven with :class:`rerun.experimental.ViewerClient`, and killed afterwards.
"""

from __future__ import annotations

import bisect
import ctypes
import ctypes.util
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Callable, Literal

from wfviz.io.outputs import write_atomically

if TYPE_CHECKING:
    import pyarrow as pa
    from rerun.chunk import Chunk
    from rerun.experimental import Timeline, ViewerClient

__all__ = [
    "Bounds", "ScreenshotError", "Shot", "crop_bounds", "frame_range", "image_size", "overlay_positions", "pick_timeline",
    "plan_shots", "render_screenshot", "render_shots", "timelines",
]

_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/usr/local/share/vulkan/icd.d", "/etc/vulkan/icd.d")
_SETTLE_MAX_SHOTS = 8
# s after its start: the viewer's start-up notifications ("Listening for gRPC connections") are
# gone by the first frame it paints then (a frame painted earlier shows them, and keeps them longer)
_TOASTS_GONE = 3.5
_LABEL_HEIGHT = 40  # px of the strip above each panel of a multi-shot picture, holding its label
_GAP = 8  # px between panels
MAX_SHOTS = 16  # panels in one picture
MAX_ZOOM = 1000.0
DEFAULT_ZOOM = 4.0

#: visual bounds of a 2D view in Rerun's scene units: (x_min, x_max, y_min, y_max)
Bounds = tuple[float, float, float, float]


class ScreenshotError(RuntimeError):
    """The viewer could not produce a screenshot (missing binary or driver, crash, timeout)."""


@dataclass(frozen=True)
class Shot:
    """One picture: the time on the timeline (None: its last), the visual bounds of the 2D
    views (None: the recording's own), and a label drawn above it in a multi-shot picture."""

    time: int | None = None
    bounds: Bounds | None = None
    label: str = ""


def crop_bounds(x: float, y: float, zoom: float, size: tuple[int, int]) -> Bounds:
    """Bounds that show ``width/zoom`` by ``height/zoom`` image pixels (``size`` = (width,
    height)) centred on image point (``x``, ``y``): x = column, y = row, origin at the centre
    of the top-left pixel, which is (x, y) in the view: wfviz's recordings place each image's
    pixel centres on integer coordinates (:func:`wfviz.record.recorder.pixel_centres`)."""
    half_w, half_h = size[0] / zoom / 2, size[1] / zoom / 2
    cx, cy = x, y
    return (cx - half_w, cx + half_w, cy - half_h, cy + half_h)


def pick_timeline(rrd: Path, timeline: str | None = None) -> str:
    """``timeline`` when given; else ``frame`` when recording ``rrd`` has it (or cannot be read:
    the viewer then reports the problem), else its only sequence timeline (``trial`` in a
    ``study.rrd``). Raises ValueError, naming ``rrd`` and its sequence timelines, when it has
    several and no ``frame``."""
    if timeline is not None:
        return timeline
    kinds = timelines(rrd)
    if kinds is None or "frame" in kinds:
        return "frame"
    sequences = sorted(n for n, k in kinds.items() if k == "sequence")
    if len(sequences) == 1:
        return sequences[0]
    held = ", ".join(sequences) or "none"
    raise ValueError(f"{rrd} has no frame timeline: give --timeline (its sequence timelines: {held})")


def plan_shots(
    rrd: Path,
    *,
    frame: int | None = None,
    frames: str | None = None,
    timeline: str = "frame",
    around: str | None = None,
    target: int | None = None,
    track: int | None = None,
    zoom: float | None = None,
) -> list[Shot]:
    """The shots that ``wfviz screenshot``'s options ask of recording ``rrd``, checked against it
    (the file is read, no viewer started). ``frames`` is ``A,B,C``; ``around`` is ``X,Y``.
    Raises ValueError with one line naming the option, the problem and ``rrd``."""
    if frame is not None and frames is not None:
        raise ValueError(f"--frame and --frames together for {rrd}: give one or the other")
    times = _parse_frames(frames, rrd) if frames is not None else [frame]
    given = [name for name, v in (("--around", around), ("--target", target), ("--track", track)) if v is not None]
    if len(given) > 1:
        raise ValueError(f"{' and '.join(given)} together for {rrd}: give one of them")
    if zoom is not None and not given:
        raise ValueError(f"--zoom {zoom:g} for {rrd}: needs --around, --target or --track")
    zoom = DEFAULT_ZOOM if zoom is None else zoom
    if not 0 < zoom <= MAX_ZOOM:  # NaN fails too
        raise ValueError(f"--zoom {zoom:g} for {rrd}: must be above 0 and at most {MAX_ZOOM:g}")
    point = _parse_point(around, rrd) if around is not None else None

    kinds = timelines(rrd)
    if kinds is not None and timeline not in kinds:
        raise ValueError(f"--timeline {timeline}: {rrd} has no such timeline (it has: {', '.join(sorted(kinds)) or 'none'})")
    if kinds is not None and kinds[timeline] != "sequence":
        seqs = ", ".join(sorted(n for n, k in kinds.items() if k == "sequence")) or "none"
        raise ValueError(f"--timeline {timeline}: a {kinds[timeline]} timeline in {rrd}, not a sequence "
                         f"(its sequences: {seqs})")
    span = frame_range(rrd, timeline)
    option = "--frames" if frames is not None else "--frame"
    for t in times:
        if span is not None and t is not None and not span[0] <= t <= span[1]:
            held = f"frames {span[0]}-{span[1]}" if timeline == "frame" else f"{timeline} {span[0]}-{span[1]}"
            raise ValueError(f"{option} {t}: {rrd} holds {held}")

    centres: list[tuple[float, float] | None] = [None] * len(times)
    size = None
    if given:
        size = image_size(rrd)
        if size is None:
            raise ValueError(f"{given[0]} for {rrd}: it holds no image to crop around")
    if point is not None and size is not None:
        if not (-0.5 <= point[0] <= size[0] - 0.5 and -0.5 <= point[1] <= size[1] - 0.5):
            raise ValueError(f"--around {point[0]:g},{point[1]:g}: outside the {size[0]}x{size[1]} image of {rrd}")
        centres = [point] * len(times)
    follow: tuple[Literal["target", "track"], int] | None = (
        ("target", target) if target is not None else ("track", track) if track is not None else None)
    if follow is not None:
        if span is None:
            raise ValueError(f"--{follow[0]} {follow[1]}: {rrd} holds no data on timeline {timeline}")
        times = [span[1] if t is None else t for t in times]  # the viewer's default: the last time
        found = overlay_positions(rrd, follow[0], follow[1], [t for t in times if t is not None], timeline)
        centres = [found[t] if t is not None else None for t in times]
    suffix = f", target {target}" if target is not None else f", track {track}" if track is not None else ""
    return [
        Shot(t, None if c is None or size is None else crop_bounds(c[0], c[1], zoom, size),
             f"{timeline} {t}{suffix}" if frames is not None else "")
        for t, c in zip(times, centres)
    ]


def _parse_frames(text: str, rrd: Path) -> list[int | None]:
    """``A,B,C`` as frame numbers (0 or more, at most ``MAX_SHOTS`` of them)."""
    parts = [p.strip() for p in text.split(",")]
    if not all(p.isdigit() for p in parts):
        raise ValueError(f"--frames {text!r} for {rrd}: expected frame numbers separated by commas, e.g. 40,76,120")
    if len(parts) > MAX_SHOTS:
        raise ValueError(f"--frames {text!r} for {rrd}: {len(parts)} frames, at most {MAX_SHOTS} fit one picture")
    return [int(p) for p in parts]


def _parse_point(text: str, rrd: Path) -> tuple[float, float]:
    """``X,Y`` as two finite numbers."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        x, y = float(parts[0]), float(parts[1])
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError
    except ValueError:
        raise ValueError(f"--around {text!r} for {rrd}: expected X,Y (column,row in image pixels), e.g. 320,256") from None
    return x, y


def render_screenshot(
    rrd: Path,
    out_png: Path,
    *,
    frame: int | None = None,
    timeline: str = "frame",
    width: int = 1600,
    height: int = 1000,
    timeout: float = 60.0,
    around: tuple[float, float] | None = None,
    zoom: float = 4.0,
) -> Path:
    """Screenshot the whole viewer showing `rrd` (with its default blueprint) at `timeline` = `frame`.

    `timeline` must be a sequence timeline; `frame=None` means its last time, and a frame outside
    the recorded range shows the latest data at or before it. The viewer window is
    `width`x`height` logical points, and the PNG has that many pixels. `around` = (x, y) crops
    the 2D views around that image point at `zoom` (see `crop_bounds`; the image size is read
    from `rrd`). Returns `out_png`. Raises `ScreenshotError` if the viewer or Vulkan is
    unavailable, the viewer crashes, `around` is given and `rrd` holds no image, or it exceeds
    `timeout` (checked between viewer calls; one call may block up to 15 s on its own).
    """
    bounds = None
    if around is not None:
        size = image_size(Path(rrd))
        if size is None:
            raise ScreenshotError(f"{Path(rrd).name} holds no image to crop around")
        bounds = crop_bounds(around[0], around[1], zoom, size)
    return render_shots(rrd, out_png, [Shot(frame, bounds)], timeline=timeline, width=width, height=height,
                        timeout=timeout)


def render_shots(
    rrd: Path,
    out_png: Path,
    shots: Sequence[Shot],
    *,
    timeline: str = "frame",
    width: int = 1600,
    height: int = 1000,
    timeout: float = 60.0,
) -> Path:
    """Screenshot the viewer showing `rrd` once per shot, in one viewer process, into `out_png`.

    One shot: its screenshot as the viewer took it (`width`x`height` pixels). Several: one PNG
    with a panel per shot, side by side up to three and in a grid beyond, each under a strip
    with its label. A shot with `bounds` shows the 2D views of the recording's blueprint with
    those visual bounds. `timeout` bounds starting the viewer and loading `rrd`, and again each
    shot. Returns `out_png`; raises `ScreenshotError` as `render_screenshot` does.
    """
    if not shots:
        raise ValueError("no shot to take")
    rrd = Path(rrd).resolve()
    out_png = Path(out_png)
    if not rrd.is_file():
        raise FileNotFoundError(rrd)
    exe = _find_viewer()
    _check_vulkan()

    started = time.monotonic()
    deadline = started + timeout
    port = _free_port()
    env = dict(os.environ, RERUN_APP_ONLY="true")  # skip the first-run analytics banner
    cmd = [
        exe, "--headless", "--renderer", "vulkan",
        "--bind", "127.0.0.1", "--port", str(port),
        "--window-size", f"{width}x{height}", "--hide-welcome-screen",
    ]  # fmt: skip
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True,
            preexec_fn=_die_with_parent(),
        )
        try:
            client = _connect(proc, port, deadline, log)
            pngs = _render(client, proc, rrd, shots, timeline, timeout, deadline, log, started + _TOASTS_GONE)
        finally:
            _kill_group(proc)
    png = pngs[0] if len(shots) == 1 else _panels(pngs, [s.label for s in shots])
    out_png.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(out_png, png)
    return out_png


def frame_range(rrd: Path, timeline: str = "frame") -> tuple[int, int] | None:
    """The first and last time of the sequence ``timeline`` in recording ``rrd``, from its
    footer (no chunk data read), else by streaming its chunks; None if it has no such data or
    cannot be read (the viewer then reports the problem)."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # Rerun's note on a file without a footer
        warnings.simplefilter("ignore")
        reader = RrdReader(rrd)
    try:  # the footer's manifest: one row per chunk, with the time range of each timeline
        index = reader.store()._chunk_index().to_arrow()
        starts, ends = index.column(f"{timeline}:start"), index.column(f"{timeline}:end")
        pairs = [(a, b) for a, b in zip(starts.to_pylist(), ends.to_pylist()) if a is not None and b is not None]
        return (int(min(a for a, _ in pairs)), int(max(b for _, b in pairs))) if pairs else None
    except Exception:  # noqa: BLE001 - no footer (an older file), or the private index changed
        pass
    lo = hi = None
    try:
        for chunk in reader.stream():
            batch = chunk.to_record_batch()
            if chunk.is_static or timeline not in batch.schema.names:
                continue
            values = [v for v in batch.column(timeline).to_pylist() if v is not None]
            if values:
                lo = min(values) if lo is None else min(lo, *values)
                hi = max(values) if hi is None else max(hi, *values)
    except Exception:  # noqa: BLE001 - unreadable: left to the viewer
        return None
    return None if lo is None or hi is None else (int(lo), int(hi))


def timelines(rrd: Path) -> dict[str, str] | None:
    """The timelines of recording ``rrd``, name -> kind (``sequence``, ``duration`` or
    ``timestamp``), from its footer, else by streaming its chunks; None if it cannot be read."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            reader = RrdReader(rrd)
        except Exception:  # noqa: BLE001 - unreadable: left to the viewer
            return None
    try:  # the footer: the schema's index columns, their types in the chunk index
        store = reader.store()
        fields = store._chunk_index().to_arrow().schema
        names = [c.name for c in store.schema().index_columns()]
        return {n: _time_kind(fields.field(f"{n}:start").type) for n in names}
    except Exception:  # noqa: BLE001 - no footer (an older file), or the private index changed
        pass
    found: dict[str, str] = {}
    try:
        for chunk in reader.stream():
            for field in chunk.to_record_batch().schema:
                if (field.metadata or {}).get(b"rerun:kind") == b"index":
                    found.setdefault(field.name, _time_kind(field.type))
    except Exception:  # noqa: BLE001
        return None
    return found


def _time_kind(dtype: pa.DataType) -> str:
    import pyarrow as pa

    return "duration" if pa.types.is_duration(dtype) else "timestamp" if pa.types.is_timestamp(dtype) else "sequence"


def image_size(rrd: Path) -> tuple[int, int] | None:
    """(width, height) of the images in recording ``rrd`` (``camera/image`` first, else any
    exact image, else the first JPEG preview decoded); None if it holds none."""
    import cv2
    import numpy as np

    sizes: dict[str, tuple[int, int]] = {}
    for chunk in _chunks(rrd, components="Image:format"):
        formats = [f for f in chunk.to_record_batch().column("Image:format").to_pylist() if f]
        if formats and chunk.entity_path not in sizes:
            sizes[chunk.entity_path] = (int(formats[0][0]["width"]), int(formats[0][0]["height"]))
    if sizes:
        return sizes.get("/camera/image", next(iter(sizes.values())))
    for chunk in _chunks(rrd, components="EncodedImage:blob"):
        for blob in chunk.to_record_batch().column("EncodedImage:blob").to_pylist():
            if blob:
                img = cv2.imdecode(np.asarray(blob[0], dtype=np.uint8), cv2.IMREAD_UNCHANGED)
                if img is not None:
                    return int(img.shape[1]), int(img.shape[0])
    return None


#: entity, position column and label column of what ``--target`` and ``--track`` follow
_OVERLAYS = {
    "target": ("/camera/truth", "Points2D:positions", "Points2D:labels", "truth target", "record with --truth"),
    "track": ("/camera/tracks", "LineStrips2D:strips", "LineStrips2D:labels", "confirmed track", ""),
}


def overlay_positions(
    rrd: Path, kind: Literal["target", "track"], ident: int, times: Sequence[int], timeline: str = "frame",
) -> dict[int, tuple[float, float]]:
    """Where truth target ``ident`` (``camera/truth``, labelled ``T<id>``) or confirmed track
    ``ident`` (the last point of its trail in ``camera/tracks``) is at each of ``times``, as the
    viewer shows it there (the latest row at or before the time). Raises ValueError, naming
    ``rrd``, when the recording has no such entity or the id is not there at a time."""
    entity, pos_col, label_col, what, hint = _OVERLAYS[kind]
    rows: list[tuple[int, list[Any], list[str]]] = []
    for chunk in _chunks(rrd, content=entity):
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if timeline not in names or pos_col not in names:
            continue
        labels = batch.column(label_col).to_pylist() if label_col in names else [None] * batch.num_rows
        for t, pos, lab in zip(batch.column(timeline).to_pylist(), batch.column(pos_col).to_pylist(), labels):
            if t is not None:
                rows.append((int(t), pos or [], lab or []))
    if not rows:
        raise ValueError(f"--{kind} {ident}: {rrd} has no {entity} on timeline {timeline}"
                         + (f" ({hint})" if hint else ""))
    rows.sort(key=lambda r: r[0])
    starts = [r[0] for r in rows]
    out: dict[int, tuple[float, float]] = {}
    for t in times:
        i = bisect.bisect_right(starts, t) - 1
        _, pos, labels = rows[i] if i >= 0 else (t, [], [])
        ids = [_overlay_id(kind, lab) for lab in labels]
        where = f"frame {t}" if timeline == "frame" else f"{timeline} {t}"
        if ident not in ids or ids.index(ident) >= len(pos):
            there = ", ".join(str(i) for i in sorted({i for i in ids if i is not None})) or "none"
            raise ValueError(f"--{kind} {ident}: no {what} {ident} at {where} of {rrd} (there: {there})")
        point = pos[ids.index(ident)]
        if kind == "track":
            point = point[-1]  # a trail ends at the track's reported position
        out[t] = (float(point[0]), float(point[1]))
    return out


def _overlay_id(kind: str, label: str | None) -> int | None:
    """The id in a truth label (``T3``, ``T3 hidden``) or a trail label (``3``)."""
    m = re.fullmatch(r"T(\d+)(?: hidden)?" if kind == "target" else r"(\d+)", label or "")
    return int(m.group(1)) if m else None


def _chunks(rrd: Path, *, content: str | None = None, components: str | None = None) -> Iterator[Chunk]:
    """The chunks of recording ``rrd`` (through its footer when it has one), filtered."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # Rerun's note on a file without a footer
        warnings.simplefilter("ignore")
        reader = RrdReader(rrd)
        try:
            stream = reader.store().stream()
        except Exception:  # noqa: BLE001 - no footer
            stream = reader.stream()
    if content is not None or components is not None:
        stream = stream.filter(content=content, components=components)
    yield from stream


def _die_with_parent() -> Callable[[], None] | None:
    """For the viewer's ``preexec_fn`` on Linux: the kernel sends it SIGKILL when wfviz dies,
    even by SIGKILL (``prctl(PR_SET_PDEATHSIG)``; it fires when the forking thread ends, here
    the main thread). None elsewhere."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up before the fork
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1: PR_SET_PDEATHSIG
        if os.getppid() != parent:  # wfviz died before the call: nothing would send the signal
            os._exit(1)

    return preexec


def _find_viewer() -> str:
    """Path of the native `rerun` binary: $RERUN_CLI_PATH, the one bundled with rerun-sdk, or PATH."""
    override = os.environ.get("RERUN_CLI_PATH")
    candidates = [override] if override else []
    try:
        import rerun_cli

        candidates.append(str(Path(rerun_cli.__file__).with_name("rerun")))
    except ImportError:
        pass
    candidates += [str(Path(sys.executable).with_name("rerun")), shutil.which("rerun")]
    for cand in candidates[:1] if override else candidates:
        if cand and os.path.isfile(cand) and os.access(cand, os.X_OK):
            return cand
    raise ScreenshotError("Rerun viewer binary not found (pip install rerun-sdk, or set RERUN_CLI_PATH)")


def _check_vulkan() -> None:
    """Fail fast when there is no Vulkan loader or no driver manifest (ICD) at all."""
    if ctypes.util.find_library("vulkan") is None:
        raise ScreenshotError("Vulkan loader libvulkan.so.1 not found (apt-get install libvulkan1 mesa-vulkan-drivers)")
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return
    if not any(Path(d).is_dir() and any(Path(d).glob("*.json")) for d in _ICD_DIRS):
        raise ScreenshotError("no Vulkan driver installed (apt-get install mesa-vulkan-drivers for lavapipe)")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _log_tail(log: IO[bytes]) -> str:
    """The most telling line of the viewer's output: a panic message if any, else the last line."""
    log.flush()
    log.seek(0)
    lines = [ln.strip() for ln in log.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    for ln in lines:
        if "panicked at" in ln:
            return ln
    return lines[-1] if lines else "(no output)"


def _check_alive(proc: subprocess.Popen[bytes], log: IO[bytes]) -> None:
    if proc.poll() is not None:
        tail = _log_tail(log)
        hint = " (no Vulkan adapter: apt-get install mesa-vulkan-drivers)" if "No graphics adapter" in tail else ""
        raise ScreenshotError(f"Rerun viewer exited with code {proc.returncode}{hint}: {tail}")


def _check_deadline(deadline: float, what: str) -> None:
    if time.monotonic() > deadline:
        raise ScreenshotError(f"timed out {what}")


def _connect(proc: subprocess.Popen[bytes], port: int, deadline: float, log: IO[bytes]) -> ViewerClient:
    """Wait until the headless viewer answers on `port`, and return a connected ViewerClient."""
    from rerun.experimental import ViewerClient

    while True:
        _check_alive(proc, log)
        _check_deadline(deadline, "waiting for the Rerun viewer to start")
        try:  # the constructor connects eagerly, so it fails until the viewer listens
            client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            client.get_state()
            return client
        except (ConnectionError, RuntimeError, OSError):
            time.sleep(0.1)


def _render(
    client: ViewerClient,
    proc: subprocess.Popen[bytes],
    rrd: Path,
    shots: Sequence[Shot],
    timeline: str,
    timeout: float,
    deadline: float,
    log: IO[bytes],
    quiet_at: float = 0.0,
) -> list[bytes]:
    """Open `rrd`, then for each shot move the time cursor, set the 2D views' bounds, and take a
    PNG once the picture stops changing (not before `quiet_at`, monotonic)."""
    try:
        opened = client.open(str(rrd))
        if not opened.store_ids:
            raise ScreenshotError(f"Rerun viewer loaded no recording from {rrd}")
        store_id = opened.store_ids[0]
        tl = _wait_for_timeline(client, proc, store_id, rrd, timeline, deadline, log)
        if tl.time_type != "sequence":
            raise ScreenshotError(f"timeline {timeline!r} is a {tl.time_type} timeline, not a frame sequence")
        base = _blueprint(client, proc, store_id, deadline, log) if any(s.bounds for s in shots) else None

        pngs: list[bytes] = []
        shown: Bounds | None = None
        for shot in shots:
            deadline = time.monotonic() + timeout
            seq = shot.time if shot.time is not None else int(tl.end or 0)
            client.set_time(timeline, sequence=seq, play_state="paused", recording=store_id)
            if base is not None and shot.bounds != shown:
                client.set_blueprint(_with_bounds(base, shot.bounds), store_id=store_id)
                shown = shot.bounds
            pngs.append(_settled_shot(client, proc, deadline, log, quiet_at))
        return pngs
    except ScreenshotError:
        raise
    except Exception as err:  # gRPC / viewer-control errors surface as plain exceptions
        msg = " ".join(str(err).split())
        _check_alive(proc, log)
        _check_deadline(deadline, f"rendering {rrd.name}: {msg}")
        raise ScreenshotError(f"Rerun viewer failed: {msg}") from err


def _settled_shot(
    client: ViewerClient, proc: subprocess.Popen[bytes], deadline: float, log: IO[bytes], not_before: float = 0.0,
) -> bytes:
    """A screenshot once two in a row match (plots animate their auto-fit bounds, and data,
    a new blueprint or bounds may still be arriving), the first taken at `not_before`
    (monotonic) or later."""
    time.sleep(max(0.0, min(not_before, deadline) - time.monotonic()))
    previous = b""
    for _ in range(_SETTLE_MAX_SHOTS):
        _check_alive(proc, log)
        _check_deadline(deadline, "waiting for the Rerun viewer screenshot")
        png: bytes = client.take_screenshot()
        if png and png == previous:
            break
        previous = png
        time.sleep(0.2)
    if not previous:
        raise ScreenshotError("Rerun viewer returned an empty screenshot")
    return previous


def _is_2d_view(entry: Any) -> bool:
    return isinstance(entry, dict) and entry.get("ViewBlueprint", {}).get("class_identifier") == "2D"


def _is_legend(entry: dict[str, Any]) -> bool:
    """The recording's legend view (origin ``legend``): a key, not the image, never cropped."""
    view = entry.get("ViewBlueprint", {})
    return str(view.get("space_origin", "")).strip("/") == "legend" or view.get("display_name") == "Legend"


def _blueprint(
    client: ViewerClient, proc: subprocess.Popen[bytes], store_id: str, deadline: float, log: IO[bytes],
) -> dict[str, Any]:
    """The recording's blueprint as the viewer holds it, once it has a 2D view (at most 5 s)."""
    until = min(deadline, time.monotonic() + 5.0)
    while True:
        _check_alive(proc, log)
        blueprint: dict[str, Any] = client.get_blueprint(store_id=store_id).blueprint
        if any(_is_2d_view(v) for v in blueprint.values()):
            return blueprint
        if time.monotonic() > until:
            raise ScreenshotError("the recording's blueprint has no 2D view to crop")
        time.sleep(0.1)


def _with_bounds(blueprint: dict[str, Any], bounds: Bounds | None) -> dict[str, Any]:
    """``blueprint`` with every 2D view's visual bounds set to ``bounds`` (None: as it was)."""
    if bounds is None:
        return blueprint
    x0, x1, y0, y1 = bounds
    out = dict(blueprint)
    for path, entry in blueprint.items():
        if _is_2d_view(entry) and not _is_legend(entry):
            out[f"{path}/VisualBounds2D"] = {"VisualBounds2D": {"range": {"x_range": [x0, x1], "y_range": [y0, y1]}}}
    return out


def _panels(pngs: Sequence[bytes], labels: Sequence[str]) -> bytes:
    """One PNG with the screenshots side by side (a grid beyond three), each under its label."""
    import cv2
    import numpy as np

    images = []
    for png in pngs:
        img = cv2.imdecode(np.frombuffer(png, dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise ScreenshotError("Rerun viewer returned a screenshot that is not a PNG")
        images.append(img)
    n = len(images)
    cols = n if n <= 3 else math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    h = max(img.shape[0] for img in images) + _LABEL_HEIGHT
    w = max(img.shape[1] for img in images)
    canvas = np.full((rows * h + (rows - 1) * _GAP, cols * w + (cols - 1) * _GAP, 3), 70, np.uint8)
    for k, (img, label) in enumerate(zip(images, labels)):
        y, x = (k // cols) * (h + _GAP), (k % cols) * (w + _GAP)
        canvas[y:y + h, x:x + w] = 24
        cv2.putText(canvas, label, (x + 12, y + 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
        canvas[y + _LABEL_HEIGHT:y + _LABEL_HEIGHT + img.shape[0], x:x + img.shape[1]] = img
    ok, buf = cv2.imencode(".png", canvas)
    if not ok:
        raise ScreenshotError("could not encode the panels as PNG")
    return bytes(buf.tobytes())


def _wait_for_timeline(
    client: ViewerClient,
    proc: subprocess.Popen[bytes],
    store_id: str,
    rrd: Path,
    timeline: str,
    deadline: float,
    log: IO[bytes],
) -> Timeline:
    """Poll the viewer until `rrd` has finished loading and return its `timeline` (with a time range)."""
    while True:
        _check_alive(proc, log)
        _check_deadline(deadline, f"loading {rrd.name} in the Rerun viewer")
        state = client.get_state()
        rec = next((r for r in state.recordings if r.store_id == store_id), None)
        if rec is not None and not state.loading:
            tl = next((t for t in rec.timelines if t.name == timeline), None)
            if tl is None:
                names = ", ".join(t.name for t in rec.timelines) or "none"
                raise ScreenshotError(f"timeline {timeline!r} not in {rrd.name} (has: {names})")
            if tl.end is not None:
                return tl
        time.sleep(0.1)


def _kill_group(proc: subprocess.Popen[bytes]) -> None:
    """Stop the viewer's whole process group: SIGTERM, then SIGKILL after 5 s."""
    for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=wait)
            return
        except subprocess.TimeoutExpired:
            continue
