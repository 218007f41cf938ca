"""Kernel interfaces stay readable: no Numba kernel in core/ takes
more than MAX_PARAMS parameters; arguments that travel together go in the
named groups (namedtuples) of each method's kernel module. Kernels are
``core.jit``'s ``kernel`` and ``inner``, never ``numba.njit`` itself."""
import ast
import pathlib

CORE = pathlib.Path(__file__).resolve().parent.parent / "core"
MAX_PARAMS = 20


def _kernels():
    for path in sorted(CORE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any(
                    ast.unparse(d).split("(")[0] in ("kernel", "inner") for d in node.decorator_list):
                a = node.args
                yield f"{path.relative_to(CORE)}:{node.name}", len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)


def test_core_has_kernels():
    assert sum(1 for _ in _kernels()) > 50


def test_no_kernel_over_max_params():
    wide = {name: n for name, n in _kernels() if n > MAX_PARAMS}
    assert wide == {}


def test_core_kernels_use_core_jit():
    """Every kernel gets its LLVM level and wrappers from ``core/jit.py``."""
    plain = [f"{p.relative_to(CORE)}" for p in sorted(CORE.rglob("*.py"))
             if p.name != "jit.py" and "njit" in p.read_text()]
    assert plain == []


def _module_of(path):
    rel = path.relative_to(CORE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _resolve(module, level, name, is_pkg):
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    if level > 1:
        base = base[:len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def test_no_python_code_calls_an_inner_kernel():
    """``jit.inner`` kernels have no Python entry (a call from Python compiles
    an uncached twin on every run): outside kernels, nothing in the package
    calls one by name or through its module (the strict mode in conftest.py
    catches the calls the tests reach; this, the ones they do not)."""
    root = CORE.parent
    files = [p for p in sorted(root.rglob("*.py"))          # the package's own modules: no venvs, tests, scenes
             if not any(part.startswith(".") or part in ("tests", "sample_blends", "build")
                        for part in p.relative_to(root).parts)]
    trees = {p: ast.parse(p.read_text()) for p in files}
    mods = {_module_of(p): p for p in files}
    inner = {m: {n.name for n in ast.walk(trees[p]) if isinstance(n, ast.FunctionDef)
                 and any(ast.unparse(d).split("(")[0] == "inner" for d in n.decorator_list)} for m, p in mods.items()}
    found = []
    for m, p in mods.items():
        names, modules = set(inner[m]), {}
        for node in ast.walk(trees[p]):
            if isinstance(node, ast.ImportFrom) and node.level:
                src = _resolve(m, node.level, node.module, p.name == "__init__.py")
                for a in node.names:
                    if a.name in inner.get(src, ()):
                        names.add(a.asname or a.name)
                    elif f"{src}.{a.name}" in mods:
                        modules[a.asname or a.name] = f"{src}.{a.name}"

        def scan(node, jitted):
            for ch in ast.iter_child_nodes(node):
                if isinstance(ch, ast.FunctionDef):
                    heads = {ast.unparse(d).split("(")[0] for d in ch.decorator_list}
                    compiled = bool(heads & {"kernel", "inner"}) or ch.name in jitted
                    inner_jit = {c.args[0].id for c in ast.walk(ch) if isinstance(c, ast.Call) and c.args
                                 and isinstance(c.args[0], ast.Name) and isinstance(c.func, ast.Call)
                                 and ast.unparse(c.func.func) == "kernel"}
                    if not compiled:
                        scan(ch, inner_jit)
                    continue
                if isinstance(ch, ast.Call):
                    f = ch.func
                    if isinstance(f, ast.Name) and f.id in names:
                        found.append(f"{p.relative_to(root)}:{ch.lineno} {f.id}")
                    elif (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                          and f.attr in inner.get(modules.get(f.value.id, ""), ())):
                        found.append(f"{p.relative_to(root)}:{ch.lineno} {f.value.id}.{f.attr}")
                scan(ch, jitted)
        scan(trees[p], set())
    assert found == []
