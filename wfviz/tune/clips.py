"""The clips of a tuning study: ``CLIP[=TRUTH]`` arguments, their truth, unique labels."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from wfviz.io.clip import open_clip
from wfviz.synth.scenarios import SYNTH_PREFIX  # registers synth: with open_clip


@dataclass(frozen=True)
class StudyClip:
    """A clip of a study: ``spec`` as :func:`wfviz.io.clip.open_clip` takes it, its truth CSV,
    a ``label`` unique in the study and its ``role`` ("tune" or "validate")."""

    label: str
    spec: str
    truth: Path
    role: str


def find_truth(spec: str, truth: str | None) -> Path | None:
    """The truth CSV of clip ``spec``: ``truth`` when given, else ``truth.csv`` in the clip
    folder, or beside a video file, a stack or a frames folder (``X/frames`` → ``X/truth.csv``).
    None: a ``synth:`` clip (it brings its own)."""
    if truth:
        return Path(truth)
    if spec.startswith(SYNTH_PREFIX):
        return None
    p = Path(spec)
    for candidate in ((p / "truth.csv", p.parent / "truth.csv") if p.is_dir() else (p.parent / "truth.csv",)):
        if candidate.is_file():
            return candidate
    raise ValueError(f"{spec}: no truth found (looked for truth.csv in and beside it); give CLIP=TRUTH")


def _label(spec: str) -> str:
    if spec.startswith(SYNTH_PREFIX):
        return spec[len(SYNTH_PREFIX):].replace(":", "-")
    p = Path(spec)
    if p.is_dir():
        return (p.parent.name if p.name == "frames" and p.parent.name else p.name) or "clip"
    return p.stem or "clip"


def split_spec(arg: str) -> tuple[str, str | None]:
    """``CLIP[=TRUTH]`` as (clip, truth or None); a ``synth:`` clip takes no truth."""
    if arg.startswith(SYNTH_PREFIX) or "=" not in arg:
        return arg, None
    clip, truth = arg.rsplit("=", 1)
    return clip, truth or None


def study_clips(tune: list[str], validate: list[str], truth_dir: Path) -> list[StudyClip]:
    """Open every clip once (errors name the clip) and resolve its truth; a ``synth:`` clip's
    truth is to be written to ``truth_dir/<label>.csv`` (:func:`synth_truth`, once the
    study is accepted), so that ``wfviz eval`` can score a reproduction against the same file.
    Nothing is written here."""
    out: list[StudyClip] = []
    seen: dict[str, int] = {}
    specs = [(a, "tune") for a in tune] + [(a, "validate") for a in validate]
    keys = [split_spec(a)[0] for a, _ in specs]
    for key in keys:
        if keys.count(key) > 1:
            raise ValueError(f"{key}: given twice (a clip is either tuned on or validated on, once)")
    for arg, role in specs:
        spec, truth_arg = split_spec(arg)
        open_clip(spec)  # a clip that cannot be opened fails here, before any trial
        base = _label(spec)
        seen[base] = seen.get(base, 0) + 1
        label = base if seen[base] == 1 else f"{base}-{seen[base]}"
        truth = find_truth(spec, truth_arg)
        if truth is None:
            truth = truth_dir / f"{label}.csv"
        elif not truth.is_file():
            raise ValueError(f"{truth}: no such truth file (for clip {spec})")
        else:
            from wfviz.evaluate import TruthError, read_truth

            shown, hidden = read_truth(truth)  # a malformed file is named before any trial runs
            if not shown and not hidden:
                raise TruthError(f"{truth}: no truth rows (only a header, or empty)")
        out.append(StudyClip(label, spec, truth, role))
    return out


def synth_truth(spec: str, stop: int | None) -> str:
    """The truth CSV text of the ``synth:`` clip ``spec`` (frames before ``stop``)."""
    rows = ["frame,target_id,x,y,visible"]
    for r in open_clip(spec).truth():
        if stop is None or r.frame < stop:
            rows.append(f"{r.frame},{r.target_id},{r.x!r},{r.y!r},{r.visible}")
    return "\n".join(rows) + "\n"


def user_inputs(clips: tuple[StudyClip, ...]) -> tuple[list[tuple[Path, str]], list[tuple[Path, str]]]:
    """The files (videos, stacks, truth) and image folders the study's clips read, each with
    what it is (``synth:`` clips and the truth the study writes for them are not the user's)."""
    files: list[tuple[Path, str]] = []
    folders: list[tuple[Path, str]] = []
    for c in clips:
        if c.spec.startswith(SYNTH_PREFIX):
            continue
        what = "the tune clip" if c.role == "tune" else "the validation clip"
        p = Path(c.spec)
        (folders if p.is_dir() else files).append((p, what))
        files.append((c.truth, f"the truth of {c.spec}"))
    return files, folders
