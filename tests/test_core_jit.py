"""``core/jit.py``: a kernel compiles at its own LLVM level and
leaves Numba's level as it found it; an inner kernel called from Python runs
its twin (same results), and from Penumbra's own modules raises in strict
mode (the suite's, ``conftest.py``); kernels compiled at -O1 and -O3 give
bit-identical results (no fast-math: LLVM keeps IEEE semantics)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numba.core import codegen, config

from penumbra.core import jit


def _levels_seen(monkeypatch):
    seen = []
    orig = codegen.CPUCodegen._pass_builder

    def spy(self, **kw):
        seen.append(int(kw.get("opt", config.OPT)))
        return orig(self, **kw)
    monkeypatch.setattr(codegen.CPUCodegen, "_pass_builder", spy)
    return seen


@pytest.mark.parametrize("level", [jit.COLD, jit.HOT])
def test_kernel_compiles_at_its_level_and_restores_numbas(monkeypatch, level):
    before = int(config.OPT)
    seen = _levels_seen(monkeypatch)

    @jit.kernel(cache=False, opt=level)
    def f(x):
        return math.sqrt(x) + 1.0

    assert f(4.0) == 3.0
    full = [s for s in seen if s != 0]             # Numba's "cheap" pre-pass always runs at 0
    assert full and set(full) == {level}
    assert int(config.OPT) == before


def test_nested_callee_keeps_its_own_level(monkeypatch):
    seen = []
    orig = codegen.CPUCodegen._pass_builder

    @jit.inner(cache=False, opt=jit.COLD)
    def callee(x):
        return x * 2.0

    @jit.kernel(cache=False, opt=jit.HOT)
    def caller(x):
        return callee(x) + 1.0

    def spy(self, **kw):
        seen.append(int(config.OPT))
        return orig(self, **kw)
    monkeypatch.setattr(codegen.CPUCodegen, "_pass_builder", spy)
    assert caller(2.0) == 5.0
    assert jit.COLD in seen and jit.HOT in seen
    assert seen[-1] == jit.HOT                     # the caller's own module, after its callee's


def _series(xs, out):
    for i in range(xs.shape[0]):
        acc = 0.0
        for k in range(1, 40):
            acc += math.sin(xs[i] * k) / k + math.exp(-xs[i] * k) * 1e-3
        out[i] = acc


def test_levels_give_bit_identical_results():
    xs = np.linspace(-3.0, 3.0, 4097)
    a, b = np.empty_like(xs), np.empty_like(xs)
    jit.kernel(cache=False, opt=jit.COLD)(_series)(xs, a)
    jit.kernel(cache=False, opt=jit.HOT)(_series)(xs, b)
    assert np.array_equal(a, b)


def test_inner_kernel_from_python_runs_its_twin():
    @jit.inner(cache=False)
    def twice(x):
        return 2 * x

    @jit.kernel(cache=False)
    def use(x):
        return twice(x) + 1

    assert use(3) == 7
    assert twice(3) == 6                           # a test module may call it: the twin
    assert any(name.endswith("twice") for name in jit.twins())
    assert isinstance(twice.python_twin(), jit.Kernel)
    assert not isinstance(twice.python_twin(), jit.InnerKernel)


def test_inner_kernel_from_penumbra_module_raises_in_strict_mode():
    @jit.inner(cache=False)
    def helper(x):
        return x + 1

    assert jit.STRICT_ENV and __import__("os").environ.get(jit.STRICT_ENV) == "1"
    with pytest.raises(TypeError, match="inner kernel"):
        exec("helper(1)", {"__name__": "penumbra.core.somewhere", "helper": helper})
    assert exec("r = helper(1)", ns := {"__name__": "tests.elsewhere", "helper": helper}) is None and ns["r"] == 2
