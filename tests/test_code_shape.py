"""The shape of fastrl's code: short functions and modules, no import cycles, nothing done at import.

These read the source with ``ast`` (no JAX), except the import check, which imports fastrl in a
fresh process and compares its environment before and after.
"""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "fastrl"
# A function's length in lines, decorators aside (nested functions count in their parent too).
MAX_LINES = 60
# A module's length in lines.
MAX_MODULE_LINES = 500
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


def test_no_function_in_fastrl_is_over_60_lines():
    """Every function of fastrl/, the engine's included, has at most MAX_LINES lines."""
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        for fn in _functions(ast.parse(path.read_text())):
            lines = fn.end_lineno - fn.lineno + 1
            if lines > MAX_LINES:
                long.append(f"{rel}:{fn.lineno} {fn.name} ({lines} lines)")
    assert not long, f"functions over {MAX_LINES} lines:\n  " + "\n  ".join(long)


def test_no_module_in_fastrl_is_over_500_lines():
    """Every module of fastrl/, the engine's included, has at most MAX_MODULE_LINES lines."""
    over = []
    for path in sorted(PACKAGE.rglob("*.py")):
        n = len(path.read_text().splitlines())
        if n > MAX_MODULE_LINES:
            over.append(f"{path.relative_to(PACKAGE).as_posix()} ({n} lines)")
    assert not over, f"modules over {MAX_MODULE_LINES} lines:\n  " + "\n  ".join(over)


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


# One path per module: the training layer's modules are imported from ``fastrl.training`` only,
# the robot scenes' locator from ``fastrl.envs.robots.assets``, devices, XLA flags and the compile
# cache from ``fastrl.runtime``, the tools that look at runs (the scene summary and the learning
# curve among them) from ``fastrl.tools``, the training command line from ``fastrl.cli``.
# ``fastrl.train``, ``fastrl.evaluate`` and ``fastrl.report`` are the commands
# (``python -m fastrl.train``), never imported by code.
REMOVED_MODULES = {
    f"fastrl.{name}"
    for name in (
        *("runner", "checkpoint", "config", "policy", "scale", "train", "robot_scenes", "envs.robot_scenes"),
        *("devices", "xla_flags", "compile_cache"),
        *("evaluate", "report", "reference", "viewer", "physics.info", "training.curve", "training.train"),
    )
}
# The command-line entry points: file in fastrl/ -> the module whose ``main`` is the command.
ENTRY_POINTS = {
    "train.py": "fastrl.cli.train",
    "evaluate.py": "fastrl.tools.evaluate",
    "report.py": "fastrl.tools.report",
}
# A dotted name through a removed module, as mock.patch strings, docstrings and scripts spell it;
# a command's name followed by a dot and a name reaches into the module, alone it names the command.
REMOVED_DOTTED = re.compile(
    r"\bfastrl\.(?:(?:runner|checkpoint|config|policy|scale|robot_scenes|envs\.robot_scenes|devices|xla_flags"
    r"|compile_cache|reference|viewer|physics\.info|training\.curve|training\.train)\b|(?:train|evaluate|report)\.\w+)"
)


def _body(tree: ast.Module) -> list[ast.stmt]:
    """A module's statements without its docstring."""
    body = tree.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]
    return body


def _sets_all(node: ast.stmt) -> bool:
    if isinstance(node, ast.Assign):
        targets = node.targets
    elif isinstance(node, ast.AnnAssign | ast.AugAssign):
        targets = [node.target]
    else:
        return False
    return any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets)


