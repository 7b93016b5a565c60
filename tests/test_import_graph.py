"""No import loops among vibro's own modules, counting imports inside functions too.

A loop hidden in a function-level import (rig.yaml's reader importing the frame reader, which imports the rig
types) works until someone moves the import to the top of the file; then one of the two modules is half
initialised when the other reads it. The graph is read from the sources (ast), not by importing them.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def own_modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the Python packages under src/ (``pkg/pkg/...``)."""
    out = {}
    for path in SRC.glob("vibro_*/vibro_*/**/*.py"):
        if "__pycache__" in path.parts:
            continue
        parts = list(path.relative_to(SRC).parts[1:])
        name = ".".join(parts)[: -len(".py")]
        out[name.removesuffix(".__init__")] = path
    return out


def from_targets(node: ast.ImportFrom, package: list[str], modules: dict[str, Path]) -> tuple[str, set[str]]:
    """The module a ``from ... import`` statement reads (relative imports resolved) and the own modules it loads
    (``from pkg.mod import f`` -> pkg.mod, ``from pkg import mod`` -> pkg.mod)."""
    base = node.module or ""
    if node.level:
        base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
    return base, {f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names}


def imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Own modules that module ``name`` imports anywhere in its source (``from pkg.mod import f`` -> pkg.mod,
    ``from pkg import mod`` -> pkg.mod, relative imports resolved)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            found.update(from_targets(node, package, modules)[1])
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {m for m in found if m in modules and m != name}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[v] = min(low[v], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def test_the_cycle_finder_finds_a_loop() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_loops_among_vibros_modules() -> None:
    modules = own_modules()
    assert len(modules) > 100 and "vibro_io.rig" in modules and "vibro_io.frames" in modules
    graph = {name: imported(name, path, modules) for name, path in modules.items()}
    assert "vibro_io.frames_source" in graph["vibro_io.rig"]  # the reader is seen through its imports
    assert cycles(graph) == []


HEAVY_PACKAGES = frozenset({"rclpy", "matplotlib", "dask", "distributed", "foxglove_websocket", "cv2",
                            "scipy.optimize", "scipy.stats", "scipy.signal", "scipy.ndimage", "scipy.interpolate",
                            "scipy.integrate", "scipy.sparse", "scipy.spatial",
                            "numba", "rosbags", "mcap", "mcap_ros2", "pyMRAW", "pysindy", "sklearn", "tifffile",
                            "PIL", "launch", "launch_ros", "vibro_msgs", "rosbag2_py", "tqdm"})


def _package(module: str, names) -> str:
    """The third-party unit a statement loads: the top package, or scipy's subpackage (``from scipy import
    optimize`` and ``import scipy.optimize`` both load scipy.optimize)."""
    parts = module.split(".")
    if parts[0] != "scipy":
        return parts[0]
    if len(parts) > 1:
        return ".".join(parts[:2])
    return next((f"scipy.{a.name}" for a in names), "scipy")


def module_level_imports(name: str, path: Path, modules: dict[str, Path]) -> tuple[set[str], set[str]]:
    """(own modules, heavy third-party packages) that module ``name`` imports when it is imported: its
    statements outside functions and classes' methods (``if TYPE_CHECKING`` blocks excluded), plus its
    packages' ``__init__``."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    own, heavy = set(), set()

    def visit(statements: list[ast.stmt]) -> None:
        for node in statements:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse)
                continue
            if isinstance(node, ast.ImportFrom):
                base, targets = from_targets(node, package, modules)
                own.update(targets)
                heavy.add(_package(base, node.names))
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    own.add(alias.name)
                    heavy.add(_package(alias.name, ()))
            for field in ("body", "orelse", "finalbody", "handlers"):
                children = getattr(node, field, None)
                if isinstance(children, list) and not isinstance(node, ast.ClassDef | ast.FunctionDef):
                    visit([c for c in children if isinstance(c, ast.stmt)] or
                          [s for h in children if isinstance(h, ast.ExceptHandler) for s in h.body])
            if isinstance(node, ast.ClassDef):
                visit([s for s in node.body if not isinstance(s, (ast.FunctionDef, ast.AsyncFunctionDef))])

    visit(ast.parse(path.read_text(encoding="utf-8")).body)
    parents = {".".join(name.split(".")[:i]) for i in range(1, len(name.split(".")))}
    own |= {p for p in parents if p in modules}
    return {m for m in own if m in modules and m != name}, heavy & HEAVY_PACKAGES


def test_own_modules_are_imported_at_module_level_unless_that_spares_a_heavy_package() -> None:
    """A function-level import of one of vibro's modules is kept only where importing it at the top would load
    a heavy package (rclpy, matplotlib, dask, scipy, ...) that the importing module does not load already: the
    start-up of the CLI and of the nodes (tests/test_startup_imports.py) is what such an import protects."""
    modules = own_modules()
    direct = {name: module_level_imports(name, path, modules) for name, path in modules.items()}

    def heavy_closure(name: str) -> set[str]:
        seen, stack, heavy = set(), [name], set()
        while stack:
            m = stack.pop()
            if m in seen:
                continue
            seen.add(m)
            own, h = direct[m]
            heavy |= h
            stack.extend(own)
        return heavy

    needless = []
    for name, path in modules.items():
        for target in imported(name, path, modules) - direct[name][0]:
            if not heavy_closure(target) - heavy_closure(name):
                needless.append(f"{path.relative_to(SRC)}: {target}")
    assert needless == [], "\n".join(sorted(needless))
