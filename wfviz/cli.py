"""Command line: ``wfviz record | track | demo | tune | run | compare | eval | config`` and more. Wiring only; no stage work here."""

from __future__ import annotations

import functools
import os
import signal
import sys
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer
from typer.core import TyperGroup
from typer.exceptions import TyperException
from rich.console import Console
from rich.markup import escape

from wfviz.record_options import EXACT_EVERY, PREVIEW_QUALITY, RecorderOptions
from wfviz.trackers import TRACKERS, config_class, load_tracker

# Everything that needs numpy, OpenCV, SciPy or Rerun is imported by the command that uses it, so
# `wfviz --help` starts in a fraction of a second and `wfviz track` never imports Rerun (tests/test_imports.py).
if TYPE_CHECKING:
    from wfviz.io.frames import Clip
    from wfviz.run import RunSummary

def _flags_take_no_value() -> None:
    """Show no value for a flag in ``--help``. Typer's rich help (0.2x) prints a flag's type as if
    it took one (``--debug <bool>``), so ``wfviz --debug true config`` looked right and failed
    ('No such command true'); its plain help prints none. Options that take a value unchanged."""
    from typer.core import TyperOption

    shown = getattr(TyperOption, "display_type_rich", None)
    if shown is None or getattr(shown, "wfviz_flags", False):  # older typer: no type shown
        return

    def display_type_rich(self, ctx):
        if getattr(self, "is_flag", False) and not getattr(self, "count", False):
            return None
        return shown(self, ctx)

    display_type_rich.wfviz_flags = True  # type: ignore[attr-defined]
    TyperOption.display_type_rich = display_type_rich  # type: ignore[method-assign]


_flags_take_no_value()


class _OneLineErrors(TyperGroup):
    """Usage errors (a bad option value, an unknown option) as one line naming the option and
    what it accepts, exit 2, instead of the usage box."""

    def main(self, *args, standalone_mode: bool = True, **kwargs):
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            code = super().main(*args, standalone_mode=False, **kwargs)
        except TyperException as exc:
            if type(exc).__name__ == "NoArgsIsHelpError" or exc.exit_code == 0:
                from typer import rich_utils
                rich_utils.rich_format_error(exc)  # type: ignore[arg-type]
                sys.exit(exc.exit_code)
            ctx = getattr(exc, "ctx", None)
            where = f" (see {ctx.command_path} --help)" if ctx is not None else ""
            err.print(f"wfviz: error: {exc.format_message()}{where}", highlight=False, markup=False, soft_wrap=True)
            sys.exit(EXIT_BAD_INPUT)
        except typer.Abort:
            err.print("wfviz: error: aborted", highlight=False, markup=False)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(add_completion=False, no_args_is_help=True, cls=_OneLineErrors,
                  help="Wide-field IR small-target tracking with every stage recorded to Rerun.")
err = Console(stderr=True, soft_wrap=True)
out = Console(soft_wrap=True)
EXIT_BAD_INPUT = 2
STATE = {"debug": False}

ClipArg = Annotated[Path, typer.Argument(help="Video (.avi/.mp4), image folder, .npy stack or synth:SCENARIO[:SEED] (a built-in scenario, generated lazily; see `wfviz synth --list`).")]
TrackerOpt = Annotated[str, typer.Option("--tracker", help=f"Tracker: {', '.join(TRACKERS)}.")]
ConfigOpt = Annotated[Optional[Path], typer.Option("--config", help="TOML config file (see `wfviz config`).")]
StartOpt = Annotated[int, typer.Option("--start", min=0, help="First frame (0-based).")]
StopOpt = Annotated[Optional[int], typer.Option("--stop", min=1, help="Stop before this frame.")]
FpsOpt = Annotated[Optional[float], typer.Option("--fps", min=0.001, help="Override the clip's frame rate.")]
ImageEveryOpt = Annotated[int, typer.Option("--image-every", min=1, help="Log images every N frames.")]
ExactEveryOpt = Annotated[int, typer.Option("--exact-every", min=0, help="Exact (lossless, source dtype) images on the first image frame of every N frames, JPEG previews between (1: every image exact; 0: previews only).")]
JpegOpt = Annotated[int, typer.Option("--jpeg-quality", min=1, max=100, help="JPEG quality of the preview images.")]
NoImagesOpt = Annotated[bool, typer.Option("--no-images", help="Log no images (overlays and scalars only).")]
SpawnOpt = Annotated[bool, typer.Option("--spawn", help="Also stream the run live to a Rerun viewer (started, or the one already on --port).")]
ConnectOpt = Annotated[Optional[str], typer.Option("--connect", help="Also stream the run live to a running viewer or server at this URL (rerun+http://HOST:PORT/proxy, or rerun:// / rerun+https://; PORT 1-65535).", show_default=False)]
ServeOpt = Annotated[bool, typer.Option("--serve", help="Also serve the run live while it lasts: a gRPC server on --bind:--port for a native or web viewer (with --bind 0.0.0.0 a web viewer is hosted on port 9090 too).")]
BindOpt = Annotated[str, typer.Option("--bind", help="With --serve: the IP address or host name to serve on (0.0.0.0 or ::: every interface, with a web viewer on port 9090); checked, with the ports, before the run starts.")]
PortOpt = Annotated[int, typer.Option("--port", min=1, max=65535, help="With --spawn or --serve: the viewer's or server's gRPC port.")]
TruthOpt = Annotated[Optional[Path], typer.Option("--truth", help="Truth CSV (frame,target_id,x,y): score the run and draw truth in the recording.")]
GateOpt = Annotated[float, typer.Option("--gate", min=0.01, help="Match distance to truth in pixels.")]
ExplainOpt = Annotated[Optional[Path], typer.Option("--explain", help="With --truth: write the cause of every truth point in every frame to this CSV (frame,target_id,cause,detail,significance,det_dist,track_id) and of every false confirmed track point to <stem>-false.csv beside it, and print where Pd went (docs/debugging.md).", show_default=False)]
BackfillOpt = Annotated[bool, typer.Option("--backfill", help="Report every confirmed track from its first frame: its tentative rows are rewritten as confirmed in the tracks CSV (column backfilled = 1) when the run is complete; for offline analysis (a live system cannot know it yet). With --truth, Pd is printed both ways.")]
SkipBadOpt = Annotated[bool, typer.Option("--skip-bad-frames", help="Skip undecodable images or video frames (warned, logged in the recording) instead of stopping.")]
ThreadsOpt = Annotated[Optional[int], typer.Option("--threads", min=1, max=64, help="Threads of the run's pipeline: decoding, the stages before detection, tracking and the outputs each in their own (1: decoding ahead, the rest in one; default: this machine's cores, at most 4). The outputs are the same whatever the count.", show_default=False)]
NanOpt = Annotated[bool, typer.Option("--nan-as-zero", help="Replace NaN/inf pixels of float frames by 0 instead of stopping.")]


