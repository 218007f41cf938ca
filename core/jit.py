"""How Penumbra's Numba kernels are compiled (compile time is a cost every
user pays on a cold start): ``kernel`` and ``inner``, the two decorators
every kernel in ``core`` uses instead of ``numba.njit``.

- **An LLVM optimisation level per kernel** (``opt``). Numba runs LLVM's -O3
  pipeline on every kernel, and again on each caller's module with its callees
  linked in. Penumbra's kernels are branchy scalar loops that -O3's loop
  vectorisation and aggressive passes rarely speed up, while its compile time
  grows with every inlined callee.
  Kernels compile at ``COLD`` (-O1) unless they are marked ``HOT`` (-O3: the
  per-pixel kernels whose warm time drops with it,
  ``penumbra_casting``'s cast loop among them). A callee linked into a ``HOT``
  caller is optimised again at -O3 there, so a hot loop's inlined helpers get
  -O3 whatever their own level. Numba reads the level
  (``numba.core.config.OPT``) when it builds each library's pass pipeline;
  :meth:`Kernel.compile` sets it for its own compile under Numba's global
  compiler lock and puts back the previous value (so a nested callee compile,
  or another package's kernels in the same process, keep theirs), after
  re-reading Numba's environment variables as its compiler does (a changed
  ``NUMBA_*`` variable would otherwise reset the level inside the compile).
- **No entry wrappers for kernels that only other kernels call**
  (``inner``). Numba compiles a CPython wrapper (unboxing each argument: a
  named tuple of a dozen arrays unboxes each one) and a cfunc wrapper with
  every dispatcher; a helper called only from kernels uses neither, yet would
  pay for both at every cold start.
  ``inner`` compiles the native function alone, as Numba does for its own
  ``@overload`` implementations. Such a dispatcher has no entry for Python
  (Numba would jump through a null pointer), so a call from Python goes to
  its *twin*, an uncached ``kernel`` of the same function made on first use
  (tests call helpers directly). :func:`twins` names those that needed
  one. With ``PENUMBRA_STRICT_INNER=1`` (the test suite sets it) a call from
  Penumbra's own modules raises instead, so the tests keep every Python
  entry point a ``kernel``. A twin is never cached: its entries would carry
  the inner kernel's cache key.

Cached kernels keep the level they were compiled at; a source change
invalidates a module's entries.
"""
from __future__ import annotations

import os
import sys
import threading

from numba.core import config
from numba.core.compiler_lock import global_compiler_lock
from numba.core.registry import CPUDispatcher

COLD = 1                              # LLVM -O1: every kernel unless marked HOT
HOT = 3                               # LLVM -O3 (Numba's default)
STRICT_ENV = "PENUMBRA_STRICT_INNER"
_PKG = __name__.rsplit(".", 2)[0]    # "penumbra" or "bl_ext.<repo>.penumbra"
_WRAPPERLESS = {"no_cpython_wrapper": True, "no_cfunc_wrapper": True}
_lock = threading.Lock()
_twins: dict = {}                    # "module:qualname" -> the twin dispatcher


class Kernel(CPUDispatcher):
    """A Numba dispatcher compiled at its own LLVM level (``opt_level``)."""

    opt_level = HOT

    def compile(self, sig):
        with global_compiler_lock:
            config.reload_config()        # as Numba's compiler does first: a changed NUMBA_* variable
            saved = config.OPT            # would otherwise reset the level inside the compile
            config.OPT = type(saved)(self.opt_level)
            try:
                return super().compile(sig)
            finally:
                config.OPT = saved


class InnerKernel(Kernel):
    """A ``Kernel`` compiled without Python and C entry wrappers; a call from
    Python runs its uncached twin (module docstring)."""

    def __call__(self, *args, **kws):
        if os.environ.get(STRICT_ENV) == "1":
            caller = sys._getframe(1).f_globals.get("__name__", "")
            if caller == _PKG or caller.startswith(_PKG + "."):
                raise TypeError(f"{self.py_func.__module__}:{self.py_func.__qualname__} is an inner kernel "
                                f"(core.jit.inner) called from Python in {caller}: make it a jit.kernel")
        return self.python_twin()(*args, **kws)

    def python_twin(self):
        """A ``kernel`` of the same function, options and ``locals``,
        uncached, made on first use."""
        key = f"{self.py_func.__module__}:{self.py_func.__qualname__}"
        with _lock:
            twin = _twins.get(key)
            if twin is None:
                opts = {k: v for k, v in self.targetoptions.items()
                        if k not in _WRAPPERLESS and k not in ("nopython", "boundscheck")}
                twin = _twins[key] = _make(Kernel, self.py_func, False, self.opt_level, dict(self.locals), opts)
            return twin


def _make(cls, func, cache: bool, opt: int, locals: dict, options: dict):
    """A ``cls`` dispatcher of ``func`` as ``numba.njit(cache=cache, locals=locals, **options)`` makes one."""
    disp = cls(py_func=func, locals=locals, targetoptions=dict(options, nopython=True, boundscheck=None))
    disp.opt_level = int(opt)
    if cache:
        disp.enable_caching()
    return disp


def kernel(fn=None, *, opt: int = COLD, cache: bool = True, locals=None, **options):
    """``numba.njit(cache=cache, **options)`` at LLVM level ``opt``:
    ``@kernel``, ``@kernel(nogil=True)``, ``@kernel(opt=HOT, ...)``."""
    def wrap(func):
        return _make(Kernel, func, cache, opt, dict(locals or {}), options)
    return wrap(fn) if fn is not None else wrap


def inner(fn=None, *, opt: int = COLD, cache: bool = True, locals=None, **options):
    """``kernel`` for a kernel that only other kernels call: no entry
    wrappers (module docstring)."""
    def wrap(func):
        return _make(InnerKernel, func, cache, opt, dict(locals or {}), dict(options, **_WRAPPERLESS))
    return wrap(fn) if fn is not None else wrap


def twins() -> list:
    """The inner kernels called from Python in this process, sorted."""
    with _lock:
        return sorted(_twins)
