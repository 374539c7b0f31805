"""No import circle among thinkfast's modules (docs/ARCHITECTURE.md: the layers import downwards
only, and so do the modules of a layer), not even one closed by an import inside a function or
under ``TYPE_CHECKING``.

pyproject.toml's ``acyclic_siblings`` contract (``lint-imports``) finds cycles between the
siblings of each package, a subpackage counted as one; this test finds them between single
modules, a package's ``__init__`` among them, on grimp's graph (which holds the imports inside
functions and under ``TYPE_CHECKING``) joined with the imports the source's syntax tree names
(any import statement anywhere in a module), so that no import the graph left out can close one.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "thinkfast"


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _syntax_imports(path: Path, modules: set[str]) -> set[str]:
    """The thinkfast modules that ``path`` imports anywhere (module level, functions,
    ``if TYPE_CHECKING:``): for ``from a.b import c`` the module ``a.b.c`` if it is one, else
    ``a.b``."""
    name = _module(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names
            ]
        else:
            continue
        for t in targets:
            while t and t not in modules:  # an attribute of a module: the module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def import_graph() -> dict[str, set[str]]:
    """importer -> the thinkfast modules it imports, grimp's edges and the syntax tree's."""
    import grimp

    graph = grimp.build_graph("thinkfast", include_external_packages=False, cache_dir=None)
    modules = set(graph.modules)
    edges = {m: set(graph.find_modules_directly_imported_by(m)) for m in modules}
    for path in ROOT.rglob("*.py"):
        edges.setdefault(_module(path), set()).update(_syntax_imports(path, modules))
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def _path(edges: dict[str, set[str]], comp: list[str]) -> str:
    """One circle through the component, as ``a -> b -> a``."""
    members, start = set(comp), comp[0]
    seen, trail = {start: None}, [start]
    while trail:  # breadth first from start, back to start
        nxt = []
        for v in trail:
            for w in sorted(edges[v] & members):
                if w == start:
                    hops = [v]
                    while seen[hops[-1]] is not None:
                        hops.append(seen[hops[-1]])
                    return " -> ".join([*reversed(hops), start])
                if w not in seen:
                    seen[w] = v
                    nxt.append(w)
        trail = nxt
    return " <-> ".join(comp)


def test_cycles_finds_a_circle_and_names_it():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(edges) == [["a", "b", "c"]]
    assert _path(edges, ["a", "b", "c"]) == "a -> b -> c -> a"
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_among_the_modules():
    edges = import_graph()
    found = [_path(edges, c) for c in cycles(edges)]
    assert not found, "import cycles:\n" + "\n".join(found)
