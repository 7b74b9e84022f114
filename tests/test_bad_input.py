"""Every kind of bad input, through the CLI: a one-line error naming the file and the problem,
exit code 2 and no output left behind (or, where the input can be read with a workaround, a
one-line warning and a normal run)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from conftest import RNG, H, W, noise, verify
from wfviz.cli import app
from wfviz.io.clip import ClipError

def folder(path: Path, images: dict[str, np.ndarray]) -> Path:
    path.mkdir()
    for name, image in images.items():
        assert cv2.imwrite(str(path / name), image)
    return path


def video(path: Path, n: int = 30) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 20, (W, H), isColor=False)
    assert writer.isOpened()
    for _ in range(n):
        writer.write(noise(np.uint8))
    writer.release()
    return path


def cli(tmp_path: Path, *args: str, debug: bool = False):
    out = tmp_path / "out"
    argv = (["--debug"] if debug else []) + [args[0], *args[1:]]
    if args[0] == "track" and "--tracks" not in args:
        argv += ["--tracks", str(out / "t.csv")]
    if args[0] == "record" and "-o" not in args:
        argv += ["-o", str(out / "r.rrd"), "--no-images"]
    return CliRunner().invoke(app, argv)


def leftovers(tmp_path: Path) -> list[Path]:
    """Output files (and partial files) under ``tmp_path/out``."""
    out = tmp_path / "out"
    return sorted(out.rglob("*")) if out.exists() else []


def assert_error(result, tmp_path: Path, *fragments: str) -> str:
    """Exit 2, stderr one line ``wfviz: error: ...`` containing ``fragments``, no outputs."""
    lines = result.stderr.strip().splitlines()
    assert result.exit_code == 2, (result.exit_code, result.stderr, result.exception)
    assert len(lines) == 1 and lines[0].startswith("wfviz: error: "), result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert leftovers(tmp_path) == []
    return lines[0]


def warnings_of(result) -> list[str]:
    return [ln for ln in result.stderr.splitlines() if ln.startswith(("wfviz: warning:", "wfviz: note:"))]


# --- paths and folders -------------------------------------------------------------------


def test_missing_path(tmp_path: Path) -> None:
    r = cli(tmp_path, "track", str(tmp_path / "nope.avi"))
    assert_error(r, tmp_path, f"{tmp_path / 'nope.avi'}: no such file or folder")


def test_debug_shows_the_exception(tmp_path: Path) -> None:
    r = cli(tmp_path, "track", str(tmp_path / "nope.avi"), debug=True)
    assert r.exit_code != 0 and isinstance(r.exception, ClipError)


def test_folder_without_images(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("x")
    r = cli(tmp_path, "track", str(tmp_path / "empty"))
    assert_error(r, tmp_path, f"{tmp_path / 'empty'}: no images (.bmp .png .tif .tiff) in folder")


def test_images_of_mixed_sizes(tmp_path: Path) -> None:
    f = folder(tmp_path / "mix", {"a.png": noise(), "b.png": noise(shape=(H + 8, W))})
    r = cli(tmp_path, "track", str(f))
    assert_error(r, tmp_path, f"{f / 'b.png'}: image 1 is 40x40 uint16, but a.png is 40x32 uint16")


def test_images_of_mixed_bit_depths(tmp_path: Path) -> None:
    f = folder(tmp_path / "mix", {"a.png": noise(), "b.png": noise(np.uint8)})
    r = cli(tmp_path, "track", str(f))
    assert_error(r, tmp_path, f"{f / 'b.png'}: image 1 is 40x32 uint8, but a.png is 40x32 uint16")


def test_non_image_files_are_skipped_with_a_warning(tmp_path: Path) -> None:
    f = folder(tmp_path / "seq", {"a.png": noise(), "b.png": noise()})
    (f / "notes.txt").write_text("x")
    (f / "truth.csv").write_text("frame,target_id,x,y\n")  # wfviz's own companion: silent
    r = cli(tmp_path, "track", str(f))
    assert r.exit_code == 0, r.stderr
    assert warnings_of(r) == [f"wfviz: warning: {f}: skipping 1 non-image entry (notes.txt)"]
    assert "done: 2 frames" in r.stdout


def test_corrupt_image_in_the_middle_names_the_frame(tmp_path: Path) -> None:
    f = folder(tmp_path / "seq", {f"{i:02d}.png": noise() for i in range(6)})
    (f / "03.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    r = cli(tmp_path, "record", str(f))
    assert_error(r, tmp_path, f"{f / '03.png'}: cannot decode image 3", "--skip-bad-frames")


def test_skip_bad_frames_goes_on_and_logs_the_gap(tmp_path: Path) -> None:
    f = folder(tmp_path / "seq", {f"{i:02d}.png": noise() for i in range(6)})
    (f / "03.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    r = cli(tmp_path, "record", str(f), "--skip-bad-frames")
    assert r.exit_code == 0, r.stderr
    assert warnings_of(r) == [f"wfviz: warning: {f / '03.png'}: cannot decode image 3; "
                              f"skipped (--skip-bad-frames)"]
    assert "done: 5 frames" in r.stdout and "skipped:   1 unreadable frames (3)" in r.stdout
    frames, logs = set(), []
    for chunk in RrdReader(tmp_path / "out" / "r.rrd").stream():
        batch = chunk.to_record_batch()
        if "frame" in batch.schema.names:
            frames.update(batch.column("frame").to_pylist())
        if chunk.entity_path == "/log":
            logs += [t for row in batch.column("TextLog:text").to_pylist() for t in row]
    assert frames == {0, 1, 2, 4, 5}
    assert f"skipped: {f / '03.png'}: cannot decode image 3" in logs
    verify(tmp_path / "out" / "r.rrd")


def wfviz(cwd: Path, *args: str | bytes) -> subprocess.CompletedProcess:
    """The CLI in a separate process (a crash must not take the test run with it)."""
    return subprocess.run([sys.executable, "-m", "wfviz", *args], cwd=cwd, capture_output=True,
                          timeout=120)


def test_file_names_that_are_not_utf8(tmp_path: Path) -> None:
    """Such names (surrogates in Python) crashed OpenCV (exit 139, temporaries left): images are
    read by bytes, a video through its descriptor, and names are printed with \\xff escapes."""
    frames = noise(shape=(5, H, W))
    plain = folder(tmp_path / "plain", {f"frame_{i}.png": f for i, f in enumerate(frames)})
    odd = folder(tmp_path / "odd", {f"frame_{i}.png": f for i, f in enumerate(frames)})
    os.rename(odd / "frame_4.png", os.fsdecode(bytes(odd) + b"/frame_\xff.png"))  # sorted last
    named = Path(os.fsdecode(bytes(tmp_path) + b"/d\xff"))
    os.rename(plain, named)
    video(tmp_path / "v.avi", n=10)
    odd_video = os.fsdecode(bytes(tmp_path) + b"/v\xfe.avi")
    os.link(tmp_path / "v.avi", odd_video)
    runs = {name: wfviz(tmp_path, "track", clip, "--tracks", f"{name}.csv") for name, clip in
            [("odd", "odd"), ("named", named.name), ("v", "v.avi"), ("odd_video", odd_video)]}
    for name, r in runs.items():
        assert r.returncode == 0 and b"Traceback" not in r.stderr, (name, r.returncode, r.stderr)
    assert (tmp_path / "odd.csv").read_bytes() == (tmp_path / "named.csv").read_bytes()
    assert (tmp_path / "v.csv").read_bytes() == (tmp_path / "odd_video.csv").read_bytes()
    r = wfviz(tmp_path, "record", named.name, "--no-images")  # default output names from the folder's
    assert r.returncode == 0, r.stderr
    assert b"recording: recordings/d\\xff-gewc.rrd" in r.stdout and r.stderr == b""
    (odd / "frame_\udcff.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    r = wfviz(tmp_path, "track", "odd", "--tracks", "bad.csv")
    assert r.returncode == 2 and r.stderr.decode().splitlines() == [
        "wfviz: error: odd/frame_\\xff.png: cannot decode image 4 (--skip-bad-frames skips it)"]
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".wfviz-part") or p.name == "bad.csv"]
    r = wfviz(tmp_path, "synth", "lowsnr-tbd", os.fsdecode(b"s\xff"), "--frames", "3", "--avi")  # writers too
    assert r.returncode == 0 and r.stdout.startswith(b"wrote 3 frames of 'lowsnr-tbd' (seed 0) to s\\xff\n"), r
    assert sorted(p.name for p in (tmp_path / "s\udcff").iterdir() if not p.name.startswith(".")) == [
        "frame_000000.png", "frame_000001.png", "frame_000002.png", "lowsnr-tbd.avi", "meta.json", "truth.csv"]


def test_study_and_comparison_outputs_with_names_that_are_not_utf8(tmp_path: Path) -> None:
    """rerun's save() (wfviz compare, the tune study's recording) and text naming such a file
    written as UTF-8 (tune's best.toml) refused the name, for tune after every trial had run."""
    from wfviz.io.outputs import write_atomically

    best = tmp_path / "tu\udcff" / "best.toml"  # what wfviz tune --out writes: text naming its folder
    best.parent.mkdir()
    write_atomically(best, f"# reproduce: wfviz track --config {best}\n")
    assert best.read_bytes() == b"# reproduce: wfviz track --config " + os.fsencode(best) + b"\n"
    rrd = tmp_path / "c\udcff.rrd"
    r = wfviz(tmp_path, "compare", "synth:lowsnr-tbd", "--stop", "3", "--run", "gewc", "--run", "tbd", "-o", rrd.name)
    assert r.returncode == 0 and rrd.stat().st_size > 0, r.stderr
    assert b"recording: c\\xff.rrd" in r.stdout


# --- videos ------------------------------------------------------------------------------


def test_truncated_video_names_the_frame(tmp_path: Path) -> None:
    data = video(tmp_path / "full.avi").read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: len(data) // 2])
    r = cli(tmp_path, "track", str(tmp_path / "cut.avi"))
    line = assert_error(r, tmp_path, f"{tmp_path / 'cut.avi'}: cannot decode frame ", " of 30",
                        "truncated or corrupt video", "--skip-bad-frames")
    r = cli(tmp_path, "track", str(tmp_path / "cut.avi"), "--skip-bad-frames")
    assert r.exit_code == 0, r.stderr
    (warning,) = warnings_of(r)
    assert "(truncated video?)" in warning and line.split("cannot decode frame ")[1].split()[0] in warning


def test_undecodable_video(tmp_path: Path) -> None:
    (tmp_path / "junk.avi").write_bytes(b"RIFF\x00\x00\x00\x00AVI junk" * 50)
    r = cli(tmp_path, "track", str(tmp_path / "junk.avi"))
    assert_error(r, tmp_path, f"{tmp_path / 'junk.avi'}: cannot decode video (truncated or unsupported codec)")


def test_corrupt_video_frame_can_be_skipped(tmp_path: Path) -> None:
    data = bytearray(video(tmp_path / "v.avi").read_bytes())
    data[len(data) // 2: len(data) // 2 + 3000] = b"\x55" * 3000
    (tmp_path / "v.avi").write_bytes(bytes(data))
    r = cli(tmp_path, "track", str(tmp_path / "v.avi"))
    assert_error(r, tmp_path, f"{tmp_path / 'v.avi'}: cannot decode frame ")
    r = cli(tmp_path, "track", str(tmp_path / "v.avi"), "--skip-bad-frames")
    assert r.exit_code == 0, r.stderr
    assert warnings_of(r) and all(  # FFmpeg may drop a damaged packet: the end comes early too
        w.startswith(f"wfviz: warning: {tmp_path / 'v.avi'}: cannot decode frame") for w in warnings_of(r))


# --- frames ------------------------------------------------------------------------------


def test_zero_frame_clip(tmp_path: Path) -> None:
    np.save(tmp_path / "empty.npy", np.zeros((0, H, W), np.uint16))
    r = cli(tmp_path, "track", str(tmp_path / "empty.npy"))
    assert_error(r, tmp_path, f"{tmp_path / 'empty.npy'}: no frames")


def test_start_past_the_end_leaves_no_output(tmp_path: Path) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    r = cli(tmp_path, "record", str(tmp_path / "s.npy"), "--start", "5")
    assert_error(r, tmp_path, f"{tmp_path / 's.npy'}: no frames in the selected range (start=5")


def test_colour_frames_become_luma_with_a_note(tmp_path: Path) -> None:
    f = folder(tmp_path / "rgb", {f"{i}.png": np.repeat(noise(np.uint8)[..., None], 3, axis=2)
                                  for i in range(3)})
    r = cli(tmp_path, "track", str(f))
    assert r.exit_code == 0, r.stderr
    assert warnings_of(r) == [f"wfviz: note: {f / '0.png'}: colour image converted to luma "
                              f"(0.299 R + 0.587 G + 0.114 B); later colour images too"]


def test_nan_and_inf_name_the_frame_or_become_zero(tmp_path: Path) -> None:
    stack = RNG.random((4, H, W)).astype(np.float32)
    stack[2, 5, 5], stack[3, 1, 1] = np.nan, -np.inf
    np.save(tmp_path / "f.npy", stack)
    r = cli(tmp_path, "track", str(tmp_path / "f.npy"))
    assert_error(r, tmp_path, f"{tmp_path / 'f.npy'}: frame 2 has 1 NaN or infinite pixels",
                 "--nan-as-zero")
    r = cli(tmp_path, "track", str(tmp_path / "f.npy"), "--nan-as-zero")
    assert r.exit_code == 0, r.stderr
    assert warnings_of(r) == [f"wfviz: warning: {tmp_path / 'f.npy'}: frame 2 has 1 NaN or infinite "
                              f"pixels, replaced by 0 (later frames are not reported)"]


def moving_target(n: int = 30, shape: tuple[int, int] = (64, 80)) -> np.ndarray:
    """(n, rows, columns) float64 frames: a background of 1000 with noise of 20 and a target of
    peak 300 moving 2 px a frame to the right."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    stack = 1000 + 20 * rng.standard_normal((n, *shape))
    for t in range(n):
        stack[t] += 300 * np.exp(-((xx - 10 - 2 * t) ** 2 + (yy - 20 - 0.7 * t) ** 2) / 2.0)
    return stack


@pytest.mark.parametrize("tracker", ["gewc", "fusion"])
def test_float_frames_of_any_scale_give_the_same_tracks(tmp_path: Path, tracker: str) -> None:
    """Float clips in small units: 1e-9 gave no track (absolute floors such as 1e-6), denormals
    (1e-40 a grey level in float32) and 1e30 overflowed float32 and crashed. Frames outside a
    spread of 2**-8..2**32 are rescaled by a power of two, with a note."""
    base = moving_target()
    tracks = {}
    for scale in (1e-40, 1e-30, 1e-9, 1e-3, 1.0, 1e10, 1e30):
        name = f"s{scale:g}"
        np.save(tmp_path / f"{name}.npy", (base * scale).astype(np.float32))
        r = cli(tmp_path, "track", str(tmp_path / f"{name}.npy"), "--tracker", tracker,
                "--tracks", str(tmp_path / f"{name}.csv"))
        assert r.exit_code == 0 and "Traceback" not in r.stderr, (scale, r.stderr, r.exception)
        rescaled = [w for w in warnings_of(r) if "float frames rescaled by 2**" in w]
        assert len(warnings_of(r)) == len(rescaled) == (0 if scale in (1e-3, 1.0) else 1), r.stderr
        tracks[scale] = (tmp_path / f"{name}.csv").read_bytes()
    assert tracks[1.0].count(b"\n") > 20
    assert all(t == tracks[1.0] for t in tracks.values())


def test_float_frames_beyond_float32_at_the_clips_scale(tmp_path: Path) -> None:
    stack = moving_target(3).astype(np.float32)
    stack[0] *= 1e-30  # sets the scale: x2**105
    np.save(tmp_path / "f.npy", stack)
    r = cli(tmp_path, "track", str(tmp_path / "f.npy"))
    assert r.exit_code == 2 and r.stderr.splitlines() == [  # the note, then the error
        f"wfviz: note: {tmp_path / 'f.npy'}: float frames rescaled by 2**105 (frame 0's spread, 1.41e-29, is "
        "outside 2**-8..2**32); tracks are unaffected, recorded values are in the new units",
        f"wfviz: error: {tmp_path / 'f.npy'}: frame 1 holds values up to 1.31e+03, too large at the clip's "
        "scale (x2**105, set by the first frame read; values must stay within 2**64 after it)"]
    assert leftovers(tmp_path) == []


def test_frames_smaller_than_the_processing_windows(tmp_path: Path) -> None:
    np.save(tmp_path / "tiny.npy", noise(shape=(3, 12, 40)))
    r = cli(tmp_path, "record", str(tmp_path / "tiny.npy"))
    assert_error(r, tmp_path, f"{tmp_path / 'tiny.npy'}: frames are 40x12, smaller than the "
                 "processing windows need (at least 16x16)")
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))  # big enough for the defaults only
    (tmp_path / "wide.toml").write_text("[horizon]\nvariance_window = 51\nstep = 10\n")
    r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--config", str(tmp_path / "wide.toml"))
    assert_error(r, tmp_path, "frames are 40x32", "(at least 37x37)")


def test_npy_holding_objects_is_not_unpickled(tmp_path: Path) -> None:
    np.save(tmp_path / "o.npy", np.array([{"x": 1}, None], dtype=object), allow_pickle=True)
    r = cli(tmp_path, "track", str(tmp_path / "o.npy"))
    assert_error(r, tmp_path, f"{tmp_path / 'o.npy'}: cannot load .npy array: it holds Python objects",
                 "allow_pickle=False")


def test_frames_too_large_are_refused_before_reading(tmp_path: Path) -> None:
    """A sparse 20000x20000 .npy ran out of memory after minutes: its header is enough."""
    np.lib.format.open_memmap(tmp_path / "huge.npy", mode="w+", dtype=np.float64, shape=(20000, 20000))
    r = cli(tmp_path, "track", str(tmp_path / "huge.npy"))
    assert_error(r, tmp_path, f"{tmp_path / 'huge.npy'}: frames are 20000x20000 (400,000,000 pixels), "
                 "larger than wfviz reads (67,108,864 pixels a frame, e.g. 8192x8192)")


# --- truth and config --------------------------------------------------------------------


def test_truth_csv_field_over_the_csv_limit(tmp_path: Path) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    truth = tmp_path / "truth.csv"
    truth.write_text("frame,target_id,x,y\n0,1,3.0,4.0\n1,1," + "9" * 140_000 + ",4.0\n")
    r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--truth", str(truth))
    assert_error(r, tmp_path, "truth.csv:3: not a valid CSV line (field larger than field limit (131072))")
    r = CliRunner().invoke(app, ["eval", str(truth), str(truth)])  # a tracks CSV goes the same way
    assert r.exit_code == 2 and r.stderr.strip().endswith("truth.csv:3: not a valid CSV line "
                                                          "(field larger than field limit (131072))")


DEEP = {"arrays": "[kalman]\nq = " + "[" * 3000 + "]" * 3000 + "\n",
        "tables": "a = " + "{b = " * 3000 + "1" + "}" * 3000 + "\n"}


@pytest.mark.parametrize("kind", DEEP)
def test_deeply_nested_toml_config_and_space(tmp_path: Path, kind: str) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    (tmp_path / "deep.toml").write_text(DEEP[kind])
    r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--config", str(tmp_path / "deep.toml"))
    assert_error(r, tmp_path, f"{tmp_path / 'deep.toml'}: nested too deeply to be a config file")
    r = CliRunner().invoke(app, ["tune", "synth:fov70-four-targets", "--out", str(tmp_path / "out" / "study"),
                                 "--space", str(tmp_path / "deep.toml"), "--trials", "1"])
    assert_error(r, tmp_path, f"{tmp_path / 'deep.toml'}: nested too deeply to be a search-space file")


def test_config_that_is_a_device_or_too_large(tmp_path: Path) -> None:
    """``--config /dev/zero`` read until memory ran out; a pipe would wait for a writer."""
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    (tmp_path / "big.toml").write_text("# padding\n" * 110_000)
    os.mkfifo(tmp_path / "fifo")
    for path, message in [("/dev/zero", "not a regular file (a device or pipe?), not a config file"),
                          (str(tmp_path / "fifo"), "not a regular file"),
                          (str(tmp_path / "big.toml"), "larger than 1 MiB, too large for a config file")]:
        r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--config", path)
        assert_error(r, tmp_path, f"{path}: {message}")
    r = CliRunner().invoke(app, ["tune", "synth:fov70-four-targets", "--out", str(tmp_path / "out" / "study"),
                                 "--space", "/dev/zero", "--trials", "1"])
    assert_error(r, tmp_path, "/dev/zero: not a regular file (a device or pipe?), not a search-space file")


def test_malformed_truth_csv_names_line_and_column(tmp_path: Path) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    truth = tmp_path / "truth.csv"
    truth.write_text("frame,target_id,x,y\n0,1,3.0,4.0\n1,1,abc,4.0\n")
    r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--truth", str(truth))
    assert_error(r, tmp_path, "truth.csv:3: column 'x': 'abc' is not a number")


@pytest.mark.parametrize("text, message", [
    ("[kalman]\ngate_sigm = 2\n", "unknown key 'kalman.gate_sigm' (did you mean 'gate_sigma'?)"),
    ("[kalmann]\nq = 2\n", "unknown key 'kalmann' (did you mean 'kalman'?)"),
    ("[kalman]\nq = \"big\"\n", "kalman.q: expected a number, got 'big'"),
    ("[horizon]\nstep = 2.5\n", "horizon.step: expected an integer, got 2.5"),
    ("[horizon]\nmin_coverage = 1.5\n", "horizon.min_coverage: 1.5 is out of range [0.0, 1.0]"),
    ("[horizon]\nstep = 1" + "0" * 30 + "\n", "horizon.step: 1" + "0" * 30 + " is out of range [1, 10]"),
    ("[kalman]\nq = 1" + "0" * 400 + "\n", "kalman.q: 10000000... (401 digits) is out of range [0.0, 1e9]"),
    ("[kalman]\nq = 1e300\n", "kalman.q: 1e+300 is out of range [0.0, 1e9]"),
    ("[circle]\nradius = 1e300\n", "circle.radius: 1e+300 is out of range [1.0, 1e9]"),
    ("[kalman\n", "not valid TOML"),
])
def test_bad_config_names_the_key(tmp_path: Path, text: str, message: str) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    (tmp_path / "c.toml").write_text(text)
    r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--config", str(tmp_path / "c.toml"))
    assert_error(r, tmp_path, f"{tmp_path / 'c.toml'}: {message}")


# --- outputs -----------------------------------------------------------------------------


def test_unwritable_output_is_found_before_processing(tmp_path: Path) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    (tmp_path / "out").write_text("a file where the output folder should be")
    r = CliRunner().invoke(app, ["record", str(tmp_path / "s.npy"), "-o", str(tmp_path / "out" / "r.rrd")])
    assert r.exit_code == 2 and r.stderr.strip() == (
        f"wfviz: error: {tmp_path / 'out'}: is a file, cannot hold the output r.csv")


def test_output_may_not_replace_the_input(tmp_path: Path) -> None:
    np.save(tmp_path / "s.npy", noise(shape=(3, H, W)))
    before = (tmp_path / "s.npy").read_bytes()
    r = cli(tmp_path, "track", str(tmp_path / "s.npy"), "--tracks", str(tmp_path / "s.npy"))
    assert_error(r, tmp_path, f"{tmp_path / 's.npy'}: output would overwrite the input clip")
    assert (tmp_path / "s.npy").read_bytes() == before
