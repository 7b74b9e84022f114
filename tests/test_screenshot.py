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


# -- crops, several frames, other timelines (issue 34) ----------------------------------------

CLIP_W, CLIP_H = 320, 256
BG = 90  # grey of the clip's background
GREEN = (0, 255, 0)


def _target_at(f: int) -> tuple[int, int]:
    """Centre (column, row) of the clip's 3x3 green target in frame ``f``."""
    return 60 + 10 * f, 80 + 5 * f


@pytest.fixture(scope="module")
def clip_rrd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """10 frames of a grey 320x256 image with a 3x3 green target moving down-right, its truth
    (``T7``, and a hidden ``T8`` in a corner) and its track trail (id 3); panels collapsed, so
    the camera view is the left half of the window."""
    path = tmp_path_factory.mktemp("clip") / "clip.rrd"
    rec = rr.RecordingStream("wfviz_test")
    bp = rrb.Blueprint(rrb.Horizontal(rrb.Spatial2DView(origin="camera", name="camera"),
                                      rrb.TimeSeriesView(origin="timing")), collapse_panels=True)
    rec.save(str(path), default_blueprint=bp)
    for f in range(10):
        x, y = _target_at(f)
        img = np.full((CLIP_H, CLIP_W, 3), BG, np.uint8)
        img[y - 1:y + 2, x - 1:x + 2] = GREEN
        rec.set_time("frame", sequence=f)
        rec.log("camera/image", rr.Image(img))
        rec.log("camera/truth", rr.Points2D([[x, y], [20, 20]], labels=["T7", "T8 hidden"], radii=0.2,
                                            colors=[255, 255, 255], show_labels=False))
        rec.log("camera/tracks", rr.LineStrips2D([[[x - 3, y - 3], [x, y]]], labels=["3"], radii=0.1,
                                                 show_labels=False))
        rec.log("timing/total", rr.Scalars(1.0 + f))
    rec.flush()
    rec.disconnect()
    return path


@pytest.fixture(scope="module")
def trial_rrd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A study-like recording: only a ``trial`` timeline, points in a 2D view and a series."""
    path = tmp_path_factory.mktemp("study") / "study.rrd"
    rec = rr.RecordingStream("wfviz_study")
    bp = rrb.Blueprint(rrb.Horizontal(rrb.TimeSeriesView(origin="study/tune"),
                                      rrb.Spatial2DView(origin="study", contents=["study/trials"])),
                       collapse_panels=True)
    rec.save(str(path), default_blueprint=bp)
    for t in range(4):
        rec.set_time("trial", sequence=t)
        rec.log("study/tune/mota", rr.Scalars(0.5 + 0.1 * t))
        rec.log("study/trials", rr.Points2D([[0.1 * t, 0.5 + 0.1 * t]], radii=rr.Radius.ui_points(6.0),
                                            colors=[230, 60, 60]))
    rec.flush()
    rec.disconnect()
    return path


def _green(rgb: np.ndarray) -> np.ndarray:
    return (rgb[..., 1] > 200) & (rgb[..., 0] < 80) & (rgb[..., 2] < 80)


def _view_box(rgb: np.ndarray) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1) of the camera view: the rows and columns mostly of the clip's grey."""
    grey = (np.abs(rgb.astype(np.int32) - BG) <= 3).all(axis=2)
    cols = np.flatnonzero(grey.mean(axis=0) > 0.5)
    rows = np.flatnonzero(grey[:, cols].mean(axis=1) > 0.5)
    assert cols.size and rows.size, "no camera image in the screenshot"
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _green_offset(rgb: np.ndarray) -> tuple[int, float, float, int]:
    """Green pixels, their centroid's offset (dx, dy) from the camera view's centre, view width."""
    y0, y1, x0, x1 = _view_box(rgb)
    ys, xs = np.nonzero(_green(rgb[y0:y1, x0:x1]))
    assert len(xs), "target not in the camera view"
    return len(xs), float(xs.mean()) - (x1 - x0) / 2, float(ys.mean()) - (y1 - y0) / 2, x1 - x0


