"""Every kind of bad input, through the CLI: a one-line error naming the file and the problem,
exit code 2 and no output left behind (or, where the input can be read with a workaround, a
one-line warning and a normal run)."""

from __future__ import annotations

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


# --- truth and config --------------------------------------------------------------------


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
