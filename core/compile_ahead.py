"""Cold-start kernel compilation on every core.

Numba compiles one kernel at a time per process (a global compiler lock),
so a cold frame's compilation would run on one core alone. The
kernels a cold frame compiles, and the order it compiles them in, are known
ahead: ``kernel_plan.json`` (recorded by ``scripts/record_kernel_plan.py``
from cold frames on the warm-up scene, ``core/warmup.py``) lists, per
producer, light kind and pixel model, the dispatchers and signatures a cold
frame compiles, callees included, in the order their compiles start (a
caller before its callees).

:func:`prefetch` starts helper processes that compile that list *from its
end* into Numba's on-disk cache, while this process compiles from its start
as it always did: the two meet in the middle. Read backwards, the list puts
callees before their callers, so a large kernel's callees (pcf's filter
kernel spends most of its compile time in them) are split between the
processes instead of landing on one. Every process claims a kernel when it
starts compiling it (a claim file, ``O_EXCL``; a callee when a caller's
typing reaches it: :func:`_hook` wraps the dispatcher's ``compile``) and
marks it done when Numba has saved it; a process that reaches a kernel
another one claimed waits for it (:func:`_claim_or_wait`) and loads it from
the cache instead of compiling it again. A helper skips what is claimed.
Nothing here changes what is computed; a stale plan only costs a helper's time.

``PENUMBRA_COMPILE_PROCESSES``: how many processes compile (this one
included; default: the cores, at most 4; 1 = no helper).

Run as a script (``python compile_ahead.py PACKAGE_DIR PACKAGE_NAME WORK_DIR``)
it is a helper: it imports the package under the caller's own name (so the
signatures' named-tuple classes are the same objects the caller's cache keys
name) and works through ``WORK_DIR/items.json``.
"""
from __future__ import annotations

import atexit
import base64
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

PLAN_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "kernel_plan.json")
ENV_PROCESSES = "PENUMBRA_COMPILE_PROCESSES"
MAX_PROCESSES = 4
MIN_ITEMS = 4                      # fewer uncached kernels than this: no helper (its start-up would not pay)
_PKG = __name__.rsplit(".", 2)[0] if __name__ != "__main__" else None    # "penumbra" or "bl_ext.<repo>.penumbra"

_lock = threading.Lock()
_started: set = set()              # plan keys already handed to helpers in this process
_jobs: list = []                   # (work dir, [Popen])
_idle: list = []                   # (work dir, [Popen]) started ahead, waiting for their list
_hooked: dict = {}                 # dispatcher name -> [(work dir, item, signature, alive())]
_waited = [0.0]                    # seconds this process spent waiting for helpers
_mine: set = set()                 # (work dir, item) this process claimed
_role = ["main"]                   # "helper" in a helper process


def plan_key(pass_id: str, kind: str, filtered: bool) -> str:
    """The plan's list for one core pass under one light kind, filtered or at pixel centres."""
    return f"{pass_id}|{kind}|{'filtered' if filtered else 'centres'}"


def frame_keys(scene, passes, filtered: bool) -> list:
    """The plan keys of a frame computing ``passes`` (``auto`` and external
    passes have none) for ``scene``'s shadow-casting lights."""
    from . import methods as method_registry
    core = set(method_registry.pass_ids(external=False))
    kinds = list(dict.fromkeys(lt.kind for lt in scene.lights if lt.casts_shadow))
    return [plan_key(p, k, filtered) for p in passes if p in core for k in kinds]


def load_plan() -> dict:
    """``{"items": [[dispatcher, sig_b64], ...], "lists": {plan key: [item index, ...]}}``
    ({} when missing or unreadable)."""
    try:
        with open(PLAN_FILE) as f:
            plan = json.load(f)
        return plan if isinstance(plan.get("items"), list) and isinstance(plan.get("lists"), dict) else {}
    except (OSError, ValueError, AttributeError):
        return {}