def _fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    from wfviz.io.clip import display

    err.print(f"[bold red]wfviz: error:[/] {escape(display(message))}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Print a warning as one line: ``wfviz: note|warning: ...``."""
    from wfviz.io.clip import ClipNote, ClipWarning, display

    if issubclass(category, ClipNote):
        kind = "note"
    elif issubclass(category, ClipWarning):
        kind = "warning"
    else:
        kind = f"warning: {category.__name__}"
    err.print(f"[yellow]wfviz: {kind}:[/] {escape(display(message))}", highlight=False, soft_wrap=True)


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived (raised so that every command's clean-up runs, as on Ctrl-C)."""


def _terminate(signum: int, _frame: object) -> None:
    raise Terminated()


def _guarded(fn):
    """Turn known bad-input errors into one-line messages (tracebacks only with --debug),
    warnings into one-line notes, and SIGTERM into the clean-up path of Ctrl-C (temporary files
    removed, child processes ended)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from wfviz.config import ConfigError
        from wfviz.io.clip import BadFrameError, ClipError, ClipWarning
        from wfviz.io.outputs import OutputError

        with warnings.catch_warnings():
            warnings.simplefilter("always", ClipWarning)
            warnings.showwarning = _show_warning
            old_term = signal.signal(signal.SIGTERM, _terminate)
            try:
                return fn(*args, **kwargs)
            except Terminated:
                if STATE["debug"]:
                    raise
                _fail("terminated", 128 + signal.SIGTERM)
            except BadFrameError as exc:
                if STATE["debug"]:
                    raise
                _fail(f"{exc} (--skip-bad-frames skips it)")
            except (ClipError, ConfigError, OutputError, ValueError) as exc:
                if STATE["debug"]:
                    raise
                _fail(str(exc))
            except KeyboardInterrupt:
                if STATE["debug"]:
                    raise
                _fail("interrupted", 128 + signal.SIGINT)
            except OSError as exc:  # e.g. disk full while writing
                if STATE["debug"]:
                    raise
                where = f"{exc.filename}: " if exc.filename else ""
                _fail(f"{where}{exc.strerror or exc}", 1)
            finally:
                signal.signal(signal.SIGTERM, old_term)
    return wrapper


def _progress(*fields: str, eta: bool = True):
    """A progress bar on stderr, hidden when stderr is not a terminal: the task's description, a
    bar, done/total, the task ``fields`` (rich format strings) and, with ``eta``, the time left.
    rich.progress is imported here, by the commands that show one."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               *(TextColumn(f) for f in fields), *([TimeRemainingColumn()] if eta else [])]
    return Progress(*columns, console=err, transient=True, disable=not err.is_terminal)


def _tracker(name: str, config: Path | None):
    return load_tracker(name, config)


def _clip_inputs(clip: Clip | None) -> tuple[list[tuple[Path, str]], list[Path]]:
    """((file, what it is), image folders) a clip reads."""
    if clip is None:
        return [], []
    path = clip.path
    files = [(Path(f), f"frame {i} of the input clip") for i, f in enumerate(clip.files)]
    if files:
        return files, [Path(path)] if path is not None else []
    return ([(Path(path), "the input clip")] if path is not None else []), []


def _inputs(truth: Path | None, config: Path | None) -> tuple[tuple[Path | None, str], ...]:
    return (truth, "the truth file"), (config, "the config file")


def _guard_outputs(*outputs: Path | None, clip: Clip | None = None,
                   inputs: tuple[tuple[Path | None, str], ...] = ()) -> None:
    """Refuse outputs that would replace an input (clip frames, truth, config, recording) or
    each other; remove temporary outputs that killed wfviz runs left beside them."""
    from wfviz.io.clip import display
    from wfviz.io.outputs import check_not_inputs, remove_stale

    files, folders = _clip_inputs(clip)
    check_not_inputs(outputs, [*files, *((p, what) for p, what in inputs if p is not None)], folders)
    for folder in dict.fromkeys(Path(o).parent for o in outputs if o is not None):
        for stale in remove_stale(folder):
            err.print(f"wfviz: note: removed {display(stale)} (left by a wfviz run that was killed)",
                      highlight=False, markup=False, soft_wrap=True)


def _live(spawn: bool, connect: str | None, serve: bool, bind: str, port: int):
    """The live view asked for (at most one of --spawn, --connect, --serve), or None."""
    asked = [name for name, on in (("--spawn", spawn), ("--connect", connect is not None), ("--serve", serve)) if on]
    if len(asked) > 1:
        raise ValueError(f"{' and '.join(asked)}: choose one live view")
    if not asked:
        return None
    from wfviz.record.live import live_view

    return live_view("spawn" if spawn else "serve" if serve else "connect", url=connect, bind=bind, port=port)


def _execute(clip: Clip, tracker, *, tracks: Path | None, recording: Path | None, start: int,
             stop: int | None, image_every: int, source: str, truth=None, gate: float = 3.0,
             jpeg_quality: int = PREVIEW_QUALITY, exact_every: int = EXACT_EVERY,
             inputs: tuple[tuple[Path | None, str], ...] = (), live=None, explain: Path | None = None,
             backfill: bool = False, threads: int | None = None) -> RunSummary:
    from wfviz.config import config_to_toml
    from wfviz.io.clip import display
    from wfviz.pipeline import default_threads
    from wfviz.run import run

    if explain is not None and truth is None:
        raise ValueError(f"--explain {explain}: needs truth (--truth FILE)")
    _guard_outputs(recording, tracks, *_explain_files(explain), clip=clip, inputs=inputs)
    total = clip.n_frames
    if total is not None:
        total = max(0, min(total, stop if stop is not None else total) - start)
    options = None
    if recording is not None:
        options = RecorderOptions(source=source, config_text=config_to_toml(tracker.config), image_every=image_every,
                                  trail_length=tracker.config.tracking.trail_length,
                                  jpeg_quality=jpeg_quality, exact_every=exact_every, live=live)
        if live is not None:
            err.print(f"wfviz: live: {live.describe()}", highlight=False, markup=False, soft_wrap=True)
    with _progress("{task.fields[fps]:>7.1f} fps") as progress:
        task = progress.add_task(escape(display(clip.name)), total=total, fps=0.0)
        count = [0]
        import time
        t0 = time.perf_counter()

        def tick(frame, result) -> None:
            count[0] += 1
            progress.update(task, advance=1, fps=count[0] / max(time.perf_counter() - t0, 1e-9))

        summary = run(clip, tracker, tracks_csv=tracks, recording=recording, recorder_options=options,
                      start=start, stop=stop, truth=truth, gate=gate, explain=explain, on_frame=tick,
                      backfill=backfill, threads=threads or default_threads())
    return summary


def _explain_files(explain: Path | None) -> tuple[Path, ...]:
    """The files ``--explain`` writes (none without it)."""
    if explain is None:
        return ()
    from wfviz.explain.report import false_path

    return explain, false_path(explain)


def _read_truth(path: Path | None):
    if path is None:
        return None
    from wfviz.evaluate import read_truth

    if not path.is_file():
        raise ValueError(f"{path}: no such truth file")
    return read_truth(path)


def _report(summary: RunSummary, tracks: Path | None, recording: Path | None, explain: Path | None = None) -> None:
    from wfviz.io.clip import display

    signum = summary.signal or (signal.SIGINT if summary.interrupted else None)
    state = f"[yellow]interrupted by {signal.Signals(signum).name}[/]" if signum else "done"
    out.print(f"{state}: {summary.frames} frames in {summary.seconds:.2f} s "
              f"({summary.fps:.1f} fps overall, {summary.tracker_ms:.2f} ms/frame tracking), "
              f"{len(summary.confirmed)} tracks confirmed", highlight=False)
    held = (f" ({summary.frames} frames, {summary.first}-{summary.last})" if summary.frames
            else " (0 frames)")
    if summary.skipped:
        shown = ", ".join(map(str, summary.skipped[:10])) + (", ..." if len(summary.skipped) > 10 else "")
        out.print(f"  skipped:   {len(summary.skipped)} unreadable frames ({shown})", highlight=False, markup=False)
    if tracks is not None:
        out.print(f"  tracks:    {display(tracks)}{held if signum else ''}", highlight=False, markup=False)
    if recording is not None:
        out.print(f"  recording: {display(recording)}{held if signum else ''}", highlight=False, markup=False)
        out.print(f"  open it:   rerun {display(recording)}", highlight=False, markup=False)
    if explain is not None:
        from wfviz.explain.report import false_path
        out.print(f"  explain:   {display(explain)}, {display(false_path(explain))}{held if signum else ''}",
                  highlight=False, markup=False)
    if summary.scores is not None:
        from wfviz.evaluate import format_backfilled, format_table
        out.print(format_table(summary.scores), highlight=False, markup=False)
        from wfviz.sinks import BackfilledScores
        filled = summary.facts.get(BackfilledScores)
        if filled is not None:
            out.print(format_backfilled(filled.result), highlight=False, markup=False)
    why = None
    if summary.scores is not None:  # the causes are explained with truth only
        from wfviz.explain.report import ExplainSummary, format_summary
        why = summary.facts.get(ExplainSummary)
    if why is not None:
        out.print("", highlight=False, markup=False)
        out.print(format_summary(why), highlight=False, markup=False)
    if signum:
        raise typer.Exit(128 + signum)


@app.callback()
def _main(debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks on errors.")] = False) -> None:
    STATE["debug"] = debug
    if not debug:  # FFmpeg's and Rerun's own error logs: wfviz reports the problem in one line
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
        os.environ.setdefault("RUST_LOG", "off")


@app.command()
@_guarded
def record(
    clip: ClipArg,
    output: Annotated[Optional[Path], typer.Option("-o", "--output", help="Recording (.rrd; default recordings/<clip>-<tracker>.rrd).")] = None,
    tracks: Annotated[Optional[Path], typer.Option("--tracks", help="Tracks CSV (default: beside the recording, <stem>.csv).")] = None,
    tracker: TrackerOpt = "gewc",
    config: ConfigOpt = None,
    start: StartOpt = 0,
    stop: StopOpt = None,
    fps: FpsOpt = None,
    image_every: ImageEveryOpt = 1,
    no_images: NoImagesOpt = False,
    exact_every: ExactEveryOpt = EXACT_EVERY,
    jpeg_quality: JpegOpt = PREVIEW_QUALITY,
    truth: TruthOpt = None,
    gate: GateOpt = 3.0,
    explain: ExplainOpt = None,
    skip_bad_frames: SkipBadOpt = False,
    nan_as_zero: NanOpt = False,
    spawn: SpawnOpt = False,
    connect: ConnectOpt = None,
    serve: ServeOpt = False,
    bind: BindOpt = "127.0.0.1",
    port: PortOpt = 9876,
    backfill: BackfillOpt = False,
    threads: ThreadsOpt = None,
) -> None:
    """Track a clip and record every stage to a Rerun .rrd (default recordings/<stem>-<tracker>.rrd)."""
    from wfviz.io.clip import open_clip

    live = _live(spawn, connect, serve, bind, port)
    trk = _tracker(tracker, config)
    truth_points = _read_truth(truth)
    source = open_clip(clip, fps=fps, skip_bad_frames=skip_bad_frames, nan_as_zero=nan_as_zero)
    output = output or Path("recordings") / f"{source.name}-{tracker}.rrd"
    tracks = tracks or output.with_suffix(".csv")
    summary = _execute(source, trk, tracks=tracks, recording=output, start=start, stop=stop,
                       image_every=0 if no_images else image_every, source=str(clip),
                       truth=truth_points, gate=gate, jpeg_quality=jpeg_quality, exact_every=exact_every,
                       inputs=_inputs(truth, config), live=live, explain=explain, backfill=backfill,
                       threads=threads)
    _report(summary, tracks, output, explain)


@app.command()
@_guarded
def track(
    clip: ClipArg,
    tracks: Annotated[Optional[Path], typer.Option("--tracks", help="Tracks CSV to write (may be left out with --truth: the scores, where Pd went and --explain's files only).", show_default=False)] = None,
    tracker: TrackerOpt = "gewc",
    config: ConfigOpt = None,
    start: StartOpt = 0,
    stop: StopOpt = None,
    fps: FpsOpt = None,
    truth: Annotated[Optional[Path], typer.Option("--truth", help="Truth CSV (frame,target_id,x,y): score the tracks against it (the table is printed).")] = None,
    gate: GateOpt = 3.0,
    explain: ExplainOpt = None,
    skip_bad_frames: Annotated[bool, typer.Option("--skip-bad-frames", help="Skip undecodable images or video frames (warned, counted in the closing summary) instead of stopping.")] = False,
    nan_as_zero: NanOpt = False,
    backfill: BackfillOpt = False,
    threads: ThreadsOpt = None,
) -> None:
    """Track a clip and write the tracks CSV only (no recording)."""
    from wfviz.io.clip import open_clip

    if tracks is None and truth is None:
        raise ValueError("track: nothing to write: give --tracks FILE (or --truth FILE to score the run)")
    trk = _tracker(tracker, config)
    truth_points = _read_truth(truth)
    source = open_clip(clip, fps=fps, skip_bad_frames=skip_bad_frames, nan_as_zero=nan_as_zero)
    summary = _execute(source, trk, tracks=tracks, recording=None, start=start, stop=stop,
                       image_every=0, source=str(clip), truth=truth_points, gate=gate, inputs=_inputs(truth, config),
                       explain=explain, backfill=backfill, threads=threads)
    _report(summary, tracks, None, explain)


@app.command()
@_guarded
def demo(
    output: Annotated[Optional[Path], typer.Option("-o", "--output", help="Recording (.rrd; default recordings/demo-<tracker>.rrd); the tracks CSV (<stem>.csv) and the truth CSV (<stem>-truth.csv) go beside it.")] = None,
    frames: Annotated[int, typer.Option("--frames", min=1, help="Clip length.")] = 160,
    seed: Annotated[int, typer.Option("--seed", help="Noise seed.")] = 0,
    save_clip: Annotated[Optional[Path], typer.Option("--save-clip", help="Also write the clip as 16-bit PNGs + truth.csv into this folder: a new or empty one, or one wfviz wrote before (only its own files are replaced).")] = None,
    tracker: TrackerOpt = "gewc",
    config: ConfigOpt = None,
    image_every: ImageEveryOpt = 1,
    no_images: NoImagesOpt = False,
    exact_every: ExactEveryOpt = EXACT_EVERY,
    jpeg_quality: JpegOpt = PREVIEW_QUALITY,
    spawn: SpawnOpt = False,
    connect: ConnectOpt = None,
    serve: ServeOpt = False,
    bind: BindOpt = "127.0.0.1",
    port: PortOpt = 9876,
    threads: ThreadsOpt = None,
) -> None:
    """Generate the built-in synthetic 180° fisheye clip, track it and record every stage."""
    from wfviz.io.outputs import check_writable, replace_into, temp_path
    from wfviz.synth.demo import demo_clip
    from wfviz.synth.folder import check_folder

    if save_clip is not None:
        check_folder(save_clip)  # before writing anything: a user's folder is refused
    live = _live(spawn, connect, serve, bind, port)
    trk = _tracker(tracker, config)
    output = output or Path("recordings") / f"demo-{tracker}.rrd"
    clip = demo_clip(seed=seed, n_frames=frames)
    tracks = output.with_suffix(".csv")
    truth = output.with_name(output.stem + "-truth.csv")
    check_writable(truth)
    _guard_outputs(output, tracks, truth, inputs=((config, "the config file"),))
    if save_clip is not None:
        clip.save(save_clip)
        out.print(f"  clip:      {save_clip}", highlight=False, markup=False)
    temp = temp_path(truth)
    try:
        clip.write_truth_csv(temp)
        replace_into(temp, truth)
    finally:
        temp.unlink(missing_ok=True)
    summary = _execute(clip, trk, tracks=tracks, recording=output, start=0, stop=None,
                       image_every=0 if no_images else image_every,
                       source=f"built-in demo (seed {seed}, {frames} frames)", truth=clip.truth_points(),
                       jpeg_quality=jpeg_quality, exact_every=exact_every, live=live, threads=threads)
    out.print(f"  truth:     {truth}", highlight=False, markup=False)
    _report(summary, tracks, output)


@app.command()
@_guarded
def synth(
    scenario: Annotated[Optional[str], typer.Argument(help="Scenario name (see --list).")] = None,
    out_dir: Annotated[Optional[Path], typer.Argument(help="Folder to write (16-bit PNGs, truth.csv, meta.json): a new or empty one, or one synth wrote before (only its own files are replaced; any other folder is refused).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Random seed (noise, textures).")] = 0,
    frames: Annotated[Optional[int], typer.Option("--frames", min=1, help="Number of frames (default: the scenario's).")] = None,
    snr: Annotated[Optional[float], typer.Option("--snr", min=0.1, max=1e6, help="Peak SNR of every target.")] = None,
    avi: Annotated[bool, typer.Option("--avi", help="Also write an 8-bit .avi.")] = False,
    list_: Annotated[bool, typer.Option("--list", help="Describe every scenario and exit.")] = False,
) -> None:
    """Write a synthetic wide-field scenario with exact truth."""
    from wfviz.synth.folder import check_folder
    from wfviz.synth.scenarios import list_scenarios, make_scenario, write_scenario

    if list_ or scenario is None:
        for info in list_scenarios():
            out.print(f"[bold]{info.name}[/]  {info.width}x{info.height}, {info.fov_deg:g}° FOV, "
                      f"{info.n_frames} frames at {info.fps:g} fps, {info.n_targets} target{'s' if info.n_targets != 1 else ''}\n    {info.description}")
        return
    if out_dir is None:
        raise ValueError("synth: give an output folder (wfviz synth SCENARIO OUT_DIR)")
    check_folder(out_dir, "the scenario")  # before rendering anything: a user's folder is refused
    clip = make_scenario(scenario, seed=seed, n_frames=frames, snr=snr)
    with _progress(eta=False) as progress:
        task = progress.add_task(escape(f"synth {scenario}"), total=clip.n_frames)
        path = write_scenario(clip, out_dir, avi=avi, progress=lambda n: progress.update(task, completed=n))
    out.print(f"wrote {clip.n_frames} frames of '{scenario}' (seed {seed}) to {path}", highlight=False, markup=False)
    out.print(f"  track it: wfviz record {path} --truth {path / 'truth.csv'}", highlight=False, markup=False)


@app.command("eval")
@_guarded
def eval_(
    tracks: Annotated[Optional[Path], typer.Argument(help="Tracks CSV (frame,track_id,x,y,confirmed).", show_default=False)] = None,
    truth: Annotated[Optional[Path], typer.Argument(help="Truth CSV (frame,target_id,x,y).", show_default=False)] = None,
    gate: Annotated[float, typer.Option("--gate", min=0.01, help="Match distance in pixels.")] = 3.0,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Also write the scores (and with --explain, where Pd went under \"explain\") as JSON.")] = None,
    all_rows: Annotated[bool, typer.Option("--all-rows", help="Score every row as a confirmed track (for CSVs without a 'confirmed' column, or to include tentative tracks).")] = False,
    explain: Annotated[Optional[Path], typer.Option("--explain", help="An EXPLAIN.csv written by `record`/`track --explain`: print where Pd went (each cause's count and share in pipeline order, per target, and the false-track causes of <stem>-false.csv beside it). TRACKS and TRUTH may then be left out.", show_default=False)] = None,
    no_boxes: Annotated[bool, typer.Option("--no-boxes", help="Match within --gate only, even when the truth has box sizes (w,h columns; by default a track inside the box matches too).")] = False,
) -> None:
    """Score tracks against ground truth: MOTA, MOTP, IDF1, HOTA (DetA, AssA), switches, CLE, Pd, FA/frame, p_d, p_f; with --explain, where Pd went."""
    import json

    from wfviz.evaluate import evaluate, format_backfilled, format_table, has_backfilled_rows
    from wfviz.io.outputs import check_writable

    if explain is None and (tracks is None or truth is None):
        raise ValueError("eval: give TRACKS and TRUTH (or --explain EXPLAIN.csv)")
    if (tracks is None) != (truth is None):
        raise ValueError("eval: give both TRACKS and TRUTH, or neither with --explain")
    for p in (tracks, truth, explain):
        if p is not None and not p.is_file():
            raise ValueError(f"{p}: no such file")
    if json_out is not None:
        check_writable(json_out)
        from wfviz.explain.report import false_path
        _guard_outputs(json_out, inputs=((tracks, "the tracks CSV"), (truth, "the truth file"),
                                         (explain, "the explain file"),
                                         (false_path(explain) if explain else None, "the explain file")))
    data: dict = {}
    if tracks is not None and truth is not None:
        result = evaluate(tracks, truth, gate=gate, all_rows=all_rows, use_boxes=not no_boxes)
        out.print(format_table(result), highlight=False, markup=False)
        data = result.to_dict()
        if not all_rows and has_backfilled_rows(tracks):
            online = evaluate(tracks, truth, gate=gate, use_boxes=not no_boxes, online=True)
            out.print(format_backfilled(online, online=True), highlight=False, markup=False)
            data["online"] = online.to_dict()
    if explain is not None:
        from wfviz.explain.report import format_summary, read_explain
        why = read_explain(explain)
        if data:
            out.print("", highlight=False, markup=False)
        out.print(format_summary(why), highlight=False, markup=False)
        data["explain"] = why.to_dict()
    if json_out is not None:
        from wfviz.io.outputs import write_atomically
        write_atomically(json_out, json.dumps(data, indent=2) + "\n")
        out.print(f"  json: {json_out}", highlight=False, markup=False)


@app.command()
@_guarded
def screenshot(
    recording: Annotated[Path, typer.Argument(help="Recording (.rrd) to render.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG to write.")] = Path("screenshot.png"),
    frame: Annotated[Optional[int], typer.Option("--frame", min=0, help="Frame to show (a time on --timeline), within the recording's range (default: its last).")] = None,
    frames: Annotated[Optional[str], typer.Option("--frames", metavar="A,B,C", help="Several frames in one PNG, one viewer for all: a panel per frame, labelled with its number, side by side (a grid beyond 3; at most 16).", show_default=False)] = None,
    timeline: Annotated[Optional[str], typer.Option("--timeline", help="Sequence timeline the frames are on (default: frame, else the recording's only sequence timeline, e.g. trial in the study.rrd of `wfviz tune`).", show_default=False)] = None,
    around: Annotated[Optional[str], typer.Option("--around", metavar="X,Y", help="Crop the 2D (camera) views around this image point: x = column, y = row, origin at the centre of the top-left pixel.", show_default=False)] = None,
    target: Annotated[Optional[int], typer.Option("--target", metavar="ID", help="Crop around truth target ID where it is in each frame shown (camera/truth: recorded with --truth, always by `wfviz demo`).", show_default=False)] = None,
    track: Annotated[Optional[int], typer.Option("--track", metavar="ID", help="Crop around confirmed track ID where it is in each frame shown (the end of its trail, camera/tracks).", show_default=False)] = None,
    zoom: Annotated[Optional[float], typer.Option("--zoom", metavar="Z", help="Zoom of the crop: the 2D views show (at least) width/Z by height/Z image pixels. Default 4.", show_default=False)] = None,
    width: Annotated[int, typer.Option("--width", min=200, help="Image width in pixels (of each panel with --frames).")] = 1600,
    height: Annotated[int, typer.Option("--height", min=200, help="Image height in pixels (of each panel with --frames).")] = 1000,
) -> None:
    """Render a recording in the real Rerun viewer, headless, with its default blueprint: one frame, or several side by side, the camera views optionally zoomed around a point, a truth target or a track."""
    from wfviz.io.outputs import OutputError
    from wfviz.record.screenshot import ScreenshotError, pick_timeline, plan_shots, render_shots

    if not recording.is_file():
        raise ValueError(f"{recording}: no such recording")
    if output.is_dir():
        raise OutputError(f"{output}: is a folder, expected a PNG file name")
    _guard_outputs(output, inputs=((recording, "the recording"),))
    timeline = pick_timeline(recording, timeline)
    shots = plan_shots(recording, frame=frame, frames=frames, timeline=timeline, around=around, target=target,
                       track=track, zoom=zoom)
    try:
        render_shots(recording, output, shots, timeline=timeline, width=width, height=height)
    except ScreenshotError as exc:
        raise ValueError(f"{recording}: {exc}") from None
    out.print(f"screenshot: {output}", highlight=False, markup=False)


@app.command("bench")
@_guarded
def bench_(
    clip: ClipArg,
    tracker: TrackerOpt = "gewc",
    config: ConfigOpt = None,
    start: StartOpt = 0,
    stop: StopOpt = None,
    fps: FpsOpt = None,
    threads: Annotated[int, typer.Option("--threads", min=0, max=os.cpu_count() or 1, help="OpenCV threads (1 = one core, 0 = OpenCV's default; at most this machine's cores).")] = 1,
) -> None:
    """Time each stage of a tracker on a clip (decoding separately), nothing written."""
    import cv2

    from wfviz.bench import bench, format_bench
    from wfviz.io.clip import open_clip

    if threads > 0:
        cv2.setNumThreads(threads)
    trk = _tracker(tracker, config)
    source = open_clip(clip, fps=fps)
    result = bench(source, trk, start=start, stop=stop)
    out.print(format_bench(result, tracker), highlight=False, markup=False)
    if result.signal is not None:
        out.print(f"[yellow]interrupted by {signal.Signals(result.signal).name}[/] after {result.frames} timed frames",
                  highlight=False)
        raise typer.Exit(128 + result.signal)


@app.command()
@_guarded
def tune(
    clips: Annotated[Optional[list[str]], typer.Argument(help="Clips to tune on, each CLIP or CLIP=TRUTH (truth: TRUTH, else truth.csv in or beside the clip; synth: clips bring their own).", show_default=False)] = None,
    out_dir: Annotated[Optional[Path], typer.Option("--out", help="Study folder: trials.csv, best.toml, report.md, study.rrd, the journal (the same command resumes it). \\[required, except with --print-space]")] = None,
    tracker: TrackerOpt = "gewc",
    space: Annotated[Optional[Path], typer.Option("--space", help="Search space TOML (default: the tracker's; see --print-space).")] = None,
    config: Annotated[Optional[Path], typer.Option("--config", help="Configuration the trials start from (default: the defaults); trial 0 runs it as it is.")] = None,
    trials: Annotated[int, typer.Option("--trials", min=1, help="Finished trials the study should have (a resumed study adds the rest).")] = 20,
    objective: Annotated[str, typer.Option("--objective", help="mota, idf1, hota, pd (maximised; pd with a --constraint on fa_per_frame) or pareto (Pd up, false tracks per frame down), averaged over the clips.")] = "mota",
    validate: Annotated[Optional[list[str]], typer.Option("--validate", metavar="<clip>", help="A clip scored in every trial but never used to choose (repeat for more).", show_default=False)] = None,
    folds: Annotated[int, typer.Option("--folds", min=0, help="Without --validate: leave-clips-out cross-validation of the chosen trial over K folds of the tune clips (report.md).")] = 0,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="Trials run at a time (local processes, or Ray tasks with --ray). Default: this machine's cores.", show_default=False)] = None,
    seed: Annotated[int, typer.Option("--seed", help="Sampler seed (same seed and --workers: same trials).")] = 0,
    ray: Annotated[Optional[str], typer.Option("--ray", help="Run the trials on a Ray cluster at this address (`--ray` alone: a local Ray). Needs Ray: pip install \"wfviz\\[ray]\".", show_default=False)] = None,
    record_best: Annotated[int, typer.Option("--record-best", min=0, help="Record the K best trials (and trial 0) on every clip as .rrd with truth.")] = 0,
    stop: StopOpt = None,
    gate: GateOpt = 3.0,
    no_cache: Annotated[bool, typer.Option("--no-cache", help="Run every trial's front end again (the same results, slower; for timing the cache).")] = False,
    constraint: Annotated[Optional[list[str]], typer.Option("--constraint", metavar="<METRIC<=VALUE>", help="A bound the chosen trial must meet, on the metric averaged over the tune clips: METRIC<=VALUE or METRIC>=VALUE, METRIC one of pd, fa_per_frame, mota, idf1, hota, id_switches (repeat for more). E.g. --constraint \"fa_per_frame<=0.1\" --objective mota.", show_default=False)] = None,
    prune: Annotated[bool, typer.Option("--prune", help="Stop a trial once its tune clips so far show it significantly worse than the best trial (Wilcoxon signed-rank, p < 0.1; clips in a seeded order, the same for every trial). Worth it with many tune clips; not with pareto.")] = False,
    print_space: Annotated[bool, typer.Option("--print-space", help="Print the tracker's default search space as TOML and exit.")] = False,
) -> None:
    """Search a tracker's parameters against ground truth (Optuna), validate on held-back clips, link every trial to its scores and recordings."""
    from wfviz.config import load_config
    from wfviz.io.outputs import OutputError
    from wfviz.trackers import default_space
    from wfviz.tune.outputs import ranked
    from wfviz.tune.space import load_space, parse_space, space_to_toml
    from wfviz.tune.study import OBJECTIVES

    if tracker not in TRACKERS:
        raise ValueError(f"unknown tracker '{tracker}' (available: {', '.join(TRACKERS)})")
    cls = config_class(tracker)
    if space is not None:
        search = load_space(space, cls)
    else:
        default = default_space(tracker)
        if default is None:
            raise ValueError(f"tracker '{tracker}' has no default search space; give --space FILE")
        search = parse_space(default, cls)
    if print_space:
        sys.stdout.write(space_to_toml(search, tracker))
        return
    if objective not in OBJECTIVES:
        raise ValueError(f"--objective: unknown '{objective}' (available: {', '.join(OBJECTIVES)})")
    if not clips:
        raise ValueError("no clip to tune on (give at least one CLIP)")
    if out_dir is None:
        raise ValueError("--out DIR is required (the study's folder)")
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: is a file, expected the study's folder")
    if folds == 1:
        raise ValueError("--folds: give at least 2 folds (or 0 for none)")
    if folds and validate:
        raise ValueError("--folds and --validate: choose one (validation clips are the stricter check)")
    if folds > len(clips):
        raise ValueError(f"--folds {folds}: more folds than tune clips ({len(clips)})")
    from wfviz.tune.constraints import parse_constraints

    constraints = parse_constraints(list(constraint or []))
    if prune and objective == "pareto":
        raise ValueError("--prune: needs one objective (mota, idf1, hota or pd), not pareto")
    base = load_config(config, cls)
    from wfviz.tune.session import prepare, tune as run_tune

    use_ray = ray is not None
    address = None if ray in (None, "", "local") else ray
    from wfviz.tune.workers import worker_count

    n_workers, note = worker_count(workers, trials, use_ray)
    if note:
        err.print(f"wfviz: note: {note}", highlight=False, markup=False, soft_wrap=True)
    settings = prepare(tracker, list(clips), list(validate or []), out_dir, search, base, objective=objective,
                       trials=trials, seed=seed, workers=n_workers, stop=stop, gate=gate,
                       use_ray=use_ray, ray_address=address, cache=not no_cache, constraints=constraints,
                       prune=prune)
    metric = OBJECTIVES[objective][0][0]
    with _progress("{task.fields[best]}") as progress:
        task = progress.add_task("trials", total=trials, best="")

        def on_batch(state) -> None:
            top = ranked(state.trials, objective)
            best = ("" if not top else f"{len(top)} scored" if objective == "pareto"
                    else f"best {metric} {top[0].values[0]:.3f} (trial {top[0].number})")
            progress.update(task, completed=len(state.trials), best=best)

        def on_stage(name: str) -> None:
            progress.update(task, description=name)

        result = run_tune(settings, out_dir, record_best=record_best, folds=folds, on_batch=on_batch,
                          on_stage=on_stage, inputs=((config, "the --config file"), (space, "the --space file")))
    _tune_summary(result, metric)
    if result.signal is not None:
        raise typer.Exit(128 + result.signal)


