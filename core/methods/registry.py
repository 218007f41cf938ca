"""Where method classes register themselves: ``@register`` instantiates the
class and records its pass ids. Imports no method module (the package
``__init__`` loads them), so registering makes no import circle."""
from __future__ import annotations

from typing import Dict

from .base import Method

_PRODUCERS: Dict[str, Method] = {}     # producer id -> instance
_PASS_TO_PRODUCER: Dict[str, str] = {} # pass id -> producer id


def register(cls):
    inst = cls()
    _PRODUCERS[inst.id] = inst
    for pid in inst.passes:
        _PASS_TO_PRODUCER[pid] = inst.id
    return cls
