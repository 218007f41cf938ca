"""Imports run one way: ``core`` <- ``bridge`` <- {``addon``, ``operators``,
``cli``}, with no circle anywhere.

Every ``.py`` of the package is parsed with ``ast`` (no import runs, so this
needs no bpy): module-level imports and the ones inside functions, relative
ones resolved against the module's package. The graph has an edge A -> B when
A imports B (``from P import name`` counts as importing ``P.name`` when that
is a module, else ``P``); a cycle fails, between modules and between
top-level packages (``core``, ``bridge``, ``addon``, ``operators``, ``cli``,
``bench`` ...).
"""
from __future__ import annotations

import ast
import os
from typing import Dict, List, Optional, Set

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PKG = "penumbra"
#: folders that are not part of the package
NOT_PACKAGE = {"tests", "scripts", "sample_blends"}
def _module_files(root: str = ROOT) -> Dict[str, str]:
    """dotted module name -> path, for every .py of the package."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        rel = os.path.relpath(dirpath, root)
        parts = [] if rel == "." else rel.split(os.sep)
        if parts and (parts[0] in NOT_PACKAGE or any(p.startswith((".", "_")) and p != "__init__"
                                                      for p in parts)):
            dirnames[:] = []
            continue
        if parts and not os.path.exists(os.path.join(dirpath, "__init__.py")):
            dirnames[:] = []
            continue
        for fn in filenames:
            if not fn.endswith(".py"):
                continue
            stem = fn[:-3]
            name = ".".join([PKG] + parts + ([] if stem == "__init__" else [stem]))
            out[name] = os.path.join(dirpath, fn)
    return out


def _imports(name: str, path: str, modules: Set[str]) -> List[str]:
    """Package modules ``name`` imports (anywhere in the file), plus the
    external top-level names (``bpy``, ``numpy``...) prefixed with ``:``."""
    is_pkg = path.endswith("__init__.py")
    package = name if is_pkg else name.rpartition(".")[0]
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    found: List[str] = []

    def add(target: str, names=()):
        if target != PKG and not target.startswith(PKG + "."):
            found.append(":" + target.split(".")[0])
            return
        subs = [f"{target}.{n}" for n in names if f"{target}.{n}" in modules]
        if subs:
            found.extend(subs)
            if len(subs) < len(names):
                found.append(_known(target, modules))
        else:
            found.append(_known(target, modules))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                add(a.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            add(target, [a.name for a in node.names])
    return [m for m in found if m and m != name]


def _known(target: str, modules: Set[str]) -> str:
    """The nearest enclosing module of ``target`` that exists."""
    while target and target not in modules:
        target = target.rpartition(".")[0]
    return target


def import_graph(root: str = ROOT) -> Dict[str, Set[str]]:
    files = _module_files(root)
    modules = set(files)
    return {name: set(_imports(name, path, modules)) for name, path in files.items()}


def top_package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else PKG


def find_cycle(graph: Dict[str, Set[str]], ignore=lambda a, b: False) -> Optional[List[str]]:
    """One cycle of ``graph`` (a list of nodes, first == last) without the
    edges ``ignore(a, b)`` names, or None."""
    nodes = {n for n in graph if not n.startswith(":")}
    edges = {n: sorted(t for t in graph.get(n, ()) if t in nodes and t != n and not ignore(n, t))
             for n in nodes}
    # strongly connected components (Tarjan), then a path inside a component
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    on: Set[str] = set()
    comps: List[List[str]] = []

    def strong(v):
        work = [(v, iter(edges[v]))]
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        while work:
            u, it = work[-1]
            nxt = next(it, None)
            if nxt is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[u])
                if low[u] == index[u]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == u:
                            break
                    comps.append(comp)
            elif nxt not in index:
                index[nxt] = low[nxt] = len(index)
                stack.append(nxt)
                on.add(nxt)
                work.append((nxt, iter(edges[nxt])))
            elif nxt in on:
                low[u] = min(low[u], index[nxt])

    for v in sorted(nodes):
        if v not in index:
            strong(v)
    for comp in comps:
        if len(comp) < 2:
            continue
        members = set(comp)
        start = min(comp)
        parent: Dict[str, Optional[str]] = {start: None}
        frontier = [start]
        while frontier:                       # breadth-first, back to start
            nxt = []
            for u in frontier:
                for w in edges[u]:
                    if w == start:
                        path = []
                        while u is not None:
                            path.append(u)
                            u = parent[u]
                        return path[::-1] + [start]
                    if w in members and w not in parent:
                        parent[w] = u
                        nxt.append(w)
            frontier = nxt
    return None


def package_graph(graph: Dict[str, Set[str]], ignore=lambda a, b: False) -> Dict[str, Set[str]]:
    out: Dict[str, Set[str]] = {}
    for a, targets in graph.items():
        pa = top_package(a)
        out.setdefault(pa, set())
        for b in targets:
            if not b.startswith(":") and top_package(b) != pa and not ignore(a, b):
                out[pa].add(top_package(b))
    return out


# --------------------------------------------------------------------------
def test_the_walker_sees_function_level_and_relative_imports(tmp_path):
    """A circle made only of a function-level relative import is found, at
    module and at package level; the graph names ``bpy`` as external."""
    pkg = tmp_path
    for d in ("core", "bridge"):
        (pkg / d).mkdir()
        (pkg / d / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "core" / "a.py").write_text("def f():\n    from ..bridge import b\n")
    (pkg / "bridge" / "b.py").write_text("import bpy\nfrom ..core.a import f\n")
    g = import_graph(str(pkg))
    assert g[f"{PKG}.core.a"] == {f"{PKG}.bridge.b"}
    assert g[f"{PKG}.bridge.b"] == {":bpy", f"{PKG}.core.a"}
    assert find_cycle(g) == [f"{PKG}.bridge.b", f"{PKG}.core.a", f"{PKG}.bridge.b"]
    assert find_cycle(package_graph(g)) == ["bridge", "core", "bridge"]
    (pkg / "core" / "a.py").write_text("def f():\n    pass\n")
    assert find_cycle(import_graph(str(pkg))) is None


def test_no_cycle_between_modules():
    g = import_graph()
    assert len(g) > 40
    cycle = find_cycle(g)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_no_cycle_between_top_level_packages():
    g = package_graph(import_graph())
    cycle = find_cycle(g)
    assert cycle is None, "import circle between packages: " + " -> ".join(cycle)
    assert {"core", "bridge", "addon", "operators", "cli"} <= set(g)


def test_core_imports_only_core_and_no_bpy():
    for mod, targets in import_graph().items():
        if top_package(mod) != "core":
            continue
        bad = sorted(t for t in targets if t in (":bpy", ":mathutils", ":bmesh")
                     or (not t.startswith(":") and top_package(t) != "core"))
        assert not bad, f"{mod} imports {bad}"


def test_bridge_never_imports_the_ui_or_the_cli():
    for mod, targets in import_graph().items():
        if top_package(mod) != "bridge":
            continue
        bad = sorted(t for t in targets if not t.startswith(":")
                     and top_package(t) not in ("core", "bridge"))
        assert not bad, f"{mod} imports {bad}"


def test_operators_never_import_the_addon():
    for mod, targets in import_graph().items():
        if top_package(mod) == "operators":
            bad = sorted(t for t in targets if not t.startswith(":") and top_package(t) == "addon")
            assert not bad, f"{mod} imports {bad}"
