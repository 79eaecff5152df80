"""The package's shape: no import cycle between gsjax's modules, the core imports neither the shell nor a reader, no
module over 400 lines of code (issue 38; docstrings aside, issue 40), at most four modules at the top level (issue
48). Module-level imports only (a function may import lazily what it alone needs)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "gsjax"
CORE = ("gsjax.raster", "gsjax.slam", "gsjax.camera", "gsjax.gaussians", "gsjax.frame", "gsjax.config")
SHELL_AND_READERS = ("gsjax.app", "gsjax.data", "gsjax.io", "gsjax.report", "gsjax.viewer")


def modules() -> dict[str, Path]:
    found = {}
    for path in ROOT.rglob("*.py"):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports(path: Path, known: dict[str, Path]) -> set[str]:
    """The gsjax modules ``path`` imports at module level (outside ``if TYPE_CHECKING:``)."""
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("gsjax"):
            names |= {f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in known else node.module
                      for a in node.names}
        elif isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.startswith("gsjax")}
    return {name for name in names if name in known}


def test_no_module_level_import_cycle():
    known = modules()
    graph = {name: imports(path, known) - {name} for name, path in known.items()}
    state: dict[str, int] = {}

    def visit(name: str, trail: list[str]) -> None:
        state[name] = 1
        for dep in sorted(graph[name]):
            assert state.get(dep) != 1, "import cycle: " + " -> ".join(trail[trail.index(dep):] + [name, dep]) \
                if dep in trail else f"import cycle through {name} -> {dep}"
            if dep not in state:
                visit(dep, trail + [name])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])
    assert len(graph) > 50  # the walk saw the package


def test_the_core_imports_neither_the_shell_nor_a_reader():
    known = modules()
    for name, path in known.items():
        if name.startswith(CORE):
            outside = sorted(dep for dep in imports(path, known) if dep.startswith(SHELL_AND_READERS))
            assert not outside, f"{name} imports {outside}"


def test_importing_the_core_loads_no_reader():
    """What ``import gsjax.slam`` loads, in a fresh process: no reader (``gsjax.data``, OpenCV, the bag libraries),
    nothing of the shell."""
    code = ("import sys, gsjax.slam, gsjax.raster; print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] "
            "in ('cv2', 'rosbags', 'pyrealsense2', 'orbax', 'matplotlib') or m.startswith(('gsjax.data', "
            "'gsjax.app', 'gsjax.io')))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert not loaded, loaded


def test_the_top_level_holds_at_most_four_modules():
    top = sorted(p.stem for p in ROOT.glob("*.py") if p.stem not in ("__init__", "__main__"))
    assert len(top) <= 4, top


def code_lines(path: Path) -> int:
    """The lines of ``path`` outside its module, class and function docstrings: those are the API reference (issue
    40, tests/test_docstrings.py), and a module's length is a measure of its code (a stage per module)."""
    text = path.read_text()
    docstrings: set[int] = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(getattr(first.value, "value", None), str):
                docstrings.update(range(first.lineno, (first.end_lineno or first.lineno) + 1))
    return len(text.splitlines()) - len(docstrings)


def test_no_module_is_over_400_lines():
    long = {name: n for name, path in modules().items() if (n := code_lines(path)) > 400}
    assert not long, long


def test_poses_are_inverted_through_gsjax_camera():
    """No matrix inverse of a pose outside ``gsjax.camera`` (``invert_transform``, ``se3_inverse_np``, ``se3_inverse``
    say which inverse is meant)."""
    offenders = [name for name, path in modules().items()
                 if name != "gsjax.camera" and "linalg.inv(" in path.read_text()]
    assert not offenders, offenders
