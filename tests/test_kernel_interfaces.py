"""Kernel interfaces stay readable (issue 19): no Numba kernel in core/ takes
more than MAX_PARAMS parameters; arguments that travel together go in the
named groups (namedtuples) of each method's kernel module."""
import ast
import pathlib

CORE = pathlib.Path(__file__).resolve().parent.parent / "core"
MAX_PARAMS = 20


def _kernels():
    for path in sorted(CORE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any(
                    "jit" in ast.unparse(d) for d in node.decorator_list):
                a = node.args
                yield f"{path.relative_to(CORE)}:{node.name}", len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)


def test_core_has_kernels():
    assert sum(1 for _ in _kernels()) > 50


def test_no_kernel_over_max_params():
    wide = {name: n for name, n in _kernels() if n > MAX_PARAMS}
    assert wide == {}
