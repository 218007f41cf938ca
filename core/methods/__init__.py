"""Method registry: one module per algorithm, keyed by DESIGN.md's method ids.

A module registers a Method subclass with ``@register``; pass ids (``embree``
and ``embree_irr`` come from one producer) map to their producer here.
"""
from __future__ import annotations

from typing import Dict, List

from .base import Method

_PRODUCERS: Dict[str, Method] = {}     # producer id -> instance
_PASS_TO_PRODUCER: Dict[str, str] = {} # pass id -> producer id


def register(cls):
    inst = cls()
    _PRODUCERS[inst.id] = inst
    for pid in inst.passes:
        _PASS_TO_PRODUCER[pid] = inst.id
    return cls


def _load():
    # import order = display order
    from . import pcf, embree_ref  # noqa: F401
    for name in ("single_sample", "layered", "depth_raytrace", "penumbra_casting", "irregular"):
        try:
            __import__(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:  # not landed yet
            if exc.name != f"{__name__}.{name}":
                raise


def pass_ids() -> List[str]:
    """Every pass id a registered method writes (``--methods all``)."""
    _load()
    return list(_PASS_TO_PRODUCER)


def producer_of(pass_id: str) -> Method:
    _load()
    return _PRODUCERS[_PASS_TO_PRODUCER[pass_id]]


def producers() -> Dict[str, Method]:
    _load()
    return dict(_PRODUCERS)
