"""The package's import layers, read from the source with ``ast`` (no import is run).

Layers, one way: ``_src`` (the core) <- ``io`` <- jobs (``batch``) <- ``cli``; ``research``
depends only on the core (and ``io`` where it reads files). Every import counts, also the ones
inside functions: a function-level import is still a dependency, only a deferred one.
"""

from __future__ import annotations

import ast
import functools
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "jaxdepth"

#: layer -> the layers it may import ("" is the root package, ``jaxdepth/__init__.py``, whose
#: names load lazily). ``options`` is the leaf module of command-line options that both
#: ``cli`` and ``research.cli`` use, ``progress`` the leaf module of their progress lines and job
#: summaries, ``interrupts`` the program's Ctrl-C handling; ``demo`` and ``cli`` sit on top and may
#: import anything.
ALLOWED = {
    "_src": {"_src", ""},
    "io": {"_src", "io", ""},
    "options": {"_src", ""},
    "progress": {""},
    "interrupts": {""},
    "batch": {"_src", "io", "batch", "research", ""},
    "research": {"_src", "io", "research", "options", "progress", ""},
}


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, pathlib.Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


MODULES = _modules()


def _resolve(module: str, path: pathlib.Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = package[: len(package) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


@functools.cache  # parsed when a test first asks (not while collecting), once per process
def _imports(module: str) -> tuple[tuple[str, str | None, int], ...]:
    """(imported jaxdepth module, imported name or None, line) of every import in ``module``."""
    path = MODULES[module]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, None, node.lineno) for alias in node.names if alias.name.startswith("jaxdepth")]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, path, node)
            if not target.startswith("jaxdepth"):
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:  # ``from jaxdepth.io import atomic``: the submodule itself
                    found.append((sub, None, node.lineno))
                else:
                    found.append((target, alias.name, node.lineno))
    return tuple(found)


def _owner(module: str) -> str:
    """The module a name like ``jaxdepth.io.rig.Rig`` comes from: the longest known module prefix."""
    parts = module.split(".")
    while parts and ".".join(parts) not in MODULES:
        parts.pop()
    return ".".join(parts)


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _package(module: str) -> str:
    """The package a module lives in (``jaxdepth.io.rig`` -> ``jaxdepth.io``; a package is its own)."""
    return module if MODULES[module].name == "__init__.py" else module.rpartition(".")[0]


@functools.cache
def _graph() -> dict[str, list[str]]:
    """module -> the jaxdepth modules it imports (built on first use: collecting needs only MODULES)."""
    return {m: sorted({_owner(t) for t, _, _ in _imports(m)} - {m, ""}) for m in MODULES}


def test_the_graph_sees_known_edges():
    # the oracle itself: edges that exist must be found (top level and inside functions)
    graph = _graph()
    assert "jaxdepth._src.pipeline" in graph["jaxdepth._src.rig"]
    assert "jaxdepth.io.errors" in graph["jaxdepth.cli"]
    assert any(t.startswith("jaxdepth.batch") for t in graph["jaxdepth.cli"])
    assert len(MODULES) > 40


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}) == [["a", "b", "c"]]
    assert _cycles({"a": ["b"], "b": []}) == []


def test_no_import_cycle_between_modules():
    # A package's __init__ re-exporting its submodules is not a cycle of concerns: the edge
    # submodule -> own package __init__ is left out (a submodule importing its package's
    # __init__ is its own package's business), every other edge counts.
    graph = {m: [t for t in targets if not (MODULES[t].name == "__init__.py" and m.startswith(t + "."))]
             for m, targets in _graph().items()}
    assert _cycles(graph) == []


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _layer(m) in ALLOWED))
def test_imports_point_one_way(module):
    layer = _layer(module)
    bad = [(target, line) for target, _, line in _imports(module) if _layer(_owner(target)) not in ALLOWED[layer]]
    assert bad == [], f"{module} ({layer}) imports a layer above it: {bad}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_private_name_across_packages(module):
    bad = []
    for target, name, line in _imports(module):
        owner = _owner(target)
        private = [part for part in target.split(".")[1:] + ([name] if name else [])
                   if part.startswith("_") and part not in ("_src", "__init__", "__version__")]
        if private and _package(owner) != _package(module):
            bad.append((target, name, line))
    assert bad == [], f"{module} imports private names of another package: {bad}"


def test_root_api_lists_each_public_name_once():
    """jaxdepth/__init__.py: the TYPE_CHECKING imports are the lazy table, name for name, and
    ``__all__`` is that table; ``import jaxdepth`` imports no JAX (checked in a fresh process)."""
    import subprocess
    import sys

    import jaxdepth

    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    guarded = next(node for node in tree.body if isinstance(node, ast.If)
                   and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING")
    typed: dict[str, list[str]] = {}
    for node in guarded.body:
        assert isinstance(node, ast.ImportFrom), ast.dump(node)
        for alias in node.names:
            assert alias.asname == alias.name, f"{alias.name} re-exported as {alias.asname}"
            typed.setdefault(node.module, []).append(alias.name)
    lazy = {module: sorted(names) for module, names in jaxdepth._LAZY.items()}
    assert {module: sorted(names) for module, names in typed.items()} == lazy
    names = [name for names in jaxdepth._LAZY.values() for name in names]
    assert len(names) == len(set(names))
    assert list(jaxdepth.__all__) == names
    code = "import sys, jaxdepth; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=PACKAGE.parent).stdout.strip()
    assert out == "False"
