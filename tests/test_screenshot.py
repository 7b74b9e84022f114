"""Headless Rerun viewer screenshots (needs Vulkan; lavapipe from mesa-vulkan-drivers works)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
rrb = pytest.importorskip("rerun.blueprint")
Image = pytest.importorskip("PIL.Image")

from conftest import needs_vulkan  # noqa: E402
from wfviz.record.screenshot import ScreenshotError, render_screenshot  # noqa: E402

W, H = 1200, 800


def _dot_x(f: int) -> float:
    return 20.0 + 12.0 * f


def _make_rrd(path: Path) -> Path:
    rec = rr.RecordingStream("wfviz_test")
    bp = rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial2DView(origin="camera", name="camera"), rrb.TimeSeriesView(origin="timing"))
    )
    rec.save(str(path), default_blueprint=bp)
    rng = np.random.default_rng(0)
    for f in range(20):
        rec.set_time("frame", sequence=f)
        rec.log("camera/image", rr.Image((rng.random((256, 320)) * 60000).astype(np.uint16)))
        rec.log("camera/detections", rr.Points2D([[_dot_x(f), 60]], radii=4, colors=[255, 0, 0]))
        rec.log("timing/total", rr.Scalars(1.0 + 0.1 * f))
    rec.flush()
    rec.disconnect()
    return path


def _longest_run(idx: np.ndarray, max_gap: int = 4) -> tuple[int, int]:
    """Longest stretch of sorted indices with gaps of at most `max_gap`, as (first, last + 1)."""
    assert idx.size, "no camera image (noise) visible in the screenshot"
    splits = np.flatnonzero(np.diff(idx) > max_gap) + 1
    runs = np.split(idx, splits)
    best = max(runs, key=lambda r: int(r[-1] - r[0]))
    return int(best[0]), int(best[-1]) + 1


def _noise_box(rgb: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box (y0, y1, x0, x1) of the noisy camera image: rows/cols dense in sharp pixel jumps."""
    gray = rgb.astype(np.int32).mean(axis=2)
    jumps = np.abs(np.diff(gray, axis=1)) > 60
    y0, y1 = _longest_run(np.flatnonzero(jumps.mean(axis=1) > 0.15))
    x0, x1 = _longest_run(np.flatnonzero(jumps[y0:y1].mean(axis=0) > 0.3))
    return y0, y1, x0, x1 + 1


def _red_dot_x(rgb: np.ndarray, box: tuple[int, int, int, int]) -> float:
    y0, y1, x0, x1 = box
    a = rgb[y0:y1, x0:x1].astype(np.int32)
    red = np.argwhere((a[..., 0] > 200) & (a[..., 1] < 60) & (a[..., 2] < 60))
    assert len(red) >= 4, "red detection point not drawn inside the camera image"
    return float(red[:, 1].mean())


@needs_vulkan
def test_render_screenshot_shows_views_at_frame(tmp_path: Path) -> None:
    rrd = _make_rrd(tmp_path / "rec.rrd")
    early = render_screenshot(rrd, tmp_path / "f2.png", frame=2, width=W, height=H, timeout=120)
    late = render_screenshot(rrd, tmp_path / "f17.png", frame=17, width=W, height=H, timeout=120)

    for png in (early, late):
        img = Image.open(png)
        assert abs(img.width - W) <= 4 and abs(img.height - H) <= 4, img.size
        rgb = np.asarray(img.convert("RGB"))
        assert rgb.reshape(-1, 3).std(axis=0).max() > 10, "screenshot is blank / uniform"

    rgb_early = np.asarray(Image.open(early).convert("RGB"))
    rgb_late = np.asarray(Image.open(late).convert("RGB"))
    box = _noise_box(rgb_early)
    y0, y1, x0, x1 = box
    # The 320x256 camera image fills a good part of the left view of the blueprint's split.
    assert (x1 - x0) > W * 0.2 and (y1 - y0) > H * 0.2, box
    assert x1 <= W * 0.75, f"camera image not in the left half of the layout: {box}"
    area = rgb_early[y0:y1, x0:x1].astype(np.int32)
    assert area.std() > 30, "camera image area is uniform"

    # The time cursor was honoured: the detection moved right by 15 frames * 12 image px.
    shift_px = _red_dot_x(rgb_late, box) - _red_dot_x(rgb_early, box)
    expected = (_dot_x(17) - _dot_x(2)) * (x1 - x0) / 320
    assert shift_px == pytest.approx(expected, rel=0.25), (shift_px, expected)


@needs_vulkan
def test_render_screenshot_unknown_timeline(tmp_path: Path) -> None:
    rrd = _make_rrd(tmp_path / "rec.rrd")
    with pytest.raises(ScreenshotError, match="timeline 'nope'"):
        render_screenshot(rrd, tmp_path / "x.png", frame=1, timeline="nope", width=640, height=480)
    assert not (tmp_path / "x.png").exists()


def test_render_screenshot_missing_viewer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rrd = tmp_path / "rec.rrd"
    rrd.write_bytes(b"")
    monkeypatch.setenv("RERUN_CLI_PATH", str(tmp_path / "no-such-rerun"))
    with pytest.raises(ScreenshotError, match="viewer binary not found"):
        render_screenshot(rrd, tmp_path / "x.png")