def _tune_summary(result, metric: str) -> None:
    from wfviz.tune.constraints import feasible
    from wfviz.tune.outputs import ranked
    from wfviz.tune.study import outcome_phrases
    from wfviz.tune.trial import dominant

    state, settings = result.state, result.settings
    done = [t for t in state.trials if t.values is not None]
    failed = sum(t.state.name == "FAIL" for t in state.trials)
    infeasible, pruned = outcome_phrases(state.trials, settings)
    how = (f"[yellow]interrupted by {signal.Signals(result.signal).name}[/]" if result.signal is not None
           else "done")
    out.print(f"{how}: {len(state.trials)} trials ({len(done)} scored{infeasible}, {pruned}{failed} failed; "
              f"{state.ran} this run)", highlight=False)
    for note in state.notes:
        out.print(f"  note: {note}", highlight=False, markup=False)
    has_val = any(c.role == "validate" for c in settings.clips)
    best = ranked(state.trials, settings.objective)
    base = [t for t in done if t.user_attrs.get("base")]
    rows = base + [t for t in best[:5] if t not in base]
    if done and not best and settings.constraints:
        out.print("  no completed trial meets the constraints: no best configuration written",
                  highlight=False, markup=False)
    for t in rows:
        tune_s = t.user_attrs["tune"]
        line = f"  trial {t.number:>4}{' (base)' if t.user_attrs.get('base') else '       '}  tune " + \
            " ".join(f"{m} {tune_s[m]:.3f}" for m in ("mota", "idf1", "hota", "pd", "fa") if m in tune_s)
        if has_val:
            v = t.user_attrs["validate"]
            line += "  | validate " + " ".join(f"{m} {v[m]:.3f}" for m in ("mota", "idf1", "hota", "pd", "fa") if m in v)
        miss = dominant((t.user_attrs.get("causes") or {}).get("tune"))
        if miss:
            line += f"  | most misses: {miss}"
        if not feasible(t):
            line += "  | outside the constraints"
        out.print(line, highlight=False, markup=False)
    for f in result.files:
        if f.suffix in (".toml", ".csv", ".md", ".rrd") and f.parent == result.files[0].parent:
            out.print(f"  {f.name:<12} {f}", highlight=False, markup=False)
    recs = [f for f in result.files if f.parent.name == "recordings"]
    if recs:
        cut = (f" (stopped: {recs[-1].name} holds the frames done, the rest were not recorded)"
               if result.signal is not None and not state.interrupted else "")
        out.print(f"  recordings: {len(recs)} in {recs[0].parent}{cut}", highlight=False, markup=False)


