"""The package's shape: no import cycles, and imports that point down the layers.

Every ``import`` statement of every module is read (also those inside functions, which a
runtime check would miss), so a cycle hidden behind a lazy import fails here too.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "cvxid"

LAYERS = [
    {"errors", "progress", "metrics", "plots", "parallel"},
    {"data"},
    {"model"},
    {"simulate", "initial_state"},
    {"regression"},
    {"identified", "export"},
    {"identify"},
    {"diagnosis"},
    {"spec"},
    {"app", "tools"},
]
"""Layers from the bottom up: a module may import its own layer's modules and those below."""


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Modules of the package that ``path`` imports (absolute or relative, at any depth)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = module_name(path).split(".")
    if path.name != "__init__.py":
        here = here[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("cvxid")}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(here[: len(here) - node.level + 1] + ([base] if base else []))
            if base.startswith("cvxid"):
                found.add(base)
                found |= {f"{base}.{a.name}" for a in node.names}
    return found


def graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    edges = {}
    for name, path in modules.items():
        edges[name] = {m for m in imports_of(path) if m in modules and m != name and not name.startswith(m + ".")}
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def layer(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) < 2:
        return None  # the package itself: its __init__ is the public API
    for i, names in enumerate(LAYERS):
        if parts[1] in names:
            return i
    raise AssertionError(f"module {module} is in no layer: add it to LAYERS in {__file__}")


def test_the_import_graph_sees_lazy_imports():
    edges = graph()
    assert "cvxid.identify.problem" in edges["cvxid.identify.path"]  # a module-level import
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]


def test_no_import_cycles():
    found = cycles(graph())
    assert not found, f"import cycles: {found}"


@pytest.mark.parametrize("module", sorted(graph()))
def test_imports_point_down_the_layers(module):
    mine = layer(module)
    if mine is None:
        return
    upward = [m for m in graph()[module] if layer(m) is not None and layer(m) > mine]
    assert not upward, f"{module} (layer {mine}) imports from higher layers: {upward}"


def test_pyproject_lists_every_subpackage():
    """The package list is explicit (problems/ installs as cvxid.problems): a new subpackage
    missing from it would be left out of every installed copy."""
    from cvxid.spec.toml import tomllib

    config = tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = {module_name(p.parent / "__init__.py") for p in PACKAGE.rglob("__init__.py")} | {"cvxid.problems"}
    assert set(config["packages"]) == found
    assert config["package-dir"] == {"cvxid.problems": "problems"}
