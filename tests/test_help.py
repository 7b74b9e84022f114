"""`--help` says what each command does, in full (issue 32, item 16): no text eaten as Rich
markup, flags shown without a value, no option promising a recording a command does not
write, `--tracker` where the README says it is."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from wfviz.cli import app
from wfviz.trackers import TRACKERS

COMMAND = typer.main.get_command(app)
NAMES = sorted(COMMAND.commands)  # type: ignore[attr-defined]
WIDE = {"COLUMNS": "1000", "TERMINAL_WIDTH": "1000"}  # one line per option: texts are never wrapped


def help_of(*command: str) -> str:
    r = CliRunner().invoke(app, [*command, "--help"], env=WIDE)
    assert r.exit_code == 0, r.output
    return r.output


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def _params(name: str | None) -> list:
    cmd = COMMAND if name is None else COMMAND.commands[name]  # type: ignore[attr-defined]
    return list(cmd.params)


@pytest.mark.parametrize("name", [None, *NAMES])
def test_every_help_text_is_shown_whole(name: str | None) -> None:
    """Each option's and argument's help appears as written (bracketed parts included: Rich
    markup would eat ``[ray]``), the escape ``\\[`` shown as ``[``."""
    shown = _flat(help_of(*([name] if name else [])))
    cmd = COMMAND if name is None else COMMAND.commands[name]  # type: ignore[attr-defined]
    assert _flat(cmd.help.replace("\\[", "[")) in shown
    for param in _params(name):
        text = getattr(param, "help", None)
        if text:
            assert _flat(text.replace("\\[", "[")) in shown, (param.name, text)


def test_bracketed_texts_survive() -> None:
    assert 'pip install "wfviz[ray]"' in help_of("tune")
    for name in ("record", "track", "bench", "compare"):
        assert "synth:SCENARIO[:SEED]" in help_of(name)
    assert "[required, except with --print-space]" in help_of("tune")


@pytest.mark.parametrize("name", [None, *NAMES])
def test_flags_show_no_value(name: str | None) -> None:
    """``--debug <bool>`` read as if the flag took a value (``wfviz --debug true config``)."""
    text = help_of(*([name] if name else []))
    assert "<bool>" not in text and "bool" not in re.sub(r"[^<>a-z]", " ", text).split()
    for param in _params(name):
        if param.param_type_name == "option" and getattr(param, "is_flag", False):
            line = next(ln for ln in text.splitlines() if f" {param.opts[0]} " in ln)
            assert "<" not in line.split(param.opts[0], 1)[1].split((param.help or "?")[:8])[0], line


def test_track_promises_no_recording() -> None:
    assert "recording" not in help_of("track").split("Options", 1)[1]


def test_compare_does_not_promise_skipped_frames_in_its_recording() -> None:
    line = next(ln for ln in help_of("compare").splitlines() if "--skip-bad-frames" in ln)
    assert "recording" not in line


def test_every_tracker_option_lists_the_trackers() -> None:
    """The README's list of the commands that take --tracker is the truth."""
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    listed = re.search(r"selected with `--tracker NAME`\s+in\s+(.*?)\(", readme, re.S)
    assert listed, "README: the sentence naming the commands that take --tracker"
    taking = sorted(n for n in NAMES if any("--tracker" in getattr(p, "opts", ()) for p in _params(n)))
    assert sorted(re.findall(r"`(\w+)`", listed.group(1))) == taking
    assert "demo" in taking


def test_demo_takes_a_tracker_and_names_its_recording_after_it(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "wfviz", "demo", "--tracker", "fusion", "--frames", "3",
                        "--no-images"], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "recordings").iterdir()) == [
        "demo-fusion-truth.csv", "demo-fusion.csv", "demo-fusion.rrd"]


def test_demo_with_an_unknown_tracker_is_one_line(tmp_path: Path) -> None:
    r = CliRunner().invoke(app, ["demo", "--tracker", "nope", "-o", str(tmp_path / "d.rrd")])
    assert r.exit_code == 2 and "nope" in r.output and ", ".join(TRACKERS) in r.output, r.output
    assert list(tmp_path.iterdir()) == []