@needs_vulkan
def test_demo_recording_renders_with_its_views(tmp_path):
    """`wfviz demo` then `wfviz screenshot`: the picture shows the blueprint's views."""
    import subprocess
    import sys

    def wfviz(*args):
        proc = subprocess.run([sys.executable, "-m", "wfviz", *args], cwd=tmp_path, capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return proc

    wfviz("demo", "--frames", "30")
    png = tmp_path / "shot.png"
    wfviz("screenshot", "recordings/demo-gewc.rrd", "--frame", "20", "-o", str(png),
          "--width", "1200", "--height", "800")
    img = np.asarray(Image.open(png).convert("L"), dtype=np.float64)
    assert abs(img.shape[1] - 1200) <= 4 and abs(img.shape[0] - 800) <= 4
    assert img.std() > 10, "blank or uniform screenshot"
    h, w = img.shape
    camera = img[int(0.08 * h): int(0.48 * h), int(0.05 * w): int(0.55 * w)]  # top-left view
    residual = img[int(0.55 * h): int(0.95 * h), int(0.05 * w): int(0.55 * w)]  # bottom-left view
    plots = img[int(0.08 * h): int(0.95 * h), int(0.62 * w):]                  # right column
    # the fisheye frame: a bright disc with dark corners, many grey levels (not the welcome screen)
    assert camera.std() > 20 and len(np.unique(camera.astype(int))) > 60
    assert residual.std() > 3 and plots.std() > 10


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (Linux /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@needs_vulkan
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_sigterm_ends_the_headless_viewer_too(tmp_path: Path) -> None:
    import signal
    import subprocess
    import sys
    import time

    rrd = _make_rrd(tmp_path / "x.rrd")
    proc = subprocess.Popen([sys.executable, "-m", "wfviz", "screenshot", str(rrd), "-o", str(tmp_path / "s.png")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    viewers: list[int] = []
    while not viewers:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        viewers = _children(proc.pid)
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM and "terminated" in stderr, stderr
    end = time.monotonic() + 10
    while any(_running(v) for v in viewers) and time.monotonic() < end:
        time.sleep(0.1)
    assert not any(_running(v) for v in viewers)
    assert not (tmp_path / "s.png").exists() and not list(tmp_path.glob(".s.png.*"))


def test_frame_outside_the_recording_is_refused(tmp_path: Path) -> None:
    """``--frame`` past the recording's frames: one line with the range, exit 2, no picture,
    and no viewer started (so no Vulkan needed)."""
    import subprocess
    import sys

    rrd = _make_rrd(tmp_path / "rec.rrd")
    for frame in ("500", "20"):
        proc = subprocess.run([sys.executable, "-m", "wfviz", "screenshot", str(rrd), "--frame", frame, "-o",
                               str(tmp_path / "s.png")], capture_output=True, text=True, timeout=120)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1, proc.stderr
        assert f"--frame {frame}: {rrd} holds frames 0-19" in lines[0], proc.stderr
        assert not list(tmp_path.glob("*.png")) and not list(tmp_path.glob(".s.png.*"))


def test_frame_range_without_a_footer(tmp_path: Path) -> None:
    """A recording without the footer's manifest: the range comes from its chunks."""
    from wfviz.record.screenshot import frame_range

    rec = rr.RecordingStream("wfviz_test")
    rec.set_sinks(rr.FileSink(str(tmp_path / "nf.rrd"), write_footer=False))
    for f in range(3, 9):
        rec.set_time("frame", sequence=f)
        rec.log("timing/total", rr.Scalars(float(f)))
    rec.flush()
    rec.disconnect()
    assert frame_range(tmp_path / "nf.rrd") == (3, 8)
    assert frame_range(_make_rrd(tmp_path / "rec.rrd")) == (0, 19)
    assert frame_range(tmp_path / "rec.rrd", "nope") is None


@needs_vulkan
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_sigkill_ends_the_headless_viewer_too(tmp_path: Path) -> None:
    """wfviz killed outright (no clean-up possible): its headless viewer dies with it."""
    import signal
    import subprocess
    import sys
    import time

    rrd = _make_rrd(tmp_path / "x.rrd")
    proc = subprocess.Popen([sys.executable, "-m", "wfviz", "screenshot", str(rrd), "-o", str(tmp_path / "s.png")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    viewers: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while not viewers:
            assert proc.poll() is None and time.monotonic() < deadline, "wfviz ended before starting its viewer"
            viewers = _children(proc.pid)
            time.sleep(0.05)
        proc.kill()
        proc.wait(timeout=10)
        end = time.monotonic() + 5
        while any(_running(v) for v in viewers) and time.monotonic() < end:
            time.sleep(0.1)
        assert not any(_running(v) for v in viewers), "the viewer outlived wfviz"
    finally:
        proc.kill()
        for v in viewers:  # on failure: do not leave it running
            try:
                os.killpg(v, signal.SIGKILL)
            except OSError:
                pass
