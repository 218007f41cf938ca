"""The cost ledger of a frame's shared buffers.

Every buffer is built once, whoever asks first; the ledger times each build
and remembers what it was built from. A method is billed the build times of
the buffers it used and of everything those were built from, summed per
phase (``billed``), so its phases do not depend on which method ran first.
``build_times`` sums the builds per buffer for the JSON's ``buffers_time_s``.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Dict, FrozenSet, Iterable, Optional, Sequence, Set, Tuple


@dataclass(frozen=True)
class Build:
    seconds: float
    phase: str                  # the phase of a method's cost it is billed as
    built_from: Tuple[str, ...] # keys of the builds it was made from


class BuildLedger:
    """Timed builds by key; ``phases``: every phase a build can be billed
    as, in the order a method's ``time_s`` lists them."""

    def __init__(self, phases: Sequence[str]):
        self.phases = tuple(phases)
        self.build_times: Dict[str, float] = {}
        self.builds: Dict[str, Build] = {}
        self._used: Optional[Set[str]] = None

    def timed(self, key: str, phase: str, fn: Callable[[], object], built_from: Iterable[str] = (),
              total: Optional[str] = None):
        """``fn()``, timed as build ``key`` billed as ``phase``;
        ``build_times[total or key]`` grows by its time."""
        t = time.perf_counter()
        out = fn()
        self.record(key, phase, time.perf_counter() - t, built_from, total)
        return out

    def record(self, key: str, phase: str, seconds: float, built_from: Iterable[str] = (),
               total: Optional[str] = None) -> None:
        """A build made elsewhere in ``seconds``."""
        total = total or key
        self.build_times[total] = self.build_times.get(total, 0.0) + float(seconds)
        self.builds[key] = Build(float(seconds), phase, tuple(built_from))

    def use(self, key: str) -> None:
        """The running method (``recording``) reads build ``key``."""
        if self._used is not None:
            self._used.add(key)

    @contextmanager
    def recording(self, used: Set[str]):
        """Record into ``used`` the builds read until the block ends (one
        method at a time)."""
        if self._used is not None:
            raise RuntimeError("one method runs on a frame's buffers at a time")
        self._used = used
        try:
            yield used
        finally:
            self._used = None

    def billed(self, used: Iterable[str], phases: Iterable[str]) -> Dict[str, float]:
        """Seconds per phase of the builds ``used`` and of what they were
        built from; every phase of ``phases`` is present (0 when nothing of
        it was used)."""
        closure = _closure((k for k in used if k in self.builds),
                           lambda k: (d for d in self.builds[k].built_from if d in self.builds))
        wanted = set(phases) | {self.builds[k].phase for k in closure}
        out = {p: 0.0 for p in self.phases if p in wanted}
        for k in sorted(closure):
            out[self.builds[k].phase] += self.builds[k].seconds
        return out

    def carry(self, prev: "BuildLedger", keys: Iterable[str]) -> None:
        """Take over ``prev``'s builds ``keys`` billed at 0 s: nothing was
        built for them in this frame."""
        for k in keys:
            if k in prev.builds:
                b = prev.builds[k]
                self.builds[k] = Build(0.0, b.phase, b.built_from)


def _closure(start: Iterable[str], edges) -> FrozenSet[str]:
    """``start`` and everything reachable from it along ``edges(node)``."""
    out, todo = set(), list(start)
    while todo:
        n = todo.pop()
        if n not in out:
            out.add(n)
            todo.extend(edges(n))
    return frozenset(out)
