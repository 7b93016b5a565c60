"""The shape of vibro's code that ruff does not watch (issue 37): no function in src/ over 100 lines, few calls
with 8 or more positional arguments, and results.json assembled in one place.

ruff watches the rest (pyproject.toml: C901 complexity <= 15, PLR0913 at most 8 parameters). A long function
and a call whose meaning hangs on the order of eight arguments are where a newcomer gets lost and where a
swapped argument passes silently. Read from the sources (ast), not by importing them.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
MAX_FUNCTION_LINES = 100
#: calls with this many positional arguments or more are counted ...
MANY_POSITIONAL = 8
#: ... and at most this many may remain (issue 37's bound)
MAX_MANY_POSITIONAL_CALLS = 10
#: numba nopython kernels take arrays, not records: their calls are exempt
KERNEL_MODULE_NAMES = ("kernels",)


@functools.cache
def _sources() -> tuple[tuple[Path, ast.Module], ...]:
    """Every source file of src/ parsed, once per test process (the counters only read the trees)."""
    return tuple((p, ast.parse(p.read_text(encoding="utf-8"))) for p in sorted(SRC.glob("vibro_*/**/*.py"))
                 if "__pycache__" not in p.parts)


def long_functions(sources: list[tuple[Path, ast.Module]], max_lines: int = MAX_FUNCTION_LINES) -> list[str]:
    """'file:line name (n lines)' of every function or method longer than ``max_lines``."""
    out = []
    for path, tree in sources:
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > max_lines:
                    out.append(f"{path.relative_to(SRC)}:{node.lineno} {node.name} ({n} lines)")
    return out


def many_positional_calls(sources: list[tuple[Path, ast.Module]], minimum: int = MANY_POSITIONAL) -> list[str]:
    """'file:line callee (n)' of every call with at least ``minimum`` positional arguments, kernels excepted."""
    out = []
    for path, tree in sources:
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call) or len(node.args) < minimum:
                continue
            callee = ast.unparse(node.func)
            if callee.split(".")[0] in KERNEL_MODULE_NAMES:
                continue
            out.append(f"{path.relative_to(SRC)}:{node.lineno} {callee} ({len(node.args)})")
    return out


def test_the_counters_see_what_they_count() -> None:
    code = ("def f():\n" + "    x = 1\n" * 100 + "\n\ndef g():\n" + "    x = 1\n" * 99
            + "h(1, 2, 3, 4, 5, 6, 7, 8)\nh(1, 2, 3, 4, 5, 6, 7)\nkernels.k(1, 2, 3, 4, 5, 6, 7, 8)\n")
    sources = [(SRC / "vibro_x" / "m.py", ast.parse(code))]
    assert long_functions(sources) == ["vibro_x/m.py:1 f (101 lines)"]
    assert many_positional_calls(sources) == ["vibro_x/m.py:204 h (8)"]
    assert len(_sources()) > 100


def test_no_function_in_src_is_over_100_lines() -> None:
    assert long_functions(_sources()) == []


def test_calls_with_eight_or_more_positional_arguments_are_few() -> None:
    calls = many_positional_calls(_sources())
    assert len(calls) <= MAX_MANY_POSITIONAL_CALLS, "\n".join(calls)


def test_results_json_is_assembled_in_one_place() -> None:
    """ResultsDocument.build is called by the assembler alone (vibro_model.assemble): every path to results.json
    (analyze, fit, results from a bag, replay, the fitter's final pass, the discrepancy node) goes through it."""
    callers = []
    for path, tree in _sources():
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "build"
                    and ast.unparse(node.func).endswith("ResultsDocument.build")):
                callers.append(str(path.relative_to(SRC)))
    assert callers == ["vibro_model/vibro_model/assemble.py"]