@needs_vulkan
def test_crop_follows_a_truth_target_in_labelled_panels(clip_rrd: Path, tmp_path: Path) -> None:
    """``--frames 2,6 --target 7 --zoom 8``: one PNG, two labelled panels side by side, each with
    the 3-px target large (about 12 screen px a pixel) at the centre of the camera view."""
    import subprocess
    import sys
    import time

    png = tmp_path / "panels.png"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "wfviz", "screenshot", str(clip_rrd), "--frames", "2,6", "--target",
                           "7", "--zoom", "8", "--width", "1000", "--height", "700", "-o", str(png)],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr
    print(f"two frames, one viewer: {time.perf_counter() - t0:.1f} s")
    rgb = np.asarray(Image.open(png).convert("RGB"))
    gap, strip = 8, 40
    assert abs(rgb.shape[1] - (2 * 1000 + gap)) <= 8 and abs(rgb.shape[0] - (700 + strip)) <= 4, rgb.shape
    w = (rgb.shape[1] - gap) // 2
    labels = []
    for k in range(2):
        panel = rgb[:, k * (w + gap):k * (w + gap) + w]
        label = panel[:strip].astype(np.int32)
        assert (label.min(axis=2) > 200).sum() > 50, "no label text above the panel"
        labels.append(label)
        n, dx, dy, view_w = _green_offset(panel[strip:])
        assert n > 500, f"panel {k}: target only {n} px: not zoomed"  # about 20 px unzoomed
        assert abs(dx) < 0.08 * view_w and abs(dy) < 0.08 * view_w, (k, dx, dy, view_w)
    assert np.abs(labels[0] - labels[1]).max() > 100, "both panels carry the same label"


@needs_vulkan
def test_crop_around_a_point_at_the_zoom(clip_rrd: Path, tmp_path: Path) -> None:
    """``--around`` 10 px right of the target at zoom 8: the view shows 320/8 = 40 image pixels
    across its width, so the target sits a quarter of the view width left of the centre."""
    x, y = _target_at(4)
    png = render_screenshot(clip_rrd, tmp_path / "a.png", frame=4, width=1000, height=700, timeout=120,
                            around=(x + 10, y), zoom=8)
    n, dx, dy, view_w = _green_offset(np.asarray(Image.open(png).convert("RGB")))
    assert n > 300, n
    assert dx == pytest.approx(-10 * view_w / (CLIP_W / 8), rel=0.2), (dx, view_w)
    assert abs(dy) < 0.05 * view_w, dy


@needs_vulkan
def test_trial_timeline_renders(trial_rrd: Path, tmp_path: Path) -> None:
    """A study's ``trial`` timeline: ``--timeline trial`` renders a chosen trial."""
    from conftest import wfviz

    png = tmp_path / "t.png"
    proc = wfviz("screenshot", str(trial_rrd), "--timeline", "trial", "--frame", "2", "-o", str(png),
                 "--width", "800", "--height", "600", timeout=180)
    assert proc.returncode == 0, proc.stderr
    rgb = np.asarray(Image.open(png).convert("RGB"))
    assert abs(rgb.shape[1] - 800) <= 4 and abs(rgb.shape[0] - 600) <= 4
    red = (rgb[..., 0] > 180) & (rgb[..., 1] < 100) & (rgb[..., 2] < 100)
    assert red.sum() > 20, "the trials' points are not drawn"


@pytest.mark.parametrize(("args", "words"), [
    (["--around", "1;2"], ["--around '1;2'", "expected X,Y"]),
    (["--around", "1,2,3"], ["--around '1,2,3'", "expected X,Y"]),
    (["--around", "nan,2"], ["expected X,Y"]),
    (["--around", "400,10"], ["--around 400,10", "outside the 320x256 image"]),
    (["--around", "5,5", "--zoom", "0"], ["--zoom 0", "above 0"]),
    (["--target", "7", "--zoom", "-2"], ["--zoom -2", "above 0"]),
    (["--zoom", "4"], ["--zoom 4", "needs --around, --target or --track"]),
    (["--frames", "1,x"], ["--frames '1,x'", "frame numbers separated by commas"]),
    (["--frames", "1,10"], ["--frames 10", "holds frames 0-9"]),
    (["--frames", ",".join(["1"] * 17)], ["17 frames, at most 16"]),
    (["--frame", "1", "--frames", "2"], ["--frame and --frames"]),
    (["--around", "5,5", "--target", "7"], ["--around and --target"]),
    (["--target", "9", "--frame", "3"], ["--target 9", "no truth target 9 at frame 3", "(there: 7, 8)"]),
    (["--track", "4"], ["--track 4", "no confirmed track 4 at frame 9", "(there: 3)"]),
    (["--timeline", "nope"], ["--timeline nope", "no such timeline", "frame", "log_time"]),
    (["--timeline", "log_time"], ["--timeline log_time", "timestamp timeline", "not a sequence"]),
])
def test_bad_options_are_one_line_naming_the_recording(clip_rrd: Path, tmp_path: Path, args: list[str],
                                                       words: list[str]) -> None:
    """Checked against the file before any viewer starts: one line, exit 2, no picture."""
    from conftest import invoke

    out = tmp_path / "s.png"
    result = invoke("screenshot", str(clip_rrd), "-o", str(out), *args)
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert lines[0].startswith("wfviz: error: ") and str(clip_rrd) in lines[0], lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert not out.exists()