@app.command("run")
@_guarded
def run_dataset(
    dataset: Annotated[Path, typer.Argument(help="A folder searched for clips (folders of 2+ images, videos, .npy stacks; truth.csv in or beside each is its truth), a list file (.txt/.list: a CLIP or CLIP=TRUTH a line, # comments, paths relative to the list) or one clip.", show_default=False)],
    out_dir: Annotated[Optional[Path], typer.Option("--out", help="The run's folder: results.csv (a row per clip), summary.md, tracks/, explain/, recordings/ (the same command resumes it). \\[required]", show_default=False)] = None,
    tracker: TrackerOpt = "gewc",
    config: ConfigOpt = None,
    jobs: Annotated[Optional[int], typer.Option("--jobs", min=1, help="Clips tracked at a time (local processes, or Ray tasks with --ray). Default: this machine's cores.", show_default=False)] = None,
    ray: Annotated[Optional[str], typer.Option("--ray", help="Run the clips on a Ray cluster at this address (`--ray` alone: a local Ray). Needs Ray: pip install \"wfviz\\[ray]\".", show_default=False)] = None,
    gate: GateOpt = 3.0,
    goal: Annotated[str, typer.Option("--goal", help="What a clip should meet (the summary's goals met, results.csv's goal column): METRIC OP NUMBER joined by and/or; METRIC one of pd, pd_settled, fa_per_frame, mota, idf1, hota, id_switches.")] = "pd>=0.9 and fa_per_frame<=0.1",
    record: Annotated[bool, typer.Option("--record", help="Record every clip (recordings/<label>.rrd, with truth, as `wfviz record --truth`).")] = False,
    record_failing: Annotated[Optional[str], typer.Option("--record-failing", metavar="EXPR", help="Record the clips whose scores meet EXPR, e.g. \"pd<0.9 or fa_per_frame>0.1\" (tracked again with the recording once scored).", show_default=False)] = None,
) -> None:
    """Track every clip of a folder or a list file (with truth: score and explain it) in local processes or on Ray; one row per clip in results.csv, a summary, resumable."""
    from wfviz.config import load_config
    from wfviz.dataset.goals import parse_goal
    from wfviz.dataset.results import format_totals, running
    from wfviz.dataset.session import RunSettings, execute, plan
    from wfviz.io.clip import display
    from wfviz.pools import require_ray, worker_count

    if out_dir is None:
        raise ValueError("--out DIR is required (the run's folder)")
    if tracker not in TRACKERS:
        raise ValueError(f"unknown tracker '{tracker}' (available: {', '.join(TRACKERS)})")
    goal_ = parse_goal(goal, "--goal")
    failing = parse_goal(record_failing) if record_failing is not None else None
    if record and failing is not None:
        raise ValueError("--record and --record-failing: choose one (--record records every clip)")
    use_ray = ray is not None
    if use_ray:
        require_ray()
    settings = RunSettings(dataset, out_dir, tracker, load_config(config, config_class(tracker)), gate=gate,
                           goal=goal_, record=record, record_if=failing)
    todo = plan(settings)
    n_workers, note = worker_count(jobs, len(todo.todo), use_ray, flag="--jobs", items_are="the clips to run")
    if note and todo.todo:
        err.print(f"wfviz: note: {note}", highlight=False, markup=False, soft_wrap=True)
    if todo.changed:
        err.print(f"wfviz: note: {todo.changed} clips done with another tracker, configuration or gate are run again",
                  highlight=False, markup=False, soft_wrap=True)
    if todo.dropped:
        err.print(f"wfviz: note: {todo.dropped} rows of clips no longer in {display(dataset)} dropped from results.csv",
                  highlight=False, markup=False, soft_wrap=True)
    kept = len(todo.kept)
    if kept:
        err.print(f"wfviz: note: {kept} of {len(todo.clips)} clips already done (results.csv): skipped",
                  highlight=False, markup=False, soft_wrap=True)
    with _progress("{task.fields[summary]}") as progress:
        task = progress.add_task("clips", total=len(todo.clips), completed=kept, summary="")
        count = [kept]

        def on_row(row, totals) -> None:
            count[0] += 1
            progress.update(task, completed=count[0], summary=escape(running(totals, goal_)))
            for n in row.notes:
                progress.console.print(f"wfviz: note: {display(row.label)}: {display(n)}", highlight=False,
                                       markup=False, soft_wrap=True)
            if not err.is_terminal or not row.ok:
                s = row.scores
                what = (f"Pd {s['pd']:.3f}, FA/frame {s['fa_per_frame']:.3f}" if row.scored and "pd" in s
                        else row.status if not row.ok else "tracked (no truth)")
                progress.console.print(f"wfviz: [{count[0]}/{len(todo.clips)}] {display(row.label)}: {display(what)} "
                                       f"({row.frames} frames, {row.seconds:.1f} s)", highlight=False,
                                       markup=False, soft_wrap=True)

        result = execute(settings, workers=n_workers, use_ray=use_ray,
                         ray_address=None if ray in (None, "", "local") else ray, on_row=on_row)
    how = (f"[yellow]interrupted by {signal.Signals(result.signal).name}[/]" if result.signal is not None
           else "done")
    out.print(f"{how}: {result.ran} clips run, {len(todo.clips) - len(result.rows)} not run"
              if result.signal is not None else f"{how}: {len(result.rows)} clips", highlight=False)
    out.print(format_totals(result.totals, goal_, result.wall, result.ran), highlight=False, markup=False)
    failed = [r for r in result.rows if not r.ok]
    for r in failed[:10]:
        out.print(f"  failed: {r.label}: {r.status.removeprefix('failed: ')}", highlight=False, markup=False)
    recs = [r for r in result.rows if r.recording]
    if recs:
        out.print(f"  recordings: {len(recs)} in {out_dir / 'recordings'}", highlight=False, markup=False)
    for f in result.files:
        out.print(f"  {f.name:<12} {f}", highlight=False, markup=False)
    if result.signal is not None:
        out.print("  the same command resumes the run", highlight=False, markup=False)
        raise typer.Exit(128 + result.signal)


