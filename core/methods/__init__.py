"""Method registry: one module (or package, named by its id) per algorithm, keyed
by DESIGN.md's method ids.

A module registers a Method subclass with ``@register`` (``registry.py``, which
imports no method, so no module imports back the package that loads it); pass
ids (``embree`` and ``embree_irr`` come from one producer) map to their producer
here.
"""
from __future__ import annotations

from typing import Dict, List

from .base import IRRADIANCE, Method
from .registry import _PASS_TO_PRODUCER, _PRODUCERS, register  # noqa: F401

# Passes produced outside core (they need Blender): id -> (V definition, what).
# The caller hands ``core.frame.render_frame`` a producer for each it wants.
EXTERNAL_PASSES = {
    "cycles": (IRRADIANCE, "Cycles render with / without the light's shadow"),
}

#: the order methods are listed in (the UI, ``--methods all``): the papers',
#: then the references
ORDER = ("pcf", "single_sample", "layered", "depth_raytrace", "penumbra_casting", "irregular", "embree")


def _load():
    from . import (pcf, embree_ref, single_sample, layered, depth_raytrace,  # noqa: F401
                   penumbra_casting, irregular)


def producers() -> Dict[str, Method]:
    """Every registered method by id, in ``ORDER`` (others after it)."""
    _load()
    rank = {mid: i for i, mid in enumerate(ORDER)}
    return {mid: _PRODUCERS[mid] for mid in sorted(_PRODUCERS, key=lambda m: rank.get(m, len(rank)))}


def pass_ids(external: bool = True) -> List[str]:
    """Every pass id a registered method writes, in producer order, then
    the external ones."""
    own = [pid for m in producers().values() for pid in m.passes]
    return own + (list(EXTERNAL_PASSES) if external else [])


def is_external(pass_id: str) -> bool:
    return pass_id in EXTERNAL_PASSES


def visibility_of(pass_id: str) -> str:
    if pass_id in EXTERNAL_PASSES:
        return EXTERNAL_PASSES[pass_id][0]
    return producer_of(pass_id).passes[pass_id]


def producer_of(pass_id: str) -> Method:
    _load()
    return _PRODUCERS[_PASS_TO_PRODUCER[pass_id]]

