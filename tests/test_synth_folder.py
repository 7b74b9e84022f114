"""`wfviz synth` and `wfviz demo --save-clip` never replace or delete a user's files (issue 32,
item 6): a non-empty folder they did not write is refused, their own may be rewritten, and a
user's file in it survives."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import digest, one_line_error, wfviz
from wfviz.synth.folder import MANIFEST

@pytest.fixture()
def user_clip(tmp_path: Path) -> Path:
    """A user's 200-frame clip folder with its truth.csv."""
    folder = tmp_path / "myclip"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(200):
        assert cv2.imwrite(str(folder / f"frame_{i:06d}.png"), rng.integers(0, 65535, (8, 8), dtype=np.uint16))
    (folder / "truth.csv").write_text("frame,target_id,x,y\n0,1,2.0,3.0\n")
    return folder


def test_synth_refuses_a_users_clip_folder(user_clip: Path) -> None:
    before = digest(user_clip)
    r = wfviz("synth", "lowsnr-tbd", str(user_clip))
    one_line_error(r, str(user_clip), "not empty")
    assert digest(user_clip) == before and len(before) == 201
    assert sorted(p.name for p in user_clip.parent.iterdir()) == ["myclip"]  # no temporary left


def test_synth_refuses_a_folder_of_a_few_user_files(tmp_path: Path) -> None:
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("my notes\n")
    assert cv2.imwrite(str(folder / "frame_000000.png"), np.zeros((4, 4), np.uint8))
    (folder / "meta.json").write_text("{}")  # a meta.json is no proof wfviz wrote the folder
    before = digest(folder)
    one_line_error(wfviz("synth", "lowsnr-tbd", str(folder), "--frames", "3"), str(folder))
    assert digest(folder) == before


def test_synth_rewrites_its_own_folder_and_keeps_a_users_file(tmp_path: Path) -> None:
    folder = tmp_path / "scene"
    r = wfviz("synth", "lowsnr-tbd", str(folder), "--frames", "6")
    assert r.returncode == 0, r.stderr
    assert json.loads((folder / MANIFEST).read_text())["files"] == sorted(
        [f"frame_{i:06d}.png" for i in range(6)] + ["meta.json", "truth.csv"])
    (folder / "notes.txt").write_text("mine\n")
    r = wfviz("synth", "lowsnr-tbd", str(folder), "--frames", "3", "--seed", "1")
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in folder.iterdir())
    assert names == [MANIFEST, *[f"frame_{i:06d}.png" for i in range(3)], "meta.json", "notes.txt", "truth.csv"]
    assert (folder / "notes.txt").read_text() == "mine\n"
    assert json.loads((folder / "meta.json").read_text())["n_frames"] == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]  # no temporary left


def test_synth_writes_into_an_empty_folder(tmp_path: Path) -> None:
    folder = tmp_path / "empty"
    folder.mkdir()
    assert wfviz("synth", "lowsnr-tbd", str(folder), "--frames", "2").returncode == 0
    assert (folder / "frame_000001.png").is_file() and (folder / MANIFEST).is_file()


def test_synth_refuses_to_replace_a_users_file_of_its_own_name(tmp_path: Path) -> None:
    folder = tmp_path / "scene"
    assert wfviz("synth", "lowsnr-tbd", str(folder), "--frames", "2").returncode == 0
    (folder / "lowsnr-tbd.avi").write_bytes(b"the user's own video")
    before = digest(folder)
    one_line_error(wfviz("synth", "lowsnr-tbd", str(folder), "--frames", "3", "--avi"), "lowsnr-tbd.avi")
    assert digest(folder) == before


def test_demo_save_clip_refuses_a_users_folder(user_clip: Path, tmp_path: Path) -> None:
    before = digest(user_clip)
    out = tmp_path / "rec" / "d.rrd"
    one_line_error(wfviz("demo", "--frames", "3", "--save-clip", str(user_clip), "-o", str(out)), str(user_clip))
    assert digest(user_clip) == before
    assert not out.parent.exists()  # nothing written


def test_demo_save_clip_rewrites_its_own_folder(tmp_path: Path) -> None:
    from wfviz.synth.demo import demo_clip

    clip = demo_clip(n_frames=4)
    folder = clip.save(tmp_path / "c")
    (folder / "notes.txt").write_text("mine\n")
    clip.save(folder, 0, 2)
    assert sorted(p.name for p in folder.iterdir()) == [
        MANIFEST, "frame_000000.png", "frame_000001.png", "notes.txt", "truth.csv"]
    (tmp_path / "c2").mkdir()
    (tmp_path / "c2" / "x.txt").write_text("x")
    with pytest.raises(OSError, match="not empty"):
        clip.save(tmp_path / "c2")
    assert [p.name for p in (tmp_path / "c2").iterdir()] == ["x.txt"]


def test_synth_into_the_current_empty_folder(tmp_path: Path) -> None:
    here = tmp_path / "here"
    here.mkdir()
    for frames in ("3", "2"):
        r = wfviz("synth", "lowsnr-tbd", ".", "--frames", frames, cwd=here)
        assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["here"]
    assert sorted(p.name for p in here.iterdir()) == [MANIFEST, "frame_000000.png", "frame_000001.png",
                                                      "meta.json", "truth.csv"]
