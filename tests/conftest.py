"""Shared pytest fixtures, and the split of the suite into core and bpy tests.

A test *touches bpy* (and gets the ``bpy`` mark) when its module's top-level
code, its own code, or the code of a fixture it uses names ``bpy``, ``factory_scene``,
``sample_path`` or a helper of tests/scenes.py that opens or builds a bpy
scene or reads one back (docstrings aside).
``--part core`` runs the other tests with bpy made unimportable, so a core
test that reaches bpy some other way fails loudly instead of being skipped;
``--part bpy`` runs the marked ones. ``make test`` (scripts/test_matrix.py)
runs the core part once and the bpy part on every tested Blender, and checks
that together they ran every collected test.

Only bpy fixtures live here, and bpy is imported inside them.

``PENUMBRA_STRICT_INNER=1`` (``core/jit.py``): a Penumbra module that calls
an inner kernel from Python fails the test that reaches it (subprocesses the
tests start inherit it).
"""
import ast
import functools
import importlib.abc
import inspect
import os
import re
import sys
import textwrap

import pytest

os.environ["PENUMBRA_STRICT_INNER"] = "1"
BPY_NAMES = re.compile(r"\b(bpy|factory_scene|sample_path|load_sample|open_sample|tiny_cycles_scene|"
                       r"save_plane_blend|image_rgba|draw_panel|render_state)\b")


def pytest_addoption(parser):
    parser.addoption("--part", choices=("all", "core", "bpy"), default="all",
                     help="core: only tests that do not touch bpy, with bpy unimportable; "
                          "bpy: only tests that touch bpy; all (default): both")


class _NoBpy(importlib.abc.MetaPathFinder):
    """Refuses ``import bpy`` in the core part."""

    def find_spec(self, name, path=None, target=None):
        if name == "bpy" or name.startswith("bpy."):
            raise ImportError("--part core runs without bpy: this test touches bpy, so "
                              "tests/conftest.py must see it (name bpy/load_sample in the test "
                              "or mark it @pytest.mark.bpy)")
        return None


def pytest_configure(config):
    if config.getoption("--part") == "core":
        sys.meta_path.insert(0, _NoBpy())


def _code_names_bpy(source: str) -> bool:
    """Whether ``source`` (a module or function) names bpy outside docstrings."""
    tree = ast.parse(textwrap.dedent(source))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
            body[0] = ast.Pass()
    return bool(BPY_NAMES.search(ast.unparse(tree)))


@functools.lru_cache(maxsize=None)
def module_touches_bpy(path: str) -> bool:
    """Top-level code (imports, constants; not def/class bodies) names bpy."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    top = [n for n in tree.body if not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]
    return _code_names_bpy(ast.unparse(ast.Module(body=top, type_ignores=[])))


@functools.lru_cache(maxsize=None)
def _function_touches_bpy(func) -> bool:
    try:
        return _code_names_bpy(inspect.getsource(func))
    except (OSError, TypeError):
        return False


def touches_bpy(item) -> bool:
    if item.get_closest_marker("bpy") is not None or module_touches_bpy(str(item.path)):
        return True
    funcs = [getattr(item, "function", None)]
    for defs in item._fixtureinfo.name2fixturedefs.values():
        funcs += [d.func for d in defs]
    return any(f is not None and _function_touches_bpy(f) for f in funcs)


def pytest_ignore_collect(collection_path, config):
    """--part core does not import the modules whose top level needs bpy
    (all their tests are bpy tests)."""
    if (config.getoption("--part") == "core" and collection_path.suffix == ".py"
            and collection_path.name.startswith("test_")):
        return module_touches_bpy(str(collection_path)) or None
    return None


def pytest_collection_modifyitems(config, items):
    part = config.getoption("--part")
    keep, drop = [], []
    for item in items:
        is_bpy = touches_bpy(item)
        if is_bpy:
            item.add_marker(pytest.mark.bpy)
        (keep if part == "all" or (part == "bpy") == is_bpy else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


@pytest.fixture
def factory_scene():
    """An empty factory-settings file; returns its (only) scene."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


@pytest.fixture
def registered():
    """Penumbra registered as an add-on for the test (unregistered after)."""
    import bpy  # noqa: F401  (marks the test as touching bpy)
    import penumbra

    penumbra.register()
    yield
    penumbra.unregister()
