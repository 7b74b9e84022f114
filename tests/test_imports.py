"""The import graph of ``wfviz``: no cycles, and the lowest layers import nothing above them.

Every ``import`` statement counts, at module level or inside a function (an import deferred
into a function still ties the layers together), except those under ``if TYPE_CHECKING:``.
Importing ``a.b.c`` runs ``a/__init__`` and ``a/b/__init__`` first, so an import is an edge to
the module and to each package above it (except the packages the importer is itself inside,
which are already being imported)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _modules() -> dict[str, Path]:
    out = {}
    for f in sorted((ROOT / "wfviz").rglob("*.py")):
        parts = list(f.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = f
    return out


def _imported(node: ast.Import | ast.ImportFrom, package: str, modules: dict[str, Path]) -> list[str]:
    """The names ``node`` imports (absolute; ``from pkg import mod`` is the module when it is one)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:
        parts = package.split(".")[: len(package.split(".")) - node.level + 1]
        base = ".".join(parts + ([base] if base else []))
    return [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]


class _Imports(ast.NodeVisitor):
    def __init__(self) -> None:
        self.nodes: list[ast.Import | ast.ImportFrom] = []

    def visit_If(self, node: ast.If) -> None:
        test = node.test
        if (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
                isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"):
            for n in node.orelse:
                self.visit(n)
            return
        self.generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        self.nodes.append(node)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        self.nodes.append(node)


def import_graph() -> dict[str, set[str]]:
    """wfviz module -> the wfviz modules and packages importing it runs."""
    modules = _modules()
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for m, path in modules.items():
        package = m if path.name == "__init__.py" else m.rpartition(".")[0]
        visitor = _Imports()
        visitor.visit(ast.parse(path.read_text(encoding="utf-8"), str(path)))
        for node in visitor.nodes:
            for name in _imported(node, package, modules):
                parts = name.split(".")
                for k in range(1, len(parts) + 1):
                    target = ".".join(parts[:k])
                    if target in modules and target != m and not m.startswith(target + "."):
                        graph[m].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_checker_finds_a_cycle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_inside_wfviz() -> None:
    graph = import_graph()
    assert len(graph) > 50 and "wfviz.io.clip" in graph["wfviz.io.outputs"]  # the graph was read
    found = cycles(graph)
    detail = "\n".join(" -> ".join(c) + "\n  " + "\n  ".join(f"{m} imports {sorted(graph[m] & set(c))}" for m in c)
                       for c in found)
    assert not found, f"import cycles inside wfviz:\n{detail}"


def test_the_lowest_layers_import_nothing_above_them() -> None:
    """``wfviz.io`` (reading clips, writing files) imports only ``wfviz.io``; ``wfviz.config``,
    ``wfviz.hota`` and ``wfviz.record_options`` import no other wfviz module, ``wfviz.evaluate``
    only the HOTA metric beside it (clip sources such as ``synth:`` register themselves from
    above, the tracks CSV writer lives with the sinks)."""
    graph = import_graph()
    for m, targets in graph.items():
        if m.startswith("wfviz.io."):
            assert all(t == "wfviz" or t.startswith("wfviz.io") for t in targets), (m, targets)
    for m in ("wfviz.config", "wfviz.hota", "wfviz.record_options"):
        assert graph[m] <= {"wfviz"}, (m, graph[m])
    assert graph["wfviz.evaluate"] <= {"wfviz", "wfviz.hota"}, graph["wfviz.evaluate"]


_LOADED = """
import atexit, sys
def _dump():
    sys.__stderr__.write("\\nMODULES " + " ".join(sorted(sys.modules)) + "\\n")
atexit.register(_dump)
sys.argv = ["wfviz", *sys.argv[1:]]
from wfviz.entry import main
main()
"""


def _modules_after(*args: str, cwd: Path, top: bool = True) -> set[str]:
    """The modules a whole ``wfviz ARGS`` process had imported when it ended (``top``: their
    top-level packages only)."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _LOADED, *args], capture_output=True, text=True, cwd=cwd,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, timeout=120)
    assert r.returncode == 0, r.stderr
    line = [ln for ln in r.stderr.splitlines() if ln.startswith("MODULES ")][-1]
    return {m.split(".")[0] if top else m for m in line.split()[1:]}


def test_help_and_track_import_no_heavy_packages(tmp_path: Path) -> None:
    """`wfviz --help` imports no numpy; `wfviz track` (GEWC, the default) imports neither Rerun nor
    pandas, Optuna, matplotlib, SciPy, nor pydantic (their import is most of a short run's start-up:
    docs/performance.md; typer 0.29 converts every argument with pydantic, hence the pin below
    0.29 in pyproject.toml), even once tracks are gated and confirmed."""
    import csv

    import numpy as np

    heavy = {"rerun", "pandas", "optuna", "matplotlib", "motmetrics", "pyarrow", "scipy", "pydantic"}
    help_mods = _modules_after("--help", cwd=tmp_path)
    assert not help_mods & (heavy | {"numpy", "cv2"}), help_mods & (heavy | {"numpy", "cv2"})
    rng = np.random.default_rng(0)
    frames = 1000 + rng.normal(0, 10, (30, 128, 160))
    yy, xx = np.mgrid[:128, :160]
    for k, frame in enumerate(frames):  # a target crossing the frame
        frame += 400 * np.exp(-((xx - 30 - 3 * k) ** 2 + (yy - 60 - k) ** 2) / 2.0)
    np.save(tmp_path / "clip.npy", frames.astype(np.uint16))
    track_mods = _modules_after("track", "clip.npy", "--tracks", "t.csv", cwd=tmp_path, top=False)
    track_mods |= {m.split(".")[0] for m in track_mods}
    with open(tmp_path / "t.csv", newline="") as f:
        confirmed = [r for r in csv.DictReader(f) if r["confirmed"] == "1"]
    assert "numpy" in track_mods and confirmed  # the check can see what it looks for
    assert not track_mods & heavy, track_mods & heavy
    # without truth nothing is scored or explained: neither is imported
    scoring = {"wfviz.evaluate", "wfviz.hota", "wfviz.explain"}
    assert not track_mods & scoring, track_mods & scoring
    np.savetxt(tmp_path / "truth.csv", [(k, 1, 30 + 3 * k, 60 + k) for k in range(30)], delimiter=",",
               header="frame,target_id,x,y", comments="", fmt="%g")
    scored = _modules_after("track", "clip.npy", "--truth", "truth.csv", cwd=tmp_path, top=False)
    assert scoring <= scored, scoring - scored  # with truth they are


def test_record_imports_no_pandas(tmp_path: Path) -> None:
    """`wfviz record` without truth does not import pandas (pyarrow would at its first conversion
    of a Python value: :func:`wfviz.record.arrow.arrow_without_pandas`); importing
    :mod:`wfviz.record` as a library leaves pyarrow's view of pandas alone; and after the probe
    pyarrow still converts to and from pandas once something imports it."""
    import subprocess
    import sys

    import numpy as np

    rng = np.random.default_rng(1)
    np.save(tmp_path / "clip.npy", (1000 + rng.normal(0, 10, (6, 64, 80))).astype(np.uint16))
    mods = _modules_after("record", "clip.npy", "--output", "c.rrd", cwd=tmp_path)
    assert "rerun" in mods and "pyarrow" in mods  # the check can see what it looks for
    assert "pandas" not in mods
    assert (tmp_path / "c.rrd").stat().st_size > 0

    def run(code: str) -> str:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                           env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
        assert r.returncode == 0, r.stderr
        return r.stdout.split()[-1]

    # a library import probes nothing: pyarrow still finds pandas
    assert run("import wfviz.record, pyarrow.lib as L; print(L._pandas_api.have_pandas)") == "True"
    # after the probe: no pandas for the soft check, and the conversions that need it still work
    assert run("from wfviz.record.arrow import arrow_without_pandas as a; a(); import sys, pyarrow as pa, "
               "pyarrow.lib as L; assert not L._pandas_api.have_pandas and 'pandas' not in sys.modules; "
               "import pandas as pd; assert pa.table({'a': [1, 2]}).to_pandas()['a'].tolist() == [1, 2]; "
               "assert pa.array(pd.Series([3.0, 4.0])).to_pylist() == [3.0, 4.0]; print('ok')") == "ok"