@app.command()
@_guarded
def compare(
    clip: ClipArg,
    run_specs: Annotated[Optional[list[str]], typer.Option("--run", metavar="<run>", help="A run: NAME (a tracker with its defaults), NAME:CONFIG.toml or LABEL=NAME:CONFIG.toml (repeat; at least two runs in all).", show_default=False)] = None,
    study: Annotated[Optional[Path], typer.Option("--study", help="A `wfviz tune` study folder: its --top best trials and the defaults are runs too.")] = None,
    top: Annotated[int, typer.Option("--top", min=1, help="With --study: how many of its best trials.")] = 3,
    output: Annotated[Optional[Path], typer.Option("-o", "--output", help="Recording (.rrd; default recordings/<clip>-compare.rrd); each run's tracks CSV goes beside it as <stem>-<label>.csv.")] = None,
    truth: Annotated[Optional[Path], typer.Option("--truth", help="Truth CSV: score every run, mark where they differ against truth (a synth: clip brings its own).")] = None,
    start: StartOpt = 0,
    stop: StopOpt = None,
    fps: FpsOpt = None,
    image_every: ImageEveryOpt = 1,
    no_images: NoImagesOpt = False,
    exact_every: ExactEveryOpt = EXACT_EVERY,
    jpeg_quality: JpegOpt = PREVIEW_QUALITY,
    gate: GateOpt = 3.0,
    explain: Annotated[bool, typer.Option("--explain", help="With truth: also write each run's cause of every truth point in every frame beside the recording as <stem>-<label>-explain.csv (frame,target_id,cause,detail,significance,det_dist,track_id) and of every false confirmed track point as <stem>-<label>-explain-false.csv (docs/debugging.md). Where each run's Pd went is printed whenever there is truth.")] = False,
    skip_bad_frames: Annotated[bool, typer.Option("--skip-bad-frames", help="Skip undecodable images or video frames (warned) instead of stopping.")] = False,
    nan_as_zero: NanOpt = False,
) -> None:
    """Several trackers or configurations on one clip, in one recording on one timeline, with the frames where they disagree marked and, with truth, where each run's Pd went."""
    from wfviz.io.clip import open_clip

    from wfviz.compare import check_fit, check_labels, format_summary, parse_run, study_runs
    from wfviz.compare.session import compare as run_compare

    runs = [parse_run(s) for s in run_specs or []]
    if study is not None:
        if not study.is_dir():
            raise ValueError(f"--study {study}: no such folder")
        runs += study_runs(study, top)
    check_labels(runs)
    truth_points = _read_truth(truth)
    source = open_clip(clip, fps=fps, skip_bad_frames=skip_bad_frames, nan_as_zero=nan_as_zero)
    own_truth = truth_points is None and hasattr(source, "truth_points")
    if own_truth:
        truth_points = source.truth_points()
    if explain and truth_points is None:
        raise ValueError("--explain: needs truth (--truth FILE, or a synth: clip, which brings its own)")
    output = output or Path("recordings") / f"{source.name}-compare.rrd"
    csvs = [output.with_name(f"{output.stem}-{r.label}.csv") for r in runs]
    whys: list[Path | None] = [output.with_name(f"{output.stem}-{r.label}-explain.csv") if explain else None
                               for r in runs]
    configs = tuple((Path(s.split(":", 1)[1]), "a --run config file") for s in run_specs or [] if ":" in s)
    studied = tuple((f, f"a file of the study {study}") for f in (study.rglob("*") if study else ()) if f.is_file())
    check_fit(source.shape, str(source.path or source.name), runs)  # refused before a folder is touched
    _guard_outputs(output, *csvs, *(f for p in whys for f in _explain_files(p)), clip=source,
                   inputs=((truth, "the truth file"), *configs, *studied))
    total = source.n_frames
    if total is not None:
        total = max(0, min(total, stop if stop is not None else total) - start)
    with _progress() as progress:
        task = progress.add_task(escape(f"{source.name}: {len(runs)} runs"), total=total)
        options = RecorderOptions(source=str(clip), image_every=0 if no_images else image_every,
                                  exact_every=exact_every, jpeg_quality=jpeg_quality)
        summary = run_compare(source, runs, recording=output, tracks=csvs, truth=truth_points, gate=gate,
                              options=options, start=start, stop=stop, explain=whys,
                              on_frame=lambda n: progress.update(task, completed=n))
    state = (f"[yellow]interrupted by {signal.Signals(summary.signal).name}[/]" if summary.signal else "done")
    out.print(f"{state}: {len(runs)} runs over {summary.frames} frames in {summary.seconds:.2f} s"
              + (" (truth: the synthetic clip's own)" if own_truth else ""), highlight=False)
    out.print(format_summary(summary), highlight=False, markup=False)
    for r in summary.runs:
        out.print(f"  tracks {r.label}: {r.tracks_csv}", highlight=False, markup=False)
    for r in summary.runs:
        if r.explain_csv is not None:
            from wfviz.explain.report import false_path

            out.print(f"  explain {r.label}: {r.explain_csv}, {false_path(r.explain_csv)}", highlight=False,
                      markup=False)
    out.print(f"  recording: {output}\n  open it:   rerun {output}", highlight=False, markup=False)
    if summary.signal:
        raise typer.Exit(128 + summary.signal)


@app.command("config")
def show_config(tracker: TrackerOpt = "gewc") -> None:
    """Print the default configuration as TOML (edit it and pass it with --config)."""
    if tracker not in TRACKERS:
        _fail(f"unknown tracker '{tracker}' (available: {', '.join(TRACKERS)})")
    from wfviz.config import config_to_toml

    sys.stdout.write(config_to_toml(config_class(tracker)()))


def _ray_flag(argv: list[str]) -> list[str]:
    """``wfviz tune|run ... --ray`` without an address: a local Ray (the option takes a value)."""
    import re

    out = list(argv)
    for i, a in enumerate(out):
        if a == "--ray":
            nxt = out[i + 1] if i + 1 < len(out) else None
            if nxt is None or not re.fullmatch(r"auto|local|ray://\S+|[\w.\-]+:\d+", nxt):
                out.insert(i + 1, "local")
            break
    return out


def main() -> None:
    """Console-script entry point."""
    if ("tune" in sys.argv[1:3] or "run" in sys.argv[1:3]) and "--ray" in sys.argv:
        sys.argv[:] = _ray_flag(sys.argv)
    app()


if __name__ == "__main__":
    main()