def processes() -> int:
    """How many processes compile a cold frame's kernels (this one included)."""
    try:
        n = int(os.environ.get(ENV_PROCESSES, "0"))
    except ValueError:
        n = 0
    if n <= 0:
        n = min(os.cpu_count() or 1, MAX_PROCESSES)
    return max(1, n)


def waited_s() -> float:
    """Seconds this process has spent waiting for helpers' kernels (compile time it did not spend)."""
    return _waited[0]


def helper_done() -> int:
    """How many kernels this process's helpers have finished so far."""
    n = 0
    for work, _ in _jobs:
        try:
            n += sum(1 for f in os.listdir(work) if f.endswith(".done"))
        except OSError:
            pass
    return n


def _dispatcher(name: str, pkg_name: str):
    """The dispatcher a plan item names (``penumbra.<module>:<qualname>``)
    in the package imported as ``pkg_name``; None when it is gone."""
    import importlib
    modname, _, qualname = name.partition(":")
    if not modname.startswith("penumbra."):
        return None
    try:
        d = getattr(importlib.import_module(pkg_name + modname[len("penumbra"):]), qualname)
    except (ImportError, AttributeError):
        return None
    return d if hasattr(d, "_cache") and hasattr(d, "compile") else None


def _uncached(disp) -> bool:
    try:
        return not disp._cache._cache_file._load_index()
    except Exception:
        return False                     # no cache (cache=False): a helper's work could not reach us


def prefetch(keys) -> int:
    """Hand the kernels of plan ``keys`` (:func:`plan_key`) that are not in
    the on-disk cache to helper processes, which compile them from the end
    of the frame's order; returns how many kernels were handed over (0: a
    warm cache, one process, no plan, or too few to pay a helper's start)."""
    n_proc = processes()
    if n_proc < 2 or _PKG is None:
        return 0
    with _lock:
        keys = [k for k in keys if k not in _started]
        if not keys:
            return 0
        _started.update(keys)
        plan = load_plan()
        if not plan:
            return 0
        order, seen = [], set()
        for k in keys:                   # the frame's order: the producers' lists one after the other
            for i in plan["lists"].get(k, ()):
                if i not in seen and 0 <= i < len(plan["items"]):
                    seen.add(i)
                    order.append(i)
        items = []
        for i in order:
            name, sig = plan["items"][i]
            d = _dispatcher(name, _PKG)
            if d is not None and name not in _hooked and _uncached(d):
                items.append((name, sig, d))
        if len(items) < MIN_ITEMS:
            return 0
        work, procs = _idle.pop() if _idle else _spawn(n_proc - 1)
        if not procs:
            return 0
        tmp = os.path.join(work, "items.json.tmp")
        with open(tmp, "w") as f:
            json.dump([[name, sig] for name, sig, _ in items], f)
        os.replace(tmp, os.path.join(work, "items.json"))      # the helpers wait for this file
        for idx, (name, sig, d) in enumerate(items):
            _hook(d, name, work, idx, sig, _any_alive(procs))
        return len(items)


def _spawn(n: int):
    """(work folder, [Popen]): ``n`` helpers started, waiting for the work
    folder's ``items.json``."""
    work = tempfile.mkdtemp(prefix="penumbra-compile-")
    pkg_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    env.pop(ENV_PROCESSES, None)
    procs = []
    for _ in range(n):
        try:
            procs.append(subprocess.Popen([sys.executable, os.path.abspath(__file__), pkg_dir, _PKG, work,
                                           str(os.getpid())],
                                          stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, env=env,
                                          creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0)))
        except OSError:
            break
    if not procs:
        shutil.rmtree(work, ignore_errors=True)
    else:
        _jobs.append((work, procs))
    return work, procs


