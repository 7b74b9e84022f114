"""Render an .rrd recording in the real Rerun viewer, headless, and save a PNG screenshot.

The viewer (`rerun --headless`) renders offscreen through wgpu on Vulkan. Without a GPU this
needs Mesa's software rasteriser lavapipe (Debian: ``apt-get install mesa-vulkan-drivers``,
which pulls in ``libvulkan1``). The viewer is started on a free loopback port in its own
process group, driven with :class:`rerun.experimental.ViewerClient`, and killed afterwards.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import IO, TYPE_CHECKING, Callable

from wfviz.io.outputs import write_atomically

if TYPE_CHECKING:
    from rerun.experimental import Timeline, ViewerClient

__all__ = ["ScreenshotError", "frame_range", "render_screenshot"]

_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/usr/local/share/vulkan/icd.d", "/etc/vulkan/icd.d")
_SETTLE_MAX_SHOTS = 8


class ScreenshotError(RuntimeError):
    """The viewer could not produce a screenshot (missing binary or driver, crash, timeout)."""


def render_screenshot(
    rrd: Path,
    out_png: Path,
    *,
    frame: int | None = None,
    timeline: str = "frame",
    width: int = 1600,
    height: int = 1000,
    timeout: float = 60.0,
) -> Path:
    """Screenshot the whole viewer showing `rrd` (with its default blueprint) at `timeline` = `frame`.

    `timeline` must be a sequence timeline; `frame=None` means its last time, and a frame outside
    the recorded range shows the latest data at or before it. The viewer window is
    `width`x`height` logical points, and the PNG has that many pixels. Returns `out_png`.
    Raises `ScreenshotError` if the viewer or Vulkan is unavailable, the viewer crashes, or it
    exceeds `timeout` (checked between viewer calls; one call may block up to 15 s on its own).
    """
    rrd = Path(rrd).resolve()
    out_png = Path(out_png)
    if not rrd.is_file():
        raise FileNotFoundError(rrd)
    exe = _find_viewer()
    _check_vulkan()

    deadline = time.monotonic() + timeout
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
            png = _render(client, proc, rrd, frame, timeline, deadline, log)
        finally:
            _kill_group(proc)
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
    frame: int | None,
    timeline: str,
    deadline: float,
    log: IO[bytes],
) -> bytes:
    """Open `rrd`, move the time cursor, and return a PNG once the picture stops changing."""
    try:
        opened = client.open(str(rrd))
        if not opened.store_ids:
            raise ScreenshotError(f"Rerun viewer loaded no recording from {rrd}")
        store_id = opened.store_ids[0]
        tl = _wait_for_timeline(client, proc, store_id, rrd, timeline, deadline, log)
        if tl.time_type != "sequence":
            raise ScreenshotError(f"timeline {timeline!r} is a {tl.time_type} timeline, not a frame sequence")

        seq = frame if frame is not None else int(tl.end or 0)
        client.set_time(timeline, sequence=seq, play_state="paused", recording=store_id)

        # Plots animate their auto-fit bounds and data may stream in: take shots until two match.
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
    except ScreenshotError:
        raise
    except Exception as err:  # gRPC / viewer-control errors surface as plain exceptions
        msg = " ".join(str(err).split())
        _check_alive(proc, log)
        _check_deadline(deadline, f"rendering {rrd.name}: {msg}")
        raise ScreenshotError(f"Rerun viewer failed: {msg}") from err


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
