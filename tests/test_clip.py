"""Tests for wfviz.io.clip: image folders, .npy stacks and videos streamed as luma frames."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import write_folder
from wfviz.io.clip import ClipError, ImageFolderClip, NpyClip, VideoClip, _choose_luma, open_clip
from wfviz.io.frames import Clip, Frame

H, W = 48, 64
LOW, HIGH = 5, 250  # near the extremes: a 16-235 stretch would clip these to 0 and 255
N_VIDEO = 12
#: Max |decoded - written|, measured on opencv-python-headless 5.0 over whole frames:
#: 0 for MJPG and FFV1, 1 for mp4v (19 if its 16-235 Y plane were returned unexpanded);
#: 3 leaves room for encoder-version drift.
VIDEO_TOL = 3


def ramp(value: int, dtype: type = np.uint8) -> np.ndarray:
    """An (H, W) image whose pixels are ``value + column``."""
    return (value + np.tile(np.arange(W), (H, 1))).astype(dtype)


def video_frame(index: int) -> np.ndarray:
    """Frame ``index`` of the test video: LOW|HIGH halves (swapped on odd frames), index band."""
    image = np.full((H, W), LOW, np.uint8)
    image[:, W // 2:] = HIGH
    if index % 2:
        image = image[:, ::-1].copy()
    image[H - 16:, :] = 16 + 18 * index  # identifies the frame after lossy coding
    return image


def interiors(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The left half, right half and index band, 4 px away from every edge."""
    return image[4:H - 20, 4:W // 2 - 4], image[4:H - 20, W // 2 + 4:W - 4], image[H - 12:H - 4, 4:-4]


def decoded_index(image: np.ndarray) -> int:
    """The frame index encoded in the band by ``video_frame``."""
    return round((float(np.median(interiors(image)[2])) - 16) / 18)


def write_video(path: Path, fourcc: str, fps: float = 25.0) -> Path:
    """Write N_VIDEO grey frames from ``video_frame`` with ``cv2.VideoWriter``."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (W, H), isColor=False)
    if not writer.isOpened():
        pytest.skip(f"this OpenCV build cannot write {fourcc}")
    for index in range(N_VIDEO):
        writer.write(video_frame(index))
    writer.release()
    return path


VIDEOS = [("a.avi", "MJPG", "raw"), ("b.mp4", "mp4v", "expand"), ("c.mkv", "FFV1", "raw"),
          ("d.mov", "mp4v", "expand")]


# --- image folders ---------------------------------------------------------------------


def test_folder_of_8bit_pngs(tmp_path: Path) -> None:
    folder = write_folder(tmp_path / "run1", {f"f{i:03d}.png": ramp(10 * i) for i in range(4)})
    clip = open_clip(folder)
    assert isinstance(clip, Clip) and isinstance(clip, ImageFolderClip)
    assert (clip.name, clip.fps, clip.n_frames, clip.shape) == ("run1", 20.0, 4, (H, W))
    frames = list(clip.frames())
    assert [f.index for f in frames] == [0, 1, 2, 3]
    for i, frame in enumerate(frames):
        assert isinstance(frame, Frame)
        assert frame.image.dtype == np.uint8 and frame.image.flags.c_contiguous
        np.testing.assert_array_equal(frame.image, ramp(10 * i))


@pytest.mark.parametrize("ext", [".png", ".tif", ".tiff"])
def test_16bit_images_keep_full_range(tmp_path: Path, ext: str) -> None:
    images = {f"f{i}{ext}": ramp(60000 - 1000 * i, np.uint16) for i in range(2)}
    clip = open_clip(write_folder(tmp_path / "raw16", images))
    frames = list(clip.frames())
    assert [f.image.dtype for f in frames] == [np.uint16, np.uint16]
    np.testing.assert_array_equal(frames[1].image, ramp(59000, np.uint16))
    assert frames[0].image.max() == 60000 + W - 1


def test_bmp_folder(tmp_path: Path) -> None:
    clip = open_clip(write_folder(tmp_path / "bmps", {"x.bmp": ramp(3), "y.BMP": ramp(7)}))
    images = [f.image for f in clip.frames()]
    np.testing.assert_array_equal(np.stack(images), np.stack([ramp(3), ramp(7)]))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_colour_png_becomes_luma(tmp_path: Path, dtype: type) -> None:
    bgr = np.zeros((H, W, 3), dtype)
    bgr[:, :, 0], bgr[:, :, 1], bgr[:, :, 2] = 30, 120, 200  # B, G, R
    bgra = np.dstack([bgr, np.full((H, W), 7, dtype)])
    clip = open_clip(write_folder(tmp_path / "col", {"a.png": bgr, "b.png": bgra}))
    expected = round(0.114 * 30 + 0.587 * 120 + 0.299 * 200)  # BT.601 luma, 4 channels too
    for frame in clip.frames():
        assert frame.image.shape == (H, W) and frame.image.dtype == dtype
        assert abs(int(frame.image[0, 0]) - expected) <= 1


def test_other_files_skipped_and_names_sorted(tmp_path: Path) -> None:
    folder = write_folder(tmp_path / "seq", {"b.png": ramp(2), "a.PNG": ramp(1), "c.tif": ramp(3)})
    (folder / "truth.csv").write_text("frame,x,y\n")
    (folder / "meta.json").write_text("{}")
    (folder / "notes").mkdir()
    clip = open_clip(folder)
    assert clip.n_frames == 3
    assert [int(f.image[0, 0]) for f in clip.frames()] == [1, 2, 3]


def test_empty_folder(tmp_path: Path) -> None:
    folder = tmp_path / "empty"
    folder.mkdir()
    (folder / "truth.csv").write_text("frame,x,y\n")
    with pytest.raises(ClipError, match=r"empty: no images"):
        open_clip(folder)


def test_mixed_sizes_name_the_file(tmp_path: Path) -> None:
    folder = write_folder(tmp_path / "mix", {"a.png": ramp(0), "b.png": ramp(0)[:, :32]})
    clip = open_clip(folder)
    with pytest.raises(ClipError) as err:
        list(clip.frames())
    assert "b.png: image 1 is 32x48 uint8, but a.png is 64x48 uint8" in str(err.value)


def test_mixed_dtypes_name_the_file(tmp_path: Path) -> None:
    folder = write_folder(tmp_path / "mix", {"a.png": ramp(0), "b.png": ramp(300, np.uint16)})
    with pytest.raises(ClipError, match=r"b\.png: image 1 is 64x48 uint16, but a\.png is 64x48 uint8"):
        list(open_clip(folder).frames())


def test_undecodable_image(tmp_path: Path) -> None:
    folder = write_folder(tmp_path / "bad", {"a.png": ramp(0)})
    (folder / "b.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    clip = open_clip(folder)
    with pytest.raises(ClipError, match=r"b\.png: cannot decode image 1$"):
        list(clip.frames())
    (folder / "a.png").write_bytes(b"")
    with pytest.raises(ClipError, match=r"a\.png: cannot decode image 0$"):
        open_clip(folder)


# --- .npy stacks -----------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_npy_round_trip(tmp_path: Path, dtype: type) -> None:
    stack = (np.arange(5 * H * W).reshape(5, H, W) * 7 % 65000).astype(dtype)
    np.save(tmp_path / "stack.npy", stack)
    clip = open_clip(tmp_path / "stack.npy")
    assert isinstance(clip, NpyClip)
    assert (clip.name, clip.n_frames, clip.shape, clip.fps) == ("stack", 5, (H, W), 20.0)
    images = [f.image for f in clip.frames()]
    assert all(im.dtype == dtype and im.flags.c_contiguous for im in images)
    np.testing.assert_array_equal(np.stack(images), stack)


def test_npy_dtype_conversions_and_single_frame(tmp_path: Path) -> None:
    np.save(tmp_path / "f64.npy", np.full((2, 3, 4), 0.25))
    np.save(tmp_path / "i16.npy", np.full((3, 4), -300, np.int16))
    (f64,) = [f.image for f in open_clip(tmp_path / "f64.npy").frames(1)]
    assert f64.dtype == np.float32 and f64[0, 0] == 0.25
    i16_clip = open_clip(tmp_path / "i16.npy")
    (i16,) = [f.image for f in i16_clip.frames()]
    assert i16_clip.n_frames == 1 and i16.dtype == np.float32 and i16[0, 0] == -300


def test_npy_frames_are_independent_copies(tmp_path: Path) -> None:
    np.save(tmp_path / "s.npy", np.arange(3 * H * W, dtype=np.uint16).reshape(3, H, W))
    clip = open_clip(tmp_path / "s.npy")
    first = [f.image for f in clip.frames()]
    for image in first:
        assert not isinstance(image, np.memmap) and image.base is None
        image[:] = 0  # writable, and must not reach the file or the next pass
    again = [f.image for f in clip.frames()]
    assert again[2][0, 0] == 2 * H * W
    assert np.load(tmp_path / "s.npy")[1, 0, 0] == H * W


def test_npy_fortran_order_is_c_contiguous(tmp_path: Path) -> None:
    stack = np.asfortranarray(np.arange(2 * H * W, dtype=np.uint8).reshape(2, H, W))
    np.save(tmp_path / "f.npy", stack)
    images = [f.image for f in open_clip(tmp_path / "f.npy").frames()]
    assert all(im.flags.c_contiguous for im in images)
    np.testing.assert_array_equal(images[1], stack[1])


@pytest.mark.parametrize("array, problem", [
    (np.array([[None, 1]], dtype=object), "cannot load .npy array"),
    (np.zeros((2, 3, 4), np.complex64), "unsupported pixel type complex64"),
    (np.zeros((2, 3, 4, 3), np.uint8), r"expected a \(T, H, W\) or \(H, W\) array"),
    (np.zeros((0, 3, 4), np.uint8), r"expected a \(T, H, W\) or \(H, W\) array"),
])
def test_bad_npy(tmp_path: Path, array: np.ndarray, problem: str) -> None:
    np.save(tmp_path / "bad.npy", array, allow_pickle=True)
    with pytest.raises(ClipError, match=problem) as err:
        open_clip(tmp_path / "bad.npy")
    assert str(err.value).startswith(f"{tmp_path / 'bad.npy'}: ") and "\n" not in str(err.value)


# --- start / stop / time, all kinds ----------------------------------------------------


@pytest.fixture(params=["folder", "npy", "video"])
def counted_clip(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    """A 12-frame clip of each kind whose frame i is identifiable by ``decoded_index``."""
    images = [video_frame(i) for i in range(N_VIDEO)]
    if request.param == "folder":
        return write_folder(tmp_path / "seq", {f"{i:02d}.png": im for i, im in enumerate(images)})
    if request.param == "npy":
        np.save(tmp_path / "seq.npy", np.stack(images))
        return tmp_path / "seq.npy"
    return write_video(tmp_path / "seq.avi", "FFV1")


def test_start_stop(counted_clip: Path) -> None:
    clip = open_clip(counted_clip)
    for start, stop, expected in [(0, None, range(12)), (3, 7, range(3, 7)), (10, 99, range(10, 12)),
                                  (5, 5, range(0)), (7, 2, range(0)), (15, None, range(0))]:
        frames = list(clip.frames(start, stop))
        assert [f.index for f in frames] == list(expected)
        assert [decoded_index(f.image) for f in frames] == list(expected)
    with pytest.raises(ValueError):
        next(iter(clip.frames(-1)))


def test_time_is_index_over_fps_and_fps_override(counted_clip: Path) -> None:
    native = 25.0 if counted_clip.suffix == ".avi" else 20.0
    assert [f.time for f in open_clip(counted_clip).frames(2, 4)] == [2 / native, 3 / native]
    clip = open_clip(counted_clip, fps=8.0)
    assert clip.fps == 8.0
    assert [f.time for f in clip.frames(2, 4)] == [0.25, 0.375]
    with pytest.raises(ClipError, match="fps must be a positive number"):
        open_clip(counted_clip, fps=0)


# --- video -----------------------------------------------------------------------------


@pytest.mark.parametrize("name, fourcc, luma", VIDEOS)
def test_video_round_trip_keeps_extremes(tmp_path: Path, name: str, fourcc: str, luma: str) -> None:
    clip = open_clip(write_video(tmp_path / name, fourcc))
    assert isinstance(clip, VideoClip) and isinstance(clip, Clip)
    assert (clip.name, clip.fps, clip.n_frames, clip.shape) == (Path(name).stem, 25.0, N_VIDEO, (H, W))
    assert clip.luma == luma
    frames = list(clip.frames())
    assert [f.index for f in frames] == list(range(N_VIDEO))
    for frame in frames:
        image = frame.image
        assert image.ndim == 2 and image.dtype == np.uint8 and image.flags.c_contiguous
        left, right, band = interiors(image)
        low, high = (left, right) if frame.index % 2 == 0 else (right, left)
        assert np.abs(low.astype(int) - LOW).max() <= VIDEO_TOL
        assert np.abs(high.astype(int) - HIGH).max() <= VIDEO_TOL
        assert np.abs(band.astype(int) - (16 + 18 * frame.index)).max() <= VIDEO_TOL


def test_video_bgr_fallback_matches(tmp_path: Path) -> None:
    path = write_video(tmp_path / "b.mp4", "mp4v")
    auto = [f.image for f in open_clip(path).frames()]
    bgr = [f.image for f in VideoClip(path, luma="bgr").frames()]
    assert np.abs(np.stack(auto).astype(int) - np.stack(bgr)).max() <= 2
    raw = [f.image for f in VideoClip(path, luma="raw").frames()]
    assert np.median(raw[0][4:20, 4:28]) > LOW + 10  # the stored plane is 16-235 coded


def write_sensor_y_video(path: Path) -> Path:
    """An uncompressed I420 AVI (limited range) whose Y plane holds 0-255 sensor values."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"I420"), 25.0, (W, H), isColor=True)
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write I420 AVI")
    for _ in range(3):
        writer.write(np.full((H, W, 3), 128, np.uint8))
    writer.release()
    data, size, patched = bytearray(path.read_bytes()), H * W * 3 // 2, 0
    at = data.find(b"00dc")
    while at >= 0:  # overwrite each frame's Y plane in place
        if int.from_bytes(data[at + 4:at + 8], "little") == size:
            data[at + 8:at + 8 + H * W] = video_frame(patched).tobytes()
            patched += 1
        at = data.find(b"00dc", at + 8)
    assert patched == 3
    path.write_bytes(bytes(data))
    return path


def test_sensor_values_in_limited_range_y_are_not_clipped(tmp_path: Path) -> None:
    path = write_sensor_y_video(tmp_path / "sensor.avi")
    clip = open_clip(path)
    assert clip.luma == "raw"
    for frame in clip.frames():
        np.testing.assert_array_equal(frame.image, video_frame(frame.index))  # exact
    stretched = next(iter(VideoClip(path, luma="bgr").frames())).image
    assert stretched[10, 10] == 0 and stretched[10, W - 10] == 255  # what BGR output does


def test_choose_luma_rejects_a_plane_that_is_not_luma() -> None:
    grey = [np.tile(np.linspace(0, 255, W).astype(np.uint8), (H, 1))]
    noise = [np.random.default_rng(0).integers(0, 256, (H, W), dtype=np.uint8)]
    assert _choose_luma(noise, grey) == "bgr"
    assert _choose_luma([grey[0][:, :32]], grey) == "bgr"
    assert _choose_luma(grey, grey) == "raw"
    limited = [np.round(16 + grey[0].astype(float) * 219 / 255).astype(np.uint8)]
    assert _choose_luma(limited, grey) == "expand"


def test_video_can_be_iterated_twice_and_seek_matches_sequential(tmp_path: Path) -> None:
    clip = open_clip(write_video(tmp_path / "b.mp4", "mp4v"))
    first = [f.image for f in clip.frames()]
    second = [f.image for f in clip.frames()]
    np.testing.assert_array_equal(np.stack(first), np.stack(second))
    for start in (1, 5, 11):
        np.testing.assert_array_equal(next(iter(clip.frames(start))).image, first[start])


def test_undecodable_video(tmp_path: Path) -> None:
    (tmp_path / "a.avi").write_bytes(b"RIFF\x00\x00\x00\x00AVI garbage" * 10)
    with pytest.raises(ClipError) as err:
        open_clip(tmp_path / "a.avi")
    assert str(err.value) == f"{tmp_path / 'a.avi'}: cannot decode video (truncated or unsupported codec)"


# --- dispatch errors -------------------------------------------------------------------


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(ClipError) as err:
        open_clip(tmp_path / "nope.avi")
    assert str(err.value) == f"{tmp_path / 'nope.avi'}: no such file or folder"


def test_unknown_extension(tmp_path: Path) -> None:
    (tmp_path / "clip.gif").write_bytes(b"GIF89a")
    with pytest.raises(ClipError, match=r"clip\.gif: unsupported input; expected a video .*\.npy stack"):
        open_clip(tmp_path / "clip.gif")


class MisreportingCapture:
    """A capture whose seek lands one frame short and says so, as on some VFR streams."""

    def __init__(self, path: Path) -> None:
        self.cap = cv2.VideoCapture(str(path))

    def set(self, prop: int, value: float) -> bool:
        return self.cap.set(prop, value - 1)

    def get(self, prop: int) -> float:
        return self.cap.get(prop)

    def release(self) -> None:
        self.cap.release()


def test_seek_falls_back_to_reading_forward(tmp_path: Path) -> None:
    from wfviz.io.clip import _decode, _seek

    path = write_video(tmp_path / "c.mkv", "FFV1")
    cap = _seek(MisreportingCapture(path), path, "raw", 7)  # type: ignore[arg-type]
    assert isinstance(cap, cv2.VideoCapture)
    image = _decode(cap, "raw")
    cap.release()
    assert image is not None and decoded_index(image) == 7