def _reexports(tree: ast.Module) -> list[str]:
    """What makes a module a re-export: star imports, ``__all__`` imported from another module."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            names = {a.name for a in node.names}
            if "*" in names:
                found.append(f"line {node.lineno}: from {node.module} import *")
            if "__all__" in names:
                found.append(f"line {node.lineno}: imports __all__ from {node.module}")
    return found


def test_no_module_in_fastrl_is_a_reexport_shim():
    """No module is only imports, ``__all__`` and a docstring (package ``__init__.py`` files, which
    name their package's API, aside), and none re-exports with ``import *`` or a borrowed
    ``__all__``: each module has one import path."""
    shims = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        tree = ast.parse(path.read_text())
        shims += [f"{rel} {what}" for what in _reexports(tree)]
        body = _body(tree)
        if path.name == "__init__.py" or not body:
            continue
        if all(isinstance(n, ast.Import | ast.ImportFrom) or _sets_all(n) for n in body):
            shims.append(f"{rel}: only imports and __all__")
    assert not shims, "re-export shims in fastrl/:\n  " + "\n  ".join(shims)


@pytest.mark.parametrize("entry_point", sorted(ENTRY_POINTS))
def test_each_command_file_is_only_its_entry_point(entry_point):
    """``fastrl/train.py`` keeps ``python -m fastrl.train`` working and exports nothing: it imports
    ``main`` from ``fastrl.cli.train`` and runs it, with no ``__all__`` and no other name;
    ``fastrl/evaluate.py`` and ``fastrl/report.py`` do the same for ``fastrl.tools``."""
    body = [ast.unparse(n) for n in _body(ast.parse((PACKAGE / entry_point).read_text()))]
    assert body == [f"from {ENTRY_POINTS[entry_point]} import main", "if __name__ == '__main__':\n    main()"]


def _imports_in(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, module) for every module an import statement names, ``from fastrl import x``
    counted as ``fastrl.x`` too. Strings that are Python themselves (scripts run in a child
    process) are read as well, their lines counted from the string's."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.append((node.lineno, node.module))
            found += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and "fastrl" in node.value:
            try:
                inner = ast.parse(node.value)
            except SyntaxError:
                continue
            found += [(node.lineno + line - 1, name) for line, name in _imports_in(inner)]
    return found


def _files(top: str, pattern: str) -> list[Path]:
    """The files under ``ROOT/top`` matching ``pattern``, hidden folders (virtual envs) aside."""
    paths = sorted((ROOT / top).rglob(pattern))
    return [p for p in paths if not any(s.startswith(".") for s in p.relative_to(ROOT).parts)]


def _removed_names(path: Path) -> list[str]:
    """Where ``path`` imports a removed module or names a member through one."""
    rel, text = path.relative_to(ROOT).as_posix(), path.read_text()
    found = [
        f"{rel}:{text.count(chr(10), 0, m.start()) + 1} names {m.group()}"
        for m in REMOVED_DOTTED.finditer(text)
    ]
    if path.suffix == ".py":
        found += [f"{rel}:{n} imports {m}" for n, m in _imports_in(ast.parse(text)) if m in REMOVED_MODULES]
    return found


def test_nothing_imports_the_removed_module_paths():
    """No file in fastrl/, tests/ or experiments/ imports a removed module path
    (``REMOVED_MODULES``) or names a member through one (a mock.patch string through a path that
    no longer holds the code would patch nothing), and the docs and configs name none either."""
    paths = [*_files("fastrl", "*.py"), *_files("tests", "*.py"), *_files("experiments", "*.py")]
    paths += [ROOT / "README.md", *_files("docs", "*.md"), *_files("conf", "*.yaml")]
    found = [where for path in paths for where in _removed_names(path)]
    assert not found, "imports of removed module paths:\n  " + "\n  ".join(found)


# The layers, bottom up: a module imports from its own layer or those below, never above.
LAYERS = ("runtime", "physics", "envs", "agents", "training", "tools", "cli")
# Each package of fastrl/ is one layer. The command lines are ``fastrl.cli``, the entry points
# (``fastrl/train.py``...) and the package's ``__init__`` (its lazy ``load_policy``). A module in
# none of them fails the layer test, so a new package or top-level module is placed in a layer
# before it lands.
PACKAGE_LAYERS = {f"fastrl.{layer}": layer for layer in LAYERS}
COMMANDS = {"fastrl", *(f"fastrl.{Path(name).stem}" for name in ENTRY_POINTS)}


def _layer(module: str) -> str | None:
    """The layer a fastrl module belongs to, or None for a module no layer holds."""
    if module in COMMANDS:
        return "cli"
    return next(
        (layer for pkg, layer in PACKAGE_LAYERS.items() if module == pkg or module.startswith(pkg + ".")),
        None,
    )


def _layer_imports() -> list[tuple[str, int, str]]:
    """(importing module, line, imported module) for every import of a fastrl module, at module
    level, in functions (lazy attributes included) and under ``TYPE_CHECKING`` alike."""
    modules = _modules()
    found = []
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import | ast.ImportFrom):
                found += [(name, node.lineno, target) for target in sorted(_imported(node, modules))]
    return found


def test_every_module_of_fastrl_has_a_layer():
    unplaced = [name for name in _modules() if _layer(name) is None]
    assert not unplaced, f"modules in no layer of {LAYERS} (place them in PACKAGE_LAYERS):\n  " + "\n  ".join(
        unplaced
    )


def test_no_layer_imports_a_layer_above_it():
    """Imports run one way, runtime < physics < envs < agents < training < tools < cli: the engine
    knows no env, the runner no tool that looks at runs (those are callbacks the command line
    hands it)."""
    upward = [
        f"{name}:{line} ({_layer(name)}) imports {target} ({_layer(target)})"
        for name, line, target in _layer_imports()
        if None not in (_layer(name), _layer(target))
        and LAYERS.index(_layer(target)) > LAYERS.index(_layer(name))
    ]
    assert not upward, "imports of a higher layer:\n  " + "\n  ".join(upward)