def start_helpers(pass_ids, kernels_cached) -> bool:
    """Start the helpers ahead of :func:`prefetch` when the kernels of a core
    pass in ``pass_ids`` (``auto``: every pass it may choose) are not in the
    on-disk cache, so their own start-up (about a second: Python, NumPy,
    Numba, the kernels' modules) overlaps the caller's (opening the .blend);
    returns whether it started them. Idle helpers are stopped at exit.
    ``kernels_cached(method_id)``: ``warmup.kernels_cached`` (handed in:
    that module imports this one)."""
    n_proc = processes()
    if n_proc < 2 or _PKG is None or not load_plan():
        return False
    from . import methods as method_registry
    core = method_registry.pass_ids(external=False)
    wanted = core if "auto" in pass_ids else [p for p in pass_ids if p in core]
    producers = {method_registry.producer_of(p).id for p in wanted}
    with _lock:
        if _idle or not producers or all(kernels_cached(m) for m in producers | {"buffers"}):
            return False
        work, procs = _spawn(n_proc - 1)
        if procs:
            _idle.append((work, procs))
        return bool(procs)


def _hook(disp, name, work, idx, sig_b64, alive) -> None:
    """Make ``disp.compile`` for item ``idx``'s signature claim the item for
    this process (a callee's too, when a caller's typing reaches it) and mark
    it done when compiled, or wait for the process that claimed it first
    (``alive()``: it may still finish). The caller and the helpers hook the
    same items, so no kernel is compiled twice; no two processes can wait
    for each other, as each only waits for a kernel on the other's compile
    stack and kernels do not call each other in a circle."""
    try:
        sig = _unpickle(sig_b64, _PKG)
    except Exception:
        return
    entries = _hooked.get(name)
    if entries is None:
        from numba.core import sigutils
        entries = _hooked[name] = []
        orig = disp.compile

        def compile(sig, _orig=orig, _entries=entries):
            args, _ = sigutils.normalize_signature(sig)
            listed = [(w, i, ok) for w, i, s, ok in _entries if s == tuple(args)]
            claimed = []                 # claimed by this call: done when it returns
            if not any((w, i) in _mine for w, i, _ in listed):
                for w, i, ok in listed:
                    if _claim_or_wait(w, i, ok):
                        claimed.append((w, i))
                        break
            try:
                return _orig(sig)
            finally:
                for w, i in claimed:
                    _mark_done(w, i)
        disp.compile = compile
    entries.append((work, idx, tuple(sig), alive))


def _claim_or_wait(work, idx, alive) -> bool:
    """Claim item ``idx`` for this process (True: it compiles it), or, when
    another process claimed it and has not finished, wait until it has (or
    ``alive()`` says it cannot, or the claimant has exited) and return False."""
    claimed = _claim(work, idx)
    if claimed is not None:
        return claimed
    claim = os.path.join(work, f"{idx}.claim")
    done = os.path.join(work, f"{idx}.done")
    t0 = time.perf_counter()
    while not os.path.exists(done) and alive() and _claimant_alive(claim):
        time.sleep(0.01)
    _waited[0] += time.perf_counter() - t0
    return False


def _claim(work, idx):
    """Claim item ``idx`` for this process (a claim file naming it, ``O_EXCL``):
    True; another process has it: None; the work folder is gone: False."""
    try:
        with open(os.path.join(work, f"{idx}.claim"), "x") as f:
            f.write(f"{_role[0]} {os.getpid()}")
    except FileExistsError:
        return None
    except OSError:
        return False
    _mine.add((work, idx))
    return True


def _claimant_alive(claim: str) -> bool:
    """The process named in a claim file still runs (unreadable: assume so)."""
    try:
        with open(claim) as f:
            return _alive(int(f.read().split()[1]))
    except (OSError, ValueError, IndexError):
        return True


def _mark_done(work, idx) -> None:
    try:
        open(os.path.join(work, f"{idx}.done"), "w").close()
    except OSError:
        pass


def _any_alive(procs):
    """``alive()`` for the caller: one of its helpers still runs."""
    return lambda: any(p.poll() is None for p in procs)


