"""Static checks of the package's shape, read with ``ast`` (nothing is imported).

Layers import only downward: core -> sim -> identification -> data -> model -> inference ->
training -> evaluation -> control -> reporting / tuning -> reproduction (which drives the others
to make the paper's tables and report), with the command doors and the predictor on top. No
import cycle between modules or between packages; no file or function egregiously long.

Sizes are smells to look at, never a reason to split cohesive code or move a method out of its
class (DESIGN.md): the limits catch only what is really too long, and classes have none.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "robomorph"
# Rank of each room: a module imports its own room and rooms of lower rank only.
RANKS = {"core": 0, "sim": 1, "identification": 2, "data": 3, "model": 4, "inference": 5, "training": 6,
         "evaluation": 7, "control": 8, "reporting": 9, "tuning": 9, "reproduction": 10}
TOP = 11  # doors (robomorph/<command>.py), predictor.py, cli.py, __init__.py, __main__.py
MAX_FILE_LINES, MAX_FUNCTION_LINES = 800, 120
TORCH_LIBS = ("torch", "lightning")


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def _imports(path: Path) -> set[str]:
    """Modules of the package and third-party top-level names that ``path`` imports (anywhere in it)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            # ``from robomorph.data import store``: the submodule is the import.
            found.update(f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in MODULES)
    return found


def _internal(path: Path) -> set[str]:
    return {m for m in _imports(path) if m in MODULES and m != "robomorph"}


def _room(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in RANKS else None


def _rank(module: str) -> int:
    room = _room(module)
    return RANKS[room] if room else TOP


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of nodes, or None (iterative three-colour DFS)."""
    colour = dict.fromkeys(graph, 0)
    for root in graph:
        if colour[root]:
            continue
        stack, path = [(root, iter(sorted(graph[root])))], [root]
        colour[root] = 1
        while stack:
            node, children = stack[-1]
            child = next(children, None)
            if child is None:
                colour[node] = 2
                stack.pop()
                path.pop()
            elif colour.get(child, 2) == 1:
                return path[path.index(child):] + [child]
            elif colour.get(child) == 0:
                colour[child] = 1
                stack.append((child, iter(sorted(graph[child]))))
                path.append(child)
    return None


def test_cycle_finder_finds_a_cycle_and_accepts_a_tree():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_between_modules():
    graph = {m: _internal(p) - {m} for m, p in MODULES.items()}
    assert _cycle(graph) is None


def test_no_import_cycle_between_rooms():
    graph: dict[str, set[str]] = {room: set() for room in RANKS}
    for module, path in MODULES.items():
        room = _room(module)
        if room:
            graph[room] |= {r for r in map(_room, _internal(path)) if r and r != room}
    assert _cycle(graph) is None


@pytest.mark.parametrize("module", sorted(MODULES))
def test_layers_import_only_downward(module):
    upward = sorted(m for m in _internal(MODULES[module])
                    if _rank(m) > _rank(module) or (_rank(m) == _rank(module) < TOP and _room(m) != _room(module)))
    assert not upward, f"{module} imports {upward}, which sit above it (or beside it) in the layers"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _room(m) == "core"))
def test_core_imports_no_torch(module):
    heavy = sorted(m for m in _imports(MODULES[module]) if m.split(".")[0] in TORCH_LIBS)
    assert not heavy, f"{module} imports {heavy}; core stays torch-free"


def _too_long(path: Path) -> list[str]:
    """``kind name: n lines`` for each function past the limit."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        limit = MAX_FUNCTION_LINES if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) else None
        if limit is not None:
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            n = node.end_lineno - start + 1
            if n > limit:
                out.append(f"{type(node).__name__} {node.name}: {n} lines (limit {limit})")
    return out


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_file_or_function_is_egregiously_long(module):
    path = MODULES[module]
    n = len(path.read_text().splitlines())
    assert n <= MAX_FILE_LINES, f"{path.name}: {n} lines (limit {MAX_FILE_LINES})"
    assert not _too_long(path), f"{module}: {_too_long(path)}"


def test_limits_are_measured_on_real_code(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    long = tmp_path / "long.py"
    long.write_text(f"def f():\n{body}\n")
    assert _too_long(long) == [f"FunctionDef f: {MAX_FUNCTION_LINES + 1} lines (limit {MAX_FUNCTION_LINES})"]


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _room(m) in ("model", "inference"))
                         + ["robomorph.predictor"])
def test_inference_needs_no_training_code(module):
    # A deployed model ships robomorph/inference/, model/ and core/; the hybrid's physics (imported
    # only when a hybrid predicts) needs identification/, sim/ and MuJoCo as well. Never training,
    # data or evaluation code.
    allowed = {"model": ("model", "core"), "inference": ("inference", "model", "identification", "sim", "core")}
    outside = sorted(m for m in _internal(MODULES[module])
                     if _room(m) not in allowed.get(_room(module), ("inference", "model", "core")))
    assert not outside, f"{module} imports {outside}"


def _module_functions_taking_self(path: Path) -> list[str]:
    """Module-level functions whose first parameter is ``self``: methods that left their class."""
    tree = ast.parse(path.read_text())
    return [f"{node.name} (line {node.lineno})" for node in tree.body
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.args.args
            and node.args.args[0].arg == "self"]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_function_takes_self(module):
    found = _module_functions_taking_self(MODULES[module])
    assert not found, f"{module}: {found} take self; a method belongs in its class"


def test_the_self_check_finds_a_method_outside_its_class(tmp_path):
    path = tmp_path / "m.py"
    path.write_text("class A:\n    def ok(self):\n        pass\n\n\ndef stray(self, x):\n    return x\n")
    assert _module_functions_taking_self(path) == ["stray (line 6)"]


def _private_reaches(path: Path) -> list[str]:
    """``x._name`` where ``x`` is not ``self`` or ``cls``: one object reading another's (or a module's) private
    parts. A line may keep one with ``# private: <why>``."""
    text = path.read_text()
    lines = text.splitlines()
    found = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
                continue
            if "# private:" not in lines[node.lineno - 1]:
                found.append(f"line {node.lineno}: {ast.unparse(node)}")
    return found


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_object_reads_anothers_private_parts(module):
    found = _private_reaches(MODULES[module])
    assert not found, f"{module} reads private parts of other objects: {found} (make them public, or say why)"


def test_the_private_check_finds_a_reach_and_accepts_a_reason(tmp_path):
    path = tmp_path / "m.py"
    path.write_text("def f(a):\n    return a._x + a._y  # private: a test of the reason\n\n\ndef g(b):\n    return b._z\n")
    assert _private_reaches(path) == ["line 6: b._z"]
