"""The shape of fastrl's code: short functions, no import cycles, nothing done at import.

These read the source with ``ast`` (no JAX), except the import check, which imports fastrl in a
fresh process and compares its environment before and after.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "fastrl"
MAX_LINES = 80
# Functions allowed over the limit while they wait to be split: none now. Every function in fastrl/
# must stay within MAX_LINES.
LONG_FOR_NOW: set[tuple[str, str]] = set()
# PEP 562 lazy attributes, the only function-local imports of fastrl modules, on purpose:
# ``fastrl.load_policy`` (importing fastrl.physics must not pull in the learners and orbax) and
# the Gymnasium adapter of fastrl.envs (importing gymnasium writes into os.environ).
LOCAL_IMPORT_OK = {("__init__.py", "__getattr__"), ("envs/__init__.py", "__getattr__")}


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _functions(tree: ast.AST):
    return [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]


def _imported(node: ast.Import | ast.ImportFrom, modules: dict[str, Path]) -> set[str]:
    """The fastrl modules an import statement loads (parent packages aside)."""
    if isinstance(node, ast.Import):
        return {a.name for a in node.names if a.name in modules}
    if node.level or not (node.module or "").startswith("fastrl"):
        return set()
    found = set()
    for alias in node.names:
        sub = f"{node.module}.{alias.name}"
        found.add(sub if sub in modules else node.module)
    return found


def test_no_function_in_fastrl_is_over_80_lines():
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        for fn in _functions(ast.parse(path.read_text())):
            lines = fn.end_lineno - fn.lineno + 1
            if lines > MAX_LINES and (rel, fn.name) not in LONG_FOR_NOW:
                long.append(f"{rel}:{fn.lineno} {fn.name} ({lines} lines)")
    assert not long, "functions over 80 lines:\n  " + "\n  ".join(long)


def test_no_function_local_imports_of_fastrl_modules():
    modules = _modules()
    local = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        for fn in _functions(ast.parse(path.read_text())):
            for node in ast.walk(fn):
                if isinstance(node, ast.Import | ast.ImportFrom) and _imported(node, modules):
                    if (rel, fn.name) not in LOCAL_IMPORT_OK:
                        local.append(f"{rel}:{node.lineno} in {fn.name}")
    assert not local, "function-local imports of fastrl modules:\n  " + "\n  ".join(local)


def test_no_import_cycles():
    """Imports between fastrl's modules, at module level or in functions, form no cycle (the
    lazy attributes of ``LOCAL_IMPORT_OK`` aside)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        rel = path.relative_to(PACKAGE).as_posix()
        tree = ast.parse(path.read_text())
        lazy = {id(n) for fn in _functions(tree) if (rel, fn.name) in LOCAL_IMPORT_OK for n in ast.walk(fn)}
        targets = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in lazy:
                targets |= _imported(node, modules)
        graph[name] = targets - {name}

    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt] if nxt in path else [*path, nxt]
            if nxt not in state and (cycle := visit(nxt, [*path, nxt])):
                return cycle
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start, [start])):
            pytest.fail("import cycle: " + " -> ".join(cycle))


_IMPORT_SCRIPT = """
import json, os
before = dict(os.environ)
import fastrl, fastrl.physics, fastrl.envs, fastrl.agents
changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))
print(json.dumps(changed))
"""


def test_importing_fastrl_leaves_the_environment_untouched():
    """``import fastrl`` (and fastrl.physics, fastrl.envs, fastrl.agents) sets no environment
    variable: XLA flags come only from the command line or ``fastrl.use_recommended_xla_flags()``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("XLA_", "FASTRL_"))}
    out = subprocess.run(
        [sys.executable, "-c", _IMPORT_SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