@atexit.register
def _stop_helpers() -> None:
    for work, procs in _jobs:
        for p in procs:
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    p.kill()
        shutil.rmtree(work, ignore_errors=True)
    _jobs.clear()
    _idle.clear()


# --------------------------------------------------------------------------
# the helper
def _import_package(pkg_dir: str, pkg_name: str):
    """Import the package at ``pkg_dir`` as ``pkg_name``; Blender's
    ``bl_ext.<repo>`` parents are made as namespace modules, as Blender does."""
    import importlib
    import types
    parts = pkg_name.split(".")
    if len(parts) == 1:
        sys.path.insert(0, os.path.dirname(pkg_dir))
    else:
        for i in range(1, len(parts)):
            parent = ".".join(parts[:i])
            if parent not in sys.modules:
                mod = types.ModuleType(parent)
                mod.__path__ = [os.path.dirname(pkg_dir)] if i == len(parts) - 1 else []
                sys.modules[parent] = mod
    return importlib.import_module(pkg_name)


def _unpickle(sig_b64: str, pkg_name: str):
    """A recorded signature, its ``penumbra.*`` classes read as ``pkg_name``'s."""
    import io
    import pickle

    class _Unpickler(pickle.Unpickler):
        def find_class(self, module, name):
            if module == "penumbra" or module.startswith("penumbra."):
                module = pkg_name + module[len("penumbra"):]
            return super().find_class(module, name)
    return _Unpickler(io.BytesIO(base64.b64decode(sig_b64))).load()


def _helper(pkg_dir: str, pkg_name: str, work: str, parent: str = "0") -> int:
    """Work through ``work/items.json`` from its end (waiting for it to
    appear, with the kernels' modules imported meanwhile); exits when the
    caller has gone."""
    _import_package(pkg_dir, pkg_name)
    import importlib
    plan = load_plan()
    for mod in sorted({name.split(":", 1)[0] for name, _ in plan.get("items", ())}):
        try:
            importlib.import_module(pkg_name + mod[len("penumbra"):])
        except Exception:
            pass
    path = os.path.join(work, "items.json")
    t_end = time.monotonic() + 600.0
    while not os.path.exists(path):
        if time.monotonic() > t_end or not os.path.isdir(work) or (parent != "0" and not _alive(int(parent))):
            return 0
        time.sleep(0.02)
    with open(path) as f:
        items = json.load(f)
    _role[0] = "helper"
    caller_alive = (lambda: True) if parent == "0" else (lambda: _alive(int(parent)))
    disps = [_dispatcher(name, pkg_name) for name, _ in items]
    for idx, ((name, sig), d) in enumerate(zip(items, disps)):
        if d is not None:
            _hook(d, name, work, idx, sig, caller_alive)   # a callee the caller compiles: wait for it
    for idx in range(len(items) - 1, -1, -1):
        if not caller_alive():
            return 0                        # the caller was killed: nobody needs the rest
        name, sig = items[idx]
        claimed = _claim(work, idx)
        if claimed is None:
            continue                        # the caller or another helper has it (or had it: a callee)
        if not claimed:
            return 0                        # the work folder is gone: the caller finished
        try:
            disps[idx].compile(_unpickle(sig, pkg_name))   # a cache hit when done already
        except Exception:
            pass                            # a stale plan entry: the caller compiles it itself
        if not os.path.isdir(work):
            return 0
        _mark_done(work, idx)
    return 0


def _alive(pid: int) -> bool:
    """The caller still runs (on Windows, ``os.kill(pid, 0)`` would end it: there
    the work folder's removal and the time-out stop an idle helper)."""
    if sys.platform == "win32":
        return True
    try:
        os.kill(pid, 0)
        return True
    except PermissionError:
        return True
    except OSError:
        return False


if __name__ == "__main__":
    sys.exit(_helper(*sys.argv[1:5]))