def test_unknown_timeline_is_one_line_listing_the_recordings_timelines(trial_rrd: Path, tmp_path: Path) -> None:
    """``--timeline frame`` on a study: the error says which timelines it has (a subprocess:
    stderr holds that one line and nothing else); its ``trial`` range, with or without
    ``--timeline trial`` (its only sequence timeline, the default there); no image to crop."""
    from conftest import invoke, one_line_error, wfviz

    one_line_error(wfviz("screenshot", str(trial_rrd), "--timeline", "frame", "-o", str(tmp_path / "s.png")),
                   "--timeline frame", str(trial_rrd), "(it has: log_time, trial)")
    for args, words in ((["--frame", "9"], "--frame 9: "), (["--around", "1,1"], "no image to crop")):
        for timeline in (["--timeline", "trial"], []):
            result = invoke("screenshot", str(trial_rrd), *timeline, *args, "-o", str(tmp_path / "s.png"))
            assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
            assert words in result.output and str(trial_rrd) in result.output, result.output
    assert "holds trial 0-3" in invoke("screenshot", str(trial_rrd), "--frame", "9", "-o",
                                       str(tmp_path / "s.png")).output
    assert "holds trial 0-3" in invoke("screenshot", str(trial_rrd), "--timeline", "trial", "--frames", "0,4",
                                       "-o", str(tmp_path / "s.png")).output
    assert not list(tmp_path.iterdir())


def test_plan_shots_centres_the_crop_on_the_target_or_track(clip_rrd: Path) -> None:
    """Bounds centred on the pixel holding the point (Rerun draws pixel i over [i, i+1]), the
    last frame by default, one label per frame with --frames."""
    from wfviz.record.screenshot import Shot, crop_bounds, plan_shots

    (shot,) = plan_shots(clip_rrd, target=7)
    x, y = _target_at(9)
    assert shot == Shot(9, crop_bounds(x, y, 4.0, (CLIP_W, CLIP_H)), "")
    assert shot.bounds == (x - 40, x + 40, y - 32, y + 32)  # the images are placed on pixel centres
    shots = plan_shots(clip_rrd, frames="1, 5", track=3, zoom=2)
    assert [s.label for s in shots] == ["frame 1, track 3", "frame 5, track 3"]
    for s in shots:
        assert s.time is not None and s.bounds is not None
        cx, cy = (s.bounds[0] + s.bounds[1]) / 2, (s.bounds[2] + s.bounds[3]) / 2
        assert (cx, cy) == _target_at(s.time)  # the trail ends at the track
        assert s.bounds[1] - s.bounds[0] == CLIP_W / 2
    assert plan_shots(clip_rrd, frames="0,3") == [Shot(0, None, "frame 0"), Shot(3, None, "frame 3")]
    assert plan_shots(clip_rrd, frame=2, around="10.5,20") == [Shot(2, crop_bounds(10.5, 20, 4.0, (CLIP_W, CLIP_H)))]


def test_overlay_positions_reads_hidden_targets_and_the_latest_row(clip_rrd: Path) -> None:
    from wfviz.record.screenshot import overlay_positions

    assert overlay_positions(clip_rrd, "target", 8, [0, 9]) == {0: (20.0, 20.0), 9: (20.0, 20.0)}
    assert overlay_positions(clip_rrd, "track", 3, [4]) == {4: tuple(float(v) for v in _target_at(4))}
    with pytest.raises(ValueError, match="has no /camera/truth"):
        overlay_positions(_make_rrd(clip_rrd.parent / "plain.rrd"), "target", 1, [3])


def test_image_size_from_a_jpeg_preview(tmp_path: Path) -> None:
    """A recording with JPEG previews only: the size comes from the first one decoded."""
    import cv2

    from wfviz.record.screenshot import image_size, timelines

    rec = rr.RecordingStream("wfviz_test")
    rec.save(str(tmp_path / "j.rrd"))
    rec.set_time("frame", sequence=0)
    ok, jpeg = cv2.imencode(".jpg", np.zeros((48, 64), np.uint8))
    rec.log("camera/image", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))
    rec.flush()
    rec.disconnect()
    assert image_size(tmp_path / "j.rrd") == (64, 48)
    assert timelines(tmp_path / "j.rrd") == {"frame": "sequence", "log_time": "timestamp"}
